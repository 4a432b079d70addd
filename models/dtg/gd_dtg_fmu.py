"""DTG FMU (FMI 2.0 co-simulation): two-axis dynamically tuned gyro with rebalance loop.

Rotor, pick-offs, torquers and the digital rebalance loop are in ``gd_dtg_core`` and
``gd_dtg_sim``; the two parameter sets (1 = paper, 2 = production) in ``gd_dtg_sets``
and README.md. Timing: ``do_step(t, h)`` holds the inputs (case rates, external torquer
voltages) over [t, t + h), integrates the rotor exactly between the controller ticks the
step contains (sub-stepping when h exceeds the controller sample time) and publishes at
t + h the pick-off voltages (with the noise of the last tick), the torquer voltages
averaged over the step and the rate read-outs ωy = Ku·Ux/L, ωx = −Ku·Uy/L (nominal Ku,
L). Case rates are piecewise constant; a change of ω between steps is an impulse of
angular acceleration, handled exactly (the rotor's inertial rates are states).
"""

from __future__ import annotations

import math
import traceback
from typing import Any

from gd_dtg_sets import PAPER, PARAMETER_SETS, parameter_set
from gd_dtg_sim import NOMINAL_FAULTS, DTGSimulator
from gd_fmu_base import GuardedSlave
from pythonfmu import Boolean, Fmi2Causality, Fmi2Variability, Integer, Real
from pythonfmu.default_experiment import DefaultExperiment
from pythonfmu.enums import Fmi2Status

#: Lower bound declared for parameters that must be > 0 (FMI bounds are inclusive).
POSITIVE = 1e-9
VARIABLE_META: dict[str, dict] = {
    "omega_x": {"unit": "rad/s"},
    "omega_y": {"unit": "rad/s"},
    "Ux_in": {"unit": "V"},
    "Uy_in": {"unit": "V"},
    "Utx": {"unit": "V"},
    "Uty": {"unit": "V"},
    "Ux": {"unit": "V"},
    "Uy": {"unit": "V"},
    "omega_x_read": {"unit": "rad/s"},
    "omega_y_read": {"unit": "rad/s"},
    "parameter_set": {"min": min(PARAMETER_SETS), "max": max(PARAMETER_SETS)},
    "seed": {"min": 0},
    "noise_std": {"unit": "V", "min": 0.0},
    "dither_std": {"unit": "V", "min": 0.0},
    "spin_fraction": {"unit": "1", "min": POSITIVE},
    "k_offset": {"unit": "N.m/rad"},
    "damping_scale": {"unit": "1", "min": POSITIVE},
    "torquer_scale": {"unit": "1", "min": POSITIVE},
    "pickoff_scale": {"unit": "1", "min": POSITIVE},
}
OUTPUT_DEPENDENCIES: dict[str, list[str]] = {}
REQUIREMENTS = ["numpy>=1.24"]

_INPUTS = ("omega_x", "omega_y", "Ux_in", "Uy_in")
_TUNABLES = ("noise_std", "dither_std", *NOMINAL_FAULTS)
_OUTPUTS = ("Utx", "Uty", "Ux", "Uy", "omega_x_read", "omega_y_read")
_FAULT_DOC = {
    "spin_fraction": "spin rate / nominal (scales L and λ, changes k through the dynamic "
                     "spring)",
    "k_offset": "detuning added to the residual spring k",
    "damping_scale": "flexure damping c / nominal (also inside λ = (c + D)Ω)",
    "torquer_scale": "torquer gain Ku / nominal",
    "pickoff_scale": "pick-off scale KT / nominal",
}


class DTG(GuardedSlave):
    author = "gyrodiag"
    description = (
        "Two-axis dynamically tuned gyro rotor (docs/methods.md §2) with case-rate inputs, seeded "
        "pick-off noise, torquers and a digital rebalance loop (switchable), exact "
        "matrix-exponential integration; physical faults as tunable parameters. "
        "parameter_set 1: rotor reproducing the paper's identified θ at 1 kHz; "
        "2: production-like tuned DTG (≈300 Hz nutation, 10 kHz loop)."
    )
    default_experiment = DefaultExperiment(start_time=0.0, stop_time=10.0, step_size=1e-3)

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(**kwargs)
        self._t0 = 0.0
        self.sim: DTGSimulator | None = None
        self.parameter_set = PAPER
        self.rebalance_on = True
        self.seed = 0
        self.noise_std = 1.0e-3
        self.dither_std = 0.0
        for name, value in NOMINAL_FAULTS.items():
            setattr(self, name, value)
        for name in _INPUTS + _OUTPUTS:
            setattr(self, name, 0.0)

        P, V = Fmi2Causality, Fmi2Variability
        docs_in = {
            "omega_x": "case angular rate about x",
            "omega_y": "case angular rate about y",
            "Ux_in": "x torquer voltage with the loop off; additive test voltage with it on",
            "Uy_in": "y torquer voltage with the loop off; additive test voltage with it on",
        }
        for name in _INPUTS:
            self.register_variable(Real(name, causality=P.input, variability=V.continuous,
                                        start=0.0, description=docs_in[name]))
        docs_out = {
            "Utx": "x pick-off voltage α/KT + noise",
            "Uty": "y pick-off voltage β/KT + noise",
            "Ux": "x torquer voltage, mean over the last communication step",
            "Uy": "y torquer voltage, mean over the last communication step",
            "omega_x_read": "rate read-out −Ku·Uy/L (nominal Ku, L)",
            "omega_y_read": "rate read-out Ku·Ux/L (nominal Ku, L)",
        }
        for name in _OUTPUTS:
            self.register_variable(Real(name, causality=P.output, variability=V.discrete,
                                        description=docs_out[name]))
        self.register_variable(Integer(
            "parameter_set", causality=P.parameter, variability=V.fixed,
            description="1 = paper (reproduces the paper's θ pattern), 2 = production"))
        self.register_variable(Boolean(
            "rebalance_on", causality=P.parameter, variability=V.fixed,
            description="true: internal rebalance loop drives Ux, Uy; false: Ux_in, Uy_in do"))
        self.register_variable(Integer(
            "seed", causality=P.parameter, variability=V.fixed,
            description="seed of the pick-off noise and torquer dither generators"))
        self.register_variable(Real(
            "noise_std", causality=P.parameter, variability=V.tunable,
            description="pick-off noise standard deviation per controller tick"))
        self.register_variable(Real(
            "dither_std", causality=P.parameter, variability=V.tunable,
            description="white torquer dither standard deviation per controller tick "
                        "(closed-loop identification excitation)"))
        for name, doc in _FAULT_DOC.items():
            self.register_variable(Real(name, causality=P.parameter, variability=V.tunable,
                                        description=doc))
        # every variable is a plain attribute: get/set read and write them by name
        self._names_by_kind: dict[str, dict[int, str]] = {}
        for vr, var in self.vars.items():
            kind = type(var).__name__
            self._names_by_kind.setdefault(kind, {})[vr] = var.local_name
        # the tunables reach the simulator only after one of them was set
        self.watched_vrs = frozenset(
            vr for vr, var in self.vars.items() if var.name in _TUNABLES)

    # ------------------------------------------------------------------ FMI calls
    def setup_experiment(self, start_time: float, stop_time: float | None = None,
                         tolerance: float | None = None) -> None:
        self._t0 = float(start_time)

    def exit_initialization_mode(self) -> None:
        if not self.parameters_in_range(VARIABLE_META):
            self.sim = None
            return
        try:
            if not isinstance(self.seed, int) or isinstance(self.seed, bool) or self.seed < 0:
                raise ValueError(f"seed must be an integer >= 0, got {self.seed!r}")
            self.sim = DTGSimulator(parameter_set(self.parameter_set),
                                    rebalance=bool(self.rebalance_on), seed=self.seed)
            self._apply_tunables()
            self.watched_changed = False
            self.sim.reset(self._t0, self.omega_x, self.omega_y, self.Ux_in, self.Uy_in)
            self._publish()
        except Exception:
            self.sim = None
            self._fail("exit_initialization_mode")

    def do_step(self, current_time: float, step_size: float) -> bool:
        if not self.check_step(step_size):
            return True
        try:
            if self.sim is None:
                raise RuntimeError("not initialised (exit_initialization_mode failed)")
            t_sim = self.sim.time
            # within half a step, as every time comparison of the FMUs: a master that
            # adds h each step drifts by ulps from the model's own time (docs/fmu.md)
            if abs(current_time - t_sim) > 0.5 * step_size:
                raise ValueError(f"current_time {current_time!r} differs from the model "
                                 f"time {t_sim!r}")
            if not (step_size > 0.0 and math.isfinite(step_size)):
                raise ValueError(f"step_size must be > 0, got {step_size!r}")
            if self.watched_changed:
                self._apply_tunables()
                self.watched_changed = False
            self.sim.advance(t_sim + step_size, self.omega_x, self.omega_y,
                             self.Ux_in, self.Uy_in)
            self._publish()
        except Exception:
            self._fail("do_step")
        return True

    # ------------------------------------------------------------------- helpers
    def _fast_get(self, kind: str, vrs: list[int], convert: Any) -> Any:
        # GuardedSlave's get_* call this first; a reference of another kind (KeyError)
        # takes pythonfmu's path, which reports it
        try:
            names = self._names_by_kind[kind]
            attrs = self.__dict__
            return [convert(attrs[names[vr]]) for vr in vrs]
        except KeyError:
            return None

    def _fast_set(self, kind: str, vrs: list[int], values: list[Any]) -> bool:
        try:
            names = self._names_by_kind[kind]
            targets = [names[vr] for vr in vrs]
        except KeyError:
            return False
        attrs = self.__dict__
        for name, value in zip(targets, values, strict=False):
            attrs[name] = value
        return True

    def _apply_tunables(self) -> None:
        assert self.sim is not None
        self.sim.noise_std = self.noise_std
        self.sim.dither_std = self.dither_std
        self.sim.set_faults(**{name: getattr(self, name) for name in NOMINAL_FAULTS})

    def _publish(self) -> None:
        assert self.sim is not None
        self.Utx, self.Uty = self.sim.pickoff
        self.Ux, self.Uy = self.sim.torquer_mean
        self.omega_x_read, self.omega_y_read = self.sim.rate_readout

    def _fail(self, where: str) -> None:
        # pythonfmu 0.7 turns any Python exception into fmi2Fatal; log the traceback at
        # error status instead and return: the status shim in the FMU binary
        # (fmu_src/shim) turns the logged error into fmi2Error for this call.
        self.log(f"DTG.{where} failed:\n{traceback.format_exc()}", status=Fmi2Status.error)

    def _state_payload(self) -> dict[str, Any]:
        state = super()._state_payload()
        state["__t0__"] = self._t0
        state["__sim__"] = None if self.sim is None else self.sim.get_state()
        return state

    def _apply_state_payload(self, state: dict[str, Any]) -> None:
        state = dict(state)
        sim_state = state.pop("__sim__")
        self._t0 = float(state.pop("__t0__"))
        super()._apply_state_payload(state)
        if sim_state is None:
            self.sim = None
            return
        if self.sim is None:
            self.sim = DTGSimulator(parameter_set(self.parameter_set),
                                    rebalance=bool(self.rebalance_on), seed=self.seed)
        self.sim.set_state(sim_state)
