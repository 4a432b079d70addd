"""The DTG diagnosis channel: prefilter → regressors → estimators → decision → class.

One object per monitored gyro, fed one sample of (Utx, Uty, Ux, Uy) per sample period.
It identifies θ on both axes with its own estimator each, learns the nominal θ0 from an
initial fault-free window (or takes it as given), judges each axis with the ratio
thresholds and classifies an alarm by the nearest signature. The Diagnoser FMU only
maps its variables onto this class.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, Literal

import numpy as np
from numpy.typing import NDArray

from ._validation import (
    check_finite_array,
    check_in_range,
    check_int,
    check_nonnegative,
    check_positive,
)
from .decision import (
    UNKNOWN_CODE,
    SignatureClassifier,
    ThresholdDecision,
    WindowedMedianFeature,
    feature_vector,
)
from .dtg import N_THETA, DTGRegressor, physical_from_theta
from .estimators import RLS, ForgettingRLS, SlidingWindowLS
from .prefilter import ButterworthPrefilter

__all__ = ["ESTIMATOR_KINDS", "DTGChannel", "DTGChannelConfig", "DTGChannelOutput"]

EstimatorKind = Literal["batch", "rls", "forgetting"]
#: Estimator kinds with their Integer codes used by the FMU (0, 1, 2).
ESTIMATOR_KINDS: tuple[EstimatorKind, ...] = ("batch", "rls", "forgetting")


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
    prefilter_cutoff_hz : float
        Cut-off frequency, Hz (paper: 50).
    prefilter_highpass_hz : float or None
        Optional high-pass corner, Hz (2nd order, cascaded: a band-pass). Removes the
        slow torquer response to case rates, which the regression does not model; None
        (paper) keeps the low-pass only.
    estimator : {"batch", "rls", "forgetting"}
        Sliding-window batch LS, RLS, or RLS with forgetting factor.
    window : int
        Window length of the batch estimator, samples (each sample adds one row).
    forgetting : float
        Forgetting factor of the "forgetting" estimator (paper: 0.99).
    p0 : float
        Initial covariance scale of the RLS estimators.
    theta0 : sequence of 5 floats or None
        Nominal θ0. None: learn it as the mean θ over the learning window.
    learn_start_s, learn_end_s : float
        Learning window for θ0, s from the first sample (used when theta0 is None).
    low, high : float
        Ratio band for η (paper: 0.5, 1.5).
    persistence_k, persistence_n : int
        Alarm when k of the last n samples violate the band.
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
        An alarm is classified by the median feature of the alarm samples in the last
        ``classify_window_s`` seconds, both ends included (round(w/T) + 1 samples;
        :func:`~gyrodiag.decision.median_feature`), the rule by which signatures are
        learned (``harness learn-signatures``, 0.5 s); the per-sample feature flickers
        between classes. 0: each sample's own feature (the paper's rule).
    """

    sample_period_s: float = 1e-3
    prefilter_enabled: bool = True
    prefilter_order: int = 6
    prefilter_cutoff_hz: float = 50.0
    prefilter_highpass_hz: float | None = None
    estimator: EstimatorKind = "forgetting"
    window: int = 500
    forgetting: float = 0.99
    p0: float = 1e6
    theta0: Sequence[float] | None = None
    learn_start_s: float = 1.0
    learn_end_s: float = 5.0
    low: float = 0.5
    high: float = 1.5
    persistence_k: int = 1
    persistence_n: int = 1
    latch: bool = False
    monitored: Sequence[bool] = (True, True, True, True, True)
    signatures: Mapping[str, Sequence[float]] = field(default_factory=dict)
    max_distance: float | None = None
    classify_window_s: float = 0.5

    def validate(self) -> None:
        """Raise ValueError/TypeError naming the first invalid setting."""
        check_positive("sample_period_s", self.sample_period_s)
        if self.prefilter_enabled:
            ButterworthPrefilter(
                self.prefilter_order, self.prefilter_cutoff_hz, 1.0 / self.sample_period_s,
                highpass_hz=self.prefilter_highpass_hz,
            )
        if self.estimator not in ESTIMATOR_KINDS:
            raise ValueError(
                f"estimator must be one of {ESTIMATOR_KINDS}, got {self.estimator!r}"
            )
        check_int("window", self.window, minimum=N_THETA)
        check_in_range("forgetting", self.forgetting, 0.0, 1.0, low_open=True)
        check_positive("p0", self.p0)
        if self.theta0 is not None:
            t0 = check_finite_array("theta0", self.theta0, shape=(N_THETA,))
            if np.any(t0 == 0.0):
                raise ValueError(f"theta0 must have no zero entry, got {list(t0)}")
        else:
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
        if self.signatures:
            SignatureClassifier(self.signatures, self.max_distance)
            for name, sig in self.signatures.items():
                check_finite_array(f"signatures[{name!r}]", sig, shape=(N_THETA,))
        elif self.max_distance is not None:
            check_nonnegative("max_distance", self.max_distance)
        check_nonnegative("classify_window_s", self.classify_window_s)


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
        self.T = float(config.sample_period_s)
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
        c = self.config
        return [
            ThresholdDecision(
                theta0, c.low, c.high, c.persistence_k, c.persistence_n, c.latch, c.monitored
            )
            for _ in range(2)
        ]

    def reset(self) -> None:
        """Return to the state right after construction."""
        c = self.config
        self._prefilter = (
            ButterworthPrefilter(
                c.prefilter_order, c.prefilter_cutoff_hz, 1.0 / self.T, 4,
                highpass_hz=c.prefilter_highpass_hz,
            )
            if c.prefilter_enabled
            else None
        )
        self._regressor = DTGRegressor()
        self._estimators = [self._make_estimator(), self._make_estimator()]
        self._classifier = (
            SignatureClassifier(c.signatures, c.max_distance) if c.signatures else None
        )
        self._n_samples = 0
        self._learn_sum = np.zeros(N_THETA)
        self._learn_count = 0
        self.theta0: NDArray[np.float64] | None = (
            None if c.theta0 is None else np.asarray(c.theta0, dtype=float).copy()
        )
        self._decisions = None if self.theta0 is None else self._make_decisions(self.theta0)
        self._first_alarm_time = float("nan")
        # both ends of the window, as the training window of harness.campaigns.signatures
        self._features = WindowedMedianFeature(N_THETA, round(c.classify_window_s / self.T) + 1)
        self._last = self._initial_output()

    def _initial_output(self) -> DTGChannelOutput:
        return DTGChannelOutput(
            valid=True, learning=self.theta0 is None, theta=np.zeros((2, N_THETA)),
            eta=np.ones((2, N_THETA)), physical=np.full(N_THETA, np.nan), alarm=False,
            fault_code=0, feature=np.zeros(N_THETA, dtype=np.int64),
            first_alarm_time_s=float("nan"),
        )

    # -- streaming ------------------------------------------------------------
    def update(self, Utx: float, Uty: float, Ux: float, Uy: float) -> DTGChannelOutput:
        """Process one sample (volts) and return the channel outputs.

        A sample with any NaN/Inf is skipped: the state is untouched and the previous
        outputs are returned with ``valid=False``.
        """
        raw = np.array([Utx, Uty, Ux, Uy], dtype=float)
        if not np.all(np.isfinite(raw)):
            self._last = _replace(self._last, valid=False)
            return self._last
        t = self._n_samples * self.T
        self._n_samples += 1
        # raw was checked finite above; the stages downstream need not check again
        sample = (
            self._prefilter.update(raw, validate=False) if self._prefilter is not None else raw
        )
        rows = self._regressor.update(*sample, validate=False)
        if rows is not None:
            self._estimators[0].update(rows[0], rows[1], validate=False)
            self._estimators[1].update(rows[2], rows[3], validate=False)
        theta = np.vstack([e.theta for e in self._estimators])

        if self.theta0 is None:
            self._learn(t, theta)
        if self.theta0 is None or self._decisions is None:
            self._last = DTGChannelOutput(
                True, not self.reference_failed, theta, np.ones((2, N_THETA)),
                _physical(theta, self.T), False, 0, np.zeros(N_THETA, dtype=np.int64),
                self._first_alarm_time,
            )
            return self._last

        decisions = [d.update(th) for d, th in zip(self._decisions, theta, strict=True)]
        eta = np.vstack([d.eta for d in decisions])
        alarm = any(d.alarm for d in decisions)
        feats = [feature_vector(e) for e in eta]
        worst = int(np.argmax([np.abs(f).sum() for f in feats]))
        feature = feats[worst]
        windowed = self._features.window > 1
        if windowed:  # window 1 (the paper's rule) needs no history
            self._features.update(feature, alarm)
        code = 0
        if alarm:
            if np.isnan(self._first_alarm_time):
                self._first_alarm_time = t
            if windowed:
                feature = self._features.median()
            code = (
                self._classifier.classify(feature).code
                if self._classifier is not None
                else UNKNOWN_CODE
            )
        self._last = DTGChannelOutput(
            True, False, theta, eta, _physical(theta, self.T), alarm, code, feature,
            self._first_alarm_time,
        )
        return self._last

    def _learn(self, t: float, theta: NDArray[np.float64]) -> None:
        c = self.config
        if c.learn_start_s <= t < c.learn_end_s:
            self._learn_sum += theta.mean(axis=0)
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
        return (self.theta0 is None and self._learn_count == 0
                and self._n_samples * self.T > self.config.learn_end_s)

    # -- state ----------------------------------------------------------------
    def get_state(self) -> dict[str, Any]:
        """Full internal state (filters, estimators, decisions, learning, outputs)."""
        return {
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
            "last": _output_to_dict(self._last),
        }

    def set_state(self, state: dict[str, Any]) -> None:
        """Restore a state produced by :meth:`get_state` of an identically configured
        channel."""
        try:  # first: a state of another classify_window_s leaves this channel untouched
            self._features.set_state(state["features"])
        except ValueError as exc:
            raise ValueError(f"state['features'] (classify_window_s): {exc}") from exc
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
        self._last = _output_from_dict(state["last"])

    @property
    def last_output(self) -> DTGChannelOutput:
        """Outputs of the most recent update (initial outputs before any)."""
        return self._last


def _physical(theta: NDArray[np.float64], T: float) -> NDArray[np.float64]:
    mean = theta.mean(axis=0)
    if mean[1] == 0.0:
        return np.full(N_THETA, np.nan)
    return physical_from_theta(mean, T).as_array()


def _replace(out: DTGChannelOutput, **changes: Any) -> DTGChannelOutput:
    d = _output_to_dict(out)
    d.update(changes)
    return _output_from_dict(d)


def _output_to_dict(out: DTGChannelOutput) -> dict[str, Any]:
    return {
        "valid": out.valid, "learning": out.learning, "theta": out.theta.copy(),
        "eta": out.eta.copy(), "physical": out.physical.copy(), "alarm": out.alarm,
        "fault_code": out.fault_code, "feature": out.feature.copy(),
        "first_alarm_time_s": out.first_alarm_time_s,
    }


def _output_from_dict(d: dict[str, Any]) -> DTGChannelOutput:
    return DTGChannelOutput(
        valid=bool(d["valid"]), learning=bool(d["learning"]),
        theta=np.asarray(d["theta"], dtype=float).reshape(2, N_THETA),
        eta=np.asarray(d["eta"], dtype=float).reshape(2, N_THETA),
        physical=np.asarray(d["physical"], dtype=float).reshape(N_THETA),
        alarm=bool(d["alarm"]), fault_code=int(d["fault_code"]),
        feature=np.asarray(d["feature"], dtype=np.int64).reshape(N_THETA),
        first_alarm_time_s=float(d["first_alarm_time_s"]),
    )

