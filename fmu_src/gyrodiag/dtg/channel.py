"""The DTG diagnosis channel: prefilter → regressors → estimators → decision → class.

One object per monitored gyro, fed one sample of (Utx, Uty, Ux, Uy) per sample period.
It identifies θ on both axes with its own estimator each and learns the nominal θ0 from
an initial fault-free window (or takes it as given). Two classifiers:

* ``"paper"`` (the paper's rule, kept so that the seed scenarios reproduce it): each
  axis is judged by the ratio band on η = |θ|/|θ0| and an alarm is classified by the
  nearest decade signature C = round(log10 η).
* ``"pattern"`` (default): the learning window is checked and frozen as a nominal
  reference (:mod:`gyrodiag.dtg.reference`); residual tests against it keep an alarm for
  as long as a fault lasts; an alarm is classified by fitting the learned response
  patterns of every fault type on every signal (:mod:`gyrodiag.dtg.patterns`), which
  names the fault type, the signal and axis, a distance and the fault's size. The ratio
  band on η still alarms too (physical faults move θ without changing the residuals
  much) and such an alarm is classified against the physical classes.

The Diagnoser FMU only maps its variables onto this class.
"""

from __future__ import annotations

import functools
import math
from collections import deque
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace
from typing import Any, Literal

import numpy as np
from numpy.typing import NDArray

from ..common._records import fast_init
from ..common._validation import (
    check_finite_array,
    check_in_range,
    check_int,
    check_nonnegative,
    check_positive,
)
from ..common.estimators import RLS, ForgettingRLS, SlidingWindowLS
from ..common.prefilter import ButterworthPrefilter
from ..common.state import migrate, stamp
from .alignment import CaseRateAligner
from .case_rate import (
    CASE_RATE_SCHEMES,
    CaseRateDTGRegressor,
    physical_from_theta_central,
)
from .decision import (
    UNKNOWN_CODE,
    SignatureClassifier,
    ThresholdDecision,
    WindowedMedianFeature,
    feature_floats,
)
from .model import N_THETA, DTGRegressor
from .patterns import PatternClassifier, PatternLibrary, PatternResult
from .reference import (
    ALLOWANCE_SIGMA,
    N_CHANNELS,
    N_TESTS,
    POWER_THRESHOLD,
    REFERENCE_STATUS,
    ClassificationStatistics,
    NominalPrior,
    NominalReference,
    ReferenceLearner,
    RegressionModel,
    ResidualMonitor,
    ResidualThresholds,
)

__all__ = [
    "AUTO_SETTINGS",
    "CLASSIFIERS",
    "ESTIMATOR_KINDS",
    "DTGChannel",
    "DTGChannelConfig",
    "DTGChannelOutput",
]

EstimatorKind = Literal["batch", "rls", "forgetting"]
#: Estimator kinds with their Integer codes used by the FMU (0, 1, 2).
ESTIMATOR_KINDS: tuple[EstimatorKind, ...] = ("batch", "rls", "forgetting")
ClassifierKind = Literal["paper", "pattern"]
#: Classifiers (the FMU's String parameter ``dtg.classifier``).
CLASSIFIERS: tuple[ClassifierKind, ...] = ("paper", "pattern")
#: Block length of the reference statistics, s (rounded to whole samples).
BLOCK_S = 0.025
#: Automatic settings, by use: on a bench (case at rest) the paper's chain; with the case
#: rate (manoeuvres) slower forgetting, a longer learning window and a fine ratio band
#: held 0.1 s of 0.2 s, so that manoeuvre edges do not alarm and physical faults do
#: (docs/dtg_case_rate.md). Persistence in seconds (0: one sample).
AUTO_SETTINGS: dict[str, dict[str, float]] = {
    "bench": {"forgetting": 0.999, "learn_start_s": 1.0, "learn_end_s": 5.0,
              "low": 0.5, "high": 1.5, "persistence_k": 0.0, "persistence_n": 0.0},
    "case_rate": {"forgetting": 0.9998, "learn_start_s": 2.0, "learn_end_s": 10.0,
                  "low": 0.93, "high": 1.07, "persistence_k": 0.1, "persistence_n": 0.2},
}
#: Auto prefilter cut-off as a fraction of the sample rate: the paper's 50 Hz at 1 kHz.
AUTO_CUTOFF_FRACTION = 0.05
#: Reference status when the guard could not run (paper classifier, too little data).
STATUS_NOT_CHECKED = 4
#: Reference status when learning ended without any usable reference (no excitation in
#: the window, e.g. a host's default zero inputs): the channel never alarms.
STATUS_FAILED = 5
#: Case rate: a block whose filtered ω lies more than this many learning-window spreads
#: from the learning mean is a manoeuvre block; a classification window holding one
#: compares only the residuals with the library (ClassificationStatistics.raw_signals).
OMEGA_EXCITATION_Z = 6.0
#: Case rate in a manoeuvre: a signal-fault fit to the residuals alone worse than this
#: (distance per library component) leaves a band alarm to the physical classes. In a
#: manoeuvre the physical fits are poor for every fault (distance 13-18 measured, spin
#: included), while a signal fault's residual fit is 0.04-0.08 and a spin's ~4.
MASKED_SIGNAL_FIT = 1.0
#: Default significance of a band violation, standard errors (:attr:`DTGChannelConfig.
#: band_sigma`). Library chain, calm level flight: largest |θ − θ0| in 4 × 600 s 3.95 of
#: them (θ5, whose standard error is accurate; ≤ 1.9 on θ3/θ4, whose v·A⁻¹ is
#: conservative); with 3× the pick-off noise θ5 left the band at 3.6-3.9 of them (3
#: false-alarmed there, 5 did not); torquer gain ±10 % reaches 5 within 4-8.5 s
#: (docs/dtg_case_rate.md §10).
BAND_SIGMA = 5.0
#: Smallest spread of the learning blocks' ω used for that test, rad/s (a noise-free
#: case rate would make every rounding a manoeuvre).
OMEGA_SPREAD_FLOOR = 1e-6


@dataclass
class DTGChannelConfig:
    """Settings of a :class:`DTGChannel` (validated by :meth:`validate`).

    Attributes
    ----------
    sample_period_s : float
        Sample period T of the signals, s (paper: 1 ms).
    prefilter_enabled : bool
        Apply the Butterworth prefilter to all four signals.
    prefilter_order : int
        Butterworth order (paper: 6).
    prefilter_cutoff_hz : float or None
        Cut-off frequency, Hz; None: :data:`AUTO_CUTOFF_FRACTION` of the sample rate
        (the paper's 50 Hz at its 1 kHz), so that it follows ``sample_period_s``.
    prefilter_highpass_hz : float or None
        Optional high-pass corner, Hz (2nd order, cascaded: a band-pass). Removes the
        slow torquer response to case rates, which the regression does not model; None
        (paper) keeps the low-pass only.
    estimator : {"batch", "rls", "forgetting"}
        Sliding-window batch LS, RLS, or RLS with forgetting factor.
    window : int
        Window length of the batch estimator, samples (each sample adds one row).
    forgetting : float or None
        Forgetting factor of the "forgetting" estimator. Paper: 0.99 (on the DTG FMU
        chain it scatters θ3/θ4 by 14 % and false-alarms in the paper band). None:
        automatic, 0.999 on a bench, 0.9998 with the case rate (:data:`AUTO_SETTINGS`,
        as every None below).
    p0 : float
        Initial covariance scale of the RLS estimators.
    theta0 : sequence of 5 floats or None
        Nominal θ0. None: learn it as the mean θ over the learning window.
    learn_start_s, learn_end_s : float or None
        Learning window for θ0, s from the first sample (used when theta0 is None);
        automatic 1–5 s, 2–10 s with the case rate.
    low, high : float or None
        Ratio band for η (paper and automatic: 0.5, 1.5; with the case rate 0.93, 1.07).
    persistence_k, persistence_n : int or None
        Alarm when k of the last n samples violate the band; automatic 1 of 1, with the
        case rate 0.1 s of 0.2 s.
    band_sigma : float
        Case rate with the pattern classifier (and the "forgetting" or "rls"
        estimator): a ratio outside the band counts as a violation only where θ also
        lies more than this many standard errors from the band's θ0, the standard error
        combining the estimate's (v·P/(1 + λ), P its RLS covariance) and θ0's (v·A⁻¹,
        :class:`~gyrodiag.dtg.reference.NominalReference`); θ0 is then refined by the
        blocks quiet in the residual tests and within half this many standard errors.
        In calm level flight the fast estimate of θ3/θ4 wanders by ~1.6 % (τ ≈ 5 s)
        about a θ0 known to ~1.6 %, so a fixed 7 % band alone false-alarms within
        minutes (docs/notes.md, issue 16). 0: the band alone (the paper's rule, and every
        channel without the case rate).
    latch : bool
        Keep an alarm until reset.
    monitored : sequence of 5 bool
        Parameters taking part in the decision.
    signatures : mapping of str to 5 ints
        Fault signature library C_j; codes 1, 2, … in order. Empty: alarms are
        reported with code ``UNKNOWN_CODE``.
    max_distance : float or None
        Feature vectors farther than this from every signature are "unknown".
    classify_window_s : float
        Paper classifier: an alarm is classified by the median feature of the alarm
        samples in the last ``classify_window_s`` seconds, both ends included
        (round(w/T) + 1 samples; :func:`~gyrodiag.dtg.decision.median_feature`), the rule by
        which signatures are learned (``harness learn-signatures``, 0.5 s); the
        per-sample feature flickers between classes. 0: each sample's own feature (the
        paper's rule).
    classifier : {"pattern", "paper"}
        Pattern classification with the frozen reference and its residual tests
        (default), or the paper's decade signatures (``signatures``).
    patterns : PatternLibrary or None
        Learned pattern library of the "pattern" classifier (None: alarms are
        "unknown"). Its nominal prior, if any, guards the reference learning.
    window_s : float
        Window of the residual level and variance tests, s (also the shortest window an
        alarm is classified on).
    long_window_s : float
        Window of the long variance test and the longest classification window, s.
    level_threshold, var_threshold, long_var_threshold : float
        Raise thresholds of the residual tests (:class:`~gyrodiag.dtg.reference.
        ResidualThresholds`): level z, short- and long-window variance ratios.
    theta_spread_threshold : float
        Learning guard: a segment's θ spread against the segments before it.
    power_threshold : float
        Threshold h of the residuals' low-frequency power CUSUM
        (:mod:`~gyrodiag.dtg.reference`; the torquer read-out noise witness); 0 switches
        it off.
    allowance_sigma : float
        Case rate only: the reference's error the variance-type residual tests allow
        for, in standard deviations of its covariance (:class:`~gyrodiag.dtg.reference.
        ResidualThresholds`; 1 is the channel's first, tighter rule).
    clear_after_s : float
        An alarm of the residual tests clears this long after the last block in which a
        test exceeded its hold threshold.
    case_rate : {"central", "paper"} or None
        None (default): the paper's regression, the case at rest; ``update``'s case rates
        are ignored. Otherwise the case rates ωx, ωy given to ``update`` (rad/s, an
        estimate that does not come from the gyro under test, e.g. a second gyro) enter
        the regression in that discretisation (:mod:`gyrodiag.dtg.case_rate`,
        docs/dtg_case_rate.md): they go through the prefilter with the voltages, θ0 and
        the reference are per axis (``theta0`` of shape (5,) is used for both axes, or
        give (2, 5)), ``physical`` inverts the central scheme's θ with ``"central"``.
        A pattern library's classes apply, its nominal prior does not (it is the paper
        regression's θ0, one for both axes): the learning guard then runs without it.
    pickoff_scale : float
        Nominal pick-off scale KT of the gyro, rad/V (datasheet value; case rate only):
        the case rate enters the regressors as ω·T/KT, in V.
    case_rate_delay_samples : int
        Case rate only: the voltages of sample k are paired with the case rate of sample
        k − d, samples (d > 0: a master that delivers the case rate ahead of the
        voltages, e.g. Jacobi coupling with the DTG plant between the aircraft and the
        Diagnoser: d = 1; d < 0: the case rate arrives later, and every output describes
        the sample |d| earlier). The delay in use at the start when
        ``case_rate_align_max`` > 0. The harness sets it from its coupling plan
        (:mod:`harness.cosim.timing`).
    case_rate_align_max : int
        Case rate only: choose d in −this … this from the data (0, the default: keep
        ``case_rate_delay_samples``). For hosts whose timing is unknown; measured limits
        in docs/dtg_case_rate.md §9 (in calm level flight the pairings' fits differ by
        noise only, and a choice made there can bias θ0). :class:`~gyrodiag.dtg.alignment.
        CaseRateAligner`, docs/dtg_case_rate.md §9: the first fast change of the case
        rate shows which pairing fits.
    case_rate_lookahead_s : float
        Case rate with ``case_rate_align_max`` > 0: the aligner runs this far ahead of
        the estimators and decisions, s, so that a new pairing applies before the edge
        that revealed it reaches them; every output describes the sample this much
        earlier.
    """

    sample_period_s: float = 1e-3
    prefilter_enabled: bool = True
    prefilter_order: int = 6
    prefilter_cutoff_hz: float | None = None
    prefilter_highpass_hz: float | None = None
    estimator: EstimatorKind = "forgetting"
    window: int = 500
    forgetting: float = None  # type: ignore[assignment]  # None: auto (AUTO_SETTINGS)
    p0: float = 1e6
    theta0: Sequence[float] | None = None
    learn_start_s: float = None  # type: ignore[assignment]
    learn_end_s: float = None  # type: ignore[assignment]
    low: float = None  # type: ignore[assignment]
    high: float = None  # type: ignore[assignment]
    persistence_k: int = None  # type: ignore[assignment]
    persistence_n: int = None  # type: ignore[assignment]
    band_sigma: float = BAND_SIGMA
    latch: bool = False
    monitored: Sequence[bool] = (True, True, True, True, True)
    signatures: Mapping[str, Sequence[float]] = field(default_factory=dict)
    max_distance: float | None = None
    classify_window_s: float = 0.5
    classifier: ClassifierKind = "pattern"
    patterns: PatternLibrary | None = None
    window_s: float = 0.5
    long_window_s: float = 2.0
    level_threshold: float = 6.0
    var_threshold: float = 4.0
    long_var_threshold: float = 2.0
    theta_spread_threshold: float = 30.0
    power_threshold: float = POWER_THRESHOLD
    allowance_sigma: float = ALLOWANCE_SIGMA
    clear_after_s: float = 0.5
    case_rate: str | None = None
    pickoff_scale: float = 1e-3
    case_rate_delay_samples: int = 0
    case_rate_align_max: int = 0
    case_rate_lookahead_s: float = 0.032

    def __post_init__(self) -> None:
        """Settings left None take their automatic value (:data:`AUTO_SETTINGS`)."""
        auto = AUTO_SETTINGS["case_rate" if self.case_rate is not None else "bench"]
        end_auto = self.learn_end_s is None
        T = self.sample_period_s  # an invalid one is left to validate() to name
        period_ok = isinstance(T, int | float) and math.isfinite(T) and T > 0
        for name, value in auto.items():
            if name.startswith("persistence_") and getattr(self, name) is None:
                setattr(self, name, max(1, round(value / T)) if value > 0 and period_ok
                        else 1)
            elif getattr(self, name) is None:
                setattr(self, name, value)
        if end_auto and period_ok:  # at least two reference blocks, at slow rates too
            self.learn_end_s = max(self.learn_end_s, self.learn_start_s
                                   + 2 * self.block_samples * self.sample_period_s)

    @property
    def lookahead_samples(self) -> int:
        """Samples the estimators run behind the newest sample: the aligner's lookahead,
        or the |d| a negative fixed delay needs (0 otherwise)."""
        if self.case_rate is None:
            return 0
        if self.case_rate_align_max == 0:
            return max(0, -int(self.case_rate_delay_samples))
        return max(1, round(self.case_rate_lookahead_s / self.sample_period_s))

    @property
    def regression(self) -> RegressionModel:
        """The regression of the reference residuals (paper's, or with the case rate)."""
        return RegressionModel(self.case_rate, self.sample_period_s, self.pickoff_scale)

    @property
    def thresholds(self) -> ResidualThresholds:
        """The residual-test thresholds."""
        return ResidualThresholds(self.level_threshold, self.var_threshold,
                                  self.long_var_threshold, self.theta_spread_threshold,
                                  self.power_threshold, self.allowance_sigma)

    @property
    def cutoff_hz(self) -> float:
        """The prefilter cut-off in use, Hz (``prefilter_cutoff_hz`` or its auto rule)."""
        if self.prefilter_cutoff_hz is None:
            return AUTO_CUTOFF_FRACTION / self.sample_period_s
        return self.prefilter_cutoff_hz

    @property
    def block_samples(self) -> int:
        """Samples per reference block (:data:`BLOCK_S`, at least one)."""
        return max(1, round(BLOCK_S / self.sample_period_s))

    def blocks(self, seconds: float) -> int:
        """Whole blocks in ``seconds`` (at least one)."""
        return max(1, round(seconds / (self.block_samples * self.sample_period_s)))

    def validate(self) -> None:
        """Raise ValueError/TypeError naming the first invalid setting."""
        check_positive("sample_period_s", self.sample_period_s)
        if self.prefilter_enabled:
            ButterworthPrefilter(
                self.prefilter_order, self.cutoff_hz, 1.0 / self.sample_period_s,
                highpass_hz=self.prefilter_highpass_hz,
            )
        if self.estimator not in ESTIMATOR_KINDS:
            raise ValueError(
                f"estimator must be one of {ESTIMATOR_KINDS}, got {self.estimator!r}"
            )
        check_int("window", self.window, minimum=N_THETA)
        check_in_range("forgetting", self.forgetting, 0.0, 1.0, low_open=True)
        check_positive("p0", self.p0)
        if self.case_rate is not None:
            if self.case_rate not in CASE_RATE_SCHEMES:
                raise ValueError(f"case_rate must be None or one of {CASE_RATE_SCHEMES}, "
                                 f"got {self.case_rate!r}")
            check_positive("pickoff_scale", self.pickoff_scale)
            align = check_int("case_rate_align_max", self.case_rate_align_max)
            if align > 50:
                raise ValueError(f"case_rate_align_max must be at most 50 samples, "
                                 f"got {align!r}")
            delay = check_int("case_rate_delay_samples", self.case_rate_delay_samples,
                              minimum=-(align or 50))
            if align and delay > align:
                raise ValueError(f"case_rate_delay_samples must be in [-case_rate_align_max, "
                                 f"case_rate_align_max] ([{-align}, {align}]), got {delay!r}")
            if delay > 50:
                raise ValueError(f"case_rate_delay_samples must be in [-50, 50] samples, "
                                 f"got {delay!r}")
            if align:
                check_in_range("case_rate_lookahead_s", self.case_rate_lookahead_s,
                               0.0, 1.0, low_open=True)
                if self.lookahead_samples < align:
                    raise ValueError(
                        f"case_rate_lookahead_s must cover case_rate_align_max ({align} "
                        f"samples of {self.sample_period_s} s), got "
                        f"{self.case_rate_lookahead_s!r}")
        if self.theta0 is not None:
            t0 = np.asarray(self.theta0, dtype=float)
            shape = ((N_THETA,) if self.case_rate is None or t0.shape == (N_THETA,)
                     else (2, N_THETA))
            t0 = check_finite_array("theta0", self.theta0, shape=shape)
            if np.any(t0 == 0.0):
                raise ValueError(f"theta0 must have no zero entry, got {list(t0)}")
        # the pattern classifier measures its nominal statistics over the learning window
        # even when θ0 is given
        if self.theta0 is None or self.classifier == "pattern":
            check_nonnegative("learn_start_s", self.learn_start_s)
            end = check_positive("learn_end_s", self.learn_end_s)
            if end < self.learn_start_s + self.sample_period_s:
                raise ValueError(
                    "learn_end_s must exceed learn_start_s by at least one sample period, "
                    f"got learn_start_s={self.learn_start_s!r}, learn_end_s={self.learn_end_s!r}"
                )
        ThresholdDecision(
            np.ones(N_THETA), self.low, self.high, self.persistence_k, self.persistence_n,
            self.latch, self.monitored,
        )
        check_nonnegative("band_sigma", self.band_sigma)
        if self.signatures:
            SignatureClassifier(self.signatures, self.max_distance)
            for name, sig in self.signatures.items():
                check_finite_array(f"signatures[{name!r}]", sig, shape=(N_THETA,))
        elif self.max_distance is not None:
            check_nonnegative("max_distance", self.max_distance)
        check_nonnegative("classify_window_s", self.classify_window_s)
        if self.classifier not in CLASSIFIERS:
            raise ValueError(
                f"classifier must be one of {CLASSIFIERS}, got {self.classifier!r}")
        check_positive("window_s", self.window_s)
        check_positive("long_window_s", self.long_window_s)
        if self.long_window_s < self.window_s:
            raise ValueError(f"long_window_s must be >= window_s ({self.window_s!r} s), "
                             f"got {self.long_window_s!r}")
        self.thresholds.validate()
        check_nonnegative("clear_after_s", self.clear_after_s)
        if self.classifier == "pattern":
            if self.signatures:
                raise ValueError(
                    "signatures (decade signatures) belong to classifier 'paper'; the "
                    "'pattern' classifier takes a pattern library (patterns)")
            if self.patterns is not None:
                if not isinstance(self.patterns, PatternLibrary):
                    raise TypeError("patterns must be a PatternLibrary, got "
                                    f"{type(self.patterns).__name__}")
                block_s = self.block_samples * self.sample_period_s
                for name, mine, theirs in (
                        ("sample_period_s", self.sample_period_s,
                         self.patterns.sample_period_s),
                        ("block_s", block_s, self.patterns.block_s)):
                    if abs(mine - theirs) > 1e-6 * theirs:
                        raise ValueError(
                            f"patterns were learned with {name} = {theirs!r}, this channel "
                            f"has {mine!r}: learn the patterns at this sample period")
            span = self.learn_end_s - self.learn_start_s
            block_s = self.block_samples * self.sample_period_s
            if span < 2 * block_s - 1e-12:
                raise ValueError(
                    "learn_end_s - learn_start_s must hold at least two reference blocks "
                    f"({2 * block_s:g} s) for the pattern classifier, got {span!r} s")


@dataclass(frozen=True)
class DTGDiagnosis:
    """Block-rate outputs of the reference, the residual tests and the classification.

    Updated at the end of each reference block (``block`` counts the updates); the same
    object is shared by the samples in between.

    Attributes
    ----------
    reference_status : int
        :data:`~gyrodiag.dtg.reference.REFERENCE_STATUS` code (0 learning, 1 valid,
        2 change inside the learning window, 3 prior mismatch: prior in use), or
        :data:`STATUS_NOT_CHECKED` (4, paper classifier with too little data) or
        :data:`STATUS_FAILED` (5, no usable data in the learning window: no reference,
        no alarm).
    residual_alarm : bool
        The residual tests are in alarm (pattern classifier).
    class_name : str
        Name of the class in ``fault_code`` ("" none, "unknown").
    fault_type, fault_signal, fault_axis : int
        Codes of :data:`~gyrodiag.dtg.patterns.FAULT_TYPES` (1 step, 2 noise, 3 loss,
        4 drift, 5 spin, 6 torquer), :data:`~gyrodiag.dtg.patterns.SIGNALS` (1 Utx,
        2 Uty, 3 Ux, 4 Uy; 0 physical) and axes (1 x, 2 y, 3 both); 0 no alarm, −1
        unknown.
    distance : float
        χ² per channel of the class (NaN if none).
    size, rate, ratio : float
        Estimated fault size (V), drift rate (V/s), physical ratio (NaN if undefined).
    level, log_variance : ndarray, shape (6,)
        Statistics of the test window (no alarm) or the classification window (alarm):
        level shift in block-spread units and log10 variance ratio of Utx, Uty, Ux, Uy,
        ex, ey.
    growth : float
        Growth of the residual level in that window (drift witness).
    window_s : float
        Length of that window, s.
    tests : ndarray, shape (8,)
        Residual test statistics: level z of ex, ey, short variance ratios of ex, ey,
        long variance ratios of ex, ey, low-frequency power CUSUMs of ex, ey over their
        threshold.
    block : int
        Update counter.
    """

    reference_status: int = REFERENCE_STATUS["learning"]
    residual_alarm: bool = False
    class_name: str = ""
    fault_type: int = 0
    fault_signal: int = 0
    fault_axis: int = 0
    distance: float = math.nan
    size: float = math.nan
    rate: float = math.nan
    ratio: float = math.nan
    level: NDArray[np.float64] = field(default_factory=lambda: np.zeros(N_CHANNELS))
    log_variance: NDArray[np.float64] = field(default_factory=lambda: np.zeros(N_CHANNELS))
    growth: float = 0.0
    window_s: float = 0.0
    tests: NDArray[np.float64] = field(default_factory=lambda: np.zeros(N_TESTS))
    block: int = 0


@fast_init
@dataclass(frozen=True)
class DTGChannelOutput:
    """Outputs of one :meth:`DTGChannel.update`.

    Attributes
    ----------
    valid : bool
        False when this sample had a NaN/Inf input and was skipped (state untouched).
    learning : bool
        θ0 is still being learned; no decision yet.
    theta : ndarray, shape (2, 5)
        θ of the x axis (row 0) and y axis (row 1).
    eta : ndarray, shape (2, 5)
        Ratios |θ|/|θ0| per axis (ones while learning).
    physical : ndarray, shape (5,)
        [c/J (1/s), k/J (1/s²), L/J (rad/s), λ/J (1/s²), Ku/(KT·J) (1/s²)] from the mean
        θ of both axes (NaN where the inversion is undefined).
    alarm : bool
        Any axis in alarm.
    fault_code : int
        0 no alarm, 1… signature index, ``UNKNOWN_CODE`` (−1) unclassified.
    feature : ndarray of int, shape (5,)
        Feature vector C that is classified: at each sample, C of the axis with the
        larger Σ|C_i|; in alarm, the median of those over the alarm samples of the last
        ``classify_window_s``.
    first_alarm_time_s : float
        Time of the first alarm since reset, s (NaN if none).
    diagnosis : DTGDiagnosis
        Reference, residual tests and pattern classification (block rate).
    """

    valid: bool
    learning: bool
    theta: NDArray[np.float64]
    eta: NDArray[np.float64]
    physical: NDArray[np.float64]
    alarm: bool
    fault_code: int
    feature: NDArray[np.int64]
    first_alarm_time_s: float
    diagnosis: DTGDiagnosis = field(default_factory=DTGDiagnosis)


class DTGChannel:
    """Streaming DTG parameter-identification diagnoser.

    Parameters
    ----------
    config : DTGChannelConfig
        Settings; validated here (ValueError naming the setting).
    """

    def __init__(self, config: DTGChannelConfig) -> None:
        config.validate()
        self.config = config
        self._pattern_mode = config.classifier == "pattern"
        self.T = float(config.sample_period_s)
        self._nb = config.block_samples
        self._short_blocks = config.blocks(config.window_s)
        self._long_blocks = max(config.blocks(config.long_window_s), self._short_blocks)
        self._clear_blocks = max(1, round(config.clear_after_s / (self._nb * self.T)))
        # sample indices of the learning window [n_start, n_end)
        self._n_start = math.ceil(config.learn_start_s / self.T - 1e-9)
        self._n_end = max(math.ceil(config.learn_end_s / self.T - 1e-9), self._n_start + 1)
        # rows left out after a skipped sample: the two regression rows that span it and
        # the prefilter's memory (impulse response above 1e-3 of its peak)
        self._gap_samples = 2 + (_ringing_samples(config, self.T)
                                 if config.prefilter_enabled else 0)
        self._model = config.regression
        self._case_rate = self._model.case_rate
        self._central = config.case_rate == "central"
        self._width = self._model.width
        self._given_theta0: NDArray[np.float64] | None = (
            None if config.theta0 is None
            else np.broadcast_to(np.asarray(config.theta0, dtype=float),
                                 self._theta0_shape()).copy())
        self._pattern = (PatternClassifier(config.patterns)
                         if config.patterns is not None else None)
        # the prior is the paper regression's θ0 (one for both axes); with the case rate
        # the reference is per axis and differs (θ5 in particular)
        self._prior: NominalPrior | None = (
            config.patterns.prior
            if config.patterns is not None and config.case_rate is None else None)
        # the estimate's covariance per unit v·P: 1/(1 + λ) for exponentially weighted
        # LS with white-equivalent errors, 1 for plain RLS; 0: no significance test (the
        # paper's regression has no reference information, the window LS no P)
        self._band_factor = 0.0
        # the decisions' confirm hooks, made once (they read the current θ)
        self._confirm = (functools.partial(self._significant, 0),
                         functools.partial(self._significant, 1))
        if (config.band_sigma > 0.0 and self._pattern_mode and self._case_rate
                and config.estimator != "batch"):
            self._band_factor = (1.0 / (1.0 + config.forgetting)
                                 if config.estimator == "forgetting" else 1.0)
        self.reset()

    # -- construction helpers -------------------------------------------------
    def _make_estimator(self) -> RLS | SlidingWindowLS:
        c = self.config
        if c.estimator == "batch":
            return SlidingWindowLS(N_THETA, window=c.window)
        if c.estimator == "rls":
            return RLS(N_THETA, p0=c.p0)
        return ForgettingRLS(N_THETA, forgetting=c.forgetting, p0=c.p0)

    def _make_decisions(self, theta0: NDArray[np.float64]) -> list[ThresholdDecision]:
        """One ratio decision per axis; θ0 (5,) for both or (2, 5) per axis."""
        c = self.config
        per_axis = theta0.reshape(-1, N_THETA)
        return [
            ThresholdDecision(
                per_axis[min(i, per_axis.shape[0] - 1)], c.low, c.high, c.persistence_k,
                c.persistence_n, c.latch, c.monitored
            )
            for i in range(2)
        ]

    def _band_sigma_active(self) -> bool:
        """The band's violations need significance (config ``band_sigma``): only once
        the monitor holds the case rate's refined band reference."""
        return (self._band_factor > 0.0 and self._monitor is not None
                and self._monitor.refines)

    def _band_z2(self, axis: int, theta: Sequence[float]) -> list[float]:
        """Squared distance of each θ of ``axis`` from the band's θ0, in standard errors
        (estimate's v·P/(1 + λ) plus θ0's v·A⁻¹)."""
        mon = self._monitor
        assert mon is not None and self.reference is not None
        assert self.reference.error_variance is not None
        theta0, var0 = mon.band_arrays()
        S = self._estimators[axis]._S  # type: ignore[union-attr]
        p_diag = (S * S).sum(axis=1)
        var = self.reference.error_variance[axis] * p_diag * self._band_factor + var0[axis]
        d = np.asarray(theta, dtype=float) - theta0[axis]
        return (d * d / var).tolist()

    def _significant(self, axis: int, eta: list[float]) -> bool:
        """A ratio outside the band whose θ (the current estimate) is also band_sigma
        standard errors off."""
        decision = self._decisions[axis]  # type: ignore[index]
        z2 = self._band_z2(axis, self._theta_now[axis])
        limit = self.config.band_sigma ** 2
        return any(z2[i] > limit for i in decision.out_of_band(eta))

    def _band_quiet(self, theta: tuple[float, ...]) -> bool:
        """Every monitored θ of both axes within half band_sigma standard errors of the
        band's θ0 (the block may refine it)."""
        limit = (0.5 * self.config.band_sigma) ** 2
        mon = self.config.monitored
        for axis in range(2):
            z2 = self._band_z2(axis, theta[axis * N_THETA:(axis + 1) * N_THETA])
            if any(z > limit for z, m in zip(z2, mon, strict=True) if m):
                return False
        return True

    def _refine_band(self) -> None:
        """Take the monitor's refined band reference as the decisions' θ0."""
        mon = self._monitor
        assert mon is not None and self._decisions is not None
        ref = mon.band_reference
        assert ref is not None
        self.theta0 = ref[0].copy()
        for axis, decision in enumerate(self._decisions):
            decision.set_theta0(ref[0][axis])

    def _theta0_shape(self) -> tuple[int, ...]:
        return (2, N_THETA) if self._case_rate else (N_THETA,)

    def reset(self) -> None:
        """Return to the state right after construction."""
        c = self.config
        self._prefilter = (
            ButterworthPrefilter(
                c.prefilter_order, c.cutoff_hz, 1.0 / self.T, self._width,
                highpass_hz=c.prefilter_highpass_hz,
            )
            if c.prefilter_enabled
            else None
        )
        self._regressor: DTGRegressor | CaseRateDTGRegressor = (
            CaseRateDTGRegressor(self.T, c.pickoff_scale, scheme=c.case_rate)  # type: ignore[arg-type]
            if c.case_rate is not None else DTGRegressor())
        self._estimators = [self._make_estimator(), self._make_estimator()]
        self._theta_now = tuple(tuple(e.theta.tolist()) for e in self._estimators)
        self._classifier = (
            SignatureClassifier(c.signatures, c.max_distance) if c.signatures else None
        )
        self._n_samples = 0
        self._learn_sum = np.zeros(self._theta0_shape())
        self._learn_count = 0
        # (5,) for both axes; (2, 5) per axis with the case rate
        self.theta0: NDArray[np.float64] | None = (
            None if self._given_theta0 is None else self._given_theta0.copy())
        self._decisions = None if self.theta0 is None else self._make_decisions(self.theta0)
        self._first_alarm_time = float("nan")
        # both ends of the window, as the training window of harness.campaigns.signatures
        self._features = WindowedMedianFeature(N_THETA, round(c.classify_window_s / self.T) + 1)
        # reference blocks: raw (nb, 4), filtered with the two samples before (nb + 2, 4),
        # fast-estimator θ of both axes (nb, 10)
        # the current block (plain lists; arrays at its end) and the two filtered samples
        # before it
        self._blk_raw: list[tuple[float, ...]] = []
        self._blk_filtered: list[tuple[float, ...]] = []
        self._blk_theta: list[tuple[float, ...]] = []
        self._blk_valid: list[bool] = []
        self._hist_filtered: list[tuple[float, ...]] = [(0.0,) * self._width] * 2
        self._gap = 0
        # case rate: block means of the filtered ω during learning, their mean and spread,
        # and each runtime block's largest deviation from it in those spreads
        self._omega_learn: list[tuple[float, float]] = []
        self._omega_ref: tuple[NDArray[np.float64], NDArray[np.float64]] | None = None
        self._omega_dev: deque[float] = deque(maxlen=self._long_blocks)
        # pattern classifier: when the residual tests clear, the fast estimators are
        # rolled back to their state half a test window before the alarm rose (a fault's
        # data would take them seconds to forget: a 0.3 V noise burst on a pick-off
        # raises their information ~1000-fold, i.e. ~7 s of forgetting 0.999, and the
        # ratio band would hold the alarm that long); during the alarm they go on
        # tracking, so that a physical fault shows in η
        self._rollback: tuple[Any, ...] | None = None
        self._snapshots: deque[tuple[Any, ...]] = deque(maxlen=self._short_blocks + 1)
        self._learner: ReferenceLearner | None = ReferenceLearner(
            self._nb, self._short_blocks, self._long_blocks, c.thresholds, self._nb * self.T,
            self._model)
        self.reference: NominalReference | None = None
        self._monitor: ResidualMonitor | None = None
        self._diagnosis = DTGDiagnosis()
        self._reset_alignment()
        self._last = self._initial_output()

    def _reset_alignment(self) -> None:
        c = self.config
        # the case-rate pairing (docs/dtg_case_rate.md §9): the aligner sees each sample
        # `lookahead` samples before the estimators do
        self._lookahead = c.lookahead_samples
        self._aligner = (
            CaseRateAligner(self.T, c.pickoff_scale, scheme=c.case_rate,  # type: ignore[arg-type]
                            max_delay=c.case_rate_align_max,
                            delay=c.case_rate_delay_samples)
            if self._case_rate and c.case_rate_align_max > 0 else None)
        self._fixed_delay = int(c.case_rate_delay_samples) if self._case_rate else 0
        self._shifting = self._aligner is not None or self._fixed_delay != 0
        max_delay = (c.case_rate_align_max if self._aligner is not None
                     else max(self._fixed_delay, 0))
        # filtered ω of the newest samples (newest first); voltages waiting in the queue
        # with their gap marks
        self._omega_hist: deque[tuple[float, float]] = deque(
            maxlen=self._lookahead + max_delay + 1)
        self._queue: deque[tuple[tuple[float, ...], tuple[float, ...], bool]] = deque()
        self._gap_pending = False
        self._aligner_holdoff = 0

    @property
    def case_rate_delay(self) -> int:
        """Delay of the case rate against the voltages in use, samples."""
        return self._aligner.delay if self._aligner is not None else self._fixed_delay

    @property
    def case_rate_switches(self) -> int:
        """How often the aligner has changed the delay."""
        return 0 if self._aligner is None else self._aligner.switches

    def _initial_output(self) -> DTGChannelOutput:
        return DTGChannelOutput(
            valid=True, learning=self.theta0 is None, theta=np.zeros((2, N_THETA)),
            eta=np.ones((2, N_THETA)), physical=np.full(N_THETA, np.nan), alarm=False,
            fault_code=0, feature=np.zeros(N_THETA, dtype=np.int64),
            first_alarm_time_s=float("nan"), diagnosis=self._diagnosis,
        )

    def _physical(self, th_x: tuple[float, ...], th_y: tuple[float, ...]
                  ) -> NDArray[np.float64]:
        if not self._central:
            return _physical(th_x, th_y, self.T)
        mean = 0.5 * (np.array(th_x) + np.array(th_y))
        try:
            return physical_from_theta_central(mean, self.T).as_array()
        except ValueError:
            return np.full(N_THETA, np.nan)

    @property
    def pattern_mode(self) -> bool:
        """The pattern classifier is configured."""
        return self._pattern_mode

    # -- streaming ------------------------------------------------------------
    def update(self, Utx: float, Uty: float, Ux: float, Uy: float,
               omega_x: float = 0.0, omega_y: float = 0.0) -> DTGChannelOutput:
        """Process one sample and return the channel outputs.

        Parameters
        ----------
        Utx, Uty, Ux, Uy : float
            Pick-off and torquer voltages, V.
        omega_x, omega_y : float
            Case rates about the gyro's x and y axes held over the sample, rad/s (an
            independent estimate); used only when ``config.case_rate`` is set.

        A sample with any NaN/Inf (case rates included when they are used) is skipped:
        the state is untouched and the previous outputs are returned with
        ``valid=False``.
        """
        raw = (float(Utx), float(Uty), float(Ux), float(Uy))
        if self._case_rate:
            w = (float(omega_x), float(omega_y))
            ok = math.isfinite(w[0]) and math.isfinite(w[1])
        else:
            ok = True
        if not (ok and math.isfinite(raw[0]) and math.isfinite(raw[1])
                and math.isfinite(raw[2]) and math.isfinite(raw[3])):
            # the regression rows spanning the gap, and the prefilter's ringing after it,
            # are left out of the reference statistics (a one-sample jump would look
            # like a burst of noise)
            if self._shifting:
                self._gap_pending = True
                self._aligner_holdoff = self._gap_samples
            else:
                self._gap = self._gap_samples
            self._last = _replace(self._last, valid=False)
            return self._last
        # raw was checked finite above; the stages downstream need not check again
        signals = raw + w if self._case_rate else raw
        sample = (tuple(self._prefilter.step(signals)) if self._prefilter is not None
                  else signals)
        if self._shifting:
            pair = self._pair(raw, sample)
            if pair is None:
                return self._last
            raw, sample = pair
        n = self._n_samples
        t = n * self.T
        self._n_samples += 1
        if self._case_rate:
            rows = self._regressor.update(*sample, validate=False)  # type: ignore[call-arg]
        else:
            rows = self._regressor.step(*sample)  # type: ignore[union-attr]
        if rows is not None and self._case_rate and n < self._gap_samples:
            # a case-rate channel may start in a manoeuvre (off trim: ω ≠ 0, torquer
            # voltages at L·ω/Ku): the prefilter, from zero state, shows every signal
            # jumping at t = 0, a ½s·Δω impulse on the y line that the rotor never had;
            # its rows are left out until the filter's start has rung down, as after a gap
            rows = None
        if rows is not None:
            self._theta_now = (self._estimators[0].step(rows[0], rows[1]),
                               self._estimators[1].step(rows[2], rows[3]))
        th_x, th_y = self._theta_now
        block_done = self._collect(n, raw, sample, th_x + th_y)
        th_x, th_y = self._theta_now  # rolled back if the residual alarm just cleared
        theta = np.array((th_x, th_y))

        if self.theta0 is None and not self._pattern_mode:
            self._learn(t, theta)
        if self.theta0 is None or self._decisions is None:
            self._last = DTGChannelOutput(
                True, not self.reference_failed, theta, np.ones((2, N_THETA)),
                self._physical(th_x, th_y), False, 0, np.zeros(N_THETA, dtype=np.int64),
                self._first_alarm_time, self._diagnosis,
            )
            return self._last

        confirm_x, confirm_y = (self._confirm if self._band_sigma_active()
                                else (None, None))
        eta_x, alarm_x = self._decisions[0].step(th_x, confirm_x)
        eta_y, alarm_y = self._decisions[1].step(th_y, confirm_y)
        eta = np.array((eta_x, eta_y))
        band_alarm = alarm_x or alarm_y
        physical = self._physical(th_x, th_y)
        if self._pattern_mode:
            return self._pattern_output(t, theta, eta, physical, band_alarm, block_done)
        alarm = band_alarm
        fx, fy = feature_floats(eta_x), feature_floats(eta_y)
        # the axis with the larger Σ|C_i| (x on a tie)
        feature = fy if sum(map(abs, fy)) > sum(map(abs, fx)) else fx
        windowed = self._features.window > 1
        if windowed:  # window 1 (the paper's rule) needs no history
            self._features.update(feature, alarm)
        code = 0
        if alarm:
            if math.isnan(self._first_alarm_time):
                self._first_alarm_time = t
            if windowed:
                feature = self._features.median()
            code = (
                self._classifier.classify(feature).code
                if self._classifier is not None
                else UNKNOWN_CODE
            )
        self._last = DTGChannelOutput(
            True, False, theta, eta, physical, alarm, code,
            np.array(feature, dtype=np.int64),
            self._first_alarm_time, self._diagnosis,
        )
        return self._last

    def _pair(self, raw: tuple[float, ...], sample: tuple[float, ...]
              ) -> tuple[tuple[float, ...], tuple[float, ...]] | None:
        """Queue a prefiltered sample; return the (raw, filtered) sample due for the
        estimators with the case rate of its pairing, or None while the queue fills."""
        aligner = self._aligner
        if aligner is not None:
            if self._aligner_holdoff:
                # the regression rows that span a skipped sample, and the prefilter's
                # ringing after it, say nothing about the pairing
                self._aligner_holdoff -= 1
                aligner.restart()
            else:
                aligner.update(sample)
        hist = self._omega_hist
        hist.appendleft((sample[4], sample[5]))
        self._queue.append((raw, sample[:4], self._gap_pending))
        self._gap_pending = False
        if len(self._queue) <= self._lookahead:
            return None
        raw_due, volts, gap = self._queue.popleft()
        if gap:
            self._gap = self._gap_samples
        omega = hist[min(self._lookahead + self.case_rate_delay, len(hist) - 1)]
        return raw_due, volts + omega

    def _pattern_output(self, t: float, theta: NDArray[np.float64],
                        eta: NDArray[np.float64], physical: NDArray[np.float64],
                        band_alarm: bool, block_done: bool) -> DTGChannelOutput:
        mon = self._monitor
        residual_alarm = mon is not None and mon.alarm
        alarm = band_alarm or residual_alarm
        if alarm and np.isnan(self._first_alarm_time):
            self._first_alarm_time = t
        d = self._diagnosis
        if block_done or (alarm and d.fault_type == 0) or (not alarm and d.fault_type != 0):
            self._diagnosis = d = self._diagnose(band_alarm)
        code = 0
        if alarm:
            code = UNKNOWN_CODE if d.fault_type <= 0 else self._class_code(d.class_name)
        self._last = DTGChannelOutput(
            True, False, theta, eta, physical, alarm, code, _NO_FEATURE,
            self._first_alarm_time, d,
        )
        return self._last

    def class_name(self, code: int) -> str:
        """Name of a ``fault_code``: its class (pattern library or signature table),
        "" for 0 (no fault), "unknown" otherwise."""
        c = self.config
        names = (c.patterns.names if c.classifier == "pattern" and c.patterns is not None
                 else list(c.signatures) if c.classifier == "paper" else [])
        if code == 0:
            return ""
        return names[code - 1] if 0 < code <= len(names) else "unknown"

    def _class_code(self, name: str) -> int:
        assert self.config.patterns is not None
        return self.config.patterns.names.index(name) + 1

    def _diagnose(self, band_alarm: bool) -> DTGDiagnosis:
        """Classify the current state (at block ends, and when the alarm changes)."""
        mon = self._monitor
        ref = self.reference
        status = ref.status if ref is not None else REFERENCE_STATUS["learning"]
        block = self._diagnosis.block + 1
        if mon is None:
            return DTGDiagnosis(reference_status=status, block=block)
        result: PatternResult | None = None
        stats = mon.classification_statistics() if mon.alarm else None
        if stats is not None:
            stats = self._raw_signals_checked(stats)
        if mon.alarm:
            if stats is not None and self._pattern is not None:
                result = self._pattern.classify_signal_fault(stats)
                if self._pattern.has_physical:
                    # a large physical fault (e.g. torquer scale 0.6) also raises the
                    # residual variance, inside the ratio band: the family that
                    # explains more wins (a signal fault corrupts one axis' estimates,
                    # which no physical class explains)
                    physical = self._pattern.classify_physical(
                        mon.window_statistics(self._long_blocks))
                    # the ratio band out and only the slow residual power up: a θ change
                    # (physical fault) explains both, a read-out noise not the band
                    if physical.fault_type > 0 and (
                            result.fault_type < 0 or physical.distance < result.distance
                            or (band_alarm and mon.power_only)
                            or (band_alarm and not stats.raw_signals
                                and result.distance > MASKED_SIGNAL_FIT)):
                        result = physical
        elif band_alarm:
            stats = self._raw_signals_checked(mon.window_statistics(self._long_blocks))
            if self._pattern is not None:
                result = self._pattern.classify_physical(stats)
        if stats is None:
            # pending classification: the blocks of the alarm so far (the test window
            # without alarm), so that the outputs never mix in data from before the alarm
            k = mon.blocks_in_alarm if mon.alarm else self._short_blocks
            stats = mon.window_statistics(max(1, min(k, self._short_blocks)))
        alarm = mon.alarm or band_alarm
        if not alarm:
            kind = (0, 0, 0, "")
        elif result is None or result.fault_type < 0:
            kind = (-1, -1, -1, "unknown")
        else:
            kind = (result.fault_type, result.signal, result.axis, result.name)
        return DTGDiagnosis(
            reference_status=status, residual_alarm=mon.alarm, class_name=kind[3],
            fault_type=kind[0], fault_signal=kind[1], fault_axis=kind[2],
            distance=math.nan if result is None or not alarm else result.distance,
            size=math.nan if result is None or not alarm else result.size,
            rate=math.nan if result is None or not alarm else result.rate,
            ratio=math.nan if result is None or not alarm else result.ratio,
            level=stats.level, log_variance=stats.log_variance, growth=stats.growth,
            window_s=stats.window_s, tests=mon.statistics.copy(), block=block)

    def _collect(self, n: int, raw: tuple[float, ...], sample: tuple[float, ...],
                 theta: tuple[float, ...]) -> bool:
        """Buffer one sample into the reference blocks; True when a runtime block ended.

        Blocks start at the learning window's first sample and again at its end (the
        partial block before the end is dropped); the learner gets the learning blocks,
        the residual monitor the blocks after.
        """
        if n == self._n_start or n == self._n_end:
            # restart the block grid; the two samples before become the history
            self._hist_filtered = (self._hist_filtered + self._blk_filtered)[-2:]
            self._clear_block()
            if n == self._n_start and self._learner is not None:
                self._learner.set_history(np.array(self._hist_filtered))
            if n == self._n_end:
                self._finish_learning()
        self._blk_raw.append(raw)
        self._blk_filtered.append(sample)
        self._blk_theta.append(theta)
        gap = self._gap
        self._blk_valid.append(gap == 0)
        if gap:
            self._gap = gap - 1
        if len(self._blk_raw) < self._nb:
            return False
        done = False
        if self._case_rate:
            self._omega_block(self._n_start <= n < self._n_end)
        if self._n_start <= n < self._n_end:
            if self._learner is not None:
                self._learner.push_block(np.array(self._blk_raw), np.array(self._blk_filtered),
                                         np.array(self._blk_theta), np.array(self._blk_valid))
        elif n >= self._n_end and self._monitor is not None:
            was = self._monitor.alarm
            active = self._band_sigma_active()
            quiet = self._band_quiet(theta) if active else True
            now = self._monitor.push_block(np.array(self._blk_raw),
                                           np.array(self._hist_filtered + self._blk_filtered),
                                           np.array(self._blk_theta),
                                           np.array(self._blk_valid), band_quiet=quiet)
            if active and quiet and not now:
                self._refine_band()
            self._hold_estimators(was, now)
            done = True
        # the two samples before the next block (a block may hold a single sample)
        self._hist_filtered = (self._hist_filtered + self._blk_filtered)[-2:]
        self._clear_block()
        return done

    def _hold_estimators(self, was: bool, now: bool) -> None:
        """Snapshot the estimators at quiet block ends; keep the oldest snapshot when the
        residual tests alarm and restore it when they clear."""
        if now:
            if not was and self._snapshots:
                self._rollback = self._snapshots[0]
            return
        if was and self._rollback is not None:
            sx, sy, theta = self._rollback
            self._estimators[0].set_state(sx)
            self._estimators[1].set_state(sy)
            self._theta_now = theta
            self._rollback = None
            self._snapshots.clear()
        self._snapshots.append((self._estimators[0].get_state(),
                                self._estimators[1].get_state(), self._theta_now))

    def _omega_block(self, learning: bool) -> None:
        """Case rate: the block mean of the filtered ω (the voltages' filter, so aligned
        with their block statistics), learned or compared with what was learned."""
        w = np.mean(np.array(self._blk_filtered)[:, 4:6], axis=0)
        if learning:
            self._omega_learn.append((float(w[0]), float(w[1])))
            return
        if self._omega_ref is None:
            if not self._omega_learn:
                return
            blocks = np.array(self._omega_learn)
            self._omega_ref = (blocks.mean(axis=0), blocks.std(axis=0))
            self._omega_learn = []
        mean, spread = self._omega_ref
        dev = np.abs(w - mean) / np.maximum(spread, OMEGA_SPREAD_FLOOR)
        self._omega_dev.append(float(dev.max()))

    def _raw_signals_checked(self, stats: ClassificationStatistics
                             ) -> ClassificationStatistics:
        """The statistics with ``raw_signals`` False when the case rate moved in their
        window: the measured voltages then carry the manoeuvre (the torquer voltages
        rebalance H·ω), and their levels and variances, compared with a reference
        learned in other flight, would read as a fault of their own."""
        if not self._case_rate or not self._omega_dev:
            return stats
        window = list(self._omega_dev)[-max(1, stats.window_blocks):]
        if max(window) > OMEGA_EXCITATION_Z:
            return replace(stats, raw_signals=False)
        return stats

    def _clear_block(self) -> None:
        self._blk_raw = []
        self._blk_filtered = []
        self._blk_theta = []
        self._blk_valid = []

    def _finish_learning(self) -> None:
        """Build the checked reference at the end of the learning window."""
        c = self.config
        learner = self._learner
        if learner is None:
            return
        try:
            ref = learner.finish(None if self._given_theta0 is None
                                 else self._given_theta0.ravel(), self._prior)
        except ValueError:
            self._learner = None
            if self.pattern_mode:
                # no reference to test against: no alarm rather than a failure of every
                # later sample (see reference_failed)
                self._diagnosis = DTGDiagnosis(reference_status=STATUS_FAILED,
                                               block=self._diagnosis.block + 1)
                return
            # the paper classifier does not need the reference: report it unchecked
            self._diagnosis = DTGDiagnosis(reference_status=STATUS_NOT_CHECKED,
                                           block=self._diagnosis.block + 1)
            return
        self.reference = ref
        if self.pattern_mode:
            mon = ResidualMonitor(ref, self._nb, self._nb * self.T, self._short_blocks,
                                  self._long_blocks, c.thresholds, self._clear_blocks,
                                  self._model)
            mon.prefill(*learner.reference_blocks(ref, self._long_blocks))
            self._monitor = mon
            if self.theta0 is None:
                self.theta0 = ref.theta0_eta.reshape(self._theta0_shape()).copy()
                self._decisions = self._make_decisions(self.theta0)
        self._learner = None  # its data are no longer needed
        self._diagnosis = DTGDiagnosis(reference_status=ref.status,
                                       block=self._diagnosis.block + 1)

    def _learn(self, t: float, theta: NDArray[np.float64]) -> None:
        c = self.config
        if c.learn_start_s <= t < c.learn_end_s:
            self._learn_sum += theta if self._case_rate else theta.mean(axis=0)
            self._learn_count += 1
        elif t >= c.learn_end_s and self._learn_count > 0:
            theta0 = self._learn_sum / self._learn_count
            self._learn_count = 0
            if np.any(theta0 == 0.0):
                # No excitation in the learning window (e.g. a host's default zero
                # inputs): no reference, so no ratios and no alarm, rather than a failure
                # of every later sample. See reference_failed.
                return
            self.theta0 = theta0
            self._decisions = self._make_decisions(theta0)

    @property
    def reference_failed(self) -> bool:
        """True once the learning window has ended without a usable θ0 (a zero entry:
        no excitation); the channel then never alarms."""
        if self.pattern_mode:
            return self._diagnosis.reference_status == STATUS_FAILED
        return (self.theta0 is None and self._learn_count == 0
                and self._n_samples * self.T > self.config.learn_end_s)

    # -- state ----------------------------------------------------------------
    def get_state(self) -> dict[str, Any]:
        """Full internal state (filters, estimators, decisions, learning, reference,
        residual tests, outputs), tagged with :data:`STATE_VERSION`."""
        return stamp({
            "prefilter": None if self._prefilter is None else self._prefilter.get_state(),
            "regressor": self._regressor.get_state(),
            "estimators": [e.get_state() for e in self._estimators],
            "n_samples": self._n_samples,
            "learn_sum": self._learn_sum.copy(),
            "learn_count": self._learn_count,
            "theta0": None if self.theta0 is None else self.theta0.copy(),
            "decisions": None
            if self._decisions is None
            else [d.get_state() for d in self._decisions],
            "first_alarm_time": self._first_alarm_time,
            "features": self._features.get_state(),
            "buffers": {"raw": np.array(self._blk_raw, dtype=float).reshape(-1, 4),
                        "filtered": np.array(self._blk_filtered, dtype=float).reshape(
                            -1, self._width),
                        "theta": np.array(self._blk_theta, dtype=float).reshape(
                            -1, 2 * N_THETA),
                        "valid": np.array(self._blk_valid, dtype=bool),
                        "history": np.array(self._hist_filtered, dtype=float),
                        "gap": self._gap},
            "omega": {"learn": np.array(self._omega_learn, dtype=float).reshape(-1, 2),
                      "ref": None if self._omega_ref is None
                      else np.vstack(self._omega_ref),
                      "deviation": np.array(self._omega_dev, dtype=float)},
            "rollback": None if self._rollback is None else list(self._rollback),
            "snapshots": [list(snap) for snap in self._snapshots],
            "learner": None if self._learner is None else self._learner.get_state(),
            "reference": None if self.reference is None else self.reference.get_state(),
            "monitor": None if self._monitor is None else self._monitor.get_state(),
            "diagnosis": _diagnosis_to_dict(self._diagnosis),
            "last": _output_to_dict(self._last),
            "alignment": {
                "aligner": None if self._aligner is None else self._aligner.get_state(),
                "omega": np.array(self._omega_hist, dtype=float).reshape(-1, 2),
                "raw": np.array([q[0] for q in self._queue], dtype=float).reshape(-1, 4),
                "voltages": np.array([q[1] for q in self._queue],
                                     dtype=float).reshape(-1, 4),
                "gaps": np.array([q[2] for q in self._queue], dtype=bool),
                "gap_pending": self._gap_pending, "holdoff": self._aligner_holdoff},
        }, STATE_VERSION)

    def set_state(self, state: dict[str, Any]) -> None:
        """Restore a state produced by :meth:`get_state` of an identically configured
        channel (an older state version is migrated first)."""
        state = migrate(state, STATE_VERSION, _MIGRATIONS, "DTG channel")
        try:  # first: a state of another classify_window_s leaves this channel untouched
            self._features.set_state(state["features"])
        except ValueError as exc:
            raise ValueError(f"state['features'] (classify_window_s): {exc}") from exc
        buffers = state["buffers"]
        raw = np.asarray(buffers["raw"], dtype=float).reshape(-1, 4)
        if raw.shape[0] >= self._nb:
            raise ValueError(f"state['buffers'] hold {raw.shape[0]} samples of a block, this "
                             f"channel's blocks have {self._nb} (another sample period?)")
        if (state["prefilter"] is None) != (self._prefilter is None):
            raise ValueError("state['prefilter'] does not match prefilter_enabled")
        if self._prefilter is not None:
            self._prefilter.set_state(state["prefilter"])
        self._regressor.set_state(state["regressor"])
        for e, s in zip(self._estimators, state["estimators"], strict=True):
            e.set_state(s)
        self._n_samples = int(state["n_samples"])
        self._learn_sum = np.asarray(state["learn_sum"], dtype=float).copy()
        self._learn_count = int(state["learn_count"])
        t0 = state["theta0"]
        self.theta0 = None if t0 is None else np.asarray(t0, dtype=float).copy()
        if state["decisions"] is None:
            self._decisions = None
        else:
            assert self.theta0 is not None
            self._decisions = self._make_decisions(self.theta0)
            for d, s in zip(self._decisions, state["decisions"], strict=True):
                d.set_state(s)
        self._first_alarm_time = float(state["first_alarm_time"])
        k = raw.shape[0]
        self._blk_raw = [tuple(r) for r in raw.tolist()]
        self._blk_filtered = [tuple(r) for r in np.asarray(
            buffers["filtered"], dtype=float).reshape(k, self._width).tolist()]
        self._blk_theta = [tuple(r) for r in np.asarray(
            buffers["theta"], dtype=float).reshape(k, 2 * N_THETA).tolist()]
        self._blk_valid = [bool(v) for v in np.asarray(buffers["valid"], dtype=bool)
                           .reshape(k).tolist()]
        self._hist_filtered = [tuple(r) for r in np.asarray(
            buffers["history"], dtype=float).reshape(2, self._width).tolist()]
        self._gap = int(buffers["gap"])
        omega = state["omega"]
        self._omega_learn = [(float(a), float(b)) for a, b in np.asarray(
            omega["learn"], dtype=float).reshape(-1, 2).tolist()]
        ref = omega["ref"]
        self._omega_ref = (None if ref is None else
                           tuple(np.asarray(ref, dtype=float).reshape(2, 2).copy()))
        self._omega_dev = deque((float(v) for v in np.asarray(
            omega["deviation"], dtype=float).reshape(-1)), maxlen=self._long_blocks)
        self._theta_now = tuple(tuple(e.theta.tolist()) for e in self._estimators)
        def snapshot(raw: Any) -> tuple[Any, ...]:
            sx, sy, theta = raw
            return sx, sy, tuple(tuple(float(v) for v in row) for row in theta)

        self._rollback = None if state["rollback"] is None else snapshot(state["rollback"])
        self._snapshots.clear()
        for raw_snap in state["snapshots"]:
            self._snapshots.append(snapshot(raw_snap))
        c = self.config
        if state["learner"] is None:
            self._learner = None
        else:
            self._learner = ReferenceLearner(self._nb, self._short_blocks, self._long_blocks,
                                             c.thresholds, self._nb * self.T, self._model)
            self._learner.set_state(state["learner"])
        ref = state["reference"]
        self.reference = None if ref is None else NominalReference.from_state(ref)
        if state["monitor"] is None:
            self._monitor = None
        else:
            assert self.reference is not None
            self._monitor = ResidualMonitor(self.reference, self._nb, self._nb * self.T,
                                            self._short_blocks, self._long_blocks,
                                            c.thresholds, self._clear_blocks, self._model)
            self._monitor.set_state(state["monitor"])
        self._diagnosis = _diagnosis_from_dict(state["diagnosis"])
        self._last = _output_from_dict(state["last"], self._diagnosis)
        self._set_alignment_state(state["alignment"])

    def _set_alignment_state(self, state: dict[str, Any] | None) -> None:
        self._reset_alignment()
        if state is None:  # none saved (state version 0): an empty queue, delay as set
            return
        if (state["aligner"] is None) != (self._aligner is None):
            raise ValueError("state['alignment'] does not match case_rate_align_max")
        if self._aligner is not None:
            self._aligner.set_state(state["aligner"])
        omega = np.asarray(state["omega"], dtype=float).reshape(-1, 2)
        raw = np.asarray(state["raw"], dtype=float).reshape(-1, 4)
        volts = np.asarray(state["voltages"], dtype=float).reshape(-1, 4)
        gaps = np.asarray(state["gaps"], dtype=bool).reshape(-1)
        if (omega.shape[0] > (self._omega_hist.maxlen or 0) or raw.shape[0] > self._lookahead
                or volts.shape != raw.shape or gaps.shape != (raw.shape[0],)):
            raise ValueError("state['alignment'] does not fit this channel's case-rate "
                             "lookahead (another case_rate_lookahead_s or sample period?)")
        self._omega_hist.extend(tuple(r) for r in omega.tolist())
        self._queue.extend((tuple(r), tuple(v), bool(g)) for r, v, g in
                           zip(raw.tolist(), volts.tolist(), gaps.tolist(), strict=True))
        self._gap_pending = bool(state["gap_pending"])
        self._aligner_holdoff = int(state["holdoff"])

    @property
    def last_output(self) -> DTGChannelOutput:
        """Outputs of the most recent update (initial outputs before any)."""
        return self._last


_NO_FEATURE = np.zeros(N_THETA, dtype=np.int64)


def _ringing_samples(config: DTGChannelConfig, T: float) -> int:
    """Samples after which the prefilter's impulse response stays below 1e-3 of its
    peak."""
    f = ButterworthPrefilter(config.prefilter_order, config.cutoff_hz, 1.0 / T,
                             highpass_hz=config.prefilter_highpass_hz)
    # sample by sample (the record path needs SciPy, which a lean host may not have)
    h = np.abs([f.step((1.0 if k == 0 else 0.0,))[0] for k in range(4096)])
    above = np.flatnonzero(h > 1e-3 * h.max())
    return int(above[-1]) + 1 if above.size else 0


def _physical(th_x: tuple[float, ...], th_y: tuple[float, ...],
              T: float) -> NDArray[np.float64]:
    """:func:`~gyrodiag.dtg.model.physical_from_theta` of the mean θ of both axes, on plain
    floats (same operations, same values); NaN where the inversion is undefined."""
    t1 = (th_x[0] + th_y[0]) / 2.0
    t2 = (th_x[1] + th_y[1]) / 2.0
    if t2 == 0.0:
        return np.full(N_THETA, np.nan)
    t3 = (th_x[2] + th_y[2]) / 2.0
    t4 = (th_x[3] + th_y[3]) / 2.0
    t5 = (th_x[4] + th_y[4]) / 2.0
    T2 = T**2
    return np.array([(t1 - 2.0 * t2) / (t2 * T), (1.0 - t1 + t2) / (t2 * T2),
                     t4 / (t2 * T), (t3 - t4) / (t2 * T2), t5 / (t2 * T2)])


def _replace(out: DTGChannelOutput, **changes: Any) -> DTGChannelOutput:
    d = _output_to_dict(out)
    d.update(changes)
    return _output_from_dict(d, out.diagnosis)


def _output_to_dict(out: DTGChannelOutput) -> dict[str, Any]:
    return {
        "valid": out.valid, "learning": out.learning, "theta": out.theta.copy(),
        "eta": out.eta.copy(), "physical": out.physical.copy(), "alarm": out.alarm,
        "fault_code": out.fault_code, "feature": out.feature.copy(),
        "first_alarm_time_s": out.first_alarm_time_s,
    }


def _output_from_dict(d: dict[str, Any], diagnosis: DTGDiagnosis) -> DTGChannelOutput:
    return DTGChannelOutput(
        valid=bool(d["valid"]), learning=bool(d["learning"]),
        theta=np.asarray(d["theta"], dtype=float).reshape(2, N_THETA),
        eta=np.asarray(d["eta"], dtype=float).reshape(2, N_THETA),
        physical=np.asarray(d["physical"], dtype=float).reshape(N_THETA),
        alarm=bool(d["alarm"]), fault_code=int(d["fault_code"]),
        feature=np.asarray(d["feature"], dtype=np.int64).reshape(N_THETA),
        first_alarm_time_s=float(d["first_alarm_time_s"]), diagnosis=diagnosis,
    )


def _diagnosis_to_dict(d: DTGDiagnosis) -> dict[str, Any]:
    return {
        "reference_status": d.reference_status, "residual_alarm": d.residual_alarm,
        "class_name": d.class_name, "fault_type": d.fault_type,
        "fault_signal": d.fault_signal, "fault_axis": d.fault_axis, "distance": d.distance,
        "size": d.size, "rate": d.rate, "ratio": d.ratio, "level": d.level.copy(),
        "log_variance": d.log_variance.copy(), "growth": d.growth, "window_s": d.window_s,
        "tests": d.tests.copy(), "block": d.block,
    }


def _diagnosis_from_dict(d: dict[str, Any]) -> DTGDiagnosis:
    return DTGDiagnosis(
        reference_status=int(d["reference_status"]), residual_alarm=bool(d["residual_alarm"]),
        class_name=str(d["class_name"]), fault_type=int(d["fault_type"]),
        fault_signal=int(d["fault_signal"]), fault_axis=int(d["fault_axis"]),
        distance=float(d["distance"]), size=float(d["size"]), rate=float(d["rate"]),
        ratio=float(d["ratio"]),
        level=np.asarray(d["level"], dtype=float).reshape(N_CHANNELS),
        log_variance=np.asarray(d["log_variance"], dtype=float).reshape(N_CHANNELS),
        growth=float(d["growth"]), window_s=float(d["window_s"]),
        tests=np.asarray(d["tests"], dtype=float).reshape(N_TESTS), block=int(d["block"]),
    )



#: Version of :meth:`DTGChannel.get_state`'s format (1: tagged; case rate and alignment
#: always present).
STATE_VERSION = 1


def _from_version_0(state: dict[str, Any]) -> dict[str, Any]:
    """Unversioned states may lack the case-rate part and the alignment queue."""
    out = dict(state)
    out.setdefault("omega", {"learn": np.zeros((0, 2)), "ref": None,
                             "deviation": np.zeros(0)})
    out.setdefault("alignment", None)
    return out


_MIGRATIONS = {0: _from_version_0}
