"""The DTG channel's reference blocks: the samples of the block being collected and,
with the case rate, the block means of ω against those of the learning window."""

from __future__ import annotations

from collections import deque
from typing import Any

import numpy as np
from numpy.typing import NDArray

__all__ = ["OMEGA_SPREAD_FLOOR", "ReferenceBlocks"]

#: Smallest spread of the learning blocks' ω used for the manoeuvre test, rad/s (a
#: noise-free case rate would make every rounding a manoeuvre).
OMEGA_SPREAD_FLOOR = 1e-6

Sample = tuple[float, ...]


class ReferenceBlocks:
    """The block being collected (plain lists; arrays at its end) and the two filtered
    samples before it; the case rate's ω block statistics.

    Parameters
    ----------
    block_samples : int
        Samples per block.
    width : int
        Filtered signals per sample: 4 (V), or 6 with ωx, ωy (rad/s).
    long_blocks : int
        Blocks of ω deviations kept (the longest classification window).
    """

    def __init__(self, block_samples: int, width: int, long_blocks: int) -> None:
        self._nb = block_samples
        self._width = width
        self._long_blocks = long_blocks
        self.reset()

    def reset(self) -> None:
        """Return to the state right after construction."""
        # raw (nb, 4), filtered (nb, width) with the two samples before, fast-estimator θ
        # of both axes (nb, 10)
        self.clear()
        self.history: list[Sample] = [(0.0,) * self._width] * 2
        #: Samples still to be marked invalid (after a skipped sample).
        self.gap = 0
        # case rate: block means of the filtered ω during learning, their mean and spread,
        # and each runtime block's largest deviation from it in those spreads
        self._omega_learn: list[tuple[float, float]] = []
        self._omega_ref: tuple[NDArray[np.float64], NDArray[np.float64]] | None = None
        self.omega_dev: deque[float] = deque(maxlen=self._long_blocks)

    def clear(self) -> None:
        """Empty the current block."""
        self.raw: list[Sample] = []
        self.filtered: list[Sample] = []
        self.theta: list[Sample] = []
        self.valid: list[bool] = []

    def next_block(self) -> None:
        """Start a new block; the last two filtered samples become the history."""
        self.history = (self.history + self.filtered)[-2:]
        self.clear()

    def append(self, raw: Sample, sample: Sample, theta: Sample) -> bool:
        """Add one sample (raw V, filtered, θ of both axes); True when the block is
        full."""
        self.raw.append(raw)
        self.filtered.append(sample)
        self.theta.append(theta)
        gap = self.gap
        self.valid.append(gap == 0)
        if gap:
            self.gap = gap - 1
        return len(self.raw) >= self._nb

    def arrays(self, with_history: bool = False) -> tuple[NDArray[Any], ...]:
        """raw, filtered (with the history first if asked), θ and validity arrays."""
        filtered = self.history + self.filtered if with_history else self.filtered
        return (np.array(self.raw), np.array(filtered), np.array(self.theta),
                np.array(self.valid))

    def omega_block(self, learning: bool) -> None:
        """Case rate: the block mean of the filtered ω (the voltages' filter, so aligned
        with their block statistics), learned or compared with what was learned."""
        w = np.mean(np.array(self.filtered)[:, 4:6], axis=0)
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
        self.omega_dev.append(float(dev.max()))

    def get_state(self) -> tuple[dict[str, Any], dict[str, Any]]:
        """The channel state's ``"buffers"`` and ``"omega"`` parts."""
        buffers = {"raw": np.array(self.raw, dtype=float).reshape(-1, 4),
                   "filtered": np.array(self.filtered, dtype=float).reshape(-1, self._width),
                   "theta": np.array(self.theta, dtype=float).reshape(-1, 10),
                   "valid": np.array(self.valid, dtype=bool),
                   "history": np.array(self.history, dtype=float),
                   "gap": self.gap}
        omega = {"learn": np.array(self._omega_learn, dtype=float).reshape(-1, 2),
                 "ref": None if self._omega_ref is None else np.vstack(self._omega_ref),
                 "deviation": np.array(self.omega_dev, dtype=float)}
        return buffers, omega

    def set_state(self, buffers: dict[str, Any], omega: dict[str, Any]) -> None:
        """Restore :meth:`get_state`."""
        k = np.asarray(buffers["raw"], dtype=float).reshape(-1, 4).shape[0]
        self.raw = [tuple(r) for r in np.asarray(
            buffers["raw"], dtype=float).reshape(k, 4).tolist()]
        self.filtered = [tuple(r) for r in np.asarray(
            buffers["filtered"], dtype=float).reshape(k, self._width).tolist()]
        self.theta = [tuple(r) for r in np.asarray(
            buffers["theta"], dtype=float).reshape(k, 10).tolist()]
        self.valid = [bool(v) for v in np.asarray(buffers["valid"], dtype=bool)
                      .reshape(k).tolist()]
        self.history = [tuple(r) for r in np.asarray(
            buffers["history"], dtype=float).reshape(2, self._width).tolist()]
        self.gap = int(buffers["gap"])
        self._omega_learn = [(float(a), float(b)) for a, b in np.asarray(
            omega["learn"], dtype=float).reshape(-1, 2).tolist()]
        ref = omega["ref"]
        self._omega_ref = (None if ref is None else
                           tuple(np.asarray(ref, dtype=float).reshape(2, 2).copy()))
        self.omega_dev = deque((float(v) for v in np.asarray(
            omega["deviation"], dtype=float).reshape(-1)), maxlen=self._long_blocks)
