"""Change-time estimates of the sequential diagnosis: where a CUSUM alarm's change
began, and the onset that best explains the whitened residual as a step.

Both read a ring of per-sample history (row ``j % N`` holds sample j, N its length).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from ..common.cusum import CusumBank

__all__ = ["refine_onset", "walk_back"]

_FloatArray = NDArray[np.float64]


def walk_back(cusum: CusumBank, history: _FloatArray, k: int, oldest: int,
              tol: float) -> int:
    """The change time of the alarm ``cusum`` raised at sample k: the sample after the
    newly alarming statistic was last zero (earliest over the charts), found by running
    its recursion back from the statistics before sample k on the inputs kept in
    ``history`` (a ring indexed by sample), no further back than ``oldest``.

    Walking back subtracts increments: a statistic that was exactly 0 comes back as a
    rounding residue, so "zero" is below ``tol`` (a tiny fraction of the threshold).
    """
    charts = np.flatnonzero(cusum.newly_raised)
    if charts.size == 0:
        return k
    n_hist = history.shape[0]
    s = cusum.previous_statistics[charts].copy()
    j = k - 1
    while j >= oldest and np.any(s > tol):
        inc = cusum.increments(history[j % n_hist])[charts]
        s = np.where(s > tol, s - inc, s)
        j -= 1
    return j + 1 if not np.any(s > tol) else oldest


def refine_onset(z_history: _FloatArray, step_response: _FloatArray, change: int,
                 oldest: int, k: int, window: int, sensors: tuple[int, ...] = ()) -> int:
    """The onset that best explains z as a step (maximum likelihood over onsets within
    ``window`` samples of ``change``, none before ``oldest``).

    On any one sensor when ``sensors`` is empty (at detection), else jointly on the
    given ones (once isolated). The CUSUM's change estimate moves with the noise, by a
    sample for a large step and by many for a small one; a misplaced onset looks like a
    model misfit (a large step) or like a ramp (a small one).

    Parameters
    ----------
    z_history : ndarray, shape (N, m)
        Ring of the main filter's whitened residuals up to sample k.
    step_response : ndarray, shape (L, m, m)
        z response (sample, channel, sensor) to a unit step on each sensor.
    change, oldest, k : int
        CUSUM change estimate, oldest sample kept, current sample.
    window : int
        Onsets tried on either side of ``change``, samples.
    sensors : tuple of int
        Sensors the step is on (empty: the best single one).
    """
    lo = max(oldest, change - window)
    hi = min(k, change + window)
    if hi <= lo:
        return change
    z = z_history[np.arange(lo, k + 1) % z_history.shape[0]]  # (N, m)
    best, best_j = -1.0, change
    cols = list(sensors)
    # the sensors' columns once (a C-ordered copy; its leading rows per onset are the
    # same array the per-onset selection made)
    h_cols = step_response[:k + 1 - lo][:, :, cols] if cols else None
    eye = np.eye(len(cols))
    for j in range(lo, hi + 1):
        if not cols:
            h = step_response[:k + 1 - j]  # (L, channels, sensors)
            num = np.einsum("lcs,lc->s", h, z[j - lo:])
            den = np.einsum("lcs,lcs->s", h, h)
            score = float(np.max(num * num / np.maximum(den, 1e-300)))
        else:
            hs = h_cols[:k + 1 - j]
            xz = np.einsum("lcs,lc->s", hs, z[j - lo:])
            gram = np.einsum("lcs,lct->st", hs, hs)
            gram += 1e-12 * max(float(np.trace(gram)), 1e-300) * eye
            score = float(xz @ np.linalg.solve(gram, xz))
        if score > best:
            best, best_j = score, j
    return best_j
