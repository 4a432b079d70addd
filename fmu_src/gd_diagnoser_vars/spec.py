"""The declaration record of one Diagnoser variable and the generic adapter.

Every variable of the Diagnoser FMU is one :class:`Var`: the facade declares it from
there, ``VARIABLE_META`` (units, ranges; build_fmu.py and the range checks) is computed
from there, and :func:`config_fields` turns the values of the variables that name a
``field`` into keyword arguments of the library's configuration objects.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass
from typing import Any

import numpy as np

#: Lower bound declared for parameters that must be > 0 (FMI bounds are inclusive).
POSITIVE = 1e-9
#: Value of a Real (AUTO) or Integer (AUTO_INT) parameter that takes its automatic value.
AUTO = -1.0
AUTO_INT = -1
#: Conversions of :attr:`Var.to` for a single value (families use "array" or "list").
SCALAR_CONVERSIONS = ("", "auto", "zero_none", "negative_none")


@dataclass(frozen=True, slots=True)
class Var:
    """One FMU variable: its declaration, unit and range, and the config field it fills.

    ``field`` is ``"target.argument"``: :func:`config_fields` of ``target`` passes the
    converted value as ``argument``. ``to`` converts it after the conversion by kind
    (Real float, Integer checked int, Boolean bool, String str): "auto" gives None for
    AUTO, "zero_none" None for 0, "negative_none" None below 0. Members of an indexed
    family share one ``field`` and carry their 1-based ``index``; ``to`` is then "array"
    (a numpy array of the family's shape) or "list".
    """

    name: str
    kind: str  # Real, Integer, Boolean, String
    causality: str  # parameter, input, output
    start: Any
    description: str
    unit: str | None = None
    lo: float | None = None
    hi: float | None = None
    tunable: bool = False
    field: str | None = None
    to: str = ""
    index: tuple[int, ...] = ()

    @property
    def meta(self) -> dict[str, Any]:
        """This variable's VARIABLE_META entry (empty when it has no unit or range)."""
        entry: dict[str, Any] = {}
        if self.unit is not None:
            entry["unit"] = self.unit
        if self.lo is not None:
            entry["min"] = self.lo
        if self.hi is not None:
            entry["max"] = self.hi
        return entry


def par(name: str, kind: str, start: Any, description: str, unit: str | None = None,
        lo: float | None = None, hi: float | None = None, **extra: Any) -> Var:
    """A parameter."""
    return Var(name, kind, "parameter", start, description, unit, lo, hi, **extra)


def inp(name: str, kind: str, start: Any, description: str, unit: str | None = None) -> Var:
    """An input."""
    return Var(name, kind, "input", start, description, unit)


def out(name: str, kind: str, start: Any, description: str, unit: str | None = None,
        lo: float | None = None) -> Var:
    """An output."""
    return Var(name, kind, "output", start, description, unit, lo)


def variable_meta(variables: Iterable[Var]) -> dict[str, dict[str, Any]]:
    """VARIABLE_META of build_fmu.py: name -> unit/min/max, for variables that have one."""
    return {v.name: v.meta for v in variables if v.meta}


def named_int(values: dict[str, Any], name: str) -> int:
    """The Integer value of ``name``, refused if it is a bool or not a whole number."""
    value = values[name]
    if isinstance(value, bool) or int(value) != value:
        raise ValueError(f"{name} must be an integer, got {value!r}")
    return int(value)


def _convert(var: Var, values: dict[str, Any]) -> Any:
    """The value of ``var`` as its config field takes it (by kind, then ``to``)."""
    if var.kind == "Integer":
        value: Any = named_int(values, var.name)
    else:
        value = {"Real": float, "Boolean": bool, "String": str}[var.kind](values[var.name])
    if var.to == "auto":
        return None if value == AUTO else value
    if var.to == "zero_none":
        return None if value == 0.0 else value
    if var.to == "negative_none":
        return None if value < 0 else value
    return value


def config_fields(variables: Iterable[Var], values: dict[str, Any],
                  target: str) -> dict[str, Any]:
    """Keyword arguments of ``target`` from the variables whose field names it, in
    declaration order; an indexed family becomes one array or list."""
    kwargs: dict[str, Any] = {}
    families: dict[str, tuple[Var, dict[tuple[int, ...], Any]]] = {}
    for var in variables:
        if var.field is None:
            continue
        group, _, argument = var.field.partition(".")
        if group != target:
            continue
        if not var.index:
            kwargs[argument] = _convert(var, values)
            continue
        kwargs.setdefault(argument, None)  # keeps the declaration order
        families.setdefault(argument, (var, {}))[1][var.index] = _convert(var, values)
    for argument, (first, cells) in families.items():
        shape = tuple(max(i[d] for i in cells) for d in range(len(first.index)))
        flat = [cells[tuple(k + 1 for k in i)] for i in np.ndindex(*shape)]  # row-major
        if first.to == "array":
            kwargs[argument] = np.array(flat).reshape(shape)
        else:
            kwargs[argument] = flat
    return kwargs
