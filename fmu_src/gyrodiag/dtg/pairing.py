"""Pairing of the DTG channel's voltages with the case rate of another sample.

With the case rate in the regression, the voltages of sample k are paired with the case
rate of sample k − d: d fixed (``case_rate_delay_samples``), or chosen from the data by a
:class:`~gyrodiag.dtg.alignment.CaseRateAligner` that runs ``lookahead`` samples ahead of
the estimators (docs/dtg_case_rate.md §9). :class:`CaseRatePairing` holds the queue of
samples waiting for the estimators.
"""

from __future__ import annotations

from collections import deque
from typing import TYPE_CHECKING, Any

import numpy as np

from .alignment import CaseRateAligner

if TYPE_CHECKING:
    from .config import DTGChannelConfig

__all__ = ["CaseRatePairing"]

Sample = tuple[float, ...]


class CaseRatePairing:
    """Queue of prefiltered samples and the case-rate delay in use.

    Parameters
    ----------
    config : DTGChannelConfig
        The channel's settings (case rate, delay, alignment range and lookahead).
    gap_samples : int
        Samples the aligner skips after a skipped (non-finite) sample.
    """

    def __init__(self, config: DTGChannelConfig, gap_samples: int) -> None:
        self.config = config
        self._gap_samples = gap_samples
        self.reset()

    def reset(self) -> None:
        """Return to the state right after construction: an empty queue, the delay as
        configured."""
        c = self.config
        case_rate = c.case_rate is not None
        # the aligner sees each sample `lookahead` samples before the estimators do
        self._lookahead = c.lookahead_samples
        self._aligner = (
            CaseRateAligner(float(c.sample_period_s), c.pickoff_scale,
                            scheme=c.case_rate,  # type: ignore[arg-type]
                            max_delay=c.case_rate_align_max,
                            delay=c.case_rate_delay_samples)
            if case_rate and c.case_rate_align_max > 0 else None)
        self._fixed_delay = int(c.case_rate_delay_samples) if case_rate else 0
        #: Samples go through the queue (an aligner, or a fixed delay other than 0).
        self.shifting = self._aligner is not None or self._fixed_delay != 0
        max_delay = (c.case_rate_align_max if self._aligner is not None
                     else max(self._fixed_delay, 0))
        # filtered ω of the newest samples (newest first); voltages waiting in the queue
        # with their gap marks
        self._omega_hist: deque[tuple[float, float]] = deque(
            maxlen=self._lookahead + max_delay + 1)
        self._queue: deque[tuple[Sample, Sample, bool]] = deque()
        self._gap_pending = False
        self._aligner_holdoff = 0

    @property
    def delay(self) -> int:
        """Delay of the case rate against the voltages in use, samples."""
        return self._aligner.delay if self._aligner is not None else self._fixed_delay

    @property
    def switches(self) -> int:
        """How often the aligner has changed the delay."""
        return 0 if self._aligner is None else self._aligner.switches

    def mark_gap(self) -> None:
        """A sample was skipped: the next queued sample carries a gap mark and the
        aligner holds off."""
        self._gap_pending = True
        self._aligner_holdoff = self._gap_samples

    def pair(self, raw: Sample, sample: Sample) -> tuple[Sample, Sample, bool] | None:
        """Queue a prefiltered sample (V, V, V, V, rad/s, rad/s); return the raw and
        filtered sample due for the estimators with the case rate of its pairing and its
        gap mark, or None while the queue fills."""
        aligner = self._aligner
        if aligner is not None:
            if self._aligner_holdoff:
                # the regression rows that span a skipped sample, and the prefilter's
                # ringing after it, say nothing about the pairing
                self._aligner_holdoff -= 1
                aligner.restart()
            else:
                aligner.update(sample)
        hist = self._omega_hist
        hist.appendleft((sample[4], sample[5]))
        self._queue.append((raw, sample[:4], self._gap_pending))
        self._gap_pending = False
        if len(self._queue) <= self._lookahead:
            return None
        raw_due, volts, gap = self._queue.popleft()
        omega = hist[min(self._lookahead + self.delay, len(hist) - 1)]
        return raw_due, volts + omega, gap

    def get_state(self) -> dict[str, Any]:
        """Aligner, ω history and queue (the channel state's ``"alignment"``)."""
        return {
            "aligner": None if self._aligner is None else self._aligner.get_state(),
            "omega": np.array(self._omega_hist, dtype=float).reshape(-1, 2),
            "raw": np.array([q[0] for q in self._queue], dtype=float).reshape(-1, 4),
            "voltages": np.array([q[1] for q in self._queue], dtype=float).reshape(-1, 4),
            "gaps": np.array([q[2] for q in self._queue], dtype=bool),
            "gap_pending": self._gap_pending, "holdoff": self._aligner_holdoff}

    def set_state(self, state: dict[str, Any] | None) -> None:
        """Restore :meth:`get_state`; None (state version 0): an empty queue, the delay
        as configured."""
        self.reset()
        if state is None:
            return
        if (state["aligner"] is None) != (self._aligner is None):
            raise ValueError("state['alignment'] does not match case_rate_align_max")
        if self._aligner is not None:
            self._aligner.set_state(state["aligner"])
        omega = np.asarray(state["omega"], dtype=float).reshape(-1, 2)
        raw = np.asarray(state["raw"], dtype=float).reshape(-1, 4)
        volts = np.asarray(state["voltages"], dtype=float).reshape(-1, 4)
        gaps = np.asarray(state["gaps"], dtype=bool).reshape(-1)
        if (omega.shape[0] > (self._omega_hist.maxlen or 0) or raw.shape[0] > self._lookahead
                or volts.shape != raw.shape or gaps.shape != (raw.shape[0],)):
            raise ValueError("state['alignment'] does not fit this channel's case-rate "
                             "lookahead (another case_rate_lookahead_s or sample period?)")
        self._omega_hist.extend(tuple(r) for r in omega.tolist())
        self._queue.extend((tuple(r), tuple(v), bool(g)) for r, v, g in
                           zip(raw.tolist(), volts.tolist(), gaps.tolist(), strict=True))
        self._gap_pending = bool(state["gap_pending"])
        self._aligner_holdoff = int(state["holdoff"])
