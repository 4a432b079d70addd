"""Shared machinery of the gyrodiag pythonfmu facades (no algorithm in here).

A facade declares its variables in a table, keeps their values in one dict, and maps
them onto plain algorithm objects. This module supplies:

* ``FacadeBase``: variable registration with explicit getters/setters (names may contain
  dots and brackets, FMI "structured" naming), a logger helper that reports errors
  through the FMU logger instead of raising (pythonfmu 0.7 turns any exception into
  fmi2Fatal; the status shim built into our FMUs turns a logged error into fmi2Error),
  and full FMU state get/set/serialize through JSON-safe encoding of numpy arrays.
* ``encode`` / ``decode`` for numpy arrays, NaN and nested containers in JSON.

The module name is unique to this project (DESIGN §6.3): every FMU ships its own copy.
"""

from __future__ import annotations

import json
import math
import traceback
from collections.abc import Callable
from typing import Any

import numpy as np
from pythonfmu import Fmi2Causality, Fmi2Slave, Fmi2Variability
from pythonfmu.enums import Fmi2Status
from pythonfmu.variables import Boolean, Integer, Real, String

_KINDS = {"Real": Real, "Integer": Integer, "Boolean": Boolean, "String": String}
_CAUSALITY = {
    "parameter": Fmi2Causality.parameter,
    "input": Fmi2Causality.input,
    "output": Fmi2Causality.output,
    "local": Fmi2Causality.local,
}
_VARIABILITY = {
    "fixed": Fmi2Variability.fixed,
    "tunable": Fmi2Variability.tunable,
    "discrete": Fmi2Variability.discrete,
    "continuous": Fmi2Variability.continuous,
    "constant": Fmi2Variability.constant,
}


def encode(obj: Any) -> Any:
    """Make ``obj`` JSON-serialisable, preserving numpy arrays (dtype, shape) and tuples."""
    if isinstance(obj, np.ndarray):
        return {"__nd__": obj.ravel().tolist(), "dtype": str(obj.dtype), "shape": obj.shape}
    if isinstance(obj, dict):
        return {"__dict__": [[encode(k), encode(v)] for k, v in obj.items()]}
    if isinstance(obj, tuple):
        return {"__tuple__": [encode(v) for v in obj]}
    if isinstance(obj, list):
        return [encode(v) for v in obj]
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, float) and not math.isfinite(obj):
        return {"__float__": repr(obj)}
    return obj


def decode(obj: Any) -> Any:
    """Inverse of :func:`encode`."""
    if isinstance(obj, dict):
        if "__nd__" in obj:
            return np.array(obj["__nd__"], dtype=obj["dtype"]).reshape(obj["shape"])
        if "__dict__" in obj:
            return {decode(k): decode(v) for k, v in obj["__dict__"]}
        if "__tuple__" in obj:
            return tuple(decode(v) for v in obj["__tuple__"])
        if "__float__" in obj:
            return float(obj["__float__"])
        return {k: decode(v) for k, v in obj.items()}
    if isinstance(obj, list):
        return [decode(v) for v in obj]
    return obj


class FacadeBase(Fmi2Slave):
    """Fmi2Slave with table-driven variables, error logging and full state handling.

    Subclasses call :meth:`add_variable` in ``__init__`` and implement
    :meth:`_capture_state` / :meth:`_restore_state` for their algorithm objects.
    """

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(**kwargs)
        self.values: dict[str, Any] = {}
        self.kinds: dict[str, str] = {}
        self.causalities: dict[str, str] = {}

    # -- variables ------------------------------------------------------------
    def add_variable(
        self, name: str, kind: str, causality: str, start: Any, description: str,
        variability: str | None = None,
    ) -> None:
        """Register one variable whose value lives in ``self.values[name]``."""
        if variability is None:
            variability = {
                "parameter": "fixed", "input": "continuous" if kind == "Real" else "discrete",
                "output": "continuous" if kind == "Real" else "discrete",
                "local": "continuous" if kind == "Real" else "discrete",
            }[causality]
        self.values[name] = start
        self.kinds[name] = kind
        self.causalities[name] = causality
        values = self.values
        getter: Callable[[], Any] = lambda: values[name]  # noqa: E731
        setter: Callable[[Any], None] = lambda v: values.__setitem__(name, v)  # noqa: E731
        var = _KINDS[kind](
            name, causality=_CAUSALITY[causality], variability=_VARIABILITY[variability],
            description=description, getter=getter, setter=setter,
        )
        self.register_variable(var, nested=False)

    # -- error reporting ------------------------------------------------------
    def report_error(self, message: str) -> None:
        """Log an error; the status shim turns it into fmi2Error for this call."""
        self.log(message, Fmi2Status.error)

    def report_exception(self, where: str, exc: BaseException) -> None:
        """Log an unexpected exception with its traceback as an error."""
        tb = "".join(traceback.format_exception(type(exc), exc, exc.__traceback__))
        self.report_error(f"{self.instance_name}: {where} failed: {exc}\n{tb}")

    # -- FMU state (DESIGN §6.8: save everything, not only registered variables) -
    def _capture_state(self) -> dict[str, Any]:
        return {}

    def _restore_state(self, state: dict[str, Any]) -> None:
        del state

    def _get_fmu_state(self) -> dict[str, Any]:
        try:
            return {"values": encode(dict(self.values)), "internal": encode(self._capture_state())}
        except Exception as exc:  # never let an exception reach the bridge
            self.report_exception("fmi2GetFMUstate", exc)
            return {"values": encode(dict(self.values)), "internal": None}

    def _set_fmu_state(self, state: dict[str, Any]) -> None:
        try:
            values = decode(state["values"])
            internal = state.get("internal")
            if internal is None:
                self.report_error("fmi2SetFMUstate: the state holds no internal part")
                return
            self.values.update(values)
            self._restore_state(decode(internal))
        except Exception as exc:
            self.report_exception("fmi2SetFMUstate", exc)

    @staticmethod
    def _fmu_state_to_bytes(state: dict[str, Any]) -> bytes:
        return json.dumps(state).encode("utf-8")

    @staticmethod
    def _fmu_state_from_bytes(state: bytes) -> dict[str, Any]:
        return json.loads(state.decode("utf-8"))
