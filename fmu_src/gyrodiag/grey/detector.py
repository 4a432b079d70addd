"""The improved moving-window grey fault detector of the HRG (:class:`GreyFaultDetector`).

A sample farther than a threshold from the one-step prediction of a
:mod:`gyrodiag.grey.predictor` raises a fault alarm; a lagged step test looks at the
last few samples for a step the one-step test misses.
"""

from __future__ import annotations

import copy
import functools
import math
from collections import deque
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ..common._distributions import chi2_ppf
from ..common._records import fast_init
from ..common._validation import (
    check_int,
    check_nonnegative,
    check_positive,
)
from .predictor import GreyPredictor

__all__ = [
    "LAG_MAX_LIMIT",
    "LONGEST_LAG_SHARE",
    "GreyDetectorOutput",
    "GreyFaultDetector",
    "lag_step_weights",
    "lag_test_threshold",
]


# ------------------------------------------------------------------ lagged step test

LAG_MAX_LIMIT = 4
"""Largest number of recent samples the lagged step test looks at (samples)."""

LONGEST_LAG_SHARE = 2.0 / 3.0
"""Share of the lagged test's design false-alarm rate given to its longest lag."""

#: Variance of the third difference y(k) − 3y(k−1) + 3y(k−2) − y(k−3) of white noise of
#: unit variance (1 + 9 + 9 + 1), and its variance-estimate inflation 1 + 2Σρ² (lag
#: correlations −15/20, 6/20, −1/20): N third differences carry N / 2.31 degrees of freedom.
_D3_VARIANCE = 20.0
_D3_DOF_FACTOR = 1.0 + 2.0 * ((15.0 / 20.0) ** 2 + (6.0 / 20.0) ** 2 + (1.0 / 20.0) ** 2)


def lag_step_weights(window: int, order: int, lag: int) -> list[float]:
    """Weights of the generalised likelihood ratio for a step in the last ``lag`` samples.

    Parameters
    ----------
    window : int
        Reference window M (samples), >= order + 3: the M samples that end ``lag``
        samples before the newest one.
    order : int
        Degree of the least-squares polynomial fitted to the reference window and
        extrapolated over the last ``lag`` samples (0..3).
    lag : int
        Number of newest samples tested, 1..:data:`LAG_MAX_LIMIT`.

    Returns
    -------
    list of float, length window + lag
        w (oldest sample first) such that z = w·y / σ is the step test statistic for
        samples y with white noise of standard deviation σ: under no step z ~ N(0, 1)
        (exactly, for a polynomial signal of degree <= order), and a step of size Δ in
        the last ``lag`` samples adds Δ·Σ w[M:]/σ to it.

    Notes
    -----
    The errors e = y_new − A·y_ref of the extrapolation A (lag × M) of the reference fit
    have covariance σ²·C, C = I + A·Aᵀ; the step estimate is Δ̂ = 1ᵀC⁻¹e / 1ᵀC⁻¹1 with
    variance σ² / 1ᵀC⁻¹1, and z = Δ̂ / its standard deviation. The reference ends before
    the tested samples, so a step there cannot be absorbed by the model before it is
    judged (the one-step predictor takes a step in within two samples).
    """
    window = check_int("window", window, minimum=1)
    order = check_int("order", order)
    lag = check_int("lag", lag, minimum=1)
    if window < order + 3:
        raise ValueError(f"window must be >= order + 3 = {order + 3}, got {window}")
    k = np.arange(window + lag, dtype=float)
    centre = 0.5 * (window - 1)
    half = max(0.5 * (window - 1), 1.0)
    ref = np.vander((k[:window] - centre) / half, order + 1)
    ext = np.vander((k[window:] - centre) / half, order + 1)
    extrapolation = ext @ np.linalg.pinv(ref)
    errors = np.hstack([-extrapolation, np.eye(lag)])
    ci1 = np.linalg.solve(errors @ errors.T, np.ones(lag))
    return ((ci1 @ errors) / math.sqrt(float(ci1.sum()))).tolist()


@functools.lru_cache(maxsize=1024)
def _lag_weights_cached(window: int, order: int, lag: int) -> tuple[float, ...]:
    return tuple(lag_step_weights(window, order, lag))


def lag_test_threshold(false_alarms_per_h: float, sample_period_s: float, lags: int
                       ) -> float:
    """Threshold on |z| of the lagged step test for a design false-alarm rate.

    Parameters
    ----------
    false_alarms_per_h : float
        Design rate (1/h, > 0) of the test, all lags and both signs together.
    sample_period_s : float
        Sample period, s (> 0).
    lags : int
        Number of lags tested at every sample (>= 1).

    Returns
    -------
    float
        c with 2·lags·Q(c) = rate·T/3600 (Q the standard normal tail): a union bound over
        the lags and both signs, and over samples (the statistics of neighbouring
        samples share data and are positively correlated, so the real rate is lower).
    """
    from scipy.special import ndtri

    rate = check_positive("false_alarms_per_h", false_alarms_per_h)
    period = check_positive("sample_period_s", sample_period_s)
    lags = check_int("lags", lags, minimum=1)
    per_test = min(rate * period / 3600.0, 0.5) / (2.0 * lags)
    return float(-ndtri(per_test))


# ------------------------------------------------------------------ detector


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
        Bound on the substituted prediction, in units of the fault-free span (>= 0,
        dimensionless): while in alarm ŷ is kept within
        [lo − margin·(hi − lo), hi + margin·(hi − lo)], lo/hi the smallest and largest
        fault-free sample seen since reset. Default 1.
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
        Design false-alarm rate (1/h, default 1e-3) and reference (σ_e, default 1.5: the
        faults a grey predictor sees are steps of 4 σ_e and more; see docs/notes.md,
        grey detector).
    suspicion_sigma : float, optional
        Calibrated: a sample with |e| > suspicion_sigma·σ_e (or a CUSUM above half its
        threshold) is not fed to the predictor, so that a step is not absorbed before
        the test has decided (default 4; lower values lock the model into false alarms
        in noise, see docs/notes.md, grey detector).
    hold_after : int, optional
        Calibrated: suspect samples not followed by an alarm are substituted for at
        most this many samples in a row (default 1: a step of 4 σ_e gives two samples
        of evidence before the predictor absorbs it); in alarm the substitute is held
        after this many samples (see :meth:`_substitute`; longer runs false-alarm where
        the signal moves fast, see docs/notes.md, grey detector).
    candidates : sequence of predictors, optional
        Calibrated: other predictors (same window) run beside ``predictor`` during the
        warm-up and calibration; the one with the least root-mean-square error on the
        calibration window is kept (e.g. the improved model with residual orders 2, 1
        and 0: the quadratic residual fit is exact on a smooth noise-free signal and
        amplifies noise).
    lag_max : int, optional
        Sequential: the lagged step test looks at the last 1..lag_max samples (0..4,
        default 3; 0 turns it off and the CUSUM decides alone). See below.
    reference_window : int, optional
        Lagged test: longest reference window M, samples (default 60, in
        [reference_order + 3, 400]); the test starts with min(M, 20) samples after the
        start or an alarm and uses up to M as they come in.
    reference_order : int, optional
        Lagged test: degree of the reference polynomial (0..3, default 3).

    Calibrated detector
    -------------------
    With noise on the signal a fixed threshold either false-alarms or misses
    (docs/methods.md §3). The first ``calibrate_samples`` one-step prediction errors after the
    warm-up (assumed fault-free) give σ_e (see :func:`_calibrated_sigma`: winsorised,
    raised to its 95 % upper confidence bound) and the threshold
    max(k_sigma·σ_e, ``threshold``); σ_e keeps learning from the samples judged
    fault-free afterwards. While a sample is suspect or the detector is in alarm, the
    predictor is fed a bounded substitute (:meth:`_substitute`); a suspect sample that
    is not followed by an alarm within ``hold_after`` samples was noise, and the
    measurements are taken again (else a substitute held while the signal moves would
    make the next samples suspect in turn, and the detector would lock itself into a
    false alarm). The prediction error of a grey predictor on white noise is not white
    (the window's fit shares samples); its positive correlations are small
    and its long-run variance below its variance (the fit differences), so a CUSUM
    threshold from the white-noise table errs on the side of fewer false alarms.

    Lagged step test (sequential, ``lag_max`` > 0): a one-step predictor takes a step
    in within two samples, so the errors hold at most two samples of evidence. For each
    lag L the last L measured samples are tested against the least-squares polynomial
    of the ``reference_window`` samples before them, extrapolated: the generalised
    likelihood ratio of a step in those L samples, z_L = w_L·y / σ_n
    (:func:`lag_step_weights`; z_L ~ N(0, 1) without a step), σ_n the signal's white
    noise (:attr:`noise_sigma`). Alarm when |z_L| >= ``lag_thresholds[L − 1]``, set from
    ``false_alarms_per_h`` (:data:`LONGEST_LAG_SHARE` of it to L = ``lag_max``, the rest
    shared, :func:`lag_test_threshold`). On that alarm the predictor is taken back to
    its state before the L samples and fed the bounded substitute for them, and the
    CUSUM of the step's sign starts at its threshold, so the alarm lasts while the
    errors do. While the lagged test is ready the CUSUM only holds alarms: the improved
    model's one-step errors have heavier tails than a normal law (−4 σ_e at fixed phases
    of a moving signal), and a CUSUM on them false-alarmed ~1 per hour on fault-free
    HRG records at 2.5–5 mV of noise. It decides only until the lagged test is ready
    (after the start, and for 20 samples after an alarm). Measured on the seed-001
    timeline and 360 fault-free hours: docs/notes.md (HRG).

    Notes
    -----
    Per valid sample y(k): error e = y(k) − ŷ(k); alarm = |e| > threshold. While in
    alarm the predictor is fed ŷ(k) instead of y(k), so the model keeps extrapolating
    the fault-free signal and the alarm lasts as long as the fault instead of a single
    pulse (after one faulty sample a plain predictor would already have absorbed it).

    Bounded substitution: once the window holds only substituted samples the
    predictor extrapolates its own extrapolation, and the GM exponential and the
    quadratic residual compound without limit over a long alarm (docs/notes.md, grey
    detector). While in alarm, ŷ is therefore
    clipped to the envelope of the fault-free samples seen since reset widened by
    ``envelope_margin`` times its span, and once it has been clipped it is held at
    that value for the rest of the alarm (see :meth:`_bounded` for why). Inside the
    envelope the substitute is the predictor's own, as in the paper. The reported
    prediction (and so the error) is the bounded value.

    No alarm is possible before the predictor's window is full: the first
    ``min_samples`` samples are assumed fault-free. A non-finite prediction with a full
    window (only the textbook classic model on an exactly degenerate window produces
    one) raises the alarm: the detector cannot vouch for that sample.

    A NaN/inf sample is skipped: the state is not touched (the pending prediction
    stays for the next valid sample) and the output has ``valid=False``.
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
        self.predictor = predictor
        self.threshold = check_positive("threshold", threshold)
        self.calibrate_samples = check_int("calibrate_samples", calibrate_samples)
        self.k_sigma = check_positive("k_sigma", k_sigma)
        self.sequential = bool(sequential)
        self.false_alarms_per_h = check_positive("false_alarms_per_h", false_alarms_per_h)
        self.cusum_k = check_positive("cusum_k", cusum_k)
        self.suspicion_sigma = check_positive("suspicion_sigma", suspicion_sigma)
        self.hold_after = (
            1 if hold_after is None else check_int("hold_after", hold_after, minimum=1))
        # fault-free samples kept (re-seeding, diagnostics)
        self.trend_samples = max(20, 4 * predictor.min_samples)
        if self.sequential and self.calibrate_samples == 0:
            raise ValueError("sequential needs calibrate_samples > 0 (the CUSUM works on "
                             "errors in units of their calibrated standard deviation)")
        if self.calibrate_samples and self.calibrate_samples < 10:
            raise ValueError(f"calibrate_samples must be 0 or >= 10, got {calibrate_samples}")
        self.candidates = list(candidates)
        for cand in self.candidates:
            if cand.min_samples != predictor.min_samples:
                raise ValueError("candidates must need as many samples as the predictor "
                                 f"({predictor.min_samples}), got {cand.min_samples}")
        if self.candidates and not self.calibrate_samples:
            raise ValueError("candidates need calibrate_samples > 0 (they are compared on "
                             "the calibration window)")
        self._configured = predictor
        self.sample_period_s = check_positive("sample_period_s", sample_period_s)
        self.clear_after_s = (
            None if clear_after_s is None else check_positive("clear_after_s", clear_after_s)
        )
        self.reseed_length = (
            predictor.min_samples if reseed_length is None
            else check_int("reseed_length", reseed_length, minimum=1)
        )
        self.envelope_margin = check_nonnegative("envelope_margin", envelope_margin)
        self.lag_max = check_int("lag_max", lag_max)
        if self.lag_max > LAG_MAX_LIMIT:
            raise ValueError(f"lag_max must be in [0, {LAG_MAX_LIMIT}], got {lag_max!r}")
        self.reference_order = check_int("reference_order", reference_order)
        if self.reference_order > 3:
            raise ValueError(f"reference_order must be in [0, 3], got {reference_order!r}")
        self.reference_window = check_int("reference_window", reference_window,
                                          minimum=self.reference_order + 3)
        if self.reference_window > 400:
            raise ValueError(f"reference_window must be in [{self.reference_order + 3}, 400], "
                             f"got {reference_window!r}")
        # the lagged step test runs with the sequential decision only
        self._lags = self.lag_max if self.sequential else 0
        self.cusum_threshold = math.nan
        #: thresholds on |z| of the lagged test, lag 1 first (empty without it)
        self.lag_thresholds: list[float] = []
        #: shortest reference window the lagged test starts with (it grows to
        #: ``reference_window`` as measured samples come in)
        self.reference_min = min(self.reference_window, max(self.reference_order + 3, 20))
        self._lag_weights: dict[tuple[int, int], NDArray[np.float64]] = {}
        if self.sequential:
            from ..common.cusum import TABLE_LOG10_ARL, arl_for_rate, mean_cusum_threshold

            # the CUSUM decides only while the lagged test cannot (see class notes): each
            # has the whole design rate
            # at most the longest run length of the shipped table (1e13 samples, no false
            # alarm in any record; a very low rate at a fast sample would ask for more,
            # beyond what the CUSUM can be solved for at start-up)
            arl = min(arl_for_rate(self.false_alarms_per_h, self.sample_period_s, 2),
                      10.0 ** TABLE_LOG10_ARL[-1])
            self.cusum_threshold = mean_cusum_threshold(arl, self.cusum_k)
            if self._lags:
                # the longest lag gets LONGEST_LAG_SHARE of the design rate (it has the
                # most power on a step that is still inside the tested samples); the
                # shorter ones share the rest and are there for large steps, seen sooner
                shares = ([1.0] if self._lags == 1 else
                          [(1.0 - LONGEST_LAG_SHARE) / (self._lags - 1)] * (self._lags - 1)
                          + [LONGEST_LAG_SHARE])
                self.lag_thresholds = [
                    lag_test_threshold(share * self.false_alarms_per_h,
                                       self.sample_period_s, 1) for share in shares]
                self._lag_weights = {
                    (m, lag): np.array(_lag_weights_cached(m, self.reference_order, lag))
                    for m in range(self.reference_min, self.reference_window + 1)
                    for lag in range(1, self._lags + 1)}
        self.reset()

    @property
    def calibrated(self) -> bool:
        """This detector learns its threshold (``calibrate_samples`` > 0)."""
        return self.calibrate_samples > 0

    def reset(self) -> None:
        """Return to the state right after construction."""
        if hasattr(self, "_configured"):
            self.predictor = self._configured
            for cand in self.candidates:
                cand.reset()
        self.predictor.reset()
        self._cand_pending = [math.nan] * len(getattr(self, "candidates", ()))
        self._cand_sq = [0.0] * len(self._cand_pending)
        self._chosen = 0
        self._pending = math.nan
        self._in_alarm = False
        self._onset = math.nan
        # the newest measured samples (re-seeding); a bounded deque, not np.append per sample
        self._recent: deque[float] = deque(maxlen=self.reseed_length)
        self._n_accepted = 0
        self._envelope_min = math.inf
        self._envelope_max = -math.inf
        self._hold = math.nan
        self._cal_errors: list[float] = []
        self._statistic = 0.0  # of the last valid sample (held over skipped ones)
        self._sigma = math.nan
        self._sq_sum = 0.0  # squared errors judged fault-free (σ_e refinement)
        self._sq_n = 0
        self._cusum = [0.0, 0.0]
        self._clean: list[float] = []   # last fault-free samples (calibrated detector)
        self._n_clean = 0               # fault-free samples accepted so far
        self._substituting = False
        self._settle = 0  # samples left to settle after a timed clearing
        self._run = 0  # samples of the current substitution run
        self._held = math.nan
        # lagged step test: measured samples (reference window + tested lags), the
        # predictor's state and pending prediction before each of the last lags samples,
        # third differences of consecutive fault-free samples (noise σ)
        self._lag_buf: list[float] = []
        self._lag_hist: deque[tuple[dict[str, Any], float]] = deque(maxlen=self._lags or 1)
        self._noise_tail: list[float] = []
        self._noise_sq = 0.0
        self._noise_n = 0
        self._noise_sigma = math.nan
        self._lag_z = 0.0

    @property
    def sigma(self) -> float:
        """Calibrated: robust standard deviation of the fault-free prediction error
        (signal units); NaN before it is learned."""
        return self._sigma

    @property
    def threshold_in_use(self) -> float:
        """Alarm threshold on |e| (signal units) of the per-sample test in use; NaN while
        a calibrated detector is calibrating."""
        if not self.calibrated:
            return self.threshold
        if math.isnan(self._sigma):
            return math.nan
        return max(self.k_sigma * self._sigma, self.threshold)

    @property
    def alarm(self) -> bool:
        """Current alarm state."""
        return self._in_alarm

    @property
    def pending_prediction(self) -> float:
        """Prediction for the next sample (signal units), NaN during warm-up.

        Bounded while in alarm (the value the next output will report)."""
        return self._pending

    @property
    def envelope(self) -> tuple[float, float]:
        """(min, max) of the fault-free samples seen since reset, signal units.

        (inf, −inf) before the first sample."""
        return self._envelope_min, self._envelope_max

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
        predicted = self._pending
        if not math.isfinite(value):
            return GreyDetectorOutput(
                t, value, predicted, math.nan, self._in_alarm, self._onset, False, False,
                self.calibrated and (math.isnan(self._sigma) or not self.predictor.ready),
                self._statistic,
            )
        if self.calibrated:
            out = self._update_calibrated(value, t, predicted)
            self._statistic = out.statistic
            return out

        was_ready = self.predictor.ready
        self._n_accepted += 1
        self._recent.append(value)
        error = value - predicted
        if not was_ready:
            alarm = False
        elif not math.isfinite(predicted):
            alarm = True
        else:
            alarm = abs(error) > self.threshold
        if alarm and not self._in_alarm:
            self._onset = t

        if alarm and self.clear_after_s is not None and (
            t - self._onset >= self.clear_after_s - 1e-6 * self.sample_period_s
        ):
            self._reseed()
            self._in_alarm = False
            self._onset = math.nan
            return GreyDetectorOutput(t, value, predicted, error, False, math.nan, True, True)

        substitute = alarm and math.isfinite(predicted)
        if not alarm:
            self._widen_envelope(value)
        self._pending = self.predictor.update(predicted if substitute else value)
        self._in_alarm = alarm
        if alarm:
            self._pending = self._bounded(self._pending)
        else:
            self._onset = math.nan
            self._hold = math.nan
        stat = abs(error) / self.threshold if was_ready and math.isfinite(error) else 0.0
        self._statistic = stat
        return GreyDetectorOutput(
            t, value, predicted, error, alarm, self._onset, True, False, False, stat
        )

    def _update_calibrated(self, value: float, t: float, predicted: float
                           ) -> GreyDetectorOutput:
        """One sample of the calibrated detector (class notes)."""
        was_ready = self.predictor.ready
        self._n_accepted += 1
        self._recent.append(value)
        if self._lags:
            self._lag_buf.append(value)
            if len(self._lag_buf) > self.reference_window + self._lags:
                del self._lag_buf[0]
        if not was_ready:
            self._accept(value)
            self._feed_candidates(value)
            return GreyDetectorOutput(t, value, predicted, math.nan, False, math.nan, True,
                                      False, True, 0.0)
        error = value - predicted
        if self._settle > 0:
            # after a timed clearing the re-seeded model settles on measured samples
            self._settle -= 1
            self._snapshot(predicted)
            self._accept(value)
            return GreyDetectorOutput(t, value, predicted, error, False, math.nan, True,
                                      False, False, 0.0)
        if math.isnan(self._sigma):
            # calibration: fault-free by assumption
            if math.isfinite(error):
                self._cal_errors.append(error)
            self._feed_candidates(value)
            self._accept(value)
            if len(self._cal_errors) >= self.calibrate_samples:
                self._choose_predictor()
                e = np.asarray(self._cal_errors)
                self._sigma = max(_calibrated_sigma(e), self.threshold / self.k_sigma)
                centre = float(np.median(e))
                self._sq_sum = float(np.sum((e - centre) ** 2))
                self._sq_n = e.size
                self._cal_errors = []
            return GreyDetectorOutput(t, value, predicted, error, False, math.nan, True,
                                      False, math.isnan(self._sigma), 0.0)
        sigma = self._sigma
        z = error / sigma if math.isfinite(error) else math.inf
        lag_alarm = 0
        if self.sequential:
            h, k = self.cusum_threshold, self.cusum_k
            up = min(max(self._cusum[0] + z - k, 0.0), h)
            down = min(max(self._cusum[1] - z - k, 0.0), h)
            self._cusum = [up, down]
            top = max(up, down)
            # with the lagged test ready, the CUSUM only holds an alarm (its one-step
            # errors have heavier tails than a normal law, see class notes)
            deciding = not (self._lags and self.lag_test_ready)
            alarm = (deciding and top >= h) or (self._in_alarm and top >= 0.5 * h)
            stat = top / h if deciding or self._in_alarm else 0.0
            suspect = abs(z) > self.suspicion_sigma or top > 0.5 * h
            if self._lags and not self._in_alarm:
                self._snapshot(predicted)
                lag, lag_z, lag_ratio = self._lag_test()
                stat = max(stat, lag_ratio)
                if lag and not alarm:
                    # a step in the last ``lag`` samples: the CUSUM of its sign starts
                    # at its threshold, so the alarm lasts while the errors do
                    alarm = True
                    lag_alarm = lag
                    self._cusum[0 if lag_z > 0.0 else 1] = h
        else:
            limit = max(self.k_sigma * sigma, self.threshold)
            alarm = abs(error) > limit if math.isfinite(error) else True
            stat = abs(error) / limit if math.isfinite(error) else 1.0
            suspect = abs(z) > self.suspicion_sigma
        if alarm and not self._in_alarm:
            self._onset = t
        if alarm and self.clear_after_s is not None and (
            t - self._onset >= self.clear_after_s - 1e-6 * self.sample_period_s
        ):
            self._reseed()
            self._cusum = [0.0, 0.0]
            self._in_alarm = False
            self._onset = math.nan
            self._substituting = False
            self._forget_lagged()
            # the re-seeded window may hold the fault's last samples and the fault may
            # have ended with them (the seed timeline's faults last exactly the 20 s of
            # the clearing): one window of measured samples settles the model before
            # errors count again, instead of a second alarm on the fault's end that a
            # substitute held over a moving signal would carry past it
            self._settle = self.predictor.min_samples
            return GreyDetectorOutput(t, value, predicted, error, False, math.nan, True,
                                      True, False, stat)
        self._in_alarm = alarm
        if lag_alarm:
            self._roll_back(lag_alarm)
        elif alarm or (suspect and not (self._substituting and self._run >= self.hold_after)):
            self._noise_tail.clear()
            self._pending = self.predictor.update(self._substitute(predicted))
            if alarm:
                # the prediction the next sample is judged against stays bounded too
                self._pending = self._clip(self._pending)
        else:
            self._substituting = False
            self._onset = math.nan
            self._pending = self.predictor.update(value)
            self._accept(value, predict=False)
            self._refine_sigma(error)
        if alarm and self._lags:
            self._forget_lagged()
        return GreyDetectorOutput(t, value, predicted, error, alarm,
                                  self._onset if alarm else math.nan, True, False, False,
                                  stat)

    def _snapshot(self, predicted: float) -> None:
        """Lagged test: keep the predictor's state and pending prediction from before this
        sample, so that an alarm on a step in the last samples can take the model back
        to before the step."""
        if self._lags:
            self._lag_hist.append((self.predictor.get_state(), predicted))

    def _forget_lagged(self) -> None:
        """Start the lagged test's reference afresh (alarm, clearing): its window must
        hold measured samples of the signal as it is now."""
        self._lag_buf.clear()
        self._lag_hist.clear()
        self._noise_tail.clear()
        self._lag_z = 0.0

    @property
    def noise_sigma(self) -> float:
        """Lagged test: standard deviation of the signal's white noise (signal units),
        from the third differences of consecutive fault-free samples, raised to its 95 %
        upper confidence bound, and ``threshold / k_sigma`` added in quadrature (an
        allowance for the reference polynomial's model error, which is what remains on a
        noise-free signal); NaN before ten
        differences are known or without the lagged test."""
        n = self._noise_n
        if not self._lags or n < 10:
            return math.nan
        dof = n / _D3_DOF_FACTOR
        c = 2.0 / (9.0 * dof)
        # χ²(0.05, dof) by Wilson–Hilferty (within 1 % for dof >= 4)
        q05 = dof * (1.0 - c - 1.6448536269514722 * math.sqrt(c)) ** 3
        var = self._noise_sq / (_D3_VARIANCE * n) * dof / q05
        return math.sqrt(var + (self.threshold / self.k_sigma) ** 2)

    @property
    def lag_statistic(self) -> float:
        """Lagged test: the z of the last sample with the largest |z| over the lags
        (dimensionless, alarm at |z| >= ``lag_thresholds[lag − 1]``); 0 when not
        tested."""
        return self._lag_z

    def _lag_test(self) -> tuple[int, float, float]:
        """(lag, z, ratio) of the lag with the largest |z| / threshold among those that
        can be tested now; lag is 0 when that ratio stays below 1."""
        sigma = self.noise_sigma
        buf = self._lag_buf
        m = self.reference_window
        best_lag, best_z, best_ratio = 0, 0.0, 0.0
        if math.isnan(sigma):
            self._lag_z = 0.0
            return 0, 0.0, 0.0
        arr = np.asarray(buf, dtype=float)
        for lag in range(1, min(self._lags, len(self._lag_hist)) + 1):
            ref = min(m, len(buf) - lag)
            if ref < self.reference_min:
                break
            z = float(np.dot(self._lag_weights[ref, lag], arr[-(ref + lag):])) / sigma
            ratio = abs(z) / self.lag_thresholds[lag - 1]
            if ratio > best_ratio:
                best_lag, best_z, best_ratio = lag, z, ratio
        self._lag_z = best_z
        return (best_lag if best_ratio >= 1.0 else 0), best_z, best_ratio

    @property
    def lag_test_ready(self) -> bool:
        """The lagged step test decides on the sample being processed (noise known, at
        least ``reference_min`` + 1 measured samples, this one included, since the start
        or the last alarm)."""
        return (bool(self._lags) and not math.isnan(self.noise_sigma)
                and len(self._lag_buf) > self.reference_min)

    def _roll_back(self, lag: int) -> None:
        """A step in the last ``lag`` samples: the predictor goes back to its state
        before them and is fed the bounded substitute for each (as in alarm), so that
        the alarm's substitute extrapolates the signal from before the step."""
        state, pending = self._lag_hist[-lag]
        self.predictor.set_state(state)
        self._noise_tail.clear()
        self._substituting = False
        pred = pending
        for _ in range(lag):
            pred = self.predictor.update(self._substitute(pred))
        self._pending = self._clip(pred)

    def _refine_sigma(self, error: float) -> None:
        """σ_e keeps learning from the samples judged fault-free: they are only those
        within ``suspicion_sigma``, whose mean square is that fraction of the full
        variance (a truncated normal), and the upper-confidence factor shrinks as they
        add up; σ_e never falls below the calibration window's point estimate by more
        than the noise of the estimate allows, and never below the floor."""
        if not math.isfinite(error):
            return
        self._sq_sum += error * error
        self._sq_n += 1
        s = self.suspicion_sigma
        # E[z² | |z| < s] for z ~ N(0, 1)
        from scipy.special import erf

        kept = erf(s / math.sqrt(2.0))
        truncated = 1.0 - 2.0 * s * math.exp(-0.5 * s * s) / math.sqrt(2.0 * math.pi) / kept
        n = self._sq_n
        rms = math.sqrt(self._sq_sum / n / truncated)
        self._sigma = max(rms * math.sqrt(n / chi2_ppf(0.05, n)),
                          self.threshold / self.k_sigma)

    def _feed_candidates(self, value: float) -> None:
        """Calibration: the candidates see the same samples; their squared errors add up
        from the first prediction on, as the main predictor's do."""
        for i, cand in enumerate(self.candidates):
            previous = self._cand_pending[i]
            if math.isfinite(previous):
                self._cand_sq[i] += (value - previous) ** 2
            self._cand_pending[i] = cand.update(value)

    def _choose_predictor(self) -> None:
        """End of calibration: keep the candidate with the least error (the configured
        predictor on ties); its errors become the calibration errors."""
        if not self.candidates:
            return
        own = float(np.sum(np.square(self._cal_errors)))
        best = min(range(len(self.candidates)), key=self._cand_sq.__getitem__)
        if self._cand_sq[best] < own:
            self.predictor = self.candidates[best]
            self._pending = self._cand_pending[best]
            self._chosen = best + 1
            # the calibration errors of the chosen one: rescale (only σ is used)
            scale = math.sqrt(self._cand_sq[best] / own) if own > 0.0 else 1.0
            self._cal_errors = [e * scale for e in self._cal_errors]

    @property
    def chosen_predictor(self) -> int:
        """0: the configured predictor is in use, i: ``candidates[i − 1]``."""
        return self._chosen

    def _accept(self, value: float, predict: bool = True) -> None:
        """A fault-free sample: envelope, the substitute line's data, (optionally) the
        predictor."""
        if predict:
            self._pending = self.predictor.update(value)
        self._widen_envelope(value)
        self._clean.append(value)
        if len(self._clean) > self.trend_samples:
            del self._clean[0]
        self._n_clean += 1
        if self._lags:
            tail = self._noise_tail
            tail.append(value)
            if len(tail) == 4:
                d3 = ((tail[3] - tail[0]) - 3.0 * (tail[2] - tail[1]))
                self._noise_sq += d3 * d3
                self._noise_n += 1
                del tail[0]

    def _clip(self, value: float) -> float:
        """``value`` limited to the fault-free envelope widened by ``envelope_margin``
        spans (NaN stays NaN)."""
        if not math.isfinite(value):
            return value
        span = self._envelope_max - self._envelope_min
        lo = self._envelope_min - self.envelope_margin * span
        hi = self._envelope_max + self.envelope_margin * span
        return min(max(value, lo), hi)

    def _substitute(self, prediction: float) -> float:
        """The value fed to the predictor instead of a suspect or faulty sample: the
        predictor's own prediction (the paper's substitution) for the first
        ``hold_after`` samples of a substitution run, then held at the last of them,
        and always clipped to the widened envelope. A predictor fed its own
        extrapolation compounds it (volts within 20 s at 20 mV of noise, docs/methods.md §3); a
        straight line fitted to the last fault-free samples misses the seed-001
        profile's curvature by ~0.05 V within its own window. Holding after a few
        samples bounds the drift by what the model extrapolates in that time."""
        span = self._envelope_max - self._envelope_min
        lo = self._envelope_min - self.envelope_margin * span
        hi = self._envelope_max + self.envelope_margin * span
        if not self._substituting:
            self._substituting = True
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

    def _widen_envelope(self, value: float) -> None:
        self._envelope_min = min(self._envelope_min, value)
        self._envelope_max = max(self._envelope_max, value)

    def _bounded(self, prediction: float) -> float:
        """The substitute for the next sample while in alarm (signal units).

        The predictor's own value, clipped to the envelope of all fault-free samples
        since reset widened by ``envelope_margin`` spans (wide enough for the signal's
        legitimate motion, and it catches a runaway). Once clipped, the value is held
        until the alarm ends or is cleared: a polynomial extrapolator fed a clipped,
        kinked window turns around and re-enters, so the alarm would chatter. The
        designs compared: docs/notes.md, grey detector.
        """
        if not math.isfinite(prediction):
            return prediction
        if not math.isnan(self._hold):
            return self._hold
        span = self._envelope_max - self._envelope_min
        lo = self._envelope_min - self.envelope_margin * span
        hi = self._envelope_max + self.envelope_margin * span
        if lo <= prediction <= hi:
            return prediction
        self._hold = min(max(prediction, lo), hi)
        return self._hold

    def _reseed(self) -> None:
        self.predictor.reset()
        self._pending = math.nan
        self._hold = math.nan
        # the re-seeded samples are the new reference signal (the paper's clearing
        # accepts them), so they count as fault-free for the envelope too
        for v in self._recent:
            self._widen_envelope(float(v))
            self._pending = self.predictor.update(float(v))
        if self.calibrated:
            self._clean = [float(v) for v in self._recent]
            self._substituting = False

    def get_state(self) -> dict[str, Any]:
        """Full state as a flat plain dict (deep copy); predictor keys are prefixed."""
        state: dict[str, Any] = {
            f"predictor.{key}": copy.deepcopy(val)
            for key, val in self.predictor.get_state().items()
        }
        state.update(
            pending_prediction=float(self._pending),
            in_alarm=int(self._in_alarm),
            onset_time_s=float(self._onset),
            recent=np.array(self._recent, dtype=float),
            n_accepted=int(self._n_accepted),
            envelope_min=float(self._envelope_min),
            envelope_max=float(self._envelope_max),
            hold=float(self._hold),
            cal_errors=np.asarray(self._cal_errors, dtype=float),
            sigma=float(self._sigma),
            statistic=float(self._statistic),
            sq_sum=float(self._sq_sum),
            sq_n=int(self._sq_n),
            cusum=np.asarray(self._cusum, dtype=float),
            clean=np.asarray(self._clean, dtype=float),
            n_clean=int(self._n_clean),
            substituting=int(self._substituting),
            run=int(self._run),
            settle=int(self._settle),
            held=float(self._held),
            chosen=int(self._chosen),
            cand_pending=np.asarray(self._cand_pending, dtype=float),
            cand_sq=np.asarray(self._cand_sq, dtype=float),
        )
        for i, cand in enumerate(self.candidates):
            for key, val in cand.get_state().items():
                state[f"candidate{i}.{key}"] = copy.deepcopy(val)
        if self._lags:
            state.update(
                lag_buf=np.asarray(self._lag_buf, dtype=float),
                lag_hist_pending=np.array([p for _, p in self._lag_hist], dtype=float),
                noise_tail=np.asarray(self._noise_tail, dtype=float),
                noise_sq=float(self._noise_sq),
                noise_n=int(self._noise_n),
                lag_z=float(self._lag_z),
            )
            for i, (snap, _) in enumerate(self._lag_hist):
                for key, val in snap.items():
                    state[f"lag_hist{i}.{key}"] = copy.deepcopy(val)
        return state

    def set_state(self, state: Mapping[str, Any]) -> None:
        """Restore a state from :meth:`get_state` of an identically built detector.

        Raises
        ------
        ValueError
            If a key is missing or the stored window does not fit.
        """
        own = {
            "pending_prediction", "in_alarm", "onset_time_s", "recent", "n_accepted",
            "envelope_min", "envelope_max", "hold", "cal_errors", "sigma", "statistic",
            "sq_sum", "sq_n",
            "cusum", "clean",
            "n_clean", "substituting", "run", "settle", "held", "chosen", "cand_pending",
            "cand_sq",
        }
        missing = own - set(state)
        if missing:
            raise ValueError(f"state is missing keys {sorted(missing)}")
        recent = np.array(state["recent"], dtype=float).reshape(-1)
        clean = np.array(state["clean"], dtype=float).reshape(-1)
        cusum = np.array(state["cusum"], dtype=float).reshape(-1)
        if clean.size > self.trend_samples or cusum.shape != (2,):
            raise ValueError("state['clean'] / state['cusum'] do not fit this detector")
        if recent.size > self.reseed_length:
            raise ValueError(
                f"state['recent'] holds {recent.size} samples, "
                f"reseed_length is {self.reseed_length}"
            )
        chosen = int(state["chosen"])
        if not 0 <= chosen <= len(self.candidates):
            raise ValueError(f"state['chosen'] must be in [0, {len(self.candidates)}]")
        for i, cand in enumerate(self.candidates):
            pre = f"candidate{i}."
            cand.set_state({k[len(pre):]: copy.deepcopy(v) for k, v in state.items()
                            if k.startswith(pre)})
        self.predictor = self._configured if chosen == 0 else self.candidates[chosen - 1]
        self._chosen = chosen
        self._cand_pending = [float(x) for x in np.asarray(state["cand_pending"]).reshape(-1)]
        self._cand_sq = [float(x) for x in np.asarray(state["cand_sq"]).reshape(-1)]
        prefix = "predictor."
        self.predictor.set_state(
            {k[len(prefix):]: copy.deepcopy(v) for k, v in state.items() if k.startswith(prefix)}
        )
        self._pending = float(state["pending_prediction"])
        self._in_alarm = bool(state["in_alarm"])
        self._onset = float(state["onset_time_s"])
        self._recent = deque((float(x) for x in recent), maxlen=self.reseed_length)
        self._n_accepted = int(state["n_accepted"])
        self._envelope_min = float(state["envelope_min"])
        self._envelope_max = float(state["envelope_max"])
        self._hold = float(state["hold"])
        self._cal_errors = [float(x) for x in np.asarray(state["cal_errors"]).reshape(-1)]
        self._sigma = float(state["sigma"])
        self._statistic = float(state["statistic"])
        self._sq_sum = float(state["sq_sum"])
        self._sq_n = int(state["sq_n"])
        self._cusum = [float(cusum[0]), float(cusum[1])]
        self._clean = [float(x) for x in clean]
        self._n_clean = int(state["n_clean"])
        self._run = int(state["run"])
        self._settle = int(state["settle"])
        self._held = float(state["held"])
        self._substituting = bool(state["substituting"])
        self._set_lag_state(state)

    def _set_lag_state(self, state: Mapping[str, Any]) -> None:
        """The lagged test's part of :meth:`set_state` (a state saved without it, or by a
        detector without the test, starts the test afresh)."""
        self._lag_hist = deque(maxlen=self._lags or 1)
        if not self._lags or "lag_buf" not in state:
            self._lag_buf, self._noise_tail = [], []
            self._noise_sq, self._noise_n, self._lag_z = 0.0, 0, 0.0
            return
        buf = np.array(state["lag_buf"], dtype=float).reshape(-1)
        pending = np.array(state["lag_hist_pending"], dtype=float).reshape(-1)
        tail = np.array(state["noise_tail"], dtype=float).reshape(-1)
        if (buf.size > self.reference_window + self._lags or pending.size > self._lags
                or tail.size > 3):
            raise ValueError("state['lag_buf'] / state['lag_hist_pending'] / "
                             "state['noise_tail'] do not fit this detector")
        for i, p in enumerate(pending):
            pre = f"lag_hist{i}."
            snap = {k[len(pre):]: copy.deepcopy(v) for k, v in state.items()
                    if k.startswith(pre)}
            self._lag_hist.append((snap, float(p)))
        self._lag_buf = buf.tolist()
        self._noise_tail = tail.tolist()
        self._noise_sq = float(state["noise_sq"])
        self._noise_n = int(state["noise_n"])
        self._lag_z = float(state["lag_z"])


def _calibrated_sigma(errors: NDArray[np.float64]) -> float:
    """Standard deviation of fault-free prediction errors, made robust and safe: the
    errors are winsorised at 5 robust σ (1.4826 × MAD) so that one outlier does not
    inflate it, and the root mean square is raised to its one-sided 95 % upper
    confidence bound (χ², N samples), since a threshold set from an underestimated σ
    false-alarms (on 40 samples the bound is 1.23 σ̂)."""
    n = errors.size
    centre = float(np.median(errors))
    robust = 1.4826 * float(np.median(np.abs(errors - centre)))
    if robust > 0.0:
        errors = np.clip(errors, centre - 5.0 * robust, centre + 5.0 * robust)
    rms = math.sqrt(float(np.mean((errors - centre) ** 2)))
    return rms * math.sqrt(n / chi2_ppf(0.05, n))
