"""Pitch-attitude command shapes of the manoeuvre family (no FMI knowledge).

A manoeuvre is one command shape ϑ_cmd(t) (rad) on [start, start + duration) and zero
(trim) outside it; duration 0 means "to the end of the run".  Shapes (``kind``):

==========  ===  =========================================================================
input        0   no shape: the command comes from outside (PitchController input)
square wave  1   +A for the first half of each period, −A for the second, phase from start
step         2   +A
doublet      3   +A for ``pulse`` s, −A for the next ``pulse`` s, then 0; repeated every
                 ``period`` s when period > 0 (period ≥ 2·pulse), once when period = 0
sine sweep   4   A·sin φ(τ), τ = t − start, frequency rising exponentially from f0 to f1
                 over the duration (φ(τ) = 2π f0 D (r^{τ/D} − 1)/ln r, r = f1/f0; the
                 linear-in-time phase 2π f0 τ when f0 = f1); the duration must be > 0
==========  ===  =========================================================================

The exponential sweep spends equal time per octave, as flight-test frequency sweeps do.
Its start is smooth (sin 0 = 0); at its end the command drops from A·sin φ(D) to 0.

Switching instants (start, end, edges) are judged with a tolerance ``tol``: a switch at T
applies from the first t >= T - tol. Masters compute communication points as k·h or
add h each step (t += h), so "t = start + pulse" arrives as 0.15000000000000002 or
0.1499999999, and after many steps several ulps away; all count as the instant itself
(the new value applies). The FMU passes half its communication step (docs/fmu.md,
"Time events"); the default ``TIME_TOL`` (1 ns) is for callers without a step.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

TIME_TOL = 1e-9
COMMAND_INPUT = 0
COMMAND_SQUARE_WAVE = 1
COMMAND_STEP = 2
COMMAND_DOUBLET = 3
COMMAND_SINE_SWEEP = 4
KIND_NAMES = {COMMAND_INPUT: "input", COMMAND_SQUARE_WAVE: "square_wave",
              COMMAND_STEP: "step", COMMAND_DOUBLET: "doublet",
              COMMAND_SINE_SWEEP: "sine_sweep"}


def _finite(name: str, value: float) -> float:
    v = float(value)
    if not math.isfinite(v):
        raise ValueError(f"{name} must be finite, got {value!r}")
    return v


@dataclass(frozen=True)
class PitchCommand:
    """One manoeuvre of the family (see the module docstring).

    Parameters
    ----------
    kind : int
        0 input, 1 square wave, 2 step, 3 doublet, 4 sine sweep.
    amplitude : float
        A (rad).
    start : float
        Start time (s).
    duration : float
        Length of the manoeuvre (s, >= 0; 0 = until the end of the run; > 0 for a sweep).
    period : float
        Square-wave period (s, > 0) or doublet repetition period (s, 0 = once,
        else >= 2·pulse).
    pulse : float
        Doublet half width (s, > 0).
    f0, f1 : float
        Sweep start and end frequencies (Hz, > 0).

    Raises
    ------
    ValueError
        Naming the first invalid parameter and its allowed range.
    """

    kind: int = COMMAND_SQUARE_WAVE
    amplitude: float = 0.25
    start: float = 0.0
    duration: float = 0.0
    period: float = 20.0
    pulse: float = 1.0
    f0: float = 0.1
    f1: float = 2.0

    def __post_init__(self) -> None:
        if self.kind not in KIND_NAMES:
            raise ValueError(f"command kind must be one of {sorted(KIND_NAMES)} "
                             f"({', '.join(KIND_NAMES.values())}), got {self.kind!r}")
        _finite("amplitude", self.amplitude)
        _finite("start", self.start)
        if _finite("duration", self.duration) < 0.0:
            raise ValueError(f"duration must be >= 0 s (0: to the end), got {self.duration!r}")
        if self.kind == COMMAND_SQUARE_WAVE and not _finite("period", self.period) > 0.0:
            raise ValueError(f"period must be > 0 s for a square wave, got {self.period!r}")
        if self.kind == COMMAND_DOUBLET:
            if not _finite("pulse", self.pulse) > 0.0:
                raise ValueError(f"pulse must be > 0 s for a doublet, got {self.pulse!r}")
            p = _finite("period", self.period)
            if p != 0.0 and p < 2.0 * self.pulse:
                raise ValueError(f"period must be 0 (once) or >= 2*pulse = {2 * self.pulse} s "
                                 f"for a doublet, got {self.period!r}")
        if self.kind == COMMAND_SINE_SWEEP:
            for name in ("f0", "f1"):
                if not _finite(name, getattr(self, name)) > 0.0:
                    raise ValueError(f"{name} must be > 0 Hz for a sine sweep, "
                                     f"got {getattr(self, name)!r}")
            if not self.duration > 0.0:
                raise ValueError(f"duration must be > 0 s for a sine sweep, got {self.duration!r}")

    def active(self, t: float, tol: float = TIME_TOL) -> bool:
        """True inside the manoeuvre window (never for kind 0); switches within ``tol``."""
        tau = t - self.start + tol
        if self.kind == COMMAND_INPUT or tau < 0.0:
            return False
        return self.duration == 0.0 or tau < self.duration

    def value(self, t: float, tol: float = TIME_TOL) -> float:
        """ϑ_cmd(t) (rad); 0 outside the window and for kind 0; switches within ``tol``."""
        if not self.active(t, tol):
            return 0.0
        a = self.amplitude
        if self.kind == COMMAND_SINE_SWEEP:
            return a * math.sin(self.sweep_phase(t - self.start))
        tau = t - self.start + tol
        if self.kind == COMMAND_SQUARE_WAVE:
            return a if (tau % self.period) < 0.5 * self.period else -a
        if self.kind == COMMAND_STEP:
            return a
        if self.kind == COMMAND_DOUBLET:
            if self.period > 0.0:
                tau %= self.period
            if tau < self.pulse:
                return a
            return -a if tau < 2.0 * self.pulse else 0.0
        raise AssertionError(f"unhandled command kind {self.kind}")  # validated in __init__

    def sweep_phase(self, tau: float) -> float:
        """Phase φ(τ) (rad) of the sweep, τ s after its start."""
        d, f0, f1 = self.duration, self.f0, self.f1
        if f1 == f0:
            return 2.0 * math.pi * f0 * tau
        r = math.log(f1 / f0)
        return 2.0 * math.pi * f0 * d * math.expm1(r * tau / d) / r

    def sweep_frequency(self, tau: float) -> float:
        """Instantaneous frequency (Hz) of the sweep, τ s after its start."""
        return self.f0 * (self.f1 / self.f0) ** (tau / self.duration)
