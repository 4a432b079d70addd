"""Configurations of the grey channel's decision rules, which build the fault detector.

Each configuration turns a streaming predictor into a
:class:`~gyrodiag.grey.detector.GreyFaultDetector` that decides by its rule (the
per-sample rule objects are in :mod:`gyrodiag.grey.rules`; docs/methods.md §3):

* :class:`PaperThreshold`: [B]'s fixed threshold on the one-step prediction error.
* :class:`CalibratedSequential`: the threshold learned from the prediction errors of a
  fault-free start, a lagged step test and a CUSUM for a design false-alarm rate.
* :class:`CalibratedKSigma`: the threshold learned the same way, a k·σ_e test per sample.

The calibrated rules take their fault-free start in seconds (``learn_end_s``, the
predictor's warm-up included), and the sequential rule its reference window
(``reference_window_s``), so they cover the same time at any sample period.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import ClassVar, Protocol

from ..common._validation import check_positive
from .detector import GreyFaultDetector
from .predictor import GreyPredictor

__all__ = [
    "DEFAULT_LEARN_END_S",
    "MIN_CALIBRATION_ERRORS",
    "REFERENCE_MAX_SAMPLES",
    "CalibratedKSigma",
    "CalibratedSequential",
    "GreyDecision",
    "PaperThreshold",
]

DEFAULT_LEARN_END_S = 25.0
"""Default fault-free start of the calibrated rules, s (warm-up and calibration)."""

MIN_CALIBRATION_ERRORS = 10
"""Fewest one-step prediction errors a calibration may hold."""

REFERENCE_MAX_SAMPLES = 400
"""Longest reference window of the lagged step test, samples (its weights are computed
for every length up to it when the detector is built)."""


class GreyDecision(Protocol):
    """A decision rule of the grey channel."""

    name: ClassVar[str]
    #: Packages beyond numpy the rule's detector imports (a host must have them).
    requires: ClassVar[tuple[str, ...]]

    def build(self, predictor: GreyPredictor, sample_period_s: float,
              clear_after_s: float | None = None,
              candidates: Sequence[GreyPredictor] = ()) -> GreyFaultDetector:
        """A fresh detector deciding by this rule (it owns ``predictor`` from now on)."""
        ...


@dataclass(frozen=True)
class PaperThreshold:
    """[B]'s rule: alarm when |y − ŷ| > ``threshold`` (signal units, V for the HRG)."""

    threshold: float = 0.05
    name: ClassVar[str] = "paper"
    requires: ClassVar[tuple[str, ...]] = ()

    def __post_init__(self) -> None:
        check_positive("threshold", self.threshold)

    def build(self, predictor: GreyPredictor, sample_period_s: float,
              clear_after_s: float | None = None,
              candidates: Sequence[GreyPredictor] = ()) -> GreyFaultDetector:
        """The fixed-threshold detector; ``candidates`` are not used (no calibration
        window to choose a predictor on)."""
        return GreyFaultDetector(predictor, self.threshold, sample_period_s, clear_after_s)


@dataclass(frozen=True)
class _Calibrated:
    """Common part of the calibrated rules.

    Attributes
    ----------
    learn_end_s : float
        The signal is fault-free from the start until this time, s: the predictor's
        warm-up window, then the one-step errors that give σ_e (at least
        :data:`MIN_CALIBRATION_ERRORS` of them).
    threshold_floor : float
        Smallest threshold allowed on |e| (signal units): σ_e >= floor / ``k_sigma``,
        and floor / ``k_sigma`` is the lagged test's allowance for its reference's
        model error (what remains on a noise-free signal).
    k_sigma, suspicion_sigma : float
        Per-sample threshold and suspicion level, in σ_e.
    """

    learn_end_s: float = DEFAULT_LEARN_END_S
    threshold_floor: float = 0.01
    k_sigma: float = 5.0
    suspicion_sigma: float = 4.0
    #: quantiles of the thresholds and σ bounds (scipy.special)
    requires: ClassVar[tuple[str, ...]] = ("scipy",)

    def __post_init__(self) -> None:
        for name in ("learn_end_s", "threshold_floor", "k_sigma", "suspicion_sigma"):
            check_positive(name, getattr(self, name))

    def calibrate_samples(self, predictor: GreyPredictor, sample_period_s: float) -> int:
        """Number of one-step errors calibrated on: the samples up to ``learn_end_s``
        less the predictor's warm-up, and at least :data:`MIN_CALIBRATION_ERRORS` (at
        slow sample rates the window is lengthened to hold them)."""
        period = check_positive("sample_period_s", sample_period_s)
        total = round(self.learn_end_s / period)
        return max(total - predictor.min_samples, MIN_CALIBRATION_ERRORS)


@dataclass(frozen=True)
class CalibratedSequential(_Calibrated):
    """Calibrated σ_e, then a lagged step test (GLR on the last 1..``lag_max`` samples
    against a polynomial reference of up to ``reference_window_s`` seconds, at most
    :data:`REFERENCE_MAX_SAMPLES` samples) and a CUSUM on e/σ_e, thresholds for
    ``false_alarms_per_h`` (see :class:`GreyFaultDetector`)."""

    false_alarms_per_h: float = 1e-3
    cusum_k: float = 1.5
    lag_max: int = 3
    reference_window_s: float = 30.0
    reference_order: int = 3
    name: ClassVar[str] = "sequential"

    def __post_init__(self) -> None:
        super().__post_init__()
        for name in ("false_alarms_per_h", "cusum_k", "reference_window_s"):
            check_positive(name, getattr(self, name))

    def reference_samples(self, sample_period_s: float) -> int:
        """Longest reference window of the lagged test, samples: ``reference_window_s``
        at the sample period, at most :data:`REFERENCE_MAX_SAMPLES`, and at least the
        ``reference_order`` + 3 the reference polynomial needs (slow sample rates)."""
        period = check_positive("sample_period_s", sample_period_s)
        samples = round(self.reference_window_s / period)
        return min(max(samples, self.reference_order + 3), REFERENCE_MAX_SAMPLES)

    def build(self, predictor: GreyPredictor, sample_period_s: float,
              clear_after_s: float | None = None,
              candidates: Sequence[GreyPredictor] = ()) -> GreyFaultDetector:
        """The calibrated sequential detector; ``candidates`` compete on the calibration."""
        return GreyFaultDetector(
            predictor, self.threshold_floor, sample_period_s, clear_after_s,
            calibrate_samples=self.calibrate_samples(predictor, sample_period_s),
            k_sigma=self.k_sigma, sequential=True,
            false_alarms_per_h=self.false_alarms_per_h, cusum_k=self.cusum_k,
            suspicion_sigma=self.suspicion_sigma, candidates=candidates,
            lag_max=self.lag_max, reference_window=self.reference_samples(sample_period_s),
            reference_order=self.reference_order)


@dataclass(frozen=True)
class CalibratedKSigma(_Calibrated):
    """Calibrated σ_e, then alarm when |e| > max(``k_sigma``·σ_e, ``threshold_floor``)."""

    name: ClassVar[str] = "k_sigma"

    def build(self, predictor: GreyPredictor, sample_period_s: float,
              clear_after_s: float | None = None,
              candidates: Sequence[GreyPredictor] = ()) -> GreyFaultDetector:
        """The calibrated per-sample detector; ``candidates`` compete on the calibration."""
        return GreyFaultDetector(
            predictor, self.threshold_floor, sample_period_s, clear_after_s,
            calibrate_samples=self.calibrate_samples(predictor, sample_period_s),
            k_sigma=self.k_sigma, suspicion_sigma=self.suspicion_sigma,
            candidates=candidates)
