"""Scale calibration of the sequential diagnoser's residual generators on fault-free data:
the model's whitened variance is a floor, the data may widen a channel, never narrow it.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..common._distributions import chi2_ppf
from ..common._validation import check_finite_array, check_in_range, check_int
from .generators import ObserverStack

if TYPE_CHECKING:
    from .sequential_diagnosis import SequentialDiagnoser

__all__ = ["calibrate_scales"]

_FloatArray = NDArray[np.float64]


def calibrate_scales(diagnoser: SequentialDiagnoser, w: ArrayLike, burn_in: int,
                     confidence: float = 0.95,
                     x_start: ArrayLike | None = None) -> list[_FloatArray]:
    """Check the whitened variance of every generator on fault-free data and widen
    the channels where it is larger than the model's.

    Runs the main and hypothesis generators from ``x0`` over ``w`` (N × (p + m)),
    takes per channel the larger of the sample variance times its upper
    ``confidence`` factor (χ², N − burn_in samples) and a Bartlett long-run variance
    estimate, and divides z by its square root where it exceeds 1 (never narrows:
    the model is the floor). Leaves the main filter at the end of the data (ready to
    monitor) and returns the factors, main generator first. ``x_start``: the state
    estimate every observer starts the data from (default ``x0``).
    """
    data = check_finite_array("w", w, shape=(None, diagnoser.p + diagnoser.m))
    burn = check_int("burn_in", burn_in)
    n_used = data.shape[0] - burn
    if n_used < 10:
        raise ValueError(f"w must have at least 10 samples after burn_in={burn}")
    conf = check_in_range("confidence", confidence, 0.5, 1.0, high_open=True)
    both = ObserverStack([diagnoser.main_generator, *diagnoser.bank_generators],
                         diagnoser.p, diagnoser.m)
    start = diagnoser.x0 if x_start is None else check_finite_array(
        "x_start", x_start, shape=(diagnoser.n,))
    for k in range(len(both.generators)):
        both.set_observer_state(k, start)
    zs = np.empty((data.shape[0], both.n_out))
    for j in range(data.shape[0]):
        zs[j] = both.update(data[j])[0]
    z = zs[burn:]
    var = z.var(axis=0, ddof=1)
    lrv = _bartlett_long_run_variance(z)
    upper = n_used / chi2_ppf(1.0 - conf, n_used)
    factor = np.sqrt(np.maximum(1.0, np.maximum(var * upper, lrv)))
    scales = [factor[sl] for sl in both.out_slices]
    diagnoser.set_scales(scales)
    diagnoser.main.x = both.x[both.state_slices[0]].copy()
    return scales


def _bartlett_long_run_variance(z: _FloatArray) -> _FloatArray:
    """Per column: long-run variance estimate with a Bartlett window of N^(1/3) lags."""
    n = z.shape[0]
    x = z - z.mean(axis=0)
    lags = max(1, round(n ** (1.0 / 3.0)))
    lrv = (x * x).sum(axis=0) / n
    for j in range(1, min(lags, n - 1) + 1):
        lrv += 2.0 * (1.0 - j / (lags + 1.0)) * (x[j:] * x[:-j]).sum(axis=0) / n
    return lrv
