"""What the grey predictor is fed instead of a suspect or faulty sample (:class:`Substitution`).

While in alarm the predictor is fed its own prediction instead of the measurement, so
the model keeps extrapolating the fault-free signal and the alarm lasts as long as the
fault. Fed its own extrapolation, a predictor compounds it (the GM exponential and the
quadratic residual, docs/notes.md, grey detector), so the substitute is bounded by the
envelope of the fault-free samples widened by ``margin`` times its span.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

__all__ = ["Substitution"]


class Substitution:
    """Fault-free envelope and the bounded substitute of the grey predictor.

    Parameters
    ----------
    margin : float
        Widening of the envelope, in units of its span (>= 0, dimensionless).
    hold_after : int
        Learned rules: the substitute is the predictor's own value for this many samples
        of a substitution run, then held (>= 1).
    """

    def __init__(self, margin: float, hold_after: int) -> None:
        self.margin = margin
        self.hold_after = hold_after
        self.reset()

    def reset(self) -> None:
        """Empty envelope, no substitution run, nothing held."""
        self._min = math.inf
        self._max = -math.inf
        self._hold = math.nan       # paper rule: the clipped value held in alarm
        self.substituting = False   # learned rules: a substitution run is going on
        self._run = 0               # samples of the current run
        self._held = math.nan

    @property
    def envelope(self) -> tuple[float, float]:
        """(min, max) of the fault-free samples, signal units; (inf, −inf) when empty."""
        return self._min, self._max

    def widen(self, value: float) -> None:
        """A fault-free sample (signal units) widens the envelope."""
        self._min = min(self._min, value)
        self._max = max(self._max, value)

    def _limits(self) -> tuple[float, float]:
        span = self._max - self._min
        return self._min - self.margin * span, self._max + self.margin * span

    def clip(self, value: float) -> float:
        """``value`` limited to the widened envelope (NaN stays NaN)."""
        if not math.isfinite(value):
            return value
        lo, hi = self._limits()
        return min(max(value, lo), hi)

    def bounded(self, prediction: float) -> float:
        """Paper rule: the substitute for the next sample while in alarm (signal units).

        The predictor's own value inside the widened envelope (wide enough for the
        signal's legitimate motion, and it catches a runaway). Once clipped, the value
        is held until :meth:`release`: a polynomial extrapolator fed a clipped, kinked
        window turns around and re-enters, so the alarm would chatter (docs/notes.md,
        grey detector).
        """
        if not math.isfinite(prediction):
            return prediction
        if not math.isnan(self._hold):
            return self._hold
        lo, hi = self._limits()
        if lo <= prediction <= hi:
            return prediction
        self._hold = min(max(prediction, lo), hi)
        return self._hold

    def release(self) -> None:
        """Paper rule: the alarm ended, nothing is held."""
        self._hold = math.nan

    def substitute(self, prediction: float) -> float:
        """Learned rules: the value fed instead of a suspect or faulty sample.

        The predictor's own prediction (the paper's substitution) for the first
        ``hold_after`` samples of a run, then held at the last of them, and always
        clipped to the widened envelope. A straight line fitted to the last fault-free
        samples would miss the seed-001 profile's curvature within its own window;
        holding after a few samples bounds the drift by what the model extrapolates in
        that time.
        """
        lo, hi = self._limits()
        if not self.substituting:
            self.substituting = True
            self._run = 0
            self._held = math.nan
        self._run += 1
        if math.isfinite(self._held) and self._run > self.hold_after:
            return self._held
        if math.isfinite(prediction):
            clipped = min(max(prediction, lo), hi)
            if clipped != prediction:
                self._held = clipped  # left the plausible range: not trusted again
                self._run = self.hold_after + 1
                return clipped
            return prediction
        return self._held if math.isfinite(self._held) else prediction

    @property
    def exhausted(self) -> bool:
        """A run has lasted ``hold_after`` samples: a suspect sample not followed by an
        alarm was noise, and measurements are taken again."""
        return self.substituting and self._run >= self.hold_after

    def end_run(self) -> None:
        """Learned rules: measured samples are fed again."""
        self.substituting = False

    def get_state(self) -> dict[str, Any]:
        """State as a flat plain dict."""
        return {"envelope_min": float(self._min), "envelope_max": float(self._max),
                "hold": float(self._hold), "substituting": int(self.substituting),
                "run": int(self._run), "held": float(self._held)}

    def set_state(self, state: Mapping[str, Any]) -> None:
        """Restore :meth:`get_state`."""
        self._min = float(state["envelope_min"])
        self._max = float(state["envelope_max"])
        self._hold = float(state["hold"])
        self.substituting = bool(state["substituting"])
        self._run = int(state["run"])
        self._held = float(state["held"])
