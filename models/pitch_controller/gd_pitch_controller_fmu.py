"""PitchController FMU (FMI 2.0 co-simulation): LQR pitch-attitude hold for the Aircraft.

Reads the (possibly faulty) sensor values alpha_meas, q_meas, theta_meas and a pitch
command, outputs ``elevator`` and a constant ``throttle``.  The command is the input
``theta_cmd_in`` (``command_source`` = 0) or one manoeuvre of the family in
``gd_pitch_commands``: 1 square wave, 2 step, 3 doublet, 4 exponential sine sweep, of
amplitude ``cmd_amplitude`` from ``cmd_start_s`` for ``cmd_duration_s`` (0: to the end),
zero (trim) outside that window; ``cmd_active`` says whether the window is open.
Timing: ``do_step(t, h)`` computes the elevator from the inputs of the step start t and
the command at t, then integrates the pitch error; the elevator is published at t + h
(one communication step of latency — keep h ≤ 0.05 s, see the margins in
``gd_pitch_controller_design``).  Before the first step ``elevator`` is computed from the
input start values.
"""

from __future__ import annotations

import traceback
from typing import Any

from gd_fmu_base import GuardedSlave
from gd_pitch_commands import (
    COMMAND_INPUT,
    COMMAND_SINE_SWEEP,
    KIND_NAMES,
    TIME_TOL,
    PitchCommand,
)
from gd_pitch_controller_design import (
    PitchController as PitchLaw,
)
from gd_pitch_controller_design import (
    design_pitch_controller,
)
from pythonfmu import Fmi2Causality, Fmi2Variability, Integer, Real
from pythonfmu.default_experiment import DefaultExperiment
from pythonfmu.enums import Fmi2Status

#: Lower bound declared for parameters that must be > 0 (FMI bounds are inclusive).
POSITIVE = 1e-9
VARIABLE_META: dict[str, dict] = {
    "alpha_meas": {"unit": "rad"},
    "q_meas": {"unit": "rad/s"},
    "theta_meas": {"unit": "rad"},
    "theta_cmd_in": {"unit": "rad"},
    "elevator": {"unit": "rad"},
    "throttle": {"unit": "1"},
    "theta_cmd": {"unit": "rad"},
    "command_source": {"min": COMMAND_INPUT, "max": COMMAND_SINE_SWEEP},
    "cmd_amplitude": {"unit": "rad"},
    "cmd_period": {"unit": "s", "min": 0.0},  # 0: a doublet flown once
    "cmd_start_s": {"unit": "s"},
    "cmd_duration_s": {"unit": "s", "min": 0.0},
    "cmd_pulse_s": {"unit": "s", "min": 0.0},
    "cmd_f0_hz": {"unit": "Hz", "min": 0.0},
    "cmd_f1_hz": {"unit": "Hz", "min": 0.0},
    "throttle_trim": {"unit": "1"},
    # LQR weights are relative: declared dimensionless
    "q_alpha": {"unit": "1", "min": 0.0},
    "q_q": {"unit": "1", "min": 0.0},
    "q_theta": {"unit": "1", "min": POSITIVE},
    "q_int": {"unit": "1", "min": POSITIVE},
    "r": {"unit": "1", "min": POSITIVE},
    "k_alpha": {"unit": "1"},
    "k_q": {"unit": "s"},
    "k_theta": {"unit": "1"},
    "k_int": {"unit": "1/s"},
}
OUTPUT_DEPENDENCIES: dict[str, list[str]] = {}
REQUIREMENTS = ["numpy>=1.24", "scipy>=1.10"]


class PitchController(GuardedSlave):
    author = "gyrodiag"
    description = (
        "LQR pitch-attitude controller (integral action, exact trim feed-forward) for the "
        "seed-002 aircraft. elevator(t+h) computed from sensor inputs at t. Command: input "
        "theta_cmd_in (command_source=0) or an internal manoeuvre: 1 square wave, 2 step, "
        "3 doublet, 4 sine sweep, from cmd_start_s for cmd_duration_s."
    )
    default_experiment = DefaultExperiment(start_time=0.0, stop_time=120.0, step_size=0.01)

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(**kwargs)
        self.alpha_meas = 0.0
        self.q_meas = 0.0
        self.theta_meas = 0.0
        self.theta_cmd_in = 0.0
        self.command_source = 1
        self.cmd_amplitude = 0.25
        self.cmd_period = 20.0
        self.cmd_start_s = 0.0
        self.cmd_duration_s = 0.0
        self.cmd_pulse_s = 1.0
        self.cmd_f0_hz = 0.1
        self.cmd_f1_hz = 2.0
        self.cmd_active = 0
        self.throttle_trim = 0.0
        self.q_alpha, self.q_q, self.q_theta, self.q_int, self.r = 1.0, 1.0, 10.0, 1.0e-3, 100.0
        self._t0 = 0.0
        self.law = PitchLaw(design_pitch_controller())
        self._publish_gains()
        self.theta_cmd = 0.0
        self.elevator = 0.0
        self.throttle = 0.0
        P, V = Fmi2Causality, Fmi2Variability
        for name, doc in [("alpha_meas", "measured angle of attack"),
                          ("q_meas", "measured pitch rate"),
                          ("theta_meas", "measured pitch angle"),
                          ("theta_cmd_in", "pilot pitch command (used if command_source=0)")]:
            self.register_variable(Real(name, causality=P.input, variability=V.continuous,
                                        start=0.0, description=doc))
        for name, doc in [("elevator", "elevator deflection command"),
                          ("throttle", "throttle command (= throttle_trim)"),
                          ("theta_cmd", "pitch command used for the published elevator")]:
            self.register_variable(Real(name, causality=P.output, variability=V.discrete,
                                        description=doc))
        self.register_variable(Integer(
            "command_source", causality=P.parameter, variability=V.tunable,
            description="0: theta_cmd_in input; internal manoeuvre: 1 square wave, 2 step, "
                        "3 doublet, 4 exponential sine sweep"))
        self.register_variable(Integer(
            "cmd_active", causality=P.output, variability=V.discrete,
            description="1 while the internal manoeuvre window is open at the step start"))
        for name, var, doc in [
            ("cmd_amplitude", V.tunable, "manoeuvre amplitude A (square wave: +A first half "
                                         "period, -A second)"),
            ("cmd_period", V.tunable, "square-wave period; doublet repetition period "
                                      "(0: once)"),
            ("cmd_start_s", V.tunable, "manoeuvre start time"),
            ("cmd_duration_s", V.tunable, "manoeuvre length (0: to the end of the run; "
                                          "> 0 for a sweep)"),
            ("cmd_pulse_s", V.tunable, "doublet half width"),
            ("cmd_f0_hz", V.tunable, "sine sweep start frequency"),
            ("cmd_f1_hz", V.tunable, "sine sweep end frequency"),
            ("throttle_trim", V.tunable, "constant throttle output"),
            ("q_alpha", V.fixed, "LQR weight on alpha"),
            ("q_q", V.fixed, "LQR weight on q"),
            ("q_theta", V.fixed, "LQR weight on theta"),
            ("q_int", V.fixed, "LQR weight on the pitch-error integral"),
            ("r", V.fixed, "LQR weight on the elevator"),
        ]:
            self.register_variable(Real(name, causality=P.parameter, variability=var,
                                        description=doc))
        for name, doc in [("k_alpha", "LQR gain on alpha (rad/rad)"),
                          ("k_q", "LQR gain on q (rad per rad/s)"),
                          ("k_theta", "LQR gain on theta (rad/rad)"),
                          ("k_int", "LQR gain on the pitch-error integral (rad per rad s)")]:
            self.register_variable(Real(name, causality=P.calculatedParameter,
                                        variability=V.fixed, description=doc))
        self._shape_kept: PitchCommand | None = None
        self.watched_vrs = frozenset(
            vr for vr, var in self.vars.items() if var.variability == V.tunable)

    def _publish_gains(self) -> None:
        self.k_alpha, self.k_q, self.k_theta, self.k_int = (float(v) for v in self.law.design.k)

    def _shape(self) -> PitchCommand:
        # rebuilt (and validated) only after a tunable was set
        if self.watched_changed or self._shape_kept is None:
            self._shape_kept = self._new_shape()
            self.watched_changed = False
        return self._shape_kept

    def _new_shape(self) -> PitchCommand:
        if self.command_source not in KIND_NAMES:
            kinds = ", ".join(f"{k} {v}" for k, v in KIND_NAMES.items())
            raise ValueError(f"command_source must be 0..{COMMAND_SINE_SWEEP} ({kinds}), "
                             f"got {self.command_source!r}")
        try:
            return PitchCommand(int(self.command_source), self.cmd_amplitude, self.cmd_start_s,
                                self.cmd_duration_s, self.cmd_period, self.cmd_pulse_s,
                                self.cmd_f0_hz, self.cmd_f1_hz)
        except ValueError as exc:  # name the FMU parameter, not the dataclass field
            raise ValueError(f"cmd_* parameters of command_source {self.command_source}: "
                             f"{exc}") from None

    def _command(self, t: float, tol: float = TIME_TOL) -> float:
        # switching instants within ``tol`` (do_step: half a step, docs/fmu.md)
        shape = self._shape()
        self.cmd_active = int(shape.active(t, tol))
        if shape.kind == COMMAND_INPUT:
            return self.theta_cmd_in
        return shape.value(t, tol)

    def setup_experiment(self, start_time: float, stop_time: float | None = None,
                         tolerance: float | None = None) -> None:
        self._t0 = float(start_time)

    def exit_initialization_mode(self) -> None:
        if not self.parameters_in_range(VARIABLE_META):
            return
        try:
            self.law = PitchLaw(design_pitch_controller(
                self.q_alpha, self.q_q, self.q_theta, self.q_int, self.r))
            self._publish_gains()
            self.theta_cmd = self._command(self._t0)
            self.elevator = self.law.elevator(self.alpha_meas, self.q_meas, self.theta_meas,
                                              self.theta_cmd)
            self.throttle = float(self.throttle_trim)
        except Exception:
            self._fail("exit_initialization_mode")

    def do_step(self, current_time: float, step_size: float) -> bool:
        if not self.check_step(step_size):
            return True
        try:
            cmd = self._command(current_time, 0.5 * step_size)
            self.elevator = self.law.update(step_size, self.alpha_meas, self.q_meas,
                                            self.theta_meas, cmd)
            self.theta_cmd = cmd
            self.throttle = float(self.throttle_trim)
        except Exception:
            self._fail("do_step")
        return True

    def _fail(self, where: str) -> None:
        # pythonfmu 0.7 turns any Python exception into fmi2Fatal; instead log the
        # traceback at error status and return: the status shim in the FMU binary
        # (fmu_src/shim) turns the logged error into fmi2Error for this call.
        self.log(f"PitchController.{where} failed:\n{traceback.format_exc()}",
                 status=Fmi2Status.error)

    def _state_payload(self) -> dict[str, Any]:
        state = super()._state_payload()
        state["__law__"] = self.law.get_state()
        return state

    def _apply_state_payload(self, state: dict[str, Any]) -> None:
        state = dict(state)
        law_state = state.pop("__law__")
        super()._apply_state_payload(state)
        self._shape_kept = None
        # gains are calculated parameters of fixed weights: rebuild, then restore ξ
        self.law = PitchLaw(design_pitch_controller(
            self.q_alpha, self.q_q, self.q_theta, self.q_int, self.r))
        self.law.set_state(law_state)
