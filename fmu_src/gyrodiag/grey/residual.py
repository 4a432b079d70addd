"""The predictor side of the grey fault detector (:class:`GreyResidual`).

It holds the one-step predictor (and the candidates that compete with it on the
calibration window), the prediction the next sample is judged against, the measured
samples kept for re-seeding and the bounded substitute fed in their place. The decision
rule only sees the residual e = y − ŷ.
"""

from __future__ import annotations

import copy
import math
from collections import deque
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from .calibration import ErrorScale, PredictorChoice
from .predictor import GreyPredictor
from .substitution import Substitution

__all__ = ["GreyResidual"]


class GreyResidual:
    """One-step predictions of a signal, fed measurements or bounded substitutes.

    Parameters
    ----------
    predictor : GreyPredictor
        The configured one-step predictor (it is reset).
    candidates : sequence of GreyPredictor
        Compared with ``predictor`` on the calibration window (learned rules).
    reseed_length : int
        Measured samples kept for re-seeding.
    envelope_margin : float
        Widening of the fault-free envelope, in spans (dimensionless).
    hold_after : int
        Substitution run after which the substitute is held, samples.
    """

    def __init__(self, predictor: GreyPredictor, candidates: Sequence[GreyPredictor],
                 reseed_length: int, envelope_margin: float, hold_after: int) -> None:
        self._configured = predictor
        self.predictor = predictor
        self.choice = PredictorChoice(candidates)
        self.substitution = Substitution(envelope_margin, hold_after)
        self.reseed_length = reseed_length
        #: fault-free samples kept (learned rules)
        self.trend_samples = max(20, 4 * predictor.min_samples)
        self.reset()

    def reset(self) -> None:
        """The configured predictor, empty; nothing kept."""
        self.predictor = self._configured
        self.choice.reset()
        self.predictor.reset()
        self.substitution.reset()
        self.pending = math.nan
        """ŷ of the next sample, signal units; NaN during warm-up."""
        # the newest measured samples (re-seeding); a bounded deque, not np.append per sample
        self.recent: deque[float] = deque(maxlen=self.reseed_length)
        self._clean: list[float] = []   # last fault-free samples (learned rules)
        self._n_clean = 0               # fault-free samples accepted so far

    def record(self, value: float) -> None:
        """A valid measured sample (signal units) is kept for re-seeding."""
        self.recent.append(value)

    def paper_step(self, value: float, predicted: float, alarm: bool) -> None:
        """Paper rule: feed the measurement, or in alarm the prediction ``predicted``
        (when finite), and bound the next prediction while in alarm
        (:meth:`~gyrodiag.grey.substitution.Substitution.bounded`)."""
        substitute = alarm and math.isfinite(predicted)
        if not alarm:
            self.substitution.widen(value)
        self.pending = self.predictor.update(predicted if substitute else value)
        if alarm:
            self.pending = self.substitution.bounded(self.pending)
        else:
            self.substitution.release()

    def accept(self, value: float, predict: bool = True) -> None:
        """Learned rules: a fault-free sample widens the envelope and is kept;
        ``predict``: the predictor is fed it too."""
        if predict:
            self.pending = self.predictor.update(value)
        self.substitution.widen(value)
        self._clean.append(value)
        if len(self._clean) > self.trend_samples:
            del self._clean[0]
        self._n_clean += 1

    def take(self, value: float) -> None:
        """Learned rules: a sample judged fault-free ends a substitution run and is fed."""
        self.substitution.end_run()
        self.pending = self.predictor.update(value)
        self.accept(value, predict=False)

    def substitute(self, predicted: float, in_alarm: bool) -> None:
        """Learned rules: the predictor is fed the bounded substitute of ``predicted``;
        in alarm the next prediction is clipped to the envelope too."""
        self.pending = self.predictor.update(self.substitution.substitute(predicted))
        if in_alarm:
            self.pending = self.substitution.clip(self.pending)

    def roll_back(self, state: dict[str, Any], pending: float, lag: int) -> None:
        """A step in the last ``lag`` samples: the predictor goes back to ``state`` (its
        state before them, with prediction ``pending``) and is fed the bounded
        substitute for each, so the alarm's substitute extrapolates the signal from
        before the step."""
        self.predictor.set_state(state)
        self.substitution.end_run()
        pred = pending
        for _ in range(lag):
            pred = self.predictor.update(self.substitution.substitute(pred))
        self.pending = self.substitution.clip(pred)

    def reseed(self, keep: bool = False) -> None:
        """Timed clearing: the predictor starts again on the newest measured samples;
        ``keep``: they also become the kept fault-free samples (learned rules)."""
        self.predictor.reset()
        self.pending = math.nan
        self.substitution.release()
        # the re-seeded samples are the new reference signal (the paper's clearing
        # accepts them), so they count as fault-free for the envelope too
        for v in self.recent:
            self.substitution.widen(float(v))
            self.pending = self.predictor.update(float(v))
        if keep:
            self._clean = [float(v) for v in self.recent]
            self.substitution.end_run()

    def choose(self, scale: ErrorScale) -> None:
        """End of calibration: a candidate with less error replaces the predictor, and
        ``scale``'s calibration errors become its errors."""
        if not self.choice.candidates:
            return
        chosen, ratio = self.choice.choose(scale.square_sum())
        if chosen:
            self.predictor = self.choice.candidates[chosen - 1]
            self.pending = self.choice.pending[chosen - 1]
            # the calibration errors of the chosen one (only σ is used)
            scale.rescale(ratio)

    def get_state(self) -> dict[str, Any]:
        """State as a flat plain dict; ``predictor.`` prefixes the predictor's keys."""
        state: dict[str, Any] = {
            f"predictor.{key}": copy.deepcopy(val)
            for key, val in self.predictor.get_state().items()
        }
        state.update(
            pending_prediction=float(self.pending),
            recent=np.array(self.recent, dtype=float),
            clean=np.asarray(self._clean, dtype=float),
            n_clean=int(self._n_clean),
        )
        state.update(self.substitution.get_state())
        state.update(self.choice.get_state())
        return state

    def set_state(self, state: Mapping[str, Any]) -> None:
        """Restore :meth:`get_state`.

        Raises
        ------
        ValueError
            If the kept samples do not fit or ``state['chosen']`` names no candidate.
        """
        recent = np.array(state["recent"], dtype=float).reshape(-1)
        clean = np.array(state["clean"], dtype=float).reshape(-1)
        if clean.size > self.trend_samples:
            raise ValueError("state['clean'] / state['cusum'] do not fit this detector")
        if recent.size > self.reseed_length:
            raise ValueError(f"state['recent'] holds {recent.size} samples, "
                             f"reseed_length is {self.reseed_length}")
        self.choice.set_state(state)
        chosen = self.choice.chosen
        self.predictor = (self._configured if chosen == 0
                          else self.choice.candidates[chosen - 1])
        prefix = "predictor."
        self.predictor.set_state(
            {k[len(prefix):]: copy.deepcopy(v) for k, v in state.items() if k.startswith(prefix)}
        )
        self.pending = float(state["pending_prediction"])
        self.recent = deque((float(x) for x in recent), maxlen=self.reseed_length)
        self._clean = [float(x) for x in clean]
        self._n_clean = int(state["n_clean"])
        self.substitution.set_state(state)
