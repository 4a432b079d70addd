"""FaultInjector FMU (FMI 2.0 co-simulation): 8 sensor channels with one fault each.

Timing: outputs are computed in ``do_step(t, h)`` from the inputs set for the step that
starts at ``t`` and the fault evaluated at sample time ``t``; they are published at
``t + h``.  So ``out_i(t_{k+1}) = F_i(in_i(t_k), t_k)``: one communication step of latency
(count it in detection delays, docs/methods.md §6.9).  Before the first step ``out_i(t_0)`` equals
the start value of ``in_i`` (no fault applied at initialisation).  Fault codes and
formulas: see ``gd_fault_injector_core``.  An idle channel is bit-exact.

Randomness: channel ``i`` (1..8) uses ``numpy.random.default_rng(seed + i - 1)``; same seed
gives the same run, and FMU get/set state also restores the generator states.
"""

from __future__ import annotations

import traceback
from typing import Any

from gd_fault_injector_core import REAL_PARAMETERS, FaultInjectorCore, FaultType
from gd_fmu_base import GuardedSlave
from pythonfmu import Boolean, Fmi2Causality, Fmi2Variability, Integer, Real
from pythonfmu.default_experiment import DefaultExperiment
from pythonfmu.enums import Fmi2Status

N_CHANNELS = 8
_FAULT_TABLE = ", ".join(f"{int(f)}={f.name}" for f in FaultType)

_PARAM_DOC = {
    "t_start": ("s", "fault window start (sample time t >= t_start)"),
    "t_end": ("s", "fault window end (t < t_end; STEP ignores it)"),
    "magnitude": ("1", "BIAS/STEP/INTERMITTENT offset, RAMP slope per second (signal unit)"),
    "gain": ("1", "GAIN factor"),
    "stuck_value": ("1", "STUCK_VALUE output (signal unit)"),
    "noise_std": ("1", "NOISE / SIGNAL_LOSS standard deviation (signal unit)"),
    "period": ("s", "INTERMITTENT period"),
    "duty": ("1", "INTERMITTENT on-fraction of the period"),
    "sat_min": ("1", "SATURATION lower limit (signal unit)"),
    "sat_max": ("1", "SATURATION upper limit (signal unit)"),
}
#: The injector does not know what it carries: signals and the values in their unit are
#: declared dimensionless ("1"); the descriptions say "signal unit".
SIGNAL_UNIT = "1"

VARIABLE_META: dict[str, dict] = {"seed": {"min": 0}}
for _i in range(1, N_CHANNELS + 1):
    VARIABLE_META[f"in_{_i}"] = {"unit": SIGNAL_UNIT}
    VARIABLE_META[f"out_{_i}"] = {"unit": SIGNAL_UNIT}
    VARIABLE_META[f"fault_type_{_i}"] = {"min": 0, "max": int(max(FaultType))}
    for _k, (_unit, _doc) in _PARAM_DOC.items():
        meta: dict[str, Any] = {}
        if _unit is not None:
            meta["unit"] = _unit
        if _k in ("noise_std", "period"):
            meta["min"] = 0.0
        if _k == "duty":
            meta.update(min=0.0, max=1.0)
        if meta:
            VARIABLE_META[f"{_k}_{_i}"] = meta

OUTPUT_DEPENDENCIES: dict[str, list[str]] = {}  # outputs computed in do_step
REQUIREMENTS = ["numpy>=1.24"]


def _jsonable(obj: Any) -> Any:
    """Nested numpy containers → plain lists/floats (pythonfmu serialises state as JSON)."""
    if isinstance(obj, dict):
        return {k: _jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_jsonable(v) for v in obj]
    if hasattr(obj, "tolist"):
        return obj.tolist()
    return obj


class FaultInjector(GuardedSlave):
    author = "gyrodiag"
    description = (
        f"{N_CHANNELS}-channel sensor fault injector. out_i(t+h) = F_i(in_i(t), t): one "
        f"communication step latency; idle channels bit-exact. fault_type codes: {_FAULT_TABLE}."
    )
    default_experiment = DefaultExperiment(start_time=0.0, stop_time=10.0, step_size=0.01)

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(**kwargs)
        self.seed = 0
        self.core = FaultInjectorCore(N_CHANNELS, seed=0)
        self._u = [0.0] * N_CHANNELS
        self._y = [0.0] * N_CHANNELS
        self._active = [False] * N_CHANNELS
        self.register_variable(Integer(
            "seed", causality=Fmi2Causality.parameter, variability=Fmi2Variability.fixed,
            description="base seed; channel i uses seed + i - 1"))
        for i in range(N_CHANNELS):
            self._register_channel(i)

    def _register_channel(self, i: int) -> None:
        n = i + 1
        core = self.core

        def set_u(v: float) -> None:
            self._u[i] = v

        def set_y(v: float) -> None:
            self._y[i] = v

        def set_active(v: bool) -> None:
            self._active[i] = bool(v)

        def set_type(v: int) -> None:
            core.fault_type[i] = int(v)

        self.register_variable(Real(
            f"in_{n}", causality=Fmi2Causality.input, variability=Fmi2Variability.continuous,
            start=0.0, description=f"channel {n} input signal (any unit)",
            getter=lambda: self._u[i], setter=set_u))
        self.register_variable(Real(
            f"out_{n}", causality=Fmi2Causality.output, variability=Fmi2Variability.discrete,
            description=f"channel {n} output: F(in_{n}(t), t) published at t + h (unit of "
                        f"in_{n})",
            getter=lambda: self._y[i], setter=set_y))
        self.register_variable(Boolean(
            f"fault_active_{n}", causality=Fmi2Causality.output,
            variability=Fmi2Variability.discrete,
            description=f"channel {n} fault altered the sample behind out_{n}",
            getter=lambda: self._active[i], setter=set_active))
        self.register_variable(Integer(
            f"fault_type_{n}", causality=Fmi2Causality.parameter,
            variability=Fmi2Variability.tunable,
            description=f"channel {n} fault code: {_FAULT_TABLE}",
            getter=lambda: int(core.fault_type[i]), setter=set_type))
        for key in REAL_PARAMETERS:
            self._register_real_parameter(i, key)

    def _register_real_parameter(self, i: int, key: str) -> None:
        def getter() -> float:
            return float(self.core.params[key][i])

        def setter(v: float) -> None:
            self.core.params[key][i] = v

        self.register_variable(Real(
            f"{key}_{i + 1}", causality=Fmi2Causality.parameter,
            variability=Fmi2Variability.tunable,
            description=f"channel {i + 1}: {_PARAM_DOC[key][1]}",
            getter=getter, setter=setter))

    # -- FMI callbacks ------------------------------------------------------------------

    def exit_initialization_mode(self) -> None:
        if not self.parameters_in_range(VARIABLE_META):
            return
        try:
            self.core.reset(seed=int(self.seed))
            for i in range(N_CHANNELS):
                self.core.check_channel(i)
            self._y = list(self._u)
            self._active = [False] * N_CHANNELS
        except Exception:
            self._fail("exit_initialization_mode")

    def do_step(self, current_time: float, step_size: float) -> bool:
        if not self.check_step(step_size):
            return True
        try:
            # time events within half a step: a master adding h each step is a few ulps
            # early at the event and must see it at the same step (docs/fmu.md)
            self._y, self._active = self.core.update(current_time, self._u,
                                                     t_tol=0.5 * step_size)
        except Exception:
            self._fail("do_step")
        return True

    def _fail(self, where: str) -> None:
        # pythonfmu 0.7 turns any Python exception into fmi2Fatal; instead log the
        # traceback at error status and return: the status shim in the FMU binary
        # (fmu_src/shim) turns the logged error into fmi2Error for this call.
        self.log(f"FaultInjector.{where} failed:\n{traceback.format_exc()}",
                 status=Fmi2Status.error)

    # -- FMU state: registered variables plus the core's latches and generators ---------

    def _state_payload(self) -> dict[str, Any]:
        state = super()._state_payload()
        state["__core__"] = _jsonable(self.core.get_state())
        return state

    def _apply_state_payload(self, state: dict[str, Any]) -> None:
        state = dict(state)
        core_state = state.pop("__core__")
        super()._apply_state_payload(state)
        self.core.set_state(core_state)
