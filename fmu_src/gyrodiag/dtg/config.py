"""Settings of the DTG diagnosis channel (:class:`DTGChannelConfig`) and their
automatic values."""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Literal

import numpy as np

from ..common._validation import (
    check_finite_array,
    check_in_range,
    check_int,
    check_nonnegative,
    check_positive,
)
from ..common.prefilter import ButterworthPrefilter
from .case_rate import CASE_RATE_SCHEMES
from .decision import SignatureClassifier, ThresholdDecision
from .model import N_THETA
from .patterns import PatternLibrary
from .physical_test import PHYSICAL_SIGMA
from .reference import (
    ALLOWANCE_SIGMA,
    POWER_THRESHOLD,
    RegressionModel,
    ResidualThresholds,
)

__all__ = [
    "AUTO_SETTINGS",
    "CLASSIFIERS",
    "ESTIMATOR_KINDS",
    "DTGChannelConfig",
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
#: Default significance of a band violation, standard errors (:attr:`DTGChannelConfig.
#: band_sigma`; measured margins in docs/dtg_case_rate.md §10 and docs/notes.md).
BAND_SIGMA = 5.0


@dataclass
class DTGChannelConfig:
    """Settings of a :class:`~gyrodiag.dtg.channel.DTGChannel` (validated by :meth:`validate`).

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
        (:mod:`gyrodiag_harness.cosim.timing`).
    case_rate_align_max : int
        Case rate only: choose d in −this … this from the data (0, the default: keep
        ``case_rate_delay_samples``). For hosts whose timing is unknown; measured limits
        in docs/dtg_case_rate.md §9 (in calm level flight the pairings' fits differ by
        noise only, and a choice made there can bias θ0). :class:`~gyrodiag.dtg.alignment.
        CaseRateAligner`, docs/dtg_case_rate.md §9: the first fast change of the case
        rate shows which pairing fits.
    physical_sigma : float
        Pattern classifier: threshold of the GLR test of a spin and a torquer scale
        change (:mod:`gyrodiag.dtg.physical_test`), standard errors; 0: off (physical
        faults then only through the ratio band).
    ratio_band : bool or None
        The ratio band alarms. None: automatic, off where the physical test runs and
        ``low`` and ``high`` are left automatic (the test sees far smaller changes, and
        the band's η of a fast estimate false-alarms on noisier benches), on otherwise.
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
    physical_sigma: float = PHYSICAL_SIGMA
    ratio_band: bool | None = None

    def __post_init__(self) -> None:
        """Settings left None take their automatic value (:data:`AUTO_SETTINGS`)."""
        auto = AUTO_SETTINGS["case_rate" if self.case_rate is not None else "bench"]
        end_auto = self.learn_end_s is None
        if self.ratio_band is None:
            self.ratio_band = not (self.low is None and self.high is None
                                   and self.physical_test_on and self.case_rate is None)
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
    def physical_test_on(self) -> bool:
        """The physical-parameter test runs: pattern classifier, a threshold > 0."""
        return self.classifier == "pattern" and self.physical_sigma > 0.0

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
            self._validate_case_rate()
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
        check_nonnegative("physical_sigma", self.physical_sigma)
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
            self._validate_pattern()

    def _validate_case_rate(self) -> None:
        """The case-rate settings (``case_rate`` set)."""
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

    def _validate_pattern(self) -> None:
        """The pattern classifier's settings (``classifier="pattern"``)."""
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
