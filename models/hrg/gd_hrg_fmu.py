"""HRG FMU (FMI 2.0 co-simulation): gyro output voltage from a rate profile.

Timing: ``do_step(t, h)`` advances the read-out filter with ω held at ω(t) = profile(t) +
rate_in(t); ``voltage`` published at t + h is the filter state plus a fresh noise draw,
``rate_true`` is profile(t + h) + rate_in.  Model and profiles: see ``gd_hrg_core``.
"""

from __future__ import annotations

import traceback
from typing import Any

from gd_fmu_base import GuardedSlave
from gd_hrg_core import PROFILES, HRGModel
from pythonfmu import Fmi2Causality, Fmi2Variability, Integer, Real
from pythonfmu.default_experiment import DefaultExperiment
from pythonfmu.enums import Fmi2Status

VARIABLE_META: dict[str, dict] = {
    "rate_in": {"unit": "rad/s"},
    "voltage": {"unit": "V"},
    "rate_true": {"unit": "rad/s"},
    "profile": {"min": min(PROFILES), "max": max(PROFILES)},
    "scale_factor": {"unit": "V/(rad/s)"},
    "bias": {"unit": "V"},
    "bandwidth_hz": {"unit": "Hz"},
    "noise_std": {"unit": "V", "min": 0.0},
    "seed": {"min": 0},
    "rate_const": {"unit": "rad/s"},
}
OUTPUT_DEPENDENCIES: dict[str, list[str]] = {}
REQUIREMENTS = ["numpy>=1.24"]


class HRG(GuardedSlave):
    author = "gyrodiag"
    description = (
        "HRG output model: voltage = first-order filter (exact ZOH discretisation) of "
        "scale_factor*rate + bias, plus seeded white noise. rate = profile(t) + rate_in; "
        "profile 0 none, 1 seed-001 timeline (flat from 825 s), 2 constant rate_const."
    )
    default_experiment = DefaultExperiment(start_time=0.0, stop_time=1000.0, step_size=0.1)

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(**kwargs)
        self.model = HRGModel()
        self._t0 = 0.0
        self.rate_in = 0.0
        self.voltage = self.model.measure()
        self.rate_true = self.model.rate(0.0, 0.0)
        m = self.model
        P, C = Fmi2Causality, Fmi2Variability
        self.register_variable(Real("rate_in", causality=P.input, variability=C.continuous,
                                    start=0.0,
                                    description="external angular rate added to the profile"))
        self.register_variable(Real("voltage", causality=P.output, variability=C.discrete,
                                    description="gyro output voltage"))
        self.register_variable(Real("rate_true", causality=P.output, variability=C.continuous,
                                    description="true angular rate profile(t) + rate_in"))
        for name, var_type, variability, doc in [
            ("profile", Integer, C.fixed, "rate profile: 0 none, 1 seed-001 timeline, 2 constant"),
            ("scale_factor", Real, C.tunable, "scale factor"),
            ("bias", Real, C.tunable, "output bias"),
            ("bandwidth_hz", Real, C.fixed, "read-out bandwidth (<= 0: no filter)"),
            ("noise_std", Real, C.tunable, "output white-noise standard deviation"),
            ("seed", Integer, C.fixed, "noise generator seed"),
            ("rate_const", Real, C.tunable, "rate of profile 2"),
        ]:
            self.register_variable(var_type(
                name, causality=P.parameter, variability=variability, description=doc,
                getter=(lambda n=name: getattr(m, n)),
                setter=(lambda v, n=name: setattr(m, n, v))))

    def exit_initialization_mode(self) -> None:
        if not self.parameters_in_range(VARIABLE_META):
            return
        try:
            self.model.check()
            self.model.reset(self._t0, self.rate_in)
            self.voltage = self.model.measure()
            self.rate_true = self.model.rate(self._t0, self.rate_in)
        except Exception:
            self._fail("exit_initialization_mode")

    def setup_experiment(self, start_time: float, stop_time: float | None = None,
                         tolerance: float | None = None) -> None:
        self._t0 = float(start_time)

    def do_step(self, current_time: float, step_size: float) -> bool:
        if not self.check_step(step_size):
            return True
        try:
            self.model.step(current_time, step_size, self.rate_in)
            self.voltage = self.model.measure()
            self.rate_true = self.model.rate(current_time + step_size, self.rate_in)
        except Exception:
            self._fail("do_step")
        return True

    def _fail(self, where: str) -> None:
        # pythonfmu 0.7 turns any Python exception into fmi2Fatal; instead log the
        # traceback at error status and return: the status shim in the FMU binary
        # (fmu_src/shim) turns the logged error into fmi2Error for this call.
        self.log(f"HRG.{where} failed:\n{traceback.format_exc()}", status=Fmi2Status.error)

    def _state_payload(self) -> dict[str, Any]:
        state = super()._state_payload()
        state["__model__"] = self.model.get_state()
        return state

    def _apply_state_payload(self, state: dict[str, Any]) -> None:
        state = dict(state)
        model_state = state.pop("__model__")
        super()._apply_state_payload(state)
        self.model.set_state(model_state)
