"""The improved moving-window grey fault detector of the HRG (:class:`GreyFaultDetector`).

A sample farther than a threshold from the one-step prediction of a
:mod:`gyrodiag.grey.predictor` raises a fault alarm. The detector composes the predictor
(and its bounded substitution, :mod:`gyrodiag.grey.substitution`; its calibration,
:mod:`gyrodiag.grey.calibration`) with one decision rule of :mod:`gyrodiag.grey.rules`.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..common._records import fast_init
from ..common._validation import (
    check_int,
    check_nonnegative,
    check_positive,
)
from .calibration import ErrorScale
from .lagged import (  # noqa: F401  (re-exported, see below)
    LAG_MAX_LIMIT,
    LONGEST_LAG_SHARE,
    LaggedStepTest,
    lag_step_weights,
    lag_test_threshold,
)
from .predictor import GreyPredictor
from .residual import GreyResidual
from .rules import DecisionRule, FixedThreshold, KSigmaTest, SequentialTest, Verdict

__all__ = ["GreyDetectorOutput", "GreyFaultDetector"]

# LAG_MAX_LIMIT, LONGEST_LAG_SHARE, lag_step_weights and lag_test_threshold moved to
# .lagged; they stay importable from here for code that imported them from this module

#: Keys of a saved state after the predictor's, in the order states have always had
#: (the candidates' and the lagged test's keys follow).
_STATE_LAYOUT = (
    "pending_prediction", "in_alarm", "onset_time_s", "recent", "n_accepted",
    "envelope_min", "envelope_max", "hold", "cal_errors", "sigma", "statistic", "sq_sum",
    "sq_n", "cusum", "clean", "n_clean", "substituting", "run", "settle", "held", "chosen",
    "cand_pending", "cand_sq",
)

_UNJUDGED = Verdict(False, 0.0)


def _in_layout_order(state: dict[str, Any]) -> dict[str, Any]:
    """``state`` with its keys in the saved layout's order: the predictor's, then
    :data:`_STATE_LAYOUT`, then the rest as they came."""
    ordered = {k: v for k, v in state.items() if k.startswith("predictor.")}
    ordered.update((k, state[k]) for k in _STATE_LAYOUT)
    ordered.update((k, v) for k, v in state.items() if k not in ordered)
    return ordered


@fast_init
@dataclass(frozen=True)
class GreyDetectorOutput:
    """Result of one :meth:`GreyFaultDetector.update`.

    Attributes
    ----------
    time_s : float
        Time of the sample, s.
    measurement : float
        The sample as received (signal units; may be NaN/inf when ``valid`` is False).
    prediction : float
        ŷ(k), predicted for this sample from the samples before it (signal units);
        NaN during warm-up. While in alarm this is the bounded substitute (see
        :class:`GreyFaultDetector`), i.e. the value that was also fed to the predictor.
    error : float
        y(k) − ŷ(k), signal units; NaN during warm-up or for an invalid sample.
    alarm : bool
        Fault alarm after this sample.
    alarm_onset_time_s : float
        Onset time of the current alarm, s; NaN when not in alarm.
    valid : bool
        False if the sample was NaN/inf and was skipped (state untouched).
    cleared : bool
        True if the alarm was cleared at this sample after ``clear_after_s``.
    calibrating : bool
        Calibrated detector: the error statistics are still being learned (no alarm).
    statistic : float
        The alarm statistic in units of its threshold (alarm at 1): |e|/threshold, or
        the larger CUSUM over its threshold; 0 during warm-up and calibration.
    """

    time_s: float
    measurement: float
    prediction: float
    error: float
    alarm: bool
    alarm_onset_time_s: float
    valid: bool
    cleared: bool
    calibrating: bool = False
    statistic: float = 0.0


class GreyFaultDetector:
    """One-step grey-prediction fault detector with substitution and timed clearing.

    Parameters
    ----------
    predictor : ClassicGreyPredictor or ImprovedGreyPredictor
        Streaming one-step predictor; the detector owns it from now on (it is reset).
    threshold : float
        Alarm threshold on |y(k) − ŷ(k)|, signal units (V for the HRG output), > 0.
    sample_period_s : float
        Sample period, s, > 0; the sample clock when ``update`` gets no ``time_s``.
    clear_after_s : float or None, optional
        Clear an alarm that has lasted this long (s, > 0) and re-seed the predictor
        with the most recent measured samples so the next fault can be seen (paper:
        20 s). None: alarms end only when the error falls below the threshold.
    reseed_length : int or None, optional
        Measured samples kept for re-seeding; default ``predictor.min_samples``.
    envelope_margin : float, optional
        Widening of the fault-free envelope that bounds the substitute, in spans (>= 0,
        default 1; :class:`~gyrodiag.grey.substitution.Substitution`).
    calibrate_samples : int, optional
        > 0: a *calibrated* detector (see below). ``threshold`` is then the smallest
        threshold allowed (signal units), a floor for a noise-free signal.
    k_sigma : float, optional
        Calibrated: alarm when |e| > k_sigma·σ_e (default 5).
    sequential : bool, optional
        Calibrated: alarm by a two-sided CUSUM on e/σ_e instead (reference
        ``cusum_k``, threshold for ``false_alarms_per_h`` by
        :func:`~gyrodiag.common.cusum.mean_cusum_threshold`).
    false_alarms_per_h, cusum_k : float, optional
        Design false-alarm rate (1/h, default 1e-3) and CUSUM reference (σ_e, default
        1.5; docs/notes.md, grey detector).
    suspicion_sigma : float, optional
        Calibrated: a sample with |e| > suspicion_sigma·σ_e (or a CUSUM above half its
        threshold) is not fed to the predictor, so that a step is not absorbed before
        the test has decided (default 4).
    hold_after : int, optional
        Calibrated: suspect samples not followed by an alarm are substituted for at
        most this many samples in a row, and in alarm the substitute is held after
        this many (default 1; :meth:`~gyrodiag.grey.substitution.Substitution.substitute`).
    candidates : sequence of predictors, optional
        Calibrated: other predictors (same window) compared with ``predictor`` on the
        calibration window (:class:`~gyrodiag.grey.calibration.PredictorChoice`).
    lag_max : int, optional
        Sequential: the lagged step test looks at the last 1..lag_max samples (0..4,
        default 3; 0 turns it off and the CUSUM decides alone; :mod:`gyrodiag.grey.lagged`).
    reference_window : int, optional
        Lagged test: longest reference window M, samples (default 60, in
        [reference_order + 3, 400]).
    reference_order : int, optional
        Lagged test: degree of the reference polynomial (0..3, default 3).

    Notes
    -----
    The arguments choose the decision rule (:mod:`gyrodiag.grey.rules`):
    ``calibrate_samples`` = 0 the fixed threshold, else ``sequential`` the CUSUM and
    lagged step test, else the k·σ_e test (:mod:`gyrodiag.grey.decision` builds them
    from a rule's configuration).

    Per valid sample y(k): error e = y(k) − ŷ(k), judged by the rule. While in alarm
    the predictor is fed ŷ(k) instead of y(k), so the model keeps extrapolating the
    fault-free signal and the alarm lasts as long as the fault instead of a single
    pulse; the substitute is bounded (:class:`~gyrodiag.grey.substitution.Substitution`)
    and the reported prediction (and so the error) is the bounded value.

    Calibrated rules: the first ``calibrate_samples`` one-step errors after the warm-up
    (assumed fault-free) give σ_e (:class:`~gyrodiag.grey.calibration.ErrorScale`:
    winsorised, raised to its 95 % upper confidence bound), which keeps learning from
    the samples judged fault-free afterwards. A suspect sample is substituted too; one
    not followed by an alarm within ``hold_after`` samples was noise, and the
    measurements are taken again (else a substitute held while the signal moves would
    lock the detector into a false alarm). After a timed clearing one window of
    measured samples settles the re-seeded model before errors count again.

    No alarm is possible before the predictor's window is full: the first
    ``min_samples`` samples are assumed fault-free. A non-finite prediction with a full
    window (only the textbook classic model on an exactly degenerate window produces
    one) raises the alarm. A NaN/inf sample is skipped: the state is not touched (the
    pending prediction stays for the next valid sample) and the output has
    ``valid=False``.
    """

    def __init__(
        self, predictor: GreyPredictor, threshold: float, sample_period_s: float,
        clear_after_s: float | None = None, *, reseed_length: int | None = None,
        envelope_margin: float = 1.0, calibrate_samples: int = 0, k_sigma: float = 5.0,
        sequential: bool = False, false_alarms_per_h: float = 1e-3, cusum_k: float = 1.5,
        suspicion_sigma: float = 4.0, hold_after: int | None = None,
        candidates: Sequence[GreyPredictor] = (), lag_max: int = 3,
        reference_window: int = 60, reference_order: int = 3,
    ) -> None:
        for attr in ("update", "reset", "get_state", "set_state", "min_samples", "ready"):
            if not hasattr(predictor, attr):
                raise TypeError(f"predictor must provide {attr!r}, got {type(predictor)!r}")
        self.threshold = check_positive("threshold", threshold)
        self.calibrate_samples = check_int("calibrate_samples", calibrate_samples)
        self.k_sigma = check_positive("k_sigma", k_sigma)
        self.sequential = bool(sequential)
        self.false_alarms_per_h = check_positive("false_alarms_per_h", false_alarms_per_h)
        self.cusum_k = check_positive("cusum_k", cusum_k)
        self.suspicion_sigma = check_positive("suspicion_sigma", suspicion_sigma)
        self.hold_after = (
            1 if hold_after is None else check_int("hold_after", hold_after, minimum=1))
        if self.sequential and self.calibrate_samples == 0:
            raise ValueError("sequential needs calibrate_samples > 0 (the CUSUM works on "
                             "errors in units of their calibrated standard deviation)")
        if self.calibrate_samples and self.calibrate_samples < 10:
            raise ValueError(f"calibrate_samples must be 0 or >= 10, got {calibrate_samples}")
        candidates = list(candidates)
        for cand in candidates:
            if cand.min_samples != predictor.min_samples:
                raise ValueError("candidates must need as many samples as the predictor "
                                 f"({predictor.min_samples}), got {cand.min_samples}")
        if candidates and not self.calibrate_samples:
            raise ValueError("candidates need calibrate_samples > 0 (they are compared on "
                             "the calibration window)")
        self.sample_period_s = check_positive("sample_period_s", sample_period_s)
        self.clear_after_s = (
            None if clear_after_s is None else check_positive("clear_after_s", clear_after_s)
        )
        self.reseed_length = (
            predictor.min_samples if reseed_length is None
            else check_int("reseed_length", reseed_length, minimum=1)
        )
        self.envelope_margin = check_nonnegative("envelope_margin", envelope_margin)
        _set_lag_test_arguments(self, lag_max, reference_window, reference_order)
        #: shortest reference window the lagged test starts with (it grows to
        #: ``reference_window`` as measured samples come in)
        self.reference_min = min(self.reference_window, max(self.reference_order + 3, 20))
        self.rule = _rule_for(self)
        self.cusum_threshold = self.rule.cusum_threshold
        #: thresholds on |z| of the lagged test, lag 1 first (empty without it)
        self.lag_thresholds: list[float] = list(self.rule.lag_thresholds)
        self._residual = GreyResidual(predictor, candidates, self.reseed_length,
                                      self.envelope_margin, self.hold_after)
        self.candidates = self._residual.choice.candidates
        #: fault-free samples kept (learned rules)
        self.trend_samples = self._residual.trend_samples
        self._scale = ErrorScale(self.calibrate_samples, self.threshold / self.k_sigma,
                                 self.suspicion_sigma)
        self._step = (self._update_calibrated if self.rule.calibrated
                      else self._update_fixed)
        self.reset()

    @property
    def calibrated(self) -> bool:
        """This detector learns its threshold (``calibrate_samples`` > 0)."""
        return self.calibrate_samples > 0

    def reset(self) -> None:
        """Return to the state right after construction."""
        self._residual.reset()
        self._scale.reset()
        self.rule.reset()
        self._in_alarm = False
        self._onset = math.nan
        self._n_accepted = 0
        self._statistic = 0.0  # of the last valid sample (held over skipped ones)
        self._settle = 0  # samples left to settle after a timed clearing

    @property
    def predictor(self) -> GreyPredictor:
        """The predictor in use (the configured one, or the candidate chosen)."""
        return self._residual.predictor

    @property
    def sigma(self) -> float:
        """Calibrated: robust standard deviation of the fault-free prediction error
        (signal units); NaN before it is learned."""
        return self._scale.sigma

    @property
    def threshold_in_use(self) -> float:
        """Alarm threshold on |e| (signal units) of the per-sample test in use; NaN while
        a calibrated detector is calibrating."""
        if not self.calibrated:
            return self.threshold
        if math.isnan(self._scale.sigma):
            return math.nan
        return max(self.k_sigma * self._scale.sigma, self.threshold)

    @property
    def alarm(self) -> bool:
        """Current alarm state."""
        return self._in_alarm

    @property
    def pending_prediction(self) -> float:
        """Prediction for the next sample (signal units), NaN during warm-up.

        Bounded while in alarm (the value the next output will report)."""
        return self._residual.pending

    @property
    def envelope(self) -> tuple[float, float]:
        """(min, max) of the fault-free samples seen since reset, signal units.

        (inf, −inf) before the first sample."""
        return self._residual.substitution.envelope

    @property
    def chosen_predictor(self) -> int:
        """0: the configured predictor is in use, i: ``candidates[i − 1]``."""
        return self._residual.choice.chosen

    @property
    def noise_sigma(self) -> float:
        """Lagged test: standard deviation of the signal's white noise (signal units),
        with ``threshold / k_sigma`` added in quadrature
        (:attr:`~gyrodiag.grey.lagged.LaggedStepTest.noise_sigma`); NaN before ten
        differences are known or without the lagged test."""
        return self.rule.noise_sigma

    @property
    def lag_statistic(self) -> float:
        """Lagged test: the z of the last sample with the largest |z| over the lags
        (dimensionless, alarm at |z| >= ``lag_thresholds[lag − 1]``); 0 when not
        tested."""
        return self.rule.lag_statistic

    @property
    def lag_test_ready(self) -> bool:
        """The lagged step test decides on the sample being processed (noise known, at
        least ``reference_min`` + 1 measured samples, this one included, since the start
        or the last alarm)."""
        return self.rule.lag_ready

    def update(self, y: float, time_s: float | None = None) -> GreyDetectorOutput:
        """Process one sample.

        Parameters
        ----------
        y : float
            Measured sample, signal units. NaN/inf is skipped, see class notes.
        time_s : float, optional
            Sample time, s. Default: ``n·sample_period_s`` with n the number of valid
            samples accepted so far (a skipped sample does not advance this clock;
            pass ``time_s`` from the host when samples can be dropped).

        Returns
        -------
        GreyDetectorOutput
        """
        if isinstance(y, bool):
            raise TypeError(f"y must be a number, got {y!r}")
        try:
            value = float(y)
        except (TypeError, ValueError):
            raise TypeError(f"y must be a number, got {y!r}") from None
        if time_s is None:
            t = self._n_accepted * self.sample_period_s
        else:
            t = float(time_s)
            if not math.isfinite(t):
                raise ValueError(f"time_s must be finite, got {time_s!r}")
        predicted = self._residual.pending
        if not math.isfinite(value):
            return GreyDetectorOutput(
                t, value, predicted, math.nan, self._in_alarm, self._onset, False, False,
                self.calibrated and (math.isnan(self._scale.sigma)
                                     or not self.predictor.ready),
                self._statistic,
            )
        return self._step(value, t, predicted)

    def _clear_due(self, t: float) -> bool:
        """The alarm has lasted ``clear_after_s`` at time ``t`` (s)."""
        return self.clear_after_s is not None and (
            t - self._onset >= self.clear_after_s - 1e-6 * self.sample_period_s)

    def _update_fixed(self, value: float, t: float, predicted: float) -> GreyDetectorOutput:
        """One valid sample of a rule that is not calibrated (the paper's detector)."""
        was_ready = self.predictor.ready
        self._n_accepted += 1
        self._residual.record(value)
        error = value - predicted
        verdict = (self.rule.decide(error, math.nan, self._in_alarm, self.predictor,
                                    predicted) if was_ready else _UNJUDGED)
        alarm = verdict.alarm
        if alarm and not self._in_alarm:
            self._onset = t
        if alarm and self._clear_due(t):
            self._residual.reseed()
            self._in_alarm = False
            self._onset = math.nan
            return GreyDetectorOutput(t, value, predicted, error, False, math.nan, True, True)
        self._residual.paper_step(value, predicted, alarm)
        self._in_alarm = alarm
        if not alarm:
            self._onset = math.nan
        self._statistic = verdict.statistic
        return GreyDetectorOutput(
            t, value, predicted, error, alarm, self._onset, True, False, False,
            verdict.statistic)

    def _update_calibrated(self, value: float, t: float, predicted: float
                           ) -> GreyDetectorOutput:
        """One valid sample of a calibrated rule (class notes)."""
        was_ready = self.predictor.ready
        self._n_accepted += 1
        self._residual.record(value)
        self.rule.observe(value)
        if not was_ready:
            self._accept(value)
            self._residual.choice.feed(value)
            out = GreyDetectorOutput(t, value, predicted, math.nan, False, math.nan, True,
                                     False, True, 0.0)
        elif self._settle > 0:
            # after a timed clearing the re-seeded model settles on measured samples
            self._settle -= 1
            self.rule.snapshot(self.predictor, predicted)
            self._accept(value)
            out = GreyDetectorOutput(t, value, predicted, value - predicted, False,
                                     math.nan, True, False, False, 0.0)
        elif self._scale.learning:
            out = self._calibrate(value, t, predicted)
        else:
            out = self._judge(value, t, predicted)
        self._statistic = out.statistic
        return out

    def _calibrate(self, value: float, t: float, predicted: float) -> GreyDetectorOutput:
        """A calibration sample: fault-free by assumption."""
        error = value - predicted
        full = self._scale.collect(error)
        self._residual.choice.feed(value)
        self._accept(value)
        if full:
            self._residual.choose(self._scale)
            self._scale.learn()
        return GreyDetectorOutput(t, value, predicted, error, False, math.nan, True,
                                  False, self._scale.learning, 0.0)

    def _judge(self, value: float, t: float, predicted: float) -> GreyDetectorOutput:
        """A sample judged by the calibrated rule, then fed (or substituted)."""
        error = value - predicted
        verdict = self.rule.decide(error, self._scale.sigma, self._in_alarm,
                                   self.predictor, predicted)
        alarm = verdict.alarm
        if alarm and not self._in_alarm:
            self._onset = t
        if alarm and self._clear_due(t):
            self._residual.reseed(keep=True)
            self.rule.clear()
            self._in_alarm = False
            self._onset = math.nan
            # the re-seeded window may hold the fault's last samples and the fault may
            # have ended with them (the seed timeline's faults last exactly the 20 s of
            # the clearing): one window of measured samples settles the model before
            # errors count again, instead of a second alarm on the fault's end that a
            # substitute held over a moving signal would carry past it
            self._settle = self.predictor.min_samples
            return GreyDetectorOutput(t, value, predicted, error, False, math.nan, True,
                                      True, False, verdict.statistic)
        self._in_alarm = alarm
        if verdict.lag:
            state, pending = self.rule.rollback_point(verdict.lag)
            self.rule.interrupt()
            self._residual.roll_back(state, pending, verdict.lag)
        elif alarm or (verdict.suspect and not self._residual.substitution.exhausted):
            self.rule.interrupt()
            self._residual.substitute(predicted, alarm)
        else:
            self._onset = math.nan
            self._residual.take(value)
            self.rule.accept(value)
            self._scale.refine(error)
        if alarm:
            self.rule.restart()
        return GreyDetectorOutput(t, value, predicted, error, alarm,
                                  self._onset if alarm else math.nan, True, False, False,
                                  verdict.statistic)

    def _accept(self, value: float) -> None:
        """A fault-free sample, fed to the predictor and seen by the rule."""
        self._residual.accept(value)
        self.rule.accept(value)

    def get_state(self) -> dict[str, Any]:
        """Full state as a flat plain dict (deep copy); predictor keys are prefixed."""
        return _saved_state(self)

    def set_state(self, state: Mapping[str, Any]) -> None:
        """Restore a state from :meth:`get_state` of an identically built detector
        (ValueError if a key is missing or the stored window does not fit)."""
        _restore_state(self, state)


def _set_lag_test_arguments(det: GreyFaultDetector, lag_max: int, reference_window: int,
                            reference_order: int) -> None:
    """Check the lagged step test's constructor arguments and set them on ``det``."""
    det.lag_max = check_int("lag_max", lag_max)
    if det.lag_max > LAG_MAX_LIMIT:
        raise ValueError(f"lag_max must be in [0, {LAG_MAX_LIMIT}], got {lag_max!r}")
    det.reference_order = check_int("reference_order", reference_order)
    if det.reference_order > 3:
        raise ValueError(f"reference_order must be in [0, 3], got {reference_order!r}")
    det.reference_window = check_int("reference_window", reference_window,
                                      minimum=det.reference_order + 3)
    if det.reference_window > 400:
        raise ValueError(f"reference_window must be in [{det.reference_order + 3}, 400], "
                         f"got {reference_window!r}")


def _saved_state(det: GreyFaultDetector) -> dict[str, Any]:
    """:meth:`GreyFaultDetector.get_state`: the flat state in the saved layout."""
    state = det._residual.get_state()
    state.update(
        in_alarm=int(det._in_alarm),
        onset_time_s=float(det._onset),
        n_accepted=int(det._n_accepted),
        statistic=float(det._statistic),
        settle=int(det._settle),
    )
    state.update(det._scale.get_state())
    state.update(det.rule.get_state())
    # every rule's state has the CUSUM slot (zeros without a CUSUM)
    state.setdefault("cusum", np.zeros(2))
    return _in_layout_order(state)


def _restore_state(det: GreyFaultDetector, state: Mapping[str, Any]) -> None:
    """:meth:`GreyFaultDetector.set_state`: check that ``state`` fits ``det``, then
    load it."""
    missing = set(_STATE_LAYOUT) - set(state)
    if missing:
        raise ValueError(f"state is missing keys {sorted(missing)}")
    clean = np.array(state["clean"], dtype=float).reshape(-1)
    cusum = np.array(state["cusum"], dtype=float).reshape(-1)
    if clean.size > det.trend_samples or cusum.shape != (2,):
        raise ValueError("state['clean'] / state['cusum'] do not fit this detector")
    det._residual.set_state(state)
    det._in_alarm = bool(state["in_alarm"])
    det._onset = float(state["onset_time_s"])
    det._n_accepted = int(state["n_accepted"])
    det._statistic = float(state["statistic"])
    det._settle = int(state["settle"])
    det._scale.set_state(state)
    det.rule.set_state(state)


def _rule_for(det: GreyFaultDetector) -> DecisionRule:
    """The rule a detector's constructor arguments name (see its class notes)."""
    if not det.calibrated:
        return FixedThreshold(det.threshold)
    if not det.sequential:
        return KSigmaTest(det.k_sigma, det.threshold, det.suspicion_sigma)
    lag_test = None
    if det.lag_max:
        lag_test = LaggedStepTest(
            det.lag_max, det.reference_window, det.reference_order,
            det.false_alarms_per_h, det.sample_period_s, det.threshold / det.k_sigma)
    return SequentialTest(det.false_alarms_per_h, det.sample_period_s, det.cusum_k,
                          det.suspicion_sigma, lag_test)
