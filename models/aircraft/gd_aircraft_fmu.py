"""Aircraft FMU (FMI 2.0 co-simulation): seed-002 longitudinal dynamics, docs/methods.md §4.

Timing: ``do_step(t, h)`` integrates exactly (ZOH matrix exponential) with throttle and
elevator held at their values set for t; at t + h it publishes the true states x(t + h)
and the sensor outputs y(t + h) = C x(t + h) + noise (no direct feedthrough, D = 0).
Before the first step the outputs are C x0 + noise.  Model: ``gd_aircraft_core``.

Turbulence: ``turbulence_sigma_w`` > 0 (m/s, tunable) switches on Dryden gusts
(``gd_aircraft_turbulence``: vertical gust of scale length ``turbulence_scale_length``,
pitch-rate gust of span ``turbulence_wingspan``, airspeed 272.24 m/s) acting on the
air-relative α and q; the gust is drawn from a stream of ``seed`` separate from the
sensor noise and is published as ``gust_alpha``, ``gust_q``.
"""

from __future__ import annotations

import traceback
from typing import Any

import numpy as np
from gd_aircraft_core import INPUT_NAMES, OUTPUT_NAMES, STATE_NAMES, AircraftModel
from gd_aircraft_turbulence import DEFAULT_SCALE_LENGTH, DEFAULT_WINGSPAN, DrydenGust
from gd_fmu_base import GuardedSlave
from pythonfmu import Fmi2Causality, Fmi2Variability, Integer, Real
from pythonfmu.default_experiment import DefaultExperiment
from pythonfmu.enums import Fmi2Status

_UNITS = {"v": "m/s", "alpha": "rad", "q": "rad/s", "theta": "rad", "gamma": "rad", "h": "m"}
_DOC = {"v": "airspeed perturbation", "alpha": "angle of attack", "q": "pitch rate",
        "theta": "pitch angle", "gamma": "flight-path angle theta - alpha",
        "h": "altitude perturbation"}

VARIABLE_META: dict[str, dict] = {"throttle": {"unit": "1"}, "elevator": {"unit": "rad"},
                                  "seed": {"min": 0},
                                  "turbulence_sigma_w": {"unit": "m/s", "min": 0.0},
                                  "turbulence_scale_length": {"unit": "m", "min": 1e-3},
                                  "turbulence_wingspan": {"unit": "m", "min": 1e-3},
                                  "turbulence_start_s": {"unit": "s", "min": 0.0},
                                  "turbulence_stop_s": {"unit": "s", "min": 0.0},
                                  "gust_alpha": {"unit": "rad"},
                                  "gust_q": {"unit": "rad/s"}}
for _n in OUTPUT_NAMES:
    VARIABLE_META[f"y_{_n}"] = {"unit": _UNITS[_n]}
    VARIABLE_META[f"noise_std_{_n}"] = {"unit": _UNITS[_n], "min": 0.0}
for _n in STATE_NAMES:
    VARIABLE_META[f"x_{_n}"] = {"unit": _UNITS[_n]}
    VARIABLE_META[f"x0_{_n}"] = {"unit": _UNITS[_n]}
OUTPUT_DEPENDENCIES: dict[str, list[str]] = {}
REQUIREMENTS = ["numpy>=1.24", "scipy>=1.10"]


class Aircraft(GuardedSlave):
    author = "gyrodiag"
    description = (
        "Seed-002 longitudinal aircraft (Ma 0.8, H 50 m): x=[v, alpha, q, theta, h], "
        "u=[throttle, elevator]; exact ZOH integration; sensor outputs y = C x + seeded "
        "noise, y=[v, alpha, q, theta, gamma=theta-alpha, h]. Open loop unstable."
    )
    default_experiment = DefaultExperiment(start_time=0.0, stop_time=10.0, step_size=0.01)

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(**kwargs)
        self.model = AircraftModel()
        self._u = np.zeros(2)
        self._y = self.model.measure()
        self._x = self.model.x.copy()
        P, V = Fmi2Causality, Fmi2Variability
        m = self.model
        for j, name in enumerate(INPUT_NAMES):
            self.register_variable(Real(
                name, causality=P.input, variability=V.continuous, start=0.0,
                description=f"{name} command (held over the step)",
                getter=(lambda j=j: float(self._u[j])),
                setter=(lambda v, j=j: self._u.__setitem__(j, v))))
        for j, name in enumerate(OUTPUT_NAMES):
            self.register_variable(Real(
                f"y_{name}", causality=P.output, variability=V.discrete,
                description=f"sensor: {_DOC[name]} (with noise)",
                getter=(lambda j=j: float(self._y[j])),
                setter=(lambda v, j=j: self._y.__setitem__(j, v))))
        for j, name in enumerate(STATE_NAMES):
            self.register_variable(Real(
                f"x_{name}", causality=P.output, variability=V.continuous,
                description=f"true state: {_DOC[name]}",
                getter=(lambda j=j: float(self._x[j])),
                setter=(lambda v, j=j: self._x.__setitem__(j, v))))
        for j, name in enumerate(STATE_NAMES):
            self.register_variable(Real(
                f"x0_{name}", causality=P.parameter, variability=V.fixed,
                description=f"initial {_DOC[name]}",
                getter=(lambda j=j: float(m.x0[j])),
                setter=(lambda v, j=j: m.x0.__setitem__(j, v))))
        for j, name in enumerate(OUTPUT_NAMES):
            self.register_variable(Real(
                f"noise_std_{name}", causality=P.parameter, variability=V.tunable,
                description=f"sensor noise standard deviation of y_{name}",
                getter=(lambda j=j: float(m.noise_std[j])),
                setter=(lambda v, j=j: m.noise_std.__setitem__(j, v))))
        self.register_variable(Integer(
            "seed", causality=P.parameter, variability=V.fixed,
            description="seed of the sensor noise and (separate stream) the turbulence",
            getter=lambda: m.seed, setter=lambda v: setattr(m, "seed", int(v))))
        self.turbulence_sigma_w = 0.0
        self.turbulence_scale_length = DEFAULT_SCALE_LENGTH
        self.turbulence_wingspan = DEFAULT_WINGSPAN
        self._gust_out = np.zeros(2)
        self.register_variable(Real(
            "turbulence_sigma_w", causality=P.parameter, variability=V.tunable,
            description="Dryden vertical gust intensity sigma_w (0: no turbulence; "
                        "MIL-F-8785C low altitude: light 0.77, moderate 1.5, severe 2.3)"))
        self._t0 = 0.0
        self.turbulence_start_s = 0.0
        self.turbulence_stop_s = 1e300
        self.register_variable(Real(
            "turbulence_start_s", causality=P.parameter, variability=V.fixed,
            description="turbulence_sigma_w acts from this time on (entering turbulence); "
                        "before it the air is calm"))
        self.register_variable(Real(
            "turbulence_stop_s", causality=P.parameter, variability=V.fixed,
            description="calm air again from this time on (leaving turbulence; the gust "
                        "present decays with the Dryden filter's own dynamics)"))
        self.register_variable(Real(
            "turbulence_scale_length", causality=P.parameter, variability=V.fixed,
            description="Dryden vertical gust scale length L_w (MIL-F-8785C below 1000 ft: "
                        "the altitude, 50 m for the seed aircraft)"))
        self.register_variable(Real(
            "turbulence_wingspan", causality=P.parameter, variability=V.fixed,
            description="wing span b of the pitch-rate gust filter 4b/(pi V)"))
        for j, (name, doc) in enumerate([("gust_alpha", "gust angle of attack w_g/V"),
                                         ("gust_q", "gust pitch rate")]):
            self.register_variable(Real(
                name, causality=P.output, variability=V.continuous,
                description=f"turbulence: {doc} (0 without turbulence)",
                getter=(lambda j=j: float(self._gust_out[j])),
                setter=(lambda v, j=j: self._gust_out.__setitem__(j, v))))

        # the tunables are validated again only after one of them was set
        self.watched_vrs = frozenset(
            vr for vr, var in self.vars.items() if var.variability == V.tunable)

    def _gust(self, t: float, tol: float = 0.0) -> DrydenGust:
        # an onset within tol of t (half a step) counts as at t: events on the grid
        on = self.turbulence_start_s <= t + tol and t + tol < self.turbulence_stop_s
        return DrydenGust(self.turbulence_sigma_w if on else 0.0,
                          self.turbulence_scale_length, wingspan=self.turbulence_wingspan)

    def setup_experiment(self, start_time: float, stop_time: float | None = None,
                         tolerance: float | None = None) -> None:
        self._t0 = float(start_time)

    def exit_initialization_mode(self) -> None:
        if not self.parameters_in_range(VARIABLE_META):
            return
        try:
            if self.turbulence_stop_s < self.turbulence_start_s:
                raise ValueError(f"turbulence_stop_s ({self.turbulence_stop_s}) must be >= "
                                 f"turbulence_start_s ({self.turbulence_start_s})")
            self.model.gust = self._gust(self._t0)
            self.model.check()
            self.watched_changed = False
            self.model.reset()
            self._publish()
        except Exception:
            self._fail("exit_initialization_mode")

    def do_step(self, current_time: float, step_size: float) -> bool:
        if not self.check_step(step_size):
            return True
        try:
            gust = self._gust(current_time, 0.5 * step_size)
            if gust.sigma_w != self.model.gust.sigma_w:
                self.model.set_gust(gust)
            if self.watched_changed:
                self.model.check()
                self.watched_changed = False
            self.model.step(step_size, self._u)
            self._publish()
        except Exception:
            self._fail("do_step")
        return True

    def _publish(self) -> None:
        self._x = self.model.x.copy()
        self._y = self.model.measure()
        self._gust_out = self.model.gust_output

    def _fail(self, where: str) -> None:
        # pythonfmu 0.7 turns any Python exception into fmi2Fatal; instead log the
        # traceback at error status and return: the status shim in the FMU binary
        # (fmu_src/shim) turns the logged error into fmi2Error for this call.
        self.log(f"Aircraft.{where} failed:\n{traceback.format_exc()}", status=Fmi2Status.error)

    def _state_payload(self) -> dict[str, Any]:
        state = super()._state_payload()
        model_state = self.model.get_state()
        state["__model__"] = {**model_state, "x": model_state["x"].tolist(),
                              "g": model_state["g"].tolist()}
        return state

    def _apply_state_payload(self, state: dict[str, Any]) -> None:
        state = dict(state)
        model_state = state.pop("__model__")
        super()._apply_state_payload(state)
        self.model.set_state(model_state)
        self.watched_changed = True
