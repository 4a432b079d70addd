"""Per-sample decision rules of the grey fault detector (strategy objects).

A :class:`~gyrodiag.grey.detector.GreyFaultDetector` composes its predictor and
substitution with one rule, which turns each one-step prediction error into a
:class:`Verdict`:

* :class:`FixedThreshold`: [B]'s rule, |e| > threshold.
* :class:`KSigmaTest`: |e| > max(k·σ_e, floor), σ_e learned on a fault-free start.
* :class:`SequentialTest`: a two-sided CUSUM on e/σ_e and the lagged step test
  (:class:`~gyrodiag.grey.lagged.LaggedStepTest`).

Every rule has ``reset()``, ``decide(...)``, ``get_state()`` / ``set_state()`` and the
hooks the detector calls on the samples it accepts or substitutes; a rule that does not
need a hook inherits a no-op. The configurations that build a detector with a rule are
in :mod:`gyrodiag.grey.decision`.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any, ClassVar, NamedTuple

import numpy as np

from .lagged import LaggedStepTest
from .predictor import GreyPredictor

__all__ = ["DecisionRule", "FixedThreshold", "KSigmaTest", "SequentialTest", "Verdict"]


class Verdict(NamedTuple):
    """A rule's decision on one sample.

    Attributes
    ----------
    alarm : bool
        Fault alarm after this sample.
    statistic : float
        The alarm statistic in units of its threshold (alarm at 1).
    suspect : bool
        The sample is not fed to the predictor (learned rules).
    lag : int
        > 0: a step in the last ``lag`` samples (lagged test); the predictor goes back
        to before them.
    """

    alarm: bool
    statistic: float
    suspect: bool = False
    lag: int = 0


class DecisionRule:
    """Base of the rules: the interface, and no-op hooks.

    ``calibrated`` rules decide on errors in units of σ_e, so the detector learns σ_e
    first and feeds the predictor bounded substitutes of suspect samples.
    """

    calibrated: ClassVar[bool] = False
    #: CUSUM threshold (NaN without a CUSUM) and lagged-test thresholds (none without it)
    cusum_threshold: float = math.nan
    lag_thresholds: tuple[float, ...] = ()

    def reset(self) -> None:
        """Return to the state right after construction."""

    def decide(self, error: float, sigma: float, in_alarm: bool, predictor: GreyPredictor,
               predicted: float) -> Verdict:
        """Judge one sample.

        Parameters
        ----------
        error : float
            y(k) − ŷ(k), signal units (non-finite when the prediction is).
        sigma : float
            σ_e, signal units (NaN for rules that are not calibrated).
        in_alarm : bool
            The detector is in alarm before this sample.
        predictor : GreyPredictor
            The predictor, not yet fed this sample (its state may be kept).
        predicted : float
            ŷ(k), signal units.
        """
        raise NotImplementedError

    def observe(self, value: float) -> None:
        """A valid measured sample (signal units), before it is judged."""

    def accept(self, value: float) -> None:
        """A sample judged fault-free (signal units)."""

    def interrupt(self) -> None:
        """The predictor is fed a substitute instead of this sample."""

    def snapshot(self, predictor: GreyPredictor, predicted: float) -> None:
        """The predictor before a sample that is accepted unjudged (settling)."""

    def restart(self) -> None:
        """The detector is in alarm after this sample."""

    def clear(self) -> None:
        """A timed clearing: the alarm ended and the predictor was re-seeded."""

    def rollback_point(self, lag: int) -> tuple[dict[str, Any], float]:
        """Predictor state and pending prediction before the last ``lag`` samples."""
        raise NotImplementedError

    @property
    def noise_sigma(self) -> float:
        """Signal's white-noise σ (signal units) of the lagged test; NaN without it."""
        return math.nan

    @property
    def lag_statistic(self) -> float:
        """z of the lagged test's last sample; 0 without it."""
        return 0.0

    @property
    def lag_ready(self) -> bool:
        """The lagged test decides on the sample being processed."""
        return False

    def get_state(self) -> dict[str, Any]:
        """State as a flat plain dict."""
        return {}

    def set_state(self, state: Mapping[str, Any]) -> None:
        """Restore :meth:`get_state`."""


class FixedThreshold(DecisionRule):
    """[B]'s rule: alarm when |e| > ``threshold`` (signal units); a non-finite
    prediction alarms (the detector cannot vouch for the sample)."""

    def __init__(self, threshold: float) -> None:
        self.threshold = threshold

    def decide(self, error: float, sigma: float, in_alarm: bool, predictor: GreyPredictor,
               predicted: float) -> Verdict:
        """|e| / threshold; alarm above 1."""
        alarm = True if not math.isfinite(predicted) else abs(error) > self.threshold
        stat = abs(error) / self.threshold if math.isfinite(error) else 0.0
        return Verdict(alarm, stat)


class KSigmaTest(DecisionRule):
    """Alarm when |e| > max(``k_sigma``·σ_e, ``floor``) (floor in signal units); a sample
    beyond ``suspicion_sigma``·σ_e is suspect."""

    calibrated = True

    def __init__(self, k_sigma: float, floor: float, suspicion_sigma: float) -> None:
        self.k_sigma = k_sigma
        self.floor = floor
        self.suspicion_sigma = suspicion_sigma

    def decide(self, error: float, sigma: float, in_alarm: bool, predictor: GreyPredictor,
               predicted: float) -> Verdict:
        """|e| over the limit; a non-finite error alarms."""
        z = error / sigma if math.isfinite(error) else math.inf
        limit = max(self.k_sigma * sigma, self.floor)
        alarm = abs(error) > limit if math.isfinite(error) else True
        stat = abs(error) / limit if math.isfinite(error) else 1.0
        return Verdict(alarm, stat, abs(z) > self.suspicion_sigma)


class SequentialTest(DecisionRule):
    """Two-sided CUSUM on z = e/σ_e (reference ``cusum_k``) and the lagged step test.

    Parameters
    ----------
    false_alarms_per_h : float
        Design false-alarm rate, 1/h (each test has all of it: the CUSUM decides only
        while the lagged test cannot).
    sample_period_s : float
        Sample period, s.
    cusum_k : float
        CUSUM reference, in σ_e.
    suspicion_sigma : float
        |z| beyond it, or a CUSUM above half its threshold, makes a sample suspect.
    lag_test : LaggedStepTest or None
        The lagged step test; None: the CUSUM decides alone.

    Notes
    -----
    While the lagged test is ready the CUSUM only holds alarms: the improved model's
    one-step errors have heavier tails than a normal law (−4 σ_e at fixed phases of a
    moving signal), and a CUSUM on them false-alarms on fault-free HRG records
    (docs/notes.md, HRG). On a lagged alarm the CUSUM of the step's sign starts at its
    threshold, so the alarm lasts while the errors do.
    """

    calibrated = True

    def __init__(self, false_alarms_per_h: float, sample_period_s: float, cusum_k: float,
                 suspicion_sigma: float, lag_test: LaggedStepTest | None = None) -> None:
        from ..common.cusum import TABLE_LOG10_ARL, arl_for_rate, mean_cusum_threshold

        # at most the longest run length of the shipped table (no false alarm in any
        # record; a very low rate at a fast sample would ask for more, beyond what the
        # CUSUM can be solved for at start-up)
        arl = min(arl_for_rate(false_alarms_per_h, sample_period_s, 2),
                  10.0 ** TABLE_LOG10_ARL[-1])
        self.cusum_threshold = mean_cusum_threshold(arl, cusum_k)
        self.cusum_k = cusum_k
        self.suspicion_sigma = suspicion_sigma
        self.lag_test = lag_test
        self.lag_thresholds = tuple(lag_test.thresholds) if lag_test else ()
        self.reset()

    def reset(self) -> None:
        """CUSUMs at zero, the lagged test afresh."""
        self._cusum = [0.0, 0.0]
        if self.lag_test:
            self.lag_test.reset()

    def decide(self, error: float, sigma: float, in_alarm: bool, predictor: GreyPredictor,
               predicted: float) -> Verdict:
        """CUSUM step, then (not in alarm) the lagged test on the predictor's state."""
        z = error / sigma if math.isfinite(error) else math.inf
        h, k = self.cusum_threshold, self.cusum_k
        up = min(max(self._cusum[0] + z - k, 0.0), h)
        down = min(max(self._cusum[1] - z - k, 0.0), h)
        self._cusum = [up, down]
        top = max(up, down)
        deciding = not self.lag_ready
        alarm = (deciding and top >= h) or (in_alarm and top >= 0.5 * h)
        stat = top / h if deciding or in_alarm else 0.0
        suspect = abs(z) > self.suspicion_sigma or top > 0.5 * h
        lag_alarm = 0
        if self.lag_test and not in_alarm:
            self.lag_test.snapshot(predictor.get_state(), predicted)
            lag, lag_z, lag_ratio = self.lag_test.test()
            stat = max(stat, lag_ratio)
            if lag and not alarm:
                alarm = True
                lag_alarm = lag
                self._cusum[0 if lag_z > 0.0 else 1] = h
        return Verdict(alarm, stat, suspect, lag_alarm)

    def observe(self, value: float) -> None:
        if self.lag_test:
            self.lag_test.observe(value)

    def accept(self, value: float) -> None:
        if self.lag_test:
            self.lag_test.accept(value)

    def interrupt(self) -> None:
        if self.lag_test:
            self.lag_test.interrupt()

    def snapshot(self, predictor: GreyPredictor, predicted: float) -> None:
        if self.lag_test:
            self.lag_test.snapshot(predictor.get_state(), predicted)

    def restart(self) -> None:
        if self.lag_test:
            self.lag_test.forget()

    def clear(self) -> None:
        self._cusum = [0.0, 0.0]
        if self.lag_test:
            self.lag_test.forget()

    def rollback_point(self, lag: int) -> tuple[dict[str, Any], float]:
        assert self.lag_test is not None
        return self.lag_test.rollback_point(lag)

    @property
    def noise_sigma(self) -> float:
        return self.lag_test.noise_sigma if self.lag_test else math.nan

    @property
    def lag_statistic(self) -> float:
        return self.lag_test.statistic if self.lag_test else 0.0

    @property
    def lag_ready(self) -> bool:
        return bool(self.lag_test) and self.lag_test.ready

    def get_state(self) -> dict[str, Any]:
        state: dict[str, Any] = {"cusum": np.asarray(self._cusum, dtype=float)}
        if self.lag_test:
            state.update(self.lag_test.get_state())
        return state

    def set_state(self, state: Mapping[str, Any]) -> None:
        cusum = np.array(state["cusum"], dtype=float).reshape(-1)
        self._cusum = [float(cusum[0]), float(cusum[1])]
        if self.lag_test:
            self.lag_test.set_state(state)
