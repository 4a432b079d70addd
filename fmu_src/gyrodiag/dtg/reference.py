"""Frozen nominal reference of the DTG channel: guarded learning and residual tests.

The paper's decision compares the estimates of a forgetting estimator with their nominal
mean θ0. A forgetting estimator absorbs a persistent fault into θ, so that decision
forgets a fault while it is still there. This module keeps the nominal model fixed
instead and tests the *data* against it:

* **Reference residuals.** With the reference θ0 the regression of docs/methods.md §2 gives, per
  axis, e(k) = y(k) − φ(k)ᵀθ0 (V). On fault-free data e is the small unexplained part
  (≈ 2e−5 V on the paper plant); a corrupted signal changes its level (steps, drifts),
  its variance (noise, loss) or both, for as long as the fault lasts.
* **Channels.** Six signals are summarised: the raw inputs Utx, Uty, Ux, Uy and the two
  residuals ex, ey (:data:`CHANNELS`). They are summarised per *block* of samples
  (``block_samples``, 25 ms at 1 kHz) as the block mean and the variance about the
  block's own straight line, and per *window* of blocks as the window mean and the
  variance about the window's straight line (:func:`window_moments`). Detrending keeps a
  drift from looking like noise.
* **Reference learning** (:class:`ReferenceLearner`): over the learning window θ0 is the
  least-squares fit of both axes, the nominal channel statistics are measured from the
  same data, and the window is checked segment by segment: each segment is tested
  against the reference fitted on the segments before it (residual level, residual
  variance, and the spread of the segment's own θ against what noise explains). A failed
  segment ends the usable data: the reference is fitted on the segments before it and
  its status says so. A nominal prior (θ0 and the channel statistics of fault-free
  training runs, :class:`NominalPrior`) is checked last; a mismatch replaces the learned
  reference by the prior.
* **Residual tests** (:class:`ResidualMonitor`): per block, over the last
  ``window_blocks``, the level z = |mean(e) − μ|/(σ_block/√K) and the variance ratio
  var(e)/var₀ of both residuals, and the variance ratio over ``long_window_blocks``.
  A CUSUM of the residuals' *low-frequency power* runs beside them: per block
  q = ((m − μ)/σ_block)², the squared block mean in nominal block spreads, enters
  S ← min(h, max(0, S + min(q, q_cap) − κ)), the log-likelihood-ratio CUSUM of a
  variance change by :data:`POWER_RATIO` (κ = ln ρ/(1 − 1/ρ)). The residual's nominal
  power sits at 40–60 Hz (the regression differences the pick-offs) while a noise on a
  torquer read-out enters through the 50 Hz prefilter and θ5: below 20 Hz a 0.3 V torquer
  noise raises the residual power ×12–45, over all frequencies ×2.2 (docs/notes.md, DTG),
  so a block mean (25 ms: a low-pass to ~18 Hz) is its best witness.
  An alarm is raised when any test exceeds its threshold (the CUSUM: reaches h), held
  while any exceeds its hold threshold (level ×2/3, variance ratios ^(2/3), CUSUM h/2)
  and cleared ``clear_blocks`` after the last block that did: an intermittent fault's
  alarm clears at most ``long window + clear time`` after it goes away (the CUSUM,
  capped at h, falls below h/2 in (h/2)/(κ − 1) blocks); a persistent fault keeps it.

σ_block (the spread of block means) over-estimates the spread of a window mean of the
residuals (their block means are negatively correlated), so the level test is
conservative by a factor ~2.5 on the paper plant; faults in the residual level are
large against it (a 0.1 V pick-off step ≈ 250 σ, a 0.1 V/s torquer drift ≈ 40 σ after
1 s).
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Callable
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ..common._validation import check_finite_array, check_int, check_positive
from .case_rate import CASE_RATE_SCHEMES, dtg_case_rate_regression
from .growth import LevelGrowth
from .model import N_THETA

__all__ = [
    "ALLOWANCE_SIGMA",
    "CHANNELS",
    "N_CHANNELS",
    "N_TESTS",
    "REFERENCE_STATUS",
    "ClassificationStatistics",
    "NominalPrior",
    "NominalReference",
    "ReferenceLearner",
    "RegressionModel",
    "ResidualMonitor",
    "ResidualThresholds",
    "block_moments",
    "regression_residuals",
    "window_moments",
]

#: Summarised channels: the four raw signals and the residuals of the x and y axis.
CHANNELS = ("Utx", "Uty", "Ux", "Uy", "ex", "ey")
N_CHANNELS = len(CHANNELS)
#: Residual channels (indices into :data:`CHANNELS`).
RESIDUALS = (4, 5)
#: Residual test statistics (:attr:`ResidualMonitor.statistics`): level z, short and long
#: variance ratio, power CUSUM / threshold, each for ex and ey.
N_TESTS = 8
#: Reference status codes: learning, valid, change inside the learning window (reference
#: from the segments before it), rejected against the prior (prior in use).
REFERENCE_STATUS = {"learning": 0, "valid": 1, "change_in_window": 2, "prior_mismatch": 3}
#: Segments of the learning window checked one after the other (at most), and their
#: shortest length, s.
N_SEGMENTS = 8
MIN_SEGMENT_S = 0.25
#: Low-frequency power CUSUM: the variance ratio it is tuned to detect, and the cap of one
#: block's squared mean (in nominal block spreads²), so that one odd block cannot alarm.
POWER_RATIO = 3.0
POWER_KAPPA = math.log(POWER_RATIO) / (1.0 - 1.0 / POWER_RATIO)
POWER_Q_CAP = 10.0
POWER_THRESHOLD = 80.0
#: θ-error allowance of the variance-type tests, in standard deviations of the
#: reference's covariance (:class:`ResidualThresholds`): 3 alarms, in the limit where
#: the allowance dominates, at a 4.2σ error (2 s ratio 2) or 6σ (0.5 s ratio 4).
ALLOWANCE_SIGMA = 3.0
#: Variance floor relative to the channel's scale, so that a silent channel stays finite.
_VAR_FLOOR = 1e-30


# --------------------------------------------------------------------------- helpers
@dataclass(frozen=True)
class RegressionModel:
    """The regression the reference is built on: the paper's, or one with the case rate.

    Attributes
    ----------
    case_rate_scheme : {"central", "paper"} or None
        None: the paper's regression of docs/methods.md §2 on (Utx, Uty, Ux, Uy), one θ0 (5,) for
        both axes (pooled). Otherwise the case-rate regression of
        :mod:`gyrodiag.dtg.case_rate` on (Utx, Uty, Ux, Uy, ωx, ωy) in that scheme, with
        a θ0 per axis (10,: x then y): the two lines see the case rate differently
        (docs/dtg_case_rate.md §5).
    sample_period_s : float
        T, s (case rate only).
    pickoff_scale : float
        Nominal pick-off scale KT, rad/V (case rate only).
    """

    case_rate_scheme: str | None = None
    sample_period_s: float = 1e-3
    pickoff_scale: float = 1e-3

    def __post_init__(self) -> None:
        if self.case_rate_scheme is not None:
            if self.case_rate_scheme not in CASE_RATE_SCHEMES:
                raise ValueError(f"case_rate_scheme must be None or one of "
                                 f"{CASE_RATE_SCHEMES}, got {self.case_rate_scheme!r}")
            check_positive("sample_period_s", self.sample_period_s)
            check_positive("pickoff_scale", self.pickoff_scale)

    @property
    def case_rate(self) -> bool:
        """The case rate is in the regression."""
        return self.case_rate_scheme is not None

    @property
    def width(self) -> int:
        """Filtered signals per sample: 4 (V), or 6 with ωx, ωy (rad/s)."""
        return 6 if self.case_rate else 4

    @property
    def n_par(self) -> int:
        """Reference parameters: 5 pooled, or 10 (θ0 per axis)."""
        return 2 * N_THETA if self.case_rate else N_THETA

    def rows(self, filtered: NDArray[np.float64]
             ) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64],
                        NDArray[np.float64]]:
        """(φx (n, 5), yx (n,), φy (n, 5), yy (n,)) of a run of ``width``-wide filtered
        samples, the first two rows being the samples before the first row wanted."""
        f = filtered
        if self.case_rate:
            return dtg_case_rate_regression(
                *f.T, self.sample_period_s, self.pickoff_scale,
                scheme=self.case_rate_scheme)  # type: ignore[arg-type]
        phx = np.column_stack([f[1:-1, 0], -f[:-2, 0], -f[2:, 1], f[1:-1, 1], f[2:, 2]])
        phy = np.column_stack([f[1:-1, 1], -f[:-2, 1], f[2:, 0], -f[1:-1, 0], f[2:, 3]])
        return phx, f[2:, 0], phy, f[2:, 1]


#: The paper's regression (the default of every class here).
PAPER_MODEL = RegressionModel()


def regression_residuals(filtered: NDArray[np.float64], theta: NDArray[np.float64],
                         model: RegressionModel = PAPER_MODEL) -> NDArray[np.float64]:
    """Reference residuals of both axes for a run of filtered samples.

    Parameters
    ----------
    filtered : ndarray, shape (n + 2, model.width)
        Filtered (Utx, Uty, Ux, Uy) in V (and ωx, ωy in rad/s with the case rate); the
        first two rows are the samples before the first one whose residual is wanted.
    theta : ndarray, shape (model.n_par,)
        Reference θ (5,), or with the case rate θ of the x then the y axis (10,).
    model : RegressionModel
        The regression (default: the paper's, docs/methods.md §2).

    Returns
    -------
    ndarray, shape (n, 2)
        e = y − φᵀθ of the x and y regressions (V).
    """
    if model.case_rate:
        th = np.asarray(theta, dtype=float).reshape(2, N_THETA)
        phx, yx, phy, yy = model.rows(filtered)
        return np.column_stack([yx - phx @ th[0], yy - phy @ th[1]])
    t1, t2, t3, t4, t5 = (float(v) for v in theta)
    f = filtered
    tx, ty = f[2:, 0], f[2:, 1]
    tx1, ty1 = f[1:-1, 0], f[1:-1, 1]
    tx2, ty2 = f[:-2, 0], f[:-2, 1]
    ex = tx - (t1 * tx1 - t2 * tx2 - t3 * ty + t4 * ty1 + t5 * f[2:, 2])
    ey = ty - (t1 * ty1 - t2 * ty2 + t3 * tx - t4 * tx1 + t5 * f[2:, 3])
    return np.column_stack([ex, ey])


def block_moments(x: NDArray[np.float64], valid: NDArray[np.bool_] | None = None
                  ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Mean and variance about the straight-line fit of one block.

    Parameters
    ----------
    x : ndarray, shape (n, c)
        n ≥ 1 samples of c channels.
    valid : ndarray of bool, shape (n,), optional
        Samples to use (at least one); default all.

    Returns
    -------
    mean, var : ndarray, shape (c,)
        Block mean and mean squared deviation from the block's least-squares line (the
        plain variance when fewer than 3 samples are used).
    """
    k = np.arange(x.shape[0], dtype=float)
    if valid is not None and not valid.all():
        x, k = x[valid], k[valid]
    n = x.shape[0]
    mean = x.mean(axis=0)
    dev = x - mean
    var = np.mean(dev * dev, axis=0)
    if n >= 3:
        k = k - k.mean()
        kk = float(k @ k)
        slope = (k @ dev) / kk
        var = var - slope * slope * kk / n
    return mean, np.maximum(var, 0.0)


def window_moments(means: NDArray[np.float64], variances: NDArray[np.float64]
                   ) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """Window mean, detrended variance and slope from per-block moments.

    Parameters
    ----------
    means, variances : ndarray, shape (K, c)
        Block means and block (detrended) variances of K consecutive blocks.

    Returns
    -------
    mean : ndarray, shape (c,)
        Window mean.
    var : ndarray, shape (c,)
        Mean within-block variance plus the variance of the block means about their
        least-squares line.
    slope : ndarray, shape (c,)
        Slope of that line, per block.
    """
    k = means.shape[0]
    mean = means.mean(axis=0)
    dev = means - mean
    if k >= 3:
        x = np.arange(k) - 0.5 * (k - 1)
        xx = float(x @ x)
        slope = (x @ dev) / xx
        between = np.mean(dev * dev, axis=0) - slope * slope * xx / k
    else:
        slope = np.zeros(means.shape[1])
        between = np.mean(dev * dev, axis=0)
    return mean, variances.mean(axis=0) + np.maximum(between, 0.0), slope


def _window_reference_variance(means: NDArray[np.float64], variances: NDArray[np.float64],
                               k: int) -> NDArray[np.float64]:
    """Mean of :func:`window_moments` variances over windows of k blocks (non-overlapping
    when there are several; one window of all blocks when there are fewer than k)."""
    n = means.shape[0]
    if n <= k:
        return window_moments(means, variances)[1]
    starts = range(n - k, -1, -k)  # aligned with the end: the newest data count
    return np.mean([window_moments(means[s:s + k], variances[s:s + k])[1] for s in starts],
                   axis=0)


def _usable(valid: NDArray[np.bool_]) -> NDArray[np.bool_]:
    """Copy of a block's usable-row mask."""
    return np.asarray(valid, dtype=bool).copy()


def _residual_moments(e: NDArray[np.float64], valid: NDArray[np.bool_]
                      ) -> tuple[NDArray[np.float64], NDArray[np.float64]] | None:
    """Block moments of the usable residual rows; None when fewer than 3 are usable
    (the caller repeats the previous block's)."""
    if valid.all():
        return block_moments(e)
    if np.count_nonzero(valid) < min(3, valid.size):
        return None
    return block_moments(e, valid)


def _fill_gaps(moments: list[tuple[NDArray[np.float64], NDArray[np.float64]] | None]
               ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Stack per-block moments, a missing block repeating its predecessor (the first
    usable block for leading gaps)."""
    usable = [m for m in moments if m is not None]
    if not usable:
        raise ValueError("no block of the learning window has usable regression rows "
                         "(non-finite inputs throughout?)")
    last = usable[0]
    means, variances = [], []
    for m in moments:
        last = m if m is not None else last
        means.append(last[0])
        variances.append(last[1])
    return np.array(means), np.array(variances)


def _ls(A: NDArray[np.float64], b: NDArray[np.float64]) -> NDArray[np.float64] | None:
    try:
        sol = np.linalg.solve(A, b)
    except np.linalg.LinAlgError:
        return None
    return sol if np.all(np.isfinite(sol)) else None


def _refinement_start(M: NDArray[np.float64], theta: NDArray[np.float64]
                      ) -> dict[str, NDArray[np.float64]]:
    """A = ΦᵀΦ and the error variance λmax(A⁻¹B) of both axes (:class:`NominalReference`)
    from the per-block normal matrices of the case-rate regression (nblk, 11, 11):
    block-diagonal in the axes, z = [φx, φy, y] (see :meth:`ReferenceLearner.finish`);
    θ (10,) the reference."""
    n = N_THETA
    info, err = [], []
    for a in range(2):
        sl = slice(a * n, (a + 1) * n)
        A_b = M[:, sl, sl]
        s_b = M[:, sl, 2 * n] - np.einsum("bij,j->bi", A_b, theta[sl])
        A = A_b.sum(axis=0)
        info.append(A)
        try:
            ev = np.linalg.eigvals(np.linalg.solve(A, s_b.T @ s_b)).real
        except np.linalg.LinAlgError:
            raise ValueError("the regression over the learning window is singular: the "
                             "signals do not excite all θ (no torquer dither?)") from None
        err.append(max(float(ev.max()), _VAR_FLOOR))
    return {"information": np.stack(info), "error_variance": np.array(err)}


def _block_regressor_moments(phi: NDArray[np.float64], nblk: int, nb: int
                             ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Per block the mean (nblk, 5) and the scatter about the block's straight line
    (nblk, 5, 5) of regressor rows (nblk·nb, 5), as :func:`block_moments` detrends."""
    x = phi.reshape(nblk, nb, phi.shape[1])
    mean = x.mean(axis=1)
    dev = x - mean[:, None, :]
    if nb >= 3:
        k = np.arange(nb) - 0.5 * (nb - 1)
        slope = np.einsum("k,bki->bi", k, dev) / float(k @ k)
        dev = dev - k[None, :, None] * slope[:, None, :]
    return mean, np.einsum("bki,bkj->bij", dev, dev) / nb


def _block_allowances(phi_blocks: list[tuple[NDArray[np.float64], NDArray[np.float64]]],
                      blocks: slice, information: NDArray[np.float64],
                      error_variance: NDArray[np.float64]) -> NDArray[np.float64]:
    """θ-uncertainty allowances (k, 4) of the blocks in ``blocks``: φ̄ᵀPφ̄ of x, y and
    tr(S·P) of x, y with P = v·A⁻¹ per axis (:meth:`ResidualMonitor._allowance`)."""
    out = []
    for a, (mean, scatter) in enumerate(phi_blocks):
        P = error_variance[a] * np.linalg.inv(information[a])
        out.append((np.einsum("bi,ij,bj->b", mean[blocks], P, mean[blocks]),
                    np.einsum("bij,ij->b", scatter[blocks], P)))
    return np.maximum(np.column_stack([out[0][0], out[1][0], out[0][1], out[1][1]]), 0.0)


# --------------------------------------------------------------------------- reference
#: A levels-only prior's θ0 tolerance, relative: the rotor the prior was learned on.
SAME_ROTOR_THETA = 0.3


@dataclass(frozen=True)
class NominalPrior:
    """Nominal reference expected from fault-free training runs (signature file).

    Attributes
    ----------
    theta0, theta0_std : ndarray, shape (5,)
        Mean and spread of the learned reference θ over the training runs.
    mean, block_std, var_short, var_long : ndarray, shape (6,)
        Median channel statistics of those runs (V, V, V², V²; :class:`NominalReference`).
    levels_only : bool
        False (a library learned on the user's bench): any mismatch replaces the learned
        reference. True (the shipped library, learned on another bench): only a
        reference with the prior's θ0 and variances but other levels is replaced (an
        offset fault before learning); one with another θ0 or noise is another gyro or
        bench, and stands.
    """

    theta0: NDArray[np.float64]
    theta0_std: NDArray[np.float64]
    mean: NDArray[np.float64]
    block_std: NDArray[np.float64]
    var_short: NDArray[np.float64]
    var_long: NDArray[np.float64]
    levels_only: bool = False

    @classmethod
    def from_dict(cls, d: dict[str, Any], where: str = "nominal") -> NominalPrior:
        """Read and check ``{theta0, theta0_std, mean, block_std, var_short, var_long}``."""
        if not isinstance(d, dict):
            raise ValueError(f"{where} must be an object, got {type(d).__name__}")
        shapes = {"theta0": N_THETA, "theta0_std": N_THETA, "mean": N_CHANNELS,
                  "block_std": N_CHANNELS, "var_short": N_CHANNELS, "var_long": N_CHANNELS}
        vals = {}
        for key, n in shapes.items():
            if key not in d:
                raise ValueError(f"{where}.{key} is missing")
            vals[key] = check_finite_array(f"{where}.{key}", d[key], shape=(n,))
        if np.any(vals["theta0"] == 0.0):
            raise ValueError(f"{where}.theta0 must have no zero entry")
        levels_only = d.get("levels_only", False)
        if not isinstance(levels_only, bool):
            raise ValueError(f"{where}.levels_only must be true or false, got {levels_only!r}")
        for key in ("theta0_std", "block_std", "var_short", "var_long"):
            if np.any(vals[key] < 0) or (key != "theta0_std" and np.any(vals[key] == 0)):
                raise ValueError(f"{where}.{key} must be positive, got {list(vals[key])}")
        return cls(**vals, levels_only=levels_only)

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready content."""
        out: dict[str, Any] = {k: [float(v) for v in getattr(self, k)] for k in
                               ("theta0", "theta0_std", "mean", "block_std", "var_short",
                                "var_long")}
        if self.levels_only:
            out["levels_only"] = True
        return out


@dataclass
class NominalReference:
    """The frozen nominal model and channel statistics the residual tests compare with.

    Attributes
    ----------
    theta0 : ndarray, shape (5,) or (10,)
        Reference θ of the residuals (least squares over the accepted learning data, or
        the given / prior θ0); (10,), x then y axis, with the case rate
        (:class:`RegressionModel`).
    theta0_eta : ndarray, shape (5,) or (10,)
        Nominal θ of the ratio test η = |θ|/|θ0| (mean fast-estimator θ over the accepted
        data, the paper's rule); per axis like ``theta0``.
    mean : ndarray, shape (6,)
        Channel means, V.
    block_std : ndarray, shape (6,)
        Standard deviation of block means, V.
    var_short, var_long : ndarray, shape (6,)
        Mean detrended variance over a short / long window, V².
    status : int
        :data:`REFERENCE_STATUS` code.
    segments_used : int
        Learning segments the reference was fitted on.
    change_segment : int
        First rejected segment (0-based), −1 if none.
    information : ndarray, shape (2, 5, 5), or None
        Case rate only: A = ΦᵀΦ of each axis' regression over the accepted learning rows
        (V², unnormalised). It says how well the learning data pinned each direction of
        θ0; the residual monitor refines θ0 from it (:class:`ResidualMonitor`). None
        for the paper's regression (and for a reference restored from an older state).
    error_variance : ndarray, shape (2,), or None
        Case rate only: per axis the scale v (V²) of the covariance v·A⁻¹ of θ0. Least
        squares with a white residual would give v = σ² (the residual variance); the
        prefiltered residual is coloured and correlated with the regressors, so v is the
        largest eigenvalue of A⁻¹B, B = Σ_b s_b s_bᵀ over the learning blocks' scores
        s_b = Φ_bᵀe_b: v·A⁻¹ then covers the batch-means sandwich covariance A⁻¹BA⁻¹ in
        every direction (measured v/σ² 5.6-8.7, docs/dtg_case_rate.md §8).
    """

    theta0: NDArray[np.float64]
    theta0_eta: NDArray[np.float64]
    mean: NDArray[np.float64]
    block_std: NDArray[np.float64]
    var_short: NDArray[np.float64]
    var_long: NDArray[np.float64]
    status: int = REFERENCE_STATUS["valid"]
    segments_used: int = 0
    change_segment: int = -1
    information: NDArray[np.float64] | None = None
    error_variance: NDArray[np.float64] | None = None

    @property
    def valid(self) -> bool:
        """The learned reference passed every check."""
        return self.status == REFERENCE_STATUS["valid"]

    def variance_at(self, blocks: int, short_blocks: int, long_blocks: int
                    ) -> NDArray[np.float64]:
        """Reference variance of a window of ``blocks`` blocks, interpolated in log
        window length between the short and the long window."""
        if blocks <= short_blocks or long_blocks <= short_blocks:
            return self.var_short
        if blocks >= long_blocks:
            return self.var_long
        f = math.log(blocks / short_blocks) / math.log(long_blocks / short_blocks)
        return self.var_short * (self.var_long / self.var_short) ** f

    def get_state(self) -> dict[str, Any]:
        """Plain copy."""
        return {"theta0": self.theta0.copy(), "theta0_eta": self.theta0_eta.copy(),
                "mean": self.mean.copy(), "block_std": self.block_std.copy(),
                "var_short": self.var_short.copy(), "var_long": self.var_long.copy(),
                "status": self.status, "segments_used": self.segments_used,
                "change_segment": self.change_segment,
                "information": None if self.information is None else self.information.copy(),
                "error_variance": (None if self.error_variance is None
                                   else self.error_variance.copy())}

    @classmethod
    def from_state(cls, s: dict[str, Any]) -> NominalReference:
        """Inverse of :meth:`get_state`."""
        n_par = np.asarray(s["theta0"]).size
        if n_par not in (N_THETA, 2 * N_THETA):
            raise ValueError(f"state['theta0'] must have {N_THETA} or {2 * N_THETA} entries, "
                             f"got {n_par}")
        arr = {k: check_finite_array(f"state[{k!r}]", s[k], shape=(n,)).copy()
               for k, n in (("theta0", n_par), ("theta0_eta", n_par),
                            ("mean", N_CHANNELS), ("block_std", N_CHANNELS),
                            ("var_short", N_CHANNELS), ("var_long", N_CHANNELS))}
        extra = {}
        for key, shape in (("information", (2, N_THETA, N_THETA)), ("error_variance", (2,))):
            val = s.get(key)
            extra[key] = (None if val is None else check_finite_array(
                f"state[{key!r}]", val, shape=shape).copy())
        if (extra["information"] is None) != (extra["error_variance"] is None):
            raise ValueError("state['information'] and state['error_variance'] come together")
        return cls(**arr, status=int(s["status"]), segments_used=int(s["segments_used"]),
                   change_segment=int(s["change_segment"]), **extra)


@dataclass(frozen=True)
class ResidualThresholds:
    """Raise thresholds of the residual tests (hold thresholds are derived).

    Attributes
    ----------
    level : float
        z of a residual window mean in units of σ_block/√K (hold: 2/3 of it).
    variance : float
        Short-window variance ratio of a residual (hold: ratio^(2/3)).
    long_variance : float
        Long-window variance ratio (hold: ratio^(2/3)).
    theta_spread : float
        Learning guard: a segment's θ against the reference of the segments before it,
        (Δθᵀ·C⁻¹·Δθ)/5 with C the least-squares covariance from the residual variance.
    power : float
        Threshold h of the low-frequency power CUSUM (hold: h/2); 0 switches it off.
    allowance_sigma : float
        Case rate only: the reference's error the variance-type tests (variance ratios,
        power CUSUM, the learning guard's ratio) allow for, in standard deviations of
        its covariance P: they add ``allowance_sigma² ·`` (the block's θ-uncertainty
        variance) to their nominal variance. The error is one draw per run, and a
        manoeuvre edge that excites a direction where it is c standard deviations off
        raises those ratios towards c², so 1 (the first, tighter allowance) lets them
        alarm at c ≈ 1.4 (2 s ratio 2): 16 % of runs per excited direction. The level
        test allows up to ``level`` standard deviations already (its allowance enters
        as a standard deviation).
    """

    level: float = 6.0
    variance: float = 4.0
    long_variance: float = 2.0
    theta_spread: float = 30.0
    power: float = POWER_THRESHOLD
    allowance_sigma: float = ALLOWANCE_SIGMA

    def validate(self) -> None:
        """Raise ValueError naming the first bad threshold."""
        check_positive("level_threshold", self.level)
        for name, v in (("var_threshold", self.variance),
                        ("long_var_threshold", self.long_variance)):
            if not (math.isfinite(v) and v > 1.0):
                raise ValueError(f"{name} must be a finite ratio > 1, got {v!r}")
        check_positive("theta_spread_threshold", self.theta_spread)
        if not (math.isfinite(self.power) and self.power >= 0.0):
            raise ValueError(f"power_threshold must be a finite number >= 0 (0: off), got "
                             f"{self.power!r}")
        if not (math.isfinite(self.allowance_sigma) and self.allowance_sigma >= 0.0):
            raise ValueError(f"allowance_sigma must be a finite number >= 0, got "
                             f"{self.allowance_sigma!r}")

    @property
    def allowance_scale(self) -> float:
        """Factor of the θ-uncertainty allowance in the variance-type tests."""
        return self.allowance_sigma ** 2

    @property
    def hold(self) -> tuple[float, float, float]:
        """(level, variance, long variance) thresholds that keep a raised alarm."""
        return (self.level * 2.0 / 3.0, self.variance ** (2.0 / 3.0),
                self.long_variance ** (2.0 / 3.0))


class ReferenceLearner:
    """Collects the learning window and builds the checked :class:`NominalReference`.

    Parameters
    ----------
    block_samples : int
        Samples per block.
    short_blocks, long_blocks : int
        Window lengths of the residual tests, blocks.
    thresholds : ResidualThresholds
        Thresholds of the segment checks (the residual tests' own, plus θ spread).
    block_s : float
        Block duration, s.
    model : RegressionModel, optional
        The regression (default: the paper's; with the case rate θ0 is fitted per axis).

    Notes
    -----
    Between :meth:`start` and :meth:`finish` it keeps the filtered samples of the
    learning window (``model.width`` floats per sample) and per block the raw-signal moments and the
    mean fast-estimator θ: the reference θ0 is not known before the end, so the
    residuals are computed then.
    """

    def __init__(self, block_samples: int, short_blocks: int, long_blocks: int,
                 thresholds: ResidualThresholds, block_s: float,
                 model: RegressionModel = PAPER_MODEL) -> None:
        self.block_samples = check_int("block_samples", block_samples, minimum=1)
        self.block_s = check_positive("block_s", block_s)
        self.short_blocks = check_int("short_blocks", short_blocks, minimum=1)
        self.long_blocks = check_int("long_blocks", long_blocks, minimum=1)
        self.thresholds = thresholds
        self.model = model
        self.reset()

    def reset(self) -> None:
        """Empty: nothing collected."""
        self._filtered: list[NDArray[np.float64]] = []   # blocks (nb, 4), in order
        self._history = np.zeros((2, self.model.width))   # the 2 samples before the window
        self._raw_mean: list[NDArray[np.float64]] = []
        self._raw_var: list[NDArray[np.float64]] = []
        self._theta: list[NDArray[np.float64]] = []       # per block mean θ, (2, 5)
        self._valid: list[NDArray[np.bool_]] = []         # regression rows to use, (nb,)

    @property
    def n_blocks(self) -> int:
        """Blocks collected."""
        return len(self._filtered)

    def set_history(self, history: NDArray[np.float64]) -> None:
        """The two filtered samples before the first block (rows k−2, k−1)."""
        self._history = np.array(history, dtype=float).reshape(2, self.model.width)

    def push_block(self, raw: NDArray[np.float64], filtered: NDArray[np.float64],
                   theta: NDArray[np.float64], valid: NDArray[np.bool_]) -> None:
        """Add one block: raw (nb, 4) and filtered samples (nb, model.width),
        fast-estimator θ (nb, 10),
        and which samples' regression rows are sound (False next to a skipped sample)."""
        m, v = block_moments(raw)
        self._raw_mean.append(m)
        self._raw_var.append(v)
        self._filtered.append(np.array(filtered, dtype=float))
        self._theta.append(theta.mean(axis=0).reshape(2, N_THETA))
        self._valid.append(_usable(valid))

    # -- the end of learning ---------------------------------------------------------
    def finish(self, theta0: NDArray[np.float64] | None = None,
               prior: NominalPrior | None = None) -> NominalReference:
        """Check the collected window and return the reference.

        Parameters
        ----------
        theta0 : ndarray, shape (model.n_par,), optional
            A given reference θ0 (used as is; the window still supplies the statistics
            and is still checked).
        prior : NominalPrior, optional
            Expected nominal reference; a learned reference outside it is replaced by it.

        Raises
        ------
        ValueError
            If no block was collected or the regression is singular (no excitation).
        """
        nblk = self.n_blocks
        if nblk == 0:
            raise ValueError("the learning window holds no complete block of samples: make "
                             "learn_end_s - learn_start_s longer than a block")
        nb = self.block_samples
        model = self.model
        npar = model.n_par
        filt = np.vstack([self._history, *self._filtered])
        M, phi_blocks = self._normal_equations(filt, nblk)
        valid_blocks = self._valid
        raw_mean = np.array(self._raw_mean)
        raw_var = np.array(self._raw_var)
        theta_blk = np.array(self._theta)                      # (nblk, 2, 5)
        segs = self._segments(nblk)

        def fit(blocks: slice) -> tuple[NDArray[np.float64] | None, NDArray[np.float64]]:
            Ms = M[blocks].sum(axis=0)
            return _ls(Ms[:npar, :npar], Ms[:npar, npar]), Ms

        def channel_blocks(theta: NDArray[np.float64], blocks: slice
                           ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
            b0, b1, _ = blocks.indices(nblk)
            e = regression_residuals(filt[b0 * nb:b1 * nb + 2], theta, model)
            e = e.reshape(b1 - b0, nb, 2)
            em, ev = _fill_gaps([_residual_moments(blk, ok) for blk, ok in
                                 zip(e, valid_blocks[b0:b1], strict=True)])
            return (np.column_stack([raw_mean[blocks], em]),
                    np.column_stack([raw_var[blocks], ev]))

        change = self._change_segment(segs, M, phi_blocks, fit, channel_blocks)
        used = slice(0, segs[change - 1].stop) if change > 0 else slice(0, nblk)
        th_ls, _ = fit(used)
        if th_ls is None:
            raise ValueError("the regression over the learning window is singular: the "
                             "signals do not excite all θ (no torquer dither?)")
        ref_theta = th_ls if theta0 is None else np.asarray(theta0, dtype=float)
        if ref_theta.shape != (npar,):
            raise ValueError(f"theta0 must have shape ({npar},) for this regression, got "
                             f"{ref_theta.shape}")
        means, variances = channel_blocks(ref_theta, used)
        if theta0 is not None:
            theta_eta = np.asarray(theta0, dtype=float)
        elif model.case_rate:
            theta_eta = theta_blk[used].mean(axis=0).reshape(npar)
        else:
            theta_eta = theta_blk[used].mean(axis=(0, 1))
        ref = NominalReference(
            theta0=ref_theta.copy(), theta0_eta=theta_eta.copy(),
            mean=means.mean(axis=0),
            block_std=np.maximum(means.std(axis=0), np.sqrt(_VAR_FLOOR)),
            var_short=np.maximum(
                _window_reference_variance(means, variances, self.short_blocks), _VAR_FLOOR),
            var_long=np.maximum(
                _window_reference_variance(means, variances, self.long_blocks), _VAR_FLOOR),
            status=REFERENCE_STATUS["valid" if change < 0 else "change_in_window"],
            segments_used=len(segs) if change < 0 else change,
            change_segment=change,
            **(_refinement_start(M[used], ref_theta) if model.case_rate else {}),
        )
        return self._checked(ref, prior)

    def _normal_equations(self, filt: NDArray[np.float64], nblk: int
                          ) -> tuple[NDArray[np.float64], list[Any] | None]:
        """Per-block normal equations of the window, (nblk, n_par + 1, n_par + 1), and with
        the case rate the per-block regressor moments (for the guard's allowance)."""
        nb = self.block_samples
        model = self.model
        npar = model.n_par
        # normal equations per block: z = [phi, y], both axes pooled (paper) or one
        # block-diagonal system of the two axes' own θ (case rate: θ0 per axis)
        phx, yx, phy, yy = model.rows(filt)
        # case rate: per-block regressor moments, for the guard's allowance of the
        # uncertainty of the segments-before fit (as the residual monitor's)
        phi_blocks = ([_block_regressor_moments(ph, nblk, nb) for ph in (phx, phy)]
                      if model.case_rate else None)
        if model.case_rate:
            zero = np.zeros_like(phx)
            phx, phy = np.hstack([phx, zero]), np.hstack([zero, phy])
        use = np.concatenate(self._valid).astype(float)[:, None]
        zx = (np.column_stack([phx, yx]) * use).reshape(nblk, nb, npar + 1)
        zy = (np.column_stack([phy, yy]) * use).reshape(nblk, nb, npar + 1)
        M = np.einsum("bki,bkj->bij", zx, zx) + np.einsum("bki,bkj->bij", zy, zy)
        return M, phi_blocks

    def _change_segment(
            self, segs: list[slice], M: NDArray[np.float64], phi_blocks: list[Any] | None,
            fit: Callable[[slice], tuple[NDArray[np.float64] | None, NDArray[np.float64]]],
            channel_blocks: Callable[[NDArray[np.float64], slice],
                                     tuple[NDArray[np.float64], NDArray[np.float64]]],
            ) -> int:
        """The first segment that fails the checks against the segments before it, or −1."""
        # sequential segment checks
        change = -1
        for j in range(1, len(segs)):
            prev = slice(segs[0].start, segs[j - 1].stop)
            th_prev, M_prev = fit(prev)
            th_seg, M_seg = fit(segs[j])
            if th_prev is None:
                raise ValueError("the regression is singular over the first learning "
                                 "segment(s): the signals do not excite all θ (no dither?)")
            means, variances = channel_blocks(th_prev, slice(prev.start, segs[j].stop))
            n_prev = prev.stop - prev.start
            allow = err_var = None
            if phi_blocks is not None:
                start = _refinement_start(M[prev], th_prev)
                err_var = start["error_variance"]
                allow = _block_allowances(phi_blocks, segs[j], start["information"],
                                          err_var)
            if self._segment_fails(means[:n_prev], variances[:n_prev], means[n_prev:],
                                   variances[n_prev:], th_prev, M_prev, th_seg, M_seg,
                                   allow, err_var):
                change = j
                break
        return change

    def _checked(self, ref: NominalReference, prior: NominalPrior | None
                 ) -> NominalReference:
        """``ref`` checked for excitation, or the prior if ``ref`` lies outside it."""
        if np.any(ref.theta0_eta == 0.0):
            raise ValueError("the learned nominal θ has a zero entry (no excitation in the "
                             f"learning window?): {list(ref.theta0_eta)}")
        if prior is not None and prior.theta0.shape != ref.theta0.shape:
            raise ValueError("the nominal prior has one θ0 for both axes; this regression "
                             "(with the case rate) has one per axis: learn the prior with it")
        if prior is not None and self._prior_replaces(ref, prior):
            return NominalReference(
                theta0=prior.theta0.copy(), theta0_eta=prior.theta0.copy(),
                mean=prior.mean.copy(), block_std=prior.block_std.copy(),
                var_short=prior.var_short.copy(), var_long=prior.var_long.copy(),
                status=REFERENCE_STATUS["prior_mismatch"],
                segments_used=ref.segments_used, change_segment=ref.change_segment)
        return ref

    def reference_blocks(self, reference: NominalReference, count: int
                         ) -> tuple[NDArray[np.float64], NDArray[np.float64],
                                    NDArray[np.float64]]:
        """Channel moments (means, variances (k, 6)) and mean θ (k, 10) of the last
        ``count`` learning blocks under ``reference``: they pre-fill the residual
        monitor, so that its tests run from the first sample after learning."""
        nblk = self.n_blocks
        k = min(count, nblk)
        nb = self.block_samples
        filt = np.vstack([self._history, *self._filtered])
        b0 = nblk - k
        e = regression_residuals(filt[:nblk * nb + 2], reference.theta0, self.model)
        em, ev = _fill_gaps([_residual_moments(blk, ok) for blk, ok in
                             zip(e.reshape(nblk, nb, 2), self._valid, strict=True)])
        means = np.column_stack([np.array(self._raw_mean[b0:]), em[b0:]])
        variances = np.column_stack([np.array(self._raw_var[b0:]), ev[b0:]])
        theta = np.array(self._theta[b0:]).reshape(k, 2 * N_THETA)
        return means, variances, theta

    def _segments(self, nblk: int) -> list[slice]:
        per = max(1, round(MIN_SEGMENT_S / self.block_s))
        n_seg = max(1, min(N_SEGMENTS, nblk // per))
        edges = np.linspace(0, nblk, n_seg + 1).round().astype(int)
        return [slice(int(a), int(b)) for a, b in itertools.pairwise(edges) if b > a]

    def _segment_fails(self, ref_means: NDArray[np.float64], ref_vars: NDArray[np.float64],
                       seg_means: NDArray[np.float64], seg_vars: NDArray[np.float64],
                       th_prev: NDArray[np.float64], M_prev: NDArray[np.float64],
                       th_seg: NDArray[np.float64] | None, M_seg: NDArray[np.float64],
                       allow: NDArray[np.float64] | None = None,
                       err_var: NDArray[np.float64] | None = None) -> bool:
        """``allow`` (k, 4), ``err_var`` (2,): case rate only, the θ-uncertainty
        allowances of the segment's blocks and the error variances of the fit before it
        (:meth:`ResidualMonitor._allowance`, :class:`NominalReference`)."""
        thr = self.thresholds
        k = seg_means.shape[0]
        res = list(RESIDUALS)
        mu = ref_means[:, res].mean(axis=0)
        sd = np.maximum(ref_means[:, res].std(axis=0), 1e-300)
        m, v, _ = window_moments(seg_means[:, res], seg_vars[:, res])
        v_ref = _window_reference_variance(ref_means[:, res], ref_vars[:, res], k)
        if allow is None:
            z = np.abs(m - mu) / (sd / math.sqrt(k))
            ratio = v / np.maximum(v_ref, _VAR_FLOOR)
        else:
            # the monitor's allowance (its _test): a manoeuvre in the segment excites
            # directions the segments before did not pin down
            z = np.abs(m - mu) / np.sqrt(sd * sd / k + np.sqrt(allow[:, :2]).mean(axis=0) ** 2)
            ratio = v / np.maximum(v_ref + thr.allowance_scale * (
                allow[:, 2:].mean(axis=0) + allow[:, :2].mean(axis=0)), _VAR_FLOOR)
        if np.any(z > thr.level) or np.any(ratio > thr.variance):
            return True
        if th_seg is None:
            return True  # the segment alone is singular: the signals changed character
        # θ spread: LS covariance σ²·A⁻¹ of each estimate, σ² per sample from the
        # reference fit (residual sum of squares / samples)
        npar = th_prev.size
        w = np.concatenate([-th_prev, [1.0]])
        rss = float(w @ M_prev @ w)
        samples = 2 * ref_means.shape[0] * self.block_samples  # both axes
        sigma2 = rss / max(samples - npar, 1)
        A_prev, A_seg = M_prev[:npar, :npar], M_seg[:npar, :npar]
        try:
            C = np.linalg.inv(A_prev) + np.linalg.inv(A_seg)
            if err_var is None:
                C *= sigma2
            else:
                # case rate: per axis θ covariance v·A⁻¹ (NominalReference.error_variance)
                C[:N_THETA] *= err_var[0]
                C[N_THETA:] *= err_var[1]
            d = th_seg - th_prev
            spread = float(d @ np.linalg.solve(C, d)) / npar
        except np.linalg.LinAlgError:
            return True
        self.last_spread = spread
        return not spread <= thr.theta_spread

    @staticmethod
    def _prior_replaces(ref: NominalReference, prior: NominalPrior) -> bool:
        """The learned reference is rejected for the prior (:class:`NominalPrior`)."""
        # θ: within 6 spreads of the training runs (floor 1e-3 relative: runs of one
        # seed set can agree better than plants do)
        tol = 6.0 * np.maximum(prior.theta0_std, 1e-3 * np.abs(prior.theta0))
        if prior.levels_only:  # the same kind of rotor; an offset moves θ3, θ4 ~20 %
            tol = np.maximum(tol, SAME_ROTOR_THETA * np.abs(prior.theta0))
        theta_ok = not np.any(np.abs(ref.theta0 - prior.theta0) > tol)
        # channel levels within 6 block spreads (over the whole window: conservative),
        # variances within a factor 3
        levels_ok = not np.any(np.abs(ref.mean - prior.mean) > 6.0 * prior.block_std)
        ratio = ref.var_short / prior.var_short
        noise_ok = bool(np.all((ratio < 3.0) & (ratio > 1.0 / 3.0)))
        if prior.levels_only:
            return theta_ok and noise_ok and not levels_ok
        return not (theta_ok and levels_ok and noise_ok)

    # -- state -----------------------------------------------------------------------
    def get_state(self) -> dict[str, Any]:
        """Collected data (copies)."""
        w = self.model.width
        return {"filtered": np.array(self._filtered).reshape(-1, w),
                "history": self._history.copy(),
                "raw_mean": np.array(self._raw_mean).reshape(-1, 4),
                "raw_var": np.array(self._raw_var).reshape(-1, 4),
                "theta": np.array(self._theta).reshape(-1, 2 * N_THETA),
                "valid": np.array(self._valid, dtype=bool).reshape(-1)}

    def set_state(self, state: dict[str, Any]) -> None:
        """Restore :meth:`get_state` output."""
        nb = self.block_samples
        w = self.model.width
        filt = np.asarray(state["filtered"], dtype=float).reshape(-1, w)
        raw_mean = np.asarray(state["raw_mean"], dtype=float).reshape(-1, 4)
        nblk = raw_mean.shape[0]
        if filt.shape[0] != nblk * nb:
            raise ValueError(f"state['filtered'] has {filt.shape[0]} samples, expected "
                             f"{nblk} blocks of {nb}")
        self._filtered = [filt[i * nb:(i + 1) * nb].copy() for i in range(nblk)]
        self._history = np.asarray(state["history"], dtype=float).reshape(2, w).copy()
        self._raw_mean = list(raw_mean.copy())
        self._raw_var = list(np.asarray(state["raw_var"], dtype=float).reshape(-1, 4).copy())
        self._theta = [t.reshape(2, N_THETA) for t in
                       np.asarray(state["theta"], dtype=float).reshape(-1, 2 * N_THETA).copy()]
        valid = np.asarray(state["valid"], dtype=bool).reshape(-1)
        self._valid = [valid[i * nb:(i + 1) * nb].copy() for i in range(nblk)]


# --------------------------------------------------------------------------- runtime
@dataclass(frozen=True)
class ClassificationStatistics:
    """What the pattern classifier sees (:class:`ResidualMonitor.classification_statistics`).

    Attributes
    ----------
    level : ndarray, shape (6,)
        (window mean − reference mean)/σ_block per channel (block-mean units).
    log_variance : ndarray, shape (6,)
        log10(window variance / reference variance) per channel.
    slope : ndarray, shape (6,)
        Slope of the block means in the window, block-mean units per second.
    growth : float
        log10((|L_end| + 1)/(|L_start| + 1)) of the residual level along its mean
        direction, from the straight-line fit over the window: ≈ 0 for a step, > 0 for
        a level that grows (drift).
    growth_t : float
        The same fit's slope over its standard error (scatter about the line), signed so
        that > 0 is a growing |level|: a drift keeps it large for as long as it grows,
        where ``growth`` falls once the window no longer starts at the onset.
    span_growth_t : float
        The same over every block since the alarm began (:class:`LevelGrowth`).
    log_eta : ndarray, shape (10,)
        log10(|mean θ|/|θ0_eta|) over the window, x then y axis.
    window_blocks : int
        Blocks in the window.
    window_s : float
        Window length, s.
    raw_signals : bool
        The four measured voltages' levels and variances describe faults, as in the
        library's training (True), or are moved by case-rate excitation and are left
        out of the signal-fault fit (False; set by a case-rate channel in a manoeuvre).
    """

    level: NDArray[np.float64]
    log_variance: NDArray[np.float64]
    slope: NDArray[np.float64]
    growth: float
    log_eta: NDArray[np.float64]
    window_blocks: int
    window_s: float
    raw_signals: bool = True
    growth_t: float = 0.0
    span_growth_t: float = 0.0


def _accumulate(info: NDArray[np.float64], rhs: NDArray[np.float64],
                theta: NDArray[np.float64], d_info: NDArray[np.float64],
                d_rhs: NDArray[np.float64]) -> None:
    """Add rows' normal equations in place and re-solve θ (kept if singular)."""
    info += d_info
    rhs += d_rhs
    sol = _ls(info, rhs)
    if sol is not None:
        theta[:] = sol


def _theta0_allowances(info: NDArray[np.float64], err_var: NDArray[np.float64],
                       phis: tuple[NDArray[np.float64], NDArray[np.float64]],
                       use: NDArray[np.bool_]) -> NDArray[np.float64]:
    """θ0-uncertainty variances of this block (V²): of its residual mean, φ̄ᵀPφ̄,
    and of its residual about the block's line, tr(S·P), per axis; P the covariance
    of the current θ0 (v·A⁻¹, :class:`NominalReference`, A grown by the accepted
    blocks) and S the detrended scatter of the block's regressors (as
    :func:`block_moments` detrends the residual)."""
    out = np.zeros(4)
    if np.count_nonzero(use) < 3:
        return out
    for a, ph in enumerate(phis):
        ph = ph[use]
        try:
            Ai = np.linalg.inv(info[a])
        except np.linalg.LinAlgError:
            continue
        P = err_var[a] * Ai
        mean = ph.mean(axis=0)
        dev = ph - mean
        k = np.flatnonzero(use).astype(float)
        k -= k.mean()
        slope = (k @ dev) / float(k @ k)
        dev = dev - np.outer(k, slope)
        out[a] = max(float(mean @ P @ mean), 0.0)
        out[2 + a] = max(float(np.einsum("ki,ij,kj->", dev, P, dev)) / ph.shape[0], 0.0)
    return out


class ResidualMonitor:
    """Runtime residual tests with alarm memory (module docstring).

    Parameters
    ----------
    reference : NominalReference
        The frozen reference.
    block_samples : int
        Samples per block.
    block_s : float
        Block duration, s.
    short_blocks, long_blocks : int
        Test windows, blocks (long ≥ short).
    thresholds : ResidualThresholds
        Raise thresholds.
    clear_blocks : int
        Blocks without any test above its hold threshold after which an alarm clears.
    model : RegressionModel, optional
        The regression of the residuals (default: the paper's); must match the
        reference's θ0 (5 pooled, or 10 per axis with the case rate).
    """

    #: Blocks after the alarm's first block that classification leaves out (the
    #: prefilter's transient of an abrupt fault).
    SKIP_BLOCKS = 2

    def __init__(self, reference: NominalReference, block_samples: int, block_s: float,
                 short_blocks: int, long_blocks: int, thresholds: ResidualThresholds,
                 clear_blocks: int, model: RegressionModel = PAPER_MODEL) -> None:
        if reference.theta0.size != model.n_par:
            raise ValueError(f"the reference has {reference.theta0.size} θ0 entries, the "
                             f"regression {model.n_par}")
        self.model = model
        self.reference = reference
        self.block_samples = check_int("block_samples", block_samples, minimum=1)
        self.block_s = check_positive("block_s", block_s)
        self.short_blocks = check_int("short_blocks", short_blocks, minimum=1)
        self.long_blocks = max(check_int("long_blocks", long_blocks, minimum=1),
                               self.short_blocks)
        self.thresholds = thresholds
        self.clear_blocks = check_int("clear_blocks", clear_blocks, minimum=1)
        self._theta0 = reference.theta0.copy()
        # case rate: θ0 is refined by the fault-free blocks and the tests allow for its
        # remaining uncertainty (class docstring)
        self._refine = model.case_rate and reference.information is not None
        eta0 = reference.theta0_eta
        self._log_theta0_eta = np.log10(np.abs(
            eta0 if eta0.size == 2 * N_THETA else np.tile(eta0, 2)))
        self.reset()

    def reset(self) -> None:
        """Empty ring, no alarm."""
        L = self.long_blocks
        self._means = np.zeros((L, N_CHANNELS))
        self._vars = np.zeros((L, N_CHANNELS))
        self._theta = np.zeros((L, 2 * N_THETA))
        self._pos = 0          # next slot
        self._count = 0        # blocks pushed (saturates at L for the ring)
        self._block_index = 0  # blocks pushed since construction
        self.alarm = False
        self._alarm_block = -1
        self._last_hold_block = -1
        self._power = np.zeros(2)  # low-frequency power CUSUM of ex, ey
        self._other_seen = False   # a test other than the power CUSUM held this alarm
        self._growth = LevelGrowth()  # block levels since the alarm (classification)
        # z_x, z_y, v_x, v_y, vL_x, vL_y, P_x, P_y (P: power CUSUM / its threshold)
        self.statistics = np.zeros(N_TESTS)
        # θ0-uncertainty allowances per block (V²): block mean x, y; within-block x, y
        self._allow = np.zeros((L, 4))
        if self._refine:
            info = self.reference.information
            assert info is not None
            assert self.reference.error_variance is not None
            self._info = info.copy()                         # (2, 5, 5) ΦᵀΦ per axis
            self._err_var = self.reference.error_variance.copy()  # θ0 cov = v·A⁻¹
            theta = self._theta0.reshape(2, N_THETA)
            self._rhs = np.einsum("aij,aj->ai", self._info, theta)  # Φᵀy of θ0
            self._theta_ref = theta.copy()
            # the ratio band's reference: starts at θ0_eta with the learning data's
            # information and is refined only by blocks that are also quiet in the band
            # (push_block's band_quiet), so a physical fault, which the residual tests
            # barely see, is not learned into it
            eta0 = self.reference.theta0_eta
            eta0 = (eta0.reshape(2, N_THETA) if eta0.size == 2 * N_THETA
                    else np.tile(eta0, (2, 1)))
            self._info_band = info.copy()
            self._rhs_band = np.einsum("aij,aj->ai", self._info_band, eta0)
            self._theta_band = eta0.copy()
            self._band_var = self._band_variances()

    @property
    def theta_reference(self) -> NDArray[np.float64]:
        """θ the residuals are computed with now: θ0, or with the case rate θ0 refined
        by the fault-free blocks so far ((10,), x then y axis)."""
        return self._theta_ref.reshape(-1).copy() if self._refine else self._theta0.copy()

    @property
    def band_reference(self) -> tuple[NDArray[np.float64], NDArray[np.float64]] | None:
        """(θ, variance of θ) of the ratio band's reference, each (2, 5) per axis, or
        None without the case rate. θ starts as the learning window's θ0_eta and is
        refined by the blocks quiet in both the residual tests and the band; its
        variance is v·diag(A⁻¹) of the information so far (:class:`NominalReference`)."""
        if not self._refine:
            return None
        return self._theta_band.copy(), self._band_var.copy()

    @property
    def refines(self) -> bool:
        """θ0 is refined (the case rate): :attr:`band_reference` exists."""
        return bool(self._refine)

    def band_arrays(self) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """:attr:`band_reference` without the copies, for the per-sample path (read
        only; valid while :attr:`refines`)."""
        return self._theta_band, self._band_var

    def _band_variances(self) -> NDArray[np.float64]:
        out = np.empty((2, N_THETA))
        for a in range(2):
            try:
                out[a] = self._err_var[a] * np.diag(np.linalg.inv(self._info_band[a]))
            except np.linalg.LinAlgError:
                out[a] = np.inf
        return out

    def prefill(self, means: NDArray[np.float64], variances: NDArray[np.float64],
                theta: NDArray[np.float64]) -> None:
        """Load learning blocks (oldest first) without testing them."""
        for m, v, t in zip(means, variances, theta, strict=True):
            self._store(m, v, t)

    def _store(self, m: NDArray[np.float64], v: NDArray[np.float64],
               t: NDArray[np.float64], allow: NDArray[np.float64] | None = None) -> None:
        p = self._pos
        self._means[p] = m
        self._vars[p] = v
        self._theta[p] = t
        self._allow[p] = 0.0 if allow is None else allow
        self._pos = (p + 1) % self.long_blocks
        self._count = min(self._count + 1, self.long_blocks)

    def _last(self, k: int) -> tuple[NDArray[np.float64], NDArray[np.float64],
                                     NDArray[np.float64]]:
        """The newest k blocks, oldest first."""
        k = min(k, self._count)
        idx = (self._pos - k + np.arange(k)) % self.long_blocks
        return self._means[idx], self._vars[idx], self._theta[idx]

    def push_block(self, raw: NDArray[np.float64], filtered: NDArray[np.float64],
                   theta: NDArray[np.float64], valid: NDArray[np.bool_],
                   band_quiet: bool = True) -> bool:
        """Add one block and run the tests; returns the alarm.

        Parameters
        ----------
        raw : ndarray, shape (nb, 4)
            Raw samples.
        filtered : ndarray, shape (nb + 2, model.width)
            Filtered samples with the two before the block first.
        theta : ndarray, shape (nb, 10)
            Fast-estimator θ of both axes per sample.
        valid : ndarray of bool, shape (nb,)
            Samples whose regression rows are sound (False next to a skipped sample).
        band_quiet : bool, optional
            The fast estimates are near the band's reference (case rate): a block the
            tests accept also refines :attr:`band_reference`.
        """
        allow = None
        if self._refine:
            phx, yx, phy, yy = self.model.rows(filtered)
            th = self._theta_ref
            e = np.column_stack([yx - phx @ th[0], yy - phy @ th[1]])
            use = np.asarray(valid, dtype=bool)
            allow = self._allowance((phx, phy), use)
        else:
            e = regression_residuals(filtered, self._theta0, self.model)
        m, v = block_moments(raw)
        res = _residual_moments(e, valid)
        fresh = res is not None
        if res is None:  # no usable row (a skipped sample): repeat the last block's
            prev = (self._pos - 1) % self.long_blocks
            res = (self._means[prev, 4:].copy(), self._vars[prev, 4:].copy())
            allow = None if allow is None else self._allow[prev].copy()
        m = np.concatenate([m, res[0]])
        v = np.concatenate([v, res[1]])
        self._store(m, v, theta.mean(axis=0), allow)
        self._block_index += 1
        if fresh:  # a repeated block is no new evidence
            self._update_power(res[0], None if allow is None else allow[:2])
        alarm = self._test()
        if not alarm:
            self._growth.reset()
        elif fresh and self.blocks_in_alarm > self.SKIP_BLOCKS:
            self._growth.update((m - self.reference.mean) / self.reference.block_std)
        if self._refine and not alarm:
            # a block the tests accept as fault-free refines θ0 (no forgetting: the rotor
            # is constant; in alarm the block is left out, so a fault is not learned)
            for a, (ph, y) in enumerate(((phx, yx), (phy, yy))):
                ph, y = ph[use], y[use]
                info, rhs = ph.T @ ph, ph.T @ y
                _accumulate(self._info[a], self._rhs[a], self._theta_ref[a], info, rhs)
                if band_quiet:
                    _accumulate(self._info_band[a], self._rhs_band[a],
                                self._theta_band[a], info, rhs)
            if band_quiet:
                self._band_var = self._band_variances()
        return alarm

    def _allowance(self, phis: tuple[NDArray[np.float64], NDArray[np.float64]],
                   use: NDArray[np.bool_]) -> NDArray[np.float64]:
        """:func:`_theta0_allowances` of the current θ0 information."""
        return _theta0_allowances(self._info, self._err_var, phis, use)

    def _update_power(self, residual_means: NDArray[np.float64],
                      allowance: NDArray[np.float64] | None) -> None:
        h = self.thresholds.power
        if h <= 0.0:
            return
        ref = self.reference
        res = list(RESIDUALS)
        var = ref.block_std[res] ** 2
        if allowance is not None:  # case rate: the block mean's θ0-uncertainty part
            var = var + self.thresholds.allowance_scale * allowance
        q = (residual_means - ref.mean[res]) ** 2 / var
        self._power = np.clip(self._power + np.minimum(q, POWER_Q_CAP) - POWER_KAPPA, 0.0, h)

    def _test(self) -> bool:
        ref = self.reference
        thr = self.thresholds
        res = list(RESIDUALS)
        means, variances, _ = self._last(self.short_blocks)
        k = means.shape[0]
        m, v, _ = window_moments(means[:, res], variances[:, res])
        lm, lv = self._last(self.long_blocks)[:2]
        kl = lm.shape[0]
        _, vl, _ = window_moments(lm[:, res], lv[:, res])
        var_s = ref.variance_at(k, self.short_blocks, self.long_blocks)[res]
        var_l = ref.variance_at(kl, self.short_blocks, self.long_blocks)[res]
        if self._refine:
            # the window mean's θ0 part: the blocks' errors share one θ0 error, so their
            # standard deviations add (fully correlated); the window variance's: the
            # within-block parts plus the spread of the block means
            a_s, a_l = self._last_allowances(k), self._last_allowances(kl)
            level_var = (ref.block_std[res] / math.sqrt(k)) ** 2 + np.sqrt(
                a_s[:, :2]).mean(axis=0) ** 2
            z = np.abs(m - ref.mean[res]) / np.sqrt(level_var)
            # a variance test meets the error squared, so its allowance is scaled to
            # the confidence wanted (ResidualThresholds.allowance_sigma)
            g = thr.allowance_scale
            vs = v / (var_s + g * (a_s[:, 2:].mean(axis=0) + a_s[:, :2].mean(axis=0)))
            vL = vl / (var_l + g * (a_l[:, 2:].mean(axis=0) + a_l[:, :2].mean(axis=0)))
        else:
            z = np.abs(m - ref.mean[res]) / (ref.block_std[res] / math.sqrt(k))
            vs = v / var_s
            vL = vl / var_l
        power = self._power / thr.power if thr.power > 0.0 else np.zeros(2)
        self.statistics = np.concatenate([z, vs, vL, power])
        hz, hv, hl = thr.hold
        raise_now = bool(np.any(z > thr.level) or np.any(vs > thr.variance)
                         or np.any(vL > thr.long_variance) or np.any(power >= 1.0))
        other_hold = bool(np.any(z > hz) or np.any(vs > hv) or np.any(vL > hl))
        hold_now = other_hold or bool(np.any(power > 0.5))
        b = self._block_index
        if hold_now:
            self._last_hold_block = b
        if not self.alarm:
            if raise_now:
                self.alarm = True
                self._alarm_block = b
                self._other_seen = other_hold
        elif other_hold:
            self._other_seen = True
        elif not hold_now and b - self._last_hold_block >= self.clear_blocks:
            self.alarm = False
            self._alarm_block = -1
        return self.alarm

    def _last_allowances(self, k: int) -> NDArray[np.float64]:
        """θ0-uncertainty allowances of the newest k blocks, (k, 4)."""
        k = min(k, self._count)
        return self._allow[(self._pos - k + np.arange(k)) % self.long_blocks]

    @property
    def power_only(self) -> bool:
        """In alarm, and only the low-frequency power CUSUM has held it: the residuals
        carry more slow power but neither a level shift nor a variance change of their
        own (a physical fault's θ change looks like this too)."""
        return self.alarm and not self._other_seen

    @property
    def blocks_in_alarm(self) -> int:
        """Blocks since the alarm was raised (0 without alarm)."""
        return 0 if not self.alarm else self._block_index - self._alarm_block + 1

    def classification_statistics(self) -> ClassificationStatistics | None:
        """Statistics of the alarm window: the blocks since the alarm was raised (less
        :data:`SKIP_BLOCKS`), at most the long window; None before a short window of them
        is available or without alarm."""
        if not self.alarm:
            return None
        k = min(self.blocks_in_alarm - self.SKIP_BLOCKS, self.long_blocks)
        if k < self.short_blocks:
            return None
        stats = self.window_statistics(k)
        growth = self._growth
        if growth.blocks > k:  # a drift's rate: the slopes over the whole span
            stats = replace(stats, slope=growth.slopes() / self.block_s)
        return replace(stats, span_growth_t=growth.t_statistic())

    def window_statistics(self, k: int) -> ClassificationStatistics:
        """:class:`ClassificationStatistics` of the newest k blocks (k ≥ 1)."""
        ref = self.reference
        means, variances, theta = self._last(k)
        k = means.shape[0]
        m, v, slope = window_moments(means, variances)
        level = (m - ref.mean) / ref.block_std
        log_var = np.log10(np.maximum(v, _VAR_FLOOR)
                           / ref.variance_at(k, self.short_blocks, self.long_blocks))
        res = list(RESIDUALS)
        blk = (means[:, res] - ref.mean[res]) / ref.block_std[res]
        mean_dir = blk.mean(axis=0)
        norm = float(np.hypot(*mean_dir))
        growth = growth_t = 0.0
        if norm > 0.0 and k >= 3:
            proj = blk @ (mean_dir / norm)
            x = np.arange(k) - 0.5 * (k - 1)
            b = float(x @ (proj - proj.mean())) / float(x @ x)
            half = b * 0.5 * (k - 1)
            growth = math.log10((abs(proj.mean() + half) + 1.0)
                                / (abs(proj.mean() - half) + 1.0))
            scatter = proj - proj.mean() - b * x
            se = math.sqrt(float(scatter @ scatter) / max(k - 2, 1) / float(x @ x))
            growth_t = b / max(se, 1e-300)  # proj's mean is > 0: b > 0 grows
        th = np.abs(theta.mean(axis=0))
        log_eta = np.log10(np.maximum(th, 1e-300)) - self._log_theta0_eta
        return ClassificationStatistics(
            level=level, log_variance=log_var, slope=slope / ref.block_std / self.block_s,
            growth=growth, log_eta=log_eta, window_blocks=k, window_s=k * self.block_s,
            growth_t=growth_t)

    # -- state -----------------------------------------------------------------------
    def get_state(self) -> dict[str, Any]:
        """Ring and alarm state (copies)."""
        return {"means": self._means.copy(), "vars": self._vars.copy(),
                "theta": self._theta.copy(), "pos": self._pos, "count": self._count,
                "block_index": self._block_index, "alarm": self.alarm,
                "alarm_block": self._alarm_block, "last_hold_block": self._last_hold_block,
                "power": self._power.copy(), "other_seen": self._other_seen,
                "statistics": self.statistics.copy(), "growth": self._growth.get_state(),
                "refinement": None if not self._refine else {
                    "allow": self._allow.copy(), "info": self._info.copy(),
                    "rhs": self._rhs.copy(), "theta_ref": self._theta_ref.copy(),
                    "info_band": self._info_band.copy(), "rhs_band": self._rhs_band.copy(),
                    "theta_band": self._theta_band.copy()}}

    def set_state(self, s: dict[str, Any]) -> None:
        """Restore :meth:`get_state` output of an identically configured monitor."""
        L = self.long_blocks
        means = np.asarray(s["means"], dtype=float)
        if means.shape != (L, N_CHANNELS):
            raise ValueError(f"state['means'] has shape {means.shape}, expected "
                             f"{(L, N_CHANNELS)}")
        self._means = means.copy()
        self._vars = np.asarray(s["vars"], dtype=float).reshape(L, N_CHANNELS).copy()
        self._theta = np.asarray(s["theta"], dtype=float).reshape(L, 2 * N_THETA).copy()
        self._pos, self._count = int(s["pos"]), int(s["count"])
        self._block_index = int(s["block_index"])
        self.alarm = bool(s["alarm"])
        self._alarm_block = int(s["alarm_block"])
        self._last_hold_block = int(s["last_hold_block"])
        self._power = check_finite_array("state['power']", s["power"], shape=(2,)).copy()
        self._other_seen = bool(s["other_seen"])
        self.statistics = np.asarray(s["statistics"], dtype=float).reshape(N_TESTS).copy()
        self._growth.set_state(s["growth"])
        ref = s.get("refinement")
        if (ref is None) != (not self._refine):
            raise ValueError("state['refinement'] does not match this monitor (the case "
                             "rate's refined reference is kept only with the case rate)")
        if ref is not None:
            self._allow = check_finite_array("state['refinement']['allow']", ref["allow"],
                                             shape=(L, 4)).copy()
            self._info = check_finite_array("state['refinement']['info']", ref["info"],
                                            shape=(2, N_THETA, N_THETA)).copy()
            self._rhs = check_finite_array("state['refinement']['rhs']", ref["rhs"],
                                           shape=(2, N_THETA)).copy()
            self._theta_ref = check_finite_array("state['refinement']['theta_ref']",
                                                 ref["theta_ref"], shape=(2, N_THETA)).copy()
            for key, shape in (("info_band", (2, N_THETA, N_THETA)),
                               ("rhs_band", (2, N_THETA)), ("theta_band", (2, N_THETA))):
                setattr(self, f"_{key}", check_finite_array(
                    f"state['refinement'][{key!r}]", ref[key], shape=shape).copy())
            self._band_var = self._band_variances()

