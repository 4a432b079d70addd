"""Sequential change detection on standardised white residuals: CUSUM tests and their
thresholds for a stated false-alarm rate.

Two tests per channel ``c`` of a standardised residual ``z_c`` (zero mean, unit variance,
white when fault-free, e.g. the whitened innovations of
:mod:`gyrodiag.df.residual`):

* two-sided **mean CUSUM** (Page 1954) with reference ``k``::

      S⁺ ← max(0, S⁺ + z − k),   S⁻ ← max(0, S⁻ − z − k)

  the log-likelihood-ratio test of a mean shift ±2k (in σ) against none;
* one-sided **variance CUSUM** for an increase of the variance by ``ratio`` r::

      V ← max(0, V + a z² − c),  a = (1 − 1/r)/2,  c = ln(r)/2

  (the log-likelihood ratio of N(0, r) against N(0, 1)).

A chart alarms when its statistic reaches its threshold ``h``. Statistics are capped at
``h`` and a channel's alarm clears when every statistic of it has fallen below
``release·h``: with a persistent fault the alarm stays, and once the fault is gone it
clears after about (1 − release)·h/k samples, so a detection follows an intermittent
fault instead of latching.

Thresholds
----------
For white Gaussian input the in-control average run length (ARL, samples to a false
alarm from a zero start) of each chart is a known function of ``h`` and ``k`` (or
``ratio``). :func:`mean_cusum_arl` and :func:`variance_cusum_arl` compute it by the
Markov-chain method of Brook & Evans (1972) with Richardson extrapolation in the number
of states; :func:`mean_cusum_threshold` and :func:`variance_cusum_threshold` invert it.
A stated false-alarm rate (alarms per hour of the whole bank) is split evenly over the
charts (a union bound: charts on correlated channels alarm together, so the real rate
is lower). The thresholds hold for *white* input only: the residual of a detection
filter is coloured (white-noise formulas applied to it are wrong, docs/methods.md §4), which is
why the detection-filter channel whitens it first and checks the whole chain by long
fault-free simulation (:func:`gyrodiag.df.residual.simulate_fault_free`).
"""

from __future__ import annotations

import math
from functools import lru_cache
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ._validation import check_finite_array, check_in_range, check_int, check_positive

__all__ = [
    "CusumBank",
    "arl_for_rate",
    "mean_cusum_arl",
    "mean_cusum_threshold",
    "variance_cusum_arl",
    "variance_cusum_increment",
    "variance_cusum_threshold",
]

_FloatArray = NDArray[np.float64]
_ONE = np.ones(1)

#: Markov-chain states of a mean-CUSUM ARL, at least (and twice as many for the
#: extrapolation; more for large h, ~3 per σ of threshold): relative ARL error below
#: 1e-5 at h = 4 and h = 20 (k = 0.5) against 960/1920 states.
MEAN_ARL_STATES = 120
#: States of a variance-CUSUM ARL, at least (more for large h, ~5 per standard
#: deviation of the increment). The χ² density is infinite at 0, the error does not
#: fall smoothly with N (no extrapolation): within 3 % of 960 states at h = 4 and 20.
VARIANCE_ARL_STATES = 400
#: Upper bound on the states of one chain (memory: N² doubles).
MAX_ARL_STATES = 2000


# ------------------------------------------------------------------- average run length


def _chain_arl(h: float, cdf: Any, n_states: int) -> float:
    """Zero-start ARL of S ← max(0, S + X), alarm at S > h, X with CDF ``cdf``.

    Brook & Evans: state 0 is S ≤ w/2, state j ≥ 1 is S in ((j − ½)w, (j + ½)w] with
    w = 2h/(2N − 1), represented by its midpoint jw.
    """
    n = n_states
    w = 2.0 * h / (2.0 * n - 1.0)
    mid = np.arange(n) * w
    edges = (np.arange(n + 1) - 0.5) * w  # upper edges of states 0..N-1 are edges[1:]
    upper = cdf(edges[None, 1:] - mid[:, None])
    lower = cdf(edges[None, :-1] - mid[:, None])
    trans = upper - lower
    trans[:, 0] = upper[:, 0]  # state 0 collects every S + X ≤ w/2 (the max(0, ·))
    arl = np.linalg.solve(np.eye(n) - trans, np.ones(n))
    return max(float(arl[0]), 1.0)  # at least the sample that alarms


def _extrapolated_arl(h: float, cdf: Any, n_states: int) -> float:
    coarse = _chain_arl(h, cdf, n_states)
    fine = _chain_arl(h, cdf, 2 * n_states)
    # The discretisation error falls as 1/N² for a smooth density; extrapolate in log
    # ARL, which keeps the result positive for very long run lengths.
    return float(math.exp((4.0 * math.log(fine) - math.log(coarse)) / 3.0))


def mean_cusum_arl(h: float, k: float, shift: float = 0.0) -> float:
    """Zero-start ARL (samples) of one side of a mean CUSUM on N(shift, 1) samples.

    Parameters
    ----------
    h : float
        Threshold, in σ of the input (> 0).
    k : float
        Reference value, σ (>= 0).
    shift : float
        Mean of the input, σ (0: in control, i.e. the false-alarm run length).
    """
    h = check_positive("h", h)
    k = float(check_in_range("k", k, 0.0, 10.0))
    shift = float(shift)
    from scipy.special import ndtr  # here: the paper rule's start-up does without it

    n_states = min(max(MEAN_ARL_STATES, math.ceil(3.0 * h) + 60), MAX_ARL_STATES)
    return _extrapolated_arl(h, lambda x: ndtr(x + k - shift), n_states)


def variance_cusum_increment(ratio: float) -> tuple[float, float]:
    """(a, c) of the variance-CUSUM increment a·z² − c for a variance increase ``ratio``."""
    r = check_in_range("ratio", ratio, 1.0, 1e6, low_open=True)
    return (1.0 - 1.0 / r) / 2.0, math.log(r) / 2.0


def variance_cusum_arl(h: float, ratio: float, true_variance: float = 1.0) -> float:
    """Zero-start ARL (samples) of the variance CUSUM designed for ``ratio``, on
    N(0, true_variance) samples (1: in control)."""
    from scipy.special import gammainc

    h = check_positive("h", h)
    a, c = variance_cusum_increment(ratio)
    var = check_positive("true_variance", true_variance)
    n_states = min(max(VARIANCE_ARL_STATES, math.ceil(5.0 * h / (a * var * math.sqrt(2.0)))),
                   MAX_ARL_STATES)
    # P(z² ≤ q) for z ~ N(0, 1) is the regularised lower gamma function P(½, q/2)
    return _chain_arl(
        h, lambda x: gammainc(0.5, np.maximum((x + c) / (a * var), 0.0) / 2.0),
        n_states,
    )


def _solve_threshold(arl_of_h: Any, target: float, h0: float) -> float:
    """h with ARL(h) = target, from a first guess ``h0``: bracketed by steps of 25 %
    (the chain's size grows with h), then secant iterations on log ARL, which is nearly
    linear in h."""
    log_target = math.log(target)
    lo, hi = 0.8 * h0, h0
    while math.log(arl_of_h(hi)) < log_target:
        lo, hi = hi, 1.25 * hi
    while lo > 1e-3 and math.log(arl_of_h(lo)) > log_target:
        hi, lo = lo, 0.8 * lo
    f_lo = math.log(arl_of_h(lo)) - log_target
    f_hi = math.log(arl_of_h(hi)) - log_target
    h = hi
    for _ in range(60):
        h = hi - f_hi * (hi - lo) / (f_hi - f_lo) if f_hi != f_lo else 0.5 * (lo + hi)
        if not lo < h < hi:
            h = 0.5 * (lo + hi)
        f = math.log(arl_of_h(h)) - log_target
        if abs(f) < 1e-6:
            return h
        if f < 0.0:
            lo, f_lo = h, f
        else:
            hi, f_hi = h, f
    return h


def _brownian_guess(arl: float, drift: float, variance: float) -> float:
    """Threshold of a CUSUM whose increments have mean ``drift`` < 0 and ``variance``,
    from the Brownian-motion approximation ARL ≈ σ²/(2μ²)·exp(2|μ|h/σ²) (a start for
    the exact solution, not a result)."""
    mu = abs(drift)
    return max(variance * math.log(max(2.0 * mu * mu * arl / variance, 2.0)) / (2.0 * mu),
               0.1)


#: Grids of the shipped threshold table (:mod:`gyrodiag.common.cusum_table`): log10 ARL, the
#: mean-CUSUM reference k and the variance ratio r. h is linear in log ARL to 1e-7 at
#: 0.25 decades, and h·k linear in k to 2e-3 at 0.05 (ARL within 0.3 %).
TABLE_LOG10_ARL = tuple(2.0 + 0.25 * i for i in range(45))  # 1e2 … 1e13
TABLE_K = tuple(round(0.1 + 0.05 * i, 2) for i in range(39))  # 0.1 … 2.0
TABLE_RATIO = (1.5, 2.0, 2.5, 3.0, 4.0, 5.0, 6.0, 8.0, 10.0, 15.0, 20.0, 30.0, 50.0, 100.0)


@lru_cache(maxsize=64)
def _mean_threshold(arl: float, k: float) -> float:
    return _solve_threshold(lambda h: mean_cusum_arl(h, k), arl,
                            _brownian_guess(arl, -k, 1.0))


@lru_cache(maxsize=64)
def _variance_threshold(arl: float, ratio: float) -> float:
    a, c = variance_cusum_increment(ratio)
    return _solve_threshold(lambda h: variance_cusum_arl(h, ratio), arl,
                            _brownian_guess(arl, a - c, 2.0 * a * a))


def _shipped_table(name: str) -> Any:
    """A table of :mod:`gyrodiag.common.cusum_table`; None while it is being regenerated
    (the chain then gives the same thresholds, slower)."""
    try:
        from . import cusum_table
    except ImportError:
        return None
    return getattr(cusum_table, name)


def _from_table(table: Any, grid: tuple[float, ...], value: float, log_arl: float,
                scale_by_value: bool) -> float | None:
    """Threshold interpolated from a shipped table (None outside it): linear in log10
    ARL, and linear in ``value`` of h·value (mean CUSUM: h·k is nearly constant) or of
    h (variance CUSUM)."""
    lg = TABLE_LOG10_ARL
    if not (lg[0] <= log_arl <= lg[-1] and grid[0] <= value <= grid[-1]):
        return None
    arr = np.asarray(table, dtype=float)
    col = np.array([np.interp(log_arl, lg, row) for row in arr])
    if scale_by_value:
        return float(np.interp(value, grid, col * np.asarray(grid)) / value)
    return float(np.interp(value, grid, col))


def mean_cusum_threshold(arl: float, k: float, *, exact: bool = False) -> float:
    """Threshold ``h`` (σ) of one side of a mean CUSUM with in-control ARL ``arl``
    samples on white N(0, 1) input.

    From the shipped table (:mod:`gyrodiag.common.cusum_table`, ARL within 0.3 %) inside it,
    else (or with ``exact``) by solving the Markov chain (ARL within 1e-5; seconds).
    """
    arl = check_in_range("arl", arl, 2.0, 1e15)
    k = check_in_range("k", k, 0.05, 5.0)
    table = None if exact else _shipped_table("MEAN_H")
    if table is not None:
        h = _from_table(table, TABLE_K, k, math.log10(arl), True)
        if h is not None:
            return h
    return _mean_threshold(float(arl), float(k))


def variance_cusum_threshold(arl: float, ratio: float, *, exact: bool = False) -> float:
    """Threshold ``h`` (log-likelihood units) of the variance CUSUM with in-control ARL
    ``arl`` samples on white N(0, 1) input; from the shipped table inside it, else (or
    with ``exact``) by the Markov chain (ARL within about 3 %)."""
    arl = check_in_range("arl", arl, 2.0, 1e15)
    ratio = check_in_range("ratio", ratio, 1.0, 1e6, low_open=True)
    table = None if exact else _shipped_table("VARIANCE_H")
    if table is not None:
        h = _from_table(table, TABLE_RATIO, ratio, math.log10(arl), False)
        if h is not None:
            return h
    return _variance_threshold(float(arl), float(ratio))


def arl_for_rate(false_alarms_per_h: float, sample_period_s: float, n_charts: int) -> float:
    """In-control ARL (samples) each of ``n_charts`` charts needs so that together they
    raise at most ``false_alarms_per_h`` false alarms per hour (union bound)."""
    rate = check_positive("false_alarms_per_h", false_alarms_per_h)
    t = check_positive("sample_period_s", sample_period_s)
    n = check_int("n_charts", n_charts, minimum=1)
    return n * 3600.0 / (t * rate)


# --------------------------------------------------------------------------- the charts


class CusumBank:
    """Two-sided mean CUSUM and variance CUSUM on each of ``n_channels`` inputs.

    Parameters
    ----------
    n_channels : int
        Number of standardised residual channels.
    k : float
        Mean-CUSUM reference, σ (> 0); optimal for mean shifts of 2k.
    h_mean : float
        Mean-CUSUM threshold, σ (> 0), e.g. from :func:`mean_cusum_threshold`.
    variance_ratio : float
        Variance increase the variance CUSUM is designed for (> 1).
    h_variance : float
        Variance-CUSUM threshold (> 0), e.g. from :func:`variance_cusum_threshold`.
    release : float
        An alarmed channel clears when all its statistics are below ``release·h``
        (0 < release < 1).

    Notes
    -----
    :meth:`update` does not validate its input (the channel owning the bank checks each
    sample once at its boundary). The classical estimate of the change time, the last
    sample at which an alarming statistic was zero, is found when needed by walking its
    recursion back from :attr:`previous_statistics` with the increments of the stored
    samples (:meth:`increments`): no per-sample bookkeeping.
    """

    def __init__(self, n_channels: int, k: float, h_mean: float, variance_ratio: float,
                 h_variance: float, release: float = 0.5) -> None:
        self.n_channels = check_int("n_channels", n_channels, minimum=1)
        self.k = check_positive("k", k)
        self.h_mean = check_positive("h_mean", h_mean)
        self.variance_ratio = check_in_range("variance_ratio", variance_ratio, 1.0, 1e6,
                                             low_open=True)
        self.h_variance = check_positive("h_variance", h_variance)
        self.release = check_in_range("release", release, 0.0, 1.0, low_open=True,
                                      high_open=True)
        self._a, self._c = variance_cusum_increment(self.variance_ratio)
        n = self.n_channels
        # statistics stacked [S⁺; S⁻; V]; their increments are one matrix product with
        # [z; z²; 1]: z − k, −z − k, a·z² − c
        self._cap = np.concatenate([np.full(2 * n, self.h_mean), np.full(n, self.h_variance)])
        self._release_level = self.release * self._cap
        eye = np.eye(n)
        zero = np.zeros((n, n))
        drift = np.concatenate([np.full(2 * n, -self.k), np.full(n, -self._c)])
        self._map = np.hstack([np.vstack([eye, -eye, zero]),
                               np.vstack([zero, zero, self._a * eye]), drift[:, None]])
        self._buf = np.ones(2 * n + 1)  # scratch of update()
        self.reset()

    def reset(self, next_sample: int = 0) -> None:
        """All statistics to zero, no alarm; the next update is sample ``next_sample``
        (the index :attr:`change_sample` counts in)."""
        n = self.n_channels
        self._s = np.zeros(3 * n)
        self._previous = self._s
        self._chart_alarm = np.zeros(3 * n, dtype=bool)
        self._raised = np.zeros(3 * n, dtype=bool)
        self._alarm = np.zeros(n, dtype=bool)
        self._count = int(next_sample)
        self._any = False

    def start_in_alarm(self, next_sample: int = 0) -> None:
        """Every statistic at its threshold and every channel in alarm: a test of
        whether a known fault is still present, which clears once the data say no."""
        self.reset(next_sample)
        self._s = self._cap.copy()
        self._chart_alarm[:] = True
        self._alarm[:] = True
        self._any = True

    def update(self, z: _FloatArray) -> bool:
        """Process one standardised sample ``z`` (shape (n,)); True if any channel is in
        alarm afterwards."""
        self._previous = self._s
        n = self.n_channels
        buf = self._buf  # [z; z²; 1] without allocating it
        buf[:n] = z
        np.multiply(z, z, out=buf[n:2 * n])
        s = self._map @ buf
        s += self._s
        np.maximum(s, 0.0, out=s)
        np.minimum(s, self._cap, out=s)
        self._s = s
        self._count += 1
        raised = s >= self._cap
        if not (self._any or raised.any()):
            return False
        chart = (self._chart_alarm & (s >= self._release_level)) | raised
        self._chart_alarm = chart
        alarm = chart[:n] | chart[n:2 * n] | chart[2 * n:]
        self._raised = raised & ~(self._previous >= self._cap)
        self._alarm = alarm
        self._any = bool(alarm.any())
        return self._any

    def increments(self, z: _FloatArray) -> _FloatArray:
        """The increments (drift included) the charts would add for sample ``z``."""
        return self._map @ np.concatenate((z, z * z, _ONE))

    @property
    def previous_statistics(self) -> _FloatArray:
        """Statistics before the last update, [S⁺; S⁻; V] (do not modify)."""
        return self._previous

    @property
    def newly_raised(self) -> NDArray[np.bool_]:
        """Charts that reached their threshold at the last update, [S⁺; S⁻; V]."""
        return self._raised

    @property
    def alarms(self) -> NDArray[np.bool_]:
        """Per-channel alarm after the last update (a new array after every change;
        do not modify it)."""
        return self._alarm

    @property
    def any_alarm(self) -> bool:
        """Some channel is in alarm."""
        return self._any

    @property
    def next_sample(self) -> int:
        """Index of the next sample."""
        return self._count

    def statistic(self) -> _FloatArray:
        """Per channel: the largest of its statistics in units of its threshold (0–1)."""
        return (self._s / self._cap).reshape(3, self.n_channels).max(axis=0)

    def mean_statistics(self) -> tuple[_FloatArray, _FloatArray]:
        """(S⁺, S⁻) per channel, σ."""
        n = self.n_channels
        return self._s[:n].copy(), self._s[n:2 * n].copy()

    def variance_statistic(self) -> _FloatArray:
        """V per channel, log-likelihood units."""
        return self._s[2 * self.n_channels:].copy()

    def get_state(self) -> dict[str, Any]:
        """Copy of every statistic, alarm flag and counter."""
        return {
            "s": self._s.copy(), "previous": self._previous.copy(),
            "chart_alarm": self._chart_alarm.astype(float),
            "raised": self._raised.astype(float), "count": int(self._count),
        }

    def set_state(self, state: dict[str, Any]) -> None:
        """Restore :meth:`get_state` output of a bank of the same size (checked first)."""
        n = self.n_channels
        s = check_finite_array("state['s']", state["s"], shape=(3 * n,))
        prev = check_finite_array("state['previous']", state["previous"], shape=(3 * n,))
        chart = check_finite_array("state['chart_alarm']", state["chart_alarm"],
                                   shape=(3 * n,)) != 0.0
        raised = check_finite_array("state['raised']", state["raised"],
                                    shape=(3 * n,)) != 0.0
        top = self._cap * (1.0 + 1e-12)
        if np.any(s < 0.0) or np.any(s > top) or np.any(prev < 0.0) or np.any(prev > top):
            raise ValueError("state['s'] holds statistics outside [0, threshold]")
        count = check_int("state['count']", int(state["count"]))
        self._s, self._previous = s.copy(), prev.copy()
        self._chart_alarm, self._raised, self._count = chart, raised, count
        self._alarm = chart[:n] | chart[n:2 * n] | chart[2 * n:]
        self._any = bool(self._alarm.any())
