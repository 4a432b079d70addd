"""The lagged step test of the grey channel's sequential rule (:class:`LaggedStepTest`).

A one-step predictor takes a step in within two samples, so its errors hold at most two
samples of evidence. For each lag L the last L measured samples are tested against the
least-squares polynomial of the reference window before them, extrapolated: the
generalised likelihood ratio of a step in those L samples, z_L = w_L·y / σ_n
(:func:`lag_step_weights`; z_L ~ N(0, 1) without a step), σ_n the signal's white noise
(:attr:`LaggedStepTest.noise_sigma`). Alarm when |z_L| >= ``thresholds[L − 1]``, set from
the design false-alarm rate (:data:`LONGEST_LAG_SHARE` of it to the longest lag, the rest
shared, :func:`lag_test_threshold`).
"""

from __future__ import annotations

import copy
import functools
import math
from collections import deque
from collections.abc import Mapping
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ..common._validation import check_int, check_positive

__all__ = [
    "LAG_MAX_LIMIT",
    "LONGEST_LAG_SHARE",
    "LaggedStepTest",
    "lag_step_weights",
    "lag_test_threshold",
]

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


class LaggedStepTest:
    """Step test on the last 1..``lags`` measured samples against an extrapolated reference.

    Parameters
    ----------
    lags : int
        Longest lag tested, samples (1..:data:`LAG_MAX_LIMIT`).
    reference_window : int
        Longest reference window M, samples; the test starts with ``reference_min`` =
        min(M, max(``reference_order`` + 3, 20)) samples and uses up to M.
    reference_order : int
        Degree of the reference polynomial (0..3).
    false_alarms_per_h : float
        Design false-alarm rate, 1/h.
    sample_period_s : float
        Sample period, s.
    allowance : float
        Added in quadrature to the noise σ_n (signal units): the reference polynomial's
        model error, what remains on a noise-free signal.
    """

    def __init__(self, lags: int, reference_window: int, reference_order: int,
                 false_alarms_per_h: float, sample_period_s: float, allowance: float
                 ) -> None:
        self.lags = check_int("lags", lags, minimum=1)
        self.reference_window = reference_window
        self.reference_min = min(reference_window, max(reference_order + 3, 20))
        self.allowance = allowance
        # the longest lag gets LONGEST_LAG_SHARE of the design rate (it has the most
        # power on a step that is still inside the tested samples); the shorter ones
        # share the rest and are there for large steps, seen sooner
        shares = ([1.0] if lags == 1 else
                  [(1.0 - LONGEST_LAG_SHARE) / (lags - 1)] * (lags - 1)
                  + [LONGEST_LAG_SHARE])
        #: thresholds on |z|, lag 1 first
        self.thresholds = [lag_test_threshold(share * false_alarms_per_h,
                                              sample_period_s, 1) for share in shares]
        self._weights: dict[tuple[int, int], NDArray[np.float64]] = {
            (m, lag): np.array(_lag_weights_cached(m, reference_order, lag))
            for m in range(self.reference_min, reference_window + 1)
            for lag in range(1, lags + 1)}
        self.reset()

    def reset(self) -> None:
        """Forget every sample and the noise estimate."""
        # measured samples (reference window + tested lags); the predictor's state and
        # pending prediction before each of the last lags samples; third differences of
        # consecutive fault-free samples (noise σ)
        self._buf: list[float] = []
        self._hist: deque[tuple[dict[str, Any], float]] = deque(maxlen=self.lags)
        self._tail: list[float] = []
        self._noise_sq = 0.0
        self._noise_n = 0
        self.statistic = 0.0
        """z of the last sample with the largest |z| over the lags; 0 when not tested."""

    def observe(self, value: float) -> None:
        """A measured sample (signal units) enters the window."""
        self._buf.append(value)
        if len(self._buf) > self.reference_window + self.lags:
            del self._buf[0]

    def accept(self, value: float) -> None:
        """A fault-free sample (signal units) adds to the noise estimate."""
        tail = self._tail
        tail.append(value)
        if len(tail) == 4:
            d3 = ((tail[3] - tail[0]) - 3.0 * (tail[2] - tail[1]))
            self._noise_sq += d3 * d3
            self._noise_n += 1
            del tail[0]

    def interrupt(self) -> None:
        """A sample was substituted: the next third difference starts afresh."""
        self._tail.clear()

    def snapshot(self, predictor_state: dict[str, Any], predicted: float) -> None:
        """Keep the predictor's state and pending prediction from before this sample."""
        self._hist.append((predictor_state, predicted))

    def rollback_point(self, lag: int) -> tuple[dict[str, Any], float]:
        """The predictor's state and pending prediction from before the last ``lag``
        samples."""
        return self._hist[-lag]

    def forget(self) -> None:
        """Start the reference afresh (alarm, clearing): its window must hold measured
        samples of the signal as it is now."""
        self._buf.clear()
        self._hist.clear()
        self._tail.clear()
        self.statistic = 0.0

    @property
    def noise_sigma(self) -> float:
        """Standard deviation of the signal's white noise (signal units) from the third
        differences of consecutive fault-free samples, raised to its 95 % upper
        confidence bound, with ``allowance`` added in quadrature; NaN before ten
        differences are known."""
        n = self._noise_n
        if n < 10:
            return math.nan
        dof = n / _D3_DOF_FACTOR
        c = 2.0 / (9.0 * dof)
        # χ²(0.05, dof) by Wilson–Hilferty (within 1 % for dof >= 4)
        q05 = dof * (1.0 - c - 1.6448536269514722 * math.sqrt(c)) ** 3
        var = self._noise_sq / (_D3_VARIANCE * n) * dof / q05
        return math.sqrt(var + self.allowance ** 2)

    @property
    def ready(self) -> bool:
        """The test decides on the sample being processed (noise known, at least
        ``reference_min`` + 1 measured samples since the start or the last alarm)."""
        return not math.isnan(self.noise_sigma) and len(self._buf) > self.reference_min

    def test(self) -> tuple[int, float, float]:
        """(lag, z, ratio) of the lag with the largest |z| / threshold among those that
        can be tested now; lag is 0 when that ratio stays below 1."""
        sigma = self.noise_sigma
        buf = self._buf
        m = self.reference_window
        best_lag, best_z, best_ratio = 0, 0.0, 0.0
        if math.isnan(sigma):
            self.statistic = 0.0
            return 0, 0.0, 0.0
        arr = np.asarray(buf, dtype=float)
        for lag in range(1, min(self.lags, len(self._hist)) + 1):
            ref = min(m, len(buf) - lag)
            if ref < self.reference_min:
                break
            z = float(np.dot(self._weights[ref, lag], arr[-(ref + lag):])) / sigma
            ratio = abs(z) / self.thresholds[lag - 1]
            if ratio > best_ratio:
                best_lag, best_z, best_ratio = lag, z, ratio
        self.statistic = best_z
        return (best_lag if best_ratio >= 1.0 else 0), best_z, best_ratio

    def get_state(self) -> dict[str, Any]:
        """State as a flat plain dict (``lag_hist{i}.`` prefixes the snapshots)."""
        state: dict[str, Any] = {
            "lag_buf": np.asarray(self._buf, dtype=float),
            "lag_hist_pending": np.array([p for _, p in self._hist], dtype=float),
            "noise_tail": np.asarray(self._tail, dtype=float),
            "noise_sq": float(self._noise_sq),
            "noise_n": int(self._noise_n),
            "lag_z": float(self.statistic),
        }
        for i, (snap, _) in enumerate(self._hist):
            for key, val in snap.items():
                state[f"lag_hist{i}.{key}"] = copy.deepcopy(val)
        return state

    def set_state(self, state: Mapping[str, Any]) -> None:
        """Restore :meth:`get_state`; a state without the test's keys starts it afresh.

        Raises
        ------
        ValueError
            If the stored samples do not fit this test.
        """
        self.reset()
        if "lag_buf" not in state:
            return
        buf = np.array(state["lag_buf"], dtype=float).reshape(-1)
        pending = np.array(state["lag_hist_pending"], dtype=float).reshape(-1)
        tail = np.array(state["noise_tail"], dtype=float).reshape(-1)
        if (buf.size > self.reference_window + self.lags or pending.size > self.lags
                or tail.size > 3):
            raise ValueError("state['lag_buf'] / state['lag_hist_pending'] / "
                             "state['noise_tail'] do not fit this detector")
        for i, p in enumerate(pending):
            pre = f"lag_hist{i}."
            snap = {k[len(pre):]: copy.deepcopy(v) for k, v in state.items()
                    if k.startswith(pre)}
            self._hist.append((snap, float(p)))
        self._buf = buf.tolist()
        self._tail = tail.tolist()
        self._noise_sq = float(state["noise_sq"])
        self._noise_n = int(state["noise_n"])
        self.statistic = float(state["lag_z"])
