"""Growth of the levels since an alarm: their slopes, and the residual level's slope in
standard errors, over every block since the alarm began (not only the classification
window).

A drift's evidence grows without bound the longer it runs (t ∝ n^1.5 blocks); a step's
level stays flat (|t| ≲ 2 on the bench), so the drift/step decision never has to flip
back once the drift is seen.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ..common._validation import check_finite_array

__all__ = ["LevelGrowth"]

# n, Σj, Σj², Σm (6 channels), Σj·m (6), Σb·bᵀ (2×2, b the residual levels m[4:6]):
# block j = 0, 1, … of the span
_N_SUMS = 19
_M, _JM, _BB = slice(3, 9), slice(9, 15), slice(15, 19)
_RES = slice(4, 6)


class LevelGrowth:
    """Running straight-line fit of the six block levels since an alarm began."""

    def __init__(self) -> None:
        self.reset()

    def reset(self) -> None:
        """No block in the span."""
        self._sums = np.zeros(_N_SUMS)

    def update(self, level: NDArray[np.float64]) -> None:
        """Add the next block's levels (6,: four signals, two residuals), in block
        standard deviations."""
        s = self._sums
        j = s[0]
        s[0] += 1.0
        s[1] += j
        s[2] += j * j
        s[_M] += level
        s[_JM] += j * level
        b = level[_RES]
        s[_BB] += np.outer(b, b).ravel()

    @property
    def blocks(self) -> int:
        """Blocks in the span."""
        return int(self._sums[0])

    def slopes(self) -> NDArray[np.float64]:
        """Slope of each level per block over the span (6,; zeros under 3 blocks)."""
        s = self._sums
        n = s[0]
        if n < 3.0:
            return np.zeros(6)
        return (s[_JM] - s[1] * s[_M] / n) / (s[2] - s[1] * s[1] / n)

    def t_statistic(self) -> float:
        """Slope of the residual level projected on its mean direction, over its
        standard error (> 0: |level| grows); 0 with fewer than 3 blocks or no level."""
        s = self._sums
        n = s[0]
        sum_b = s[_M][_RES]
        norm = float(np.hypot(*sum_b))
        if n < 3.0 or norm == 0.0:
            return 0.0
        d = sum_b / norm
        sp, sjp = norm, float(d @ s[_JM][_RES])
        spp = float(d @ s[_BB].reshape(2, 2) @ d)
        sxx = s[2] - s[1] * s[1] / n
        sxp = sjp - s[1] * sp / n
        slope = sxp / sxx
        rss = max(spp - sp * sp / n - slope * sxp, 0.0)
        se = math.sqrt(rss / (n - 2.0) / sxx)
        return slope / max(se, 1e-300)

    def get_state(self) -> list[float]:
        """The running sums (a copy)."""
        return self._sums.tolist()

    def set_state(self, state: Any) -> None:
        """Restore :meth:`get_state` output."""
        self._sums = check_finite_array("state['growth']", state, shape=(_N_SUMS,)).copy()
