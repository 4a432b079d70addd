"""Shared machinery of the gyrodiag pythonfmu facades (no algorithm in here).

This module supplies:

* ``GuardedSlave``: the base of every gyrodiag FMU. Error reporting through the FMU
  logger instead of raising (pythonfmu 0.7 turns any exception into fmi2Fatal; the
  status shim built into our FMUs turns a logged error into fmi2Error), the
  communication-step checks, and FMU states that cannot kill the instance: a state is
  tagged with its model and format, a state of another model, an unreadable or
  ill-fitting one gives fmi2Error and leaves the instance exactly as it was
  (docs/methods.md §6.14; the shim also frames serialized states with the FMU's GUID and a
  checksum).
* ``FacadeBase``: a ``GuardedSlave`` with table-driven variables (names may contain dots
  and brackets, FMI "structured" naming), values in one dict, and full FMU state
  through JSON-safe encoding of numpy arrays.
* ``encode`` / ``decode`` for numpy arrays, NaN and nested containers in JSON.

The module name is unique to this project (docs/methods.md §6.3). build_fmu.py ships this file
with every FMU; all gyrodiag FMUs in one process share the copy imported first, so FMUs
of one process should come from one build.
"""

from __future__ import annotations

import functools
import json
import math
import operator
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


#: Tag of the FMU state layout written by :class:`GuardedSlave`.
STATE_FORMAT = "gyrodiag-fmu-state/1"
#: Relative tolerance on "the communication step is a whole number of sample periods".
STEP_RTOL = 1e-6


def samples_in_step(step_size: float, sample_period: float) -> int | None:
    """Number n >= 1 of sample periods in a communication step, None if it is no multiple.

    A step counts as ``n * sample_period`` when it differs from that by at most
    ``STEP_RTOL`` of the step (floating-point masters add or lose a few ulps per step).
    """
    if not (math.isfinite(step_size) and step_size > 0.0):
        return None
    n = round(step_size / sample_period)
    if n < 1 or abs(step_size - n * sample_period) > STEP_RTOL * step_size:
        return None
    return int(n)


def sample_instants(start: float, period: float, t: float, h: float) -> list[float]:
    """Sample instants ``start + k*period`` in the communication step [t, t + h).

    For steps that are not a whole number of periods: a step shorter than a period
    holds the outputs (no sample), a longer one takes every instant it spans. Instants
    within ``STEP_RTOL`` of a period from either end count as on the step's start.
    """
    k0 = math.ceil((t - start) / period - STEP_RTOL)
    k1 = math.ceil((t + h - start) / period - STEP_RTOL)
    return [start + k * period for k in range(k0, k1)]


class GuardedSlave(Fmi2Slave):
    """Fmi2Slave base of every gyrodiag FMU: errors as fmi2Error, guarded FMU states,
    outputs that are right in initialisation mode.

    Subclasses keep their algorithm state in :meth:`_state_payload` /
    :meth:`_apply_state_payload` (default: every registered variable through its getter
    and setter) and never override ``_get_fmu_state`` / ``_set_fmu_state``.

    Initialisation mode: FMI masters may read outputs before fmi2ExitInitializationMode
    (they are initial unknowns) and propagate them through the connections, as libcosim
    does. pythonfmu facades compute their initial outputs in
    ``exit_initialization_mode``, so an output read earlier would be a stale start value.
    Here, reading an output in initialisation mode after a parameter or input changed runs
    the subclass's ``exit_initialization_mode`` provisionally (its messages held back;
    the real call at the end of initialisation reports), so that every master sees the
    same initial outputs. Facades whose initialisation is costly and whose initial
    outputs depend on no input set :attr:`provisional_outputs` to False.
    """

    #: Compute outputs read in initialisation mode (see the class docstring).
    provisional_outputs: bool = True
    #: Between fmi2EnterInitializationMode and fmi2ExitInitializationMode.
    _in_initialisation: bool = False

    def __init_subclass__(cls, **kwargs: Any) -> None:
        super().__init_subclass__(**kwargs)
        own_exit = cls.__dict__.get("exit_initialization_mode")
        if own_exit is None or getattr(own_exit, "_gd_marks_end", False):
            return

        @functools.wraps(own_exit)
        def exit_initialization_mode(self: GuardedSlave, *args: Any, **kw: Any) -> Any:
            self._in_initialisation = False
            return own_exit(self, *args, **kw)

        exit_initialization_mode._gd_marks_end = True  # type: ignore[attr-defined]
        cls.exit_initialization_mode = exit_initialization_mode  # type: ignore[method-assign]

    def enter_initialization_mode(self) -> None:
        self._in_initialisation = True
        self._outputs_stale = True

    def _refresh_initial_outputs(self, vrs: list[int]) -> None:
        if not (getattr(self, "_in_initialisation", False) and self._outputs_stale
                and self.provisional_outputs):
            return
        if not any(self.vars[vr].causality == Fmi2Causality.output for vr in vrs):
            return
        self._outputs_stale = False
        provisional = getattr(type(self).exit_initialization_mode, "__wrapped__", None)
        if provisional is None:
            return
        refused = getattr(self, "_initialisation_refused", False)
        self.log = lambda *args, **kwargs: None  # type: ignore[method-assign]
        try:
            provisional(self)
        except Exception:  # reported by the real call at the end of initialisation
            pass
        finally:
            del self.log
            self._initialisation_refused = refused

    #: value references whose setting raises :attr:`watched_changed` (e.g. tunables)
    watched_vrs: frozenset[int] = frozenset()
    #: a watched variable may have changed since the subclass last cleared this
    watched_changed: bool = True

    def register_variable(self, var: Any, nested: bool = True) -> None:
        super().register_variable(var, nested)
        self.__dict__.pop("_accessor_cache", None)

    def _mark_inputs_changed(self, vrs: list[int] | None = None) -> None:
        if vrs is not None and self.watched_vrs and not self.watched_vrs.isdisjoint(vrs):
            self.watched_changed = True
        if self._in_initialisation:
            self._outputs_stale = True

    # Fast paths for variables registered by add_variable (value in self.values). A read
    # of a set of value references seen before is one C-level gather (an itemgetter over
    # the names, kept per set) and one C-level conversion; a reference not in the map
    # (another kind, or registered otherwise) takes pythonfmu's path for the whole call,
    # which keeps its errors.
    #: most value-reference sets whose gather is kept per type (hosts read a few sets)
    _GATHER_CACHE_SIZE = 256

    def _fast_get(self, kind: str, vrs: list[int], convert: Callable[[Any], Any]) -> Any:
        if getattr(self, "_vr_names", None) is None:
            return self._accessor_get(kind, vrs, convert)
        try:
            v = self.values
            if len(vrs) == 1:
                return [convert(v[self._vr_names[kind][vrs[0]]])]
            key = tuple(vrs)
            gathers = self._gathers[kind]
            gather = gathers.get(key)
            if gather is None:
                names = self._vr_names[kind]
                gather = operator.itemgetter(*[names[vr] for vr in key]) if key else None
                if len(gathers) >= self._GATHER_CACHE_SIZE:
                    gathers.clear()
                gathers[key] = gather
            return [] if gather is None else list(map(convert, gather(v)))
        except (KeyError, AttributeError):
            return self._accessor_get(kind, vrs, convert)

    def _fast_set(self, kind: str, vrs: list[int], values: list[Any]) -> bool:
        if getattr(self, "_vr_names", None) is not None:
            try:
                names = self._vr_names[kind]
                targets = [names[vr] for vr in vrs]
            except KeyError:
                pass
            else:
                self.values.update(zip(targets, values, strict=False))
                return True
        setters = self._accessors(kind, vrs, "setter")
        if setters is None:
            return False
        for setter, value in zip(setters, values, strict=False):
            setter(value)
        return True

    def _accessors(self, kind: str, vrs: list[int], which: str) -> tuple[Any, ...] | None:
        """The getters or setters of ``vrs`` (kept per set), None unless every one is a
        registered variable of ``kind`` with that accessor (then the slow path reports)."""
        cache = self.__dict__.get("_accessor_cache")
        if cache is None:
            cache = self.__dict__["_accessor_cache"] = {}
        key = (kind, which, tuple(vrs))
        found = cache.get(key)
        if found is None:
            cls, found_list = _KINDS[kind], []
            for vr in vrs:
                var = self.vars.get(vr)
                accessor = getattr(var, which, None)
                if type(var) is not cls or accessor is None:
                    return None
                found_list.append(accessor)
            if len(cache) >= self._GATHER_CACHE_SIZE:
                cache.clear()
            found = cache[key] = tuple(found_list)
        return found

    def _accessor_get(self, kind: str, vrs: list[int], convert: Callable[[Any], Any]) -> Any:
        getters = self._accessors(kind, vrs, "getter")
        return None if getters is None else [convert(g()) for g in getters]

    def _sync_outputs(self) -> None:
        """Bring outputs computed lazily up to date before they are read or saved
        (facades that defer their output copying override this)."""

    def _wrong_vrs(self, kind: str, vrs: list[int], call: str) -> bool:
        """True (with an error logged) if a value reference is unknown or of another type.

        The status shim refuses such calls before they reach Python (from the model
        description); this is the same check for a binary without the shim or without a
        readable model description: pythonfmu would raise, i.e. return fmi2Fatal and
        release the instance. Only the slow path (not every value in the fast map) runs it.
        """
        problems = []
        for i, vr in enumerate(vrs):
            var = self.vars.get(vr)
            if var is None:
                problems.append(f"unknown value reference {vr} (vr[{i}]): this FMU has no "
                                "such variable")
            elif not isinstance(var, _KINDS[kind]):
                real = type(var).__name__
                article = "an" if kind == "Integer" else "a"
                problems.append(f"value reference {vr} (vr[{i}]) is the {real} variable "
                                f"'{var.name}', not {article} {kind}: use {call[:7]}{real}")
        for problem in problems[:5]:
            self.report_error(f"{call}: {problem}; nothing was "
                              f"{'set' if call.startswith('fmi2Set') else 'read'}")
        return bool(problems)

    def _slow_get(self, kind: str, vrs: list[int], default: Any) -> list[Any]:
        if self._wrong_vrs(kind, vrs, f"fmi2Get{kind}"):
            return [default] * len(vrs)
        return getattr(super(), f"get_{kind.lower()}")(vrs)

    def get_real(self, vrs: list[int]) -> list[float]:
        if self._in_initialisation:
            self._refresh_initial_outputs(vrs)
        self._sync_outputs()
        fast = self._fast_get("Real", vrs, float)
        return self._slow_get("Real", vrs, 0.0) if fast is None else fast

    def get_integer(self, vrs: list[int]) -> list[int]:
        if self._in_initialisation:
            self._refresh_initial_outputs(vrs)
        self._sync_outputs()
        fast = self._fast_get("Integer", vrs, int)
        return self._slow_get("Integer", vrs, 0) if fast is None else fast

    def get_boolean(self, vrs: list[int]) -> list[bool]:
        if self._in_initialisation:
            self._refresh_initial_outputs(vrs)
        self._sync_outputs()
        fast = self._fast_get("Boolean", vrs, bool)
        return self._slow_get("Boolean", vrs, False) if fast is None else fast

    def set_real(self, vrs: list[int], values: list[float]) -> None:
        if not self._fast_set("Real", vrs, values):
            if self._wrong_vrs("Real", vrs, "fmi2SetReal"):
                return
            super().set_real(vrs, values)
        self._mark_inputs_changed(vrs)

    def set_integer(self, vrs: list[int], values: list[int]) -> None:
        if not self._fast_set("Integer", vrs, values):
            if self._wrong_vrs("Integer", vrs, "fmi2SetInteger"):
                return
            super().set_integer(vrs, values)
        self._mark_inputs_changed(vrs)

    def set_boolean(self, vrs: list[int], values: list[bool]) -> None:
        if not self._fast_set("Boolean", vrs, values):
            if self._wrong_vrs("Boolean", vrs, "fmi2SetBoolean"):
                return
            super().set_boolean(vrs, values)
        self._mark_inputs_changed(vrs)

    def get_string(self, vrs: list[int]) -> list[str]:
        self._sync_outputs()
        return self._slow_get("String", vrs, "")

    def set_string(self, vrs: list[int], values: list[str]) -> None:
        if self._wrong_vrs("String", vrs, "fmi2SetString"):
            return
        super().set_string(vrs, values)
        self._mark_inputs_changed(vrs)

    # -- error reporting ------------------------------------------------------
    def report_error(self, message: str) -> None:
        """Log an error; the status shim turns it into fmi2Error for this call."""
        self.log(message, Fmi2Status.error)

    def report_warning(self, message: str) -> None:
        """Log a warning; the status shim turns it into fmi2Warning for this call."""
        self.log(message, Fmi2Status.warning)

    def report_exception(self, where: str, exc: BaseException) -> None:
        """Log an unexpected exception with its traceback as an error."""
        tb = "".join(traceback.format_exception(type(exc), exc, exc.__traceback__))
        self.report_error(f"{self.instance_name}: {where} failed: {exc}\n{tb}")

    def check_step(self, step_size: float) -> bool:
        """False (with an error logged) unless ``step_size`` is finite and > 0 and the
        initialisation was not refused."""
        if getattr(self, "_initialisation_refused", False):
            self.report_error(f"{self.instance_name}: fmi2DoStep: initialisation did not "
                              "succeed (see the earlier error); fix the parameters and "
                              "re-instantiate or reset")
            return False
        if math.isfinite(step_size) and step_size > 0.0:
            return True
        self.report_error(f"{self.instance_name}: fmi2DoStep: communication step "
                          f"{step_size!r} s must be finite and > 0; the step was not taken")
        return False

    def parameters_in_range(self, meta: dict[str, dict[str, Any]], names: Any = None,
                            call: str = "fmi2ExitInitializationMode") -> bool:
        """False (with an error naming each parameter and its range) if a parameter is
        outside its declared [min, max]; see :meth:`range_errors`."""
        errors = self.range_errors(meta, names)
        if call == "fmi2ExitInitializationMode":
            self._initialisation_refused = bool(errors)
        if errors:
            self.report_error(f"{self.instance_name}: {call}: invalid parameter: "
                              + "; ".join(errors))
            return False
        return True

    def range_errors(self, meta: dict[str, dict[str, Any]],
                     names: Any = None) -> list[str]:
        """Messages for parameters outside their declared [min, max] (``meta`` is the
        script's VARIABLE_META); only ``names`` if given, else every parameter."""
        errors = []
        for var in self.vars.values():
            if names is not None and var.name not in names:
                continue
            if var.causality != Fmi2Causality.parameter or var.name not in meta:
                continue
            lo, hi = meta[var.name].get("min"), meta[var.name].get("max")
            if lo is None and hi is None:
                continue
            value = var.getter()
            if isinstance(value, bool) or not isinstance(value, (int, float)):
                continue
            if not math.isfinite(value) or (lo is not None and value < lo) or (
                    hi is not None and value > hi):
                bounds = f"[{'-inf' if lo is None else lo}, {'inf' if hi is None else hi}]"
                errors.append(f"{var.name} = {value!r} is outside its range {bounds}")
        return errors

    # -- FMU state (docs/methods.md §6.8, §6.14) ---------------------------------------
    def _state_payload(self) -> dict[str, Any]:
        """Everything the instance needs to resume (JSON-serialisable)."""
        return {var.name: var.getter() for var in self.vars.values()}

    def _apply_state_payload(self, payload: dict[str, Any]) -> None:
        """Restore :meth:`_state_payload`; raise ValueError if it does not fit."""
        by_name = {v.name: v for v in self.vars.values()}
        unknown = sorted(set(payload) - set(by_name))
        missing = sorted(set(by_name) - set(payload))
        if unknown or missing:
            raise ValueError(f"its variables differ from this FMU's (unknown: "
                             f"{unknown[:5]}, missing: {missing[:5]})")
        for name, value in payload.items():
            if by_name[name].setter is not None:
                by_name[name].setter(value)
        self.watched_changed = True

    def _get_fmu_state(self) -> dict[str, Any]:
        try:
            return {"format": STATE_FORMAT, "model": type(self).__name__,
                    "payload": self._state_payload()}
        except Exception as exc:  # never let an exception reach the bridge
            self.report_exception("fmi2GetFMUstate", exc)
            return {"invalid": f"fmi2GetFMUstate of {self.instance_name} failed: {exc}"}

    def _set_fmu_state(self, state: Any) -> None:
        where = f"{self.instance_name}: fmi2SetFMUstate"
        problem = _state_problem(state, type(self).__name__)
        if problem:
            self.report_error(f"{where}: {problem}; the instance is unchanged")
            return
        try:
            backup = self._state_payload()
        except Exception as exc:
            self.report_exception("fmi2SetFMUstate (saving the current state)", exc)
            return
        try:
            self._apply_state_payload(state["payload"])
        except Exception as exc:
            try:
                self._apply_state_payload(backup)
            except Exception as exc_back:
                self.report_exception("fmi2SetFMUstate (going back to the previous state)",
                                      exc_back)
                return
            self.report_error(f"{where}: the state does not fit this instance "
                              f"({type(exc).__name__}: {exc}); the instance is unchanged")

    @staticmethod
    def _fmu_state_to_bytes(state: Any) -> bytes:
        try:
            return json.dumps(state).encode("utf-8")
        except (TypeError, ValueError) as exc:  # reported when the bytes are used
            return json.dumps({"invalid": f"the state could not be serialised: {exc}"}).encode()

    @staticmethod
    def _fmu_state_from_bytes(state: bytes) -> Any:
        # Called on the class (no instance to log through): an unreadable state becomes
        # a marker that fmi2SetFMUstate reports as fmi2Error.
        try:
            return json.loads(bytes(state).decode("utf-8"))
        except (UnicodeDecodeError, ValueError) as exc:
            return {"invalid": f"serialized state of {len(state)} bytes is truncated or "
                               f"corrupt ({type(exc).__name__}: {exc})"}


def _state_problem(state: Any, model: str) -> str | None:
    """Why ``state`` is no state of ``model`` (None if it is one)."""
    if not isinstance(state, dict):
        return f"foreign FMU state (a {type(state).__name__}, not a gyrodiag state)"
    if "invalid" in state:
        return str(state["invalid"])
    if state.get("format") != STATE_FORMAT:
        return (f"foreign FMU state (format {state.get('format')!r}, this FMU reads "
                f"{STATE_FORMAT!r})")
    if state.get("model") != model:
        return f"foreign FMU state: made by model {state.get('model')!r}, this is {model!r}"
    if not isinstance(state.get("payload"), dict):
        return "corrupt FMU state: no payload"
    return None


class FacadeBase(GuardedSlave):
    """GuardedSlave with table-driven variables and full state handling.

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
            # outputs of a sampled-data facade change only at communication points
            variability = {
                "parameter": "fixed", "input": "continuous" if kind == "Real" else "discrete",
                "output": "discrete",
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
        if not hasattr(self, "_vr_names"):
            self._vr_names: dict[str, dict[int, str]] = {}
            self._gathers: dict[str, dict[tuple[int, ...], Any]] = {}
        self._vr_names.setdefault(kind, {})[var.value_reference] = name
        self._gathers.setdefault(kind, {}).clear()

    # -- FMU state (docs/methods.md §6.8: save everything, not only registered variables) -
    def _capture_state(self) -> dict[str, Any]:
        return {}

    def _restore_state(self, state: dict[str, Any]) -> None:
        del state

    def _state_payload(self) -> dict[str, Any]:
        self._sync_outputs()
        return {"values": encode(dict(self.values)), "internal": encode(self._capture_state())}

    def _apply_state_payload(self, payload: dict[str, Any]) -> None:
        values = decode(payload["values"])
        if not isinstance(values, dict) or set(values) != set(self.values):
            names = set(values) if isinstance(values, dict) else set()
            raise ValueError(
                f"its variables differ from this FMU's (unknown: "
                f"{sorted(names - set(self.values))[:5]}, missing: "
                f"{sorted(set(self.values) - names)[:5]})")
        internal = decode(payload["internal"])
        self.values.update(values)
        self._restore_state(internal)
