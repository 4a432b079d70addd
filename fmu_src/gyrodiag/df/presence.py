"""Presence test of an isolated fault (sequential diagnosis): a CUSUM bank on what the
fitted fault model leaves of the whitened residual (a mean model) or on the residual
itself (a noise increase, started in alarm); when it clears, the fault is gone and the
episode ends.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ..common._validation import check_finite_array
from ..common.cusum import CusumBank
from .onset import walk_back

__all__ = ["PresenceTest"]

_FloatArray = NDArray[np.float64]


class PresenceTest:
    """The presence test of the current episode's fault (module notes).

    Parameters
    ----------
    n_sensors : int
        m: channels of the test (those of the main filter).
    n_hist : int
        Samples of the test's inputs kept (to date the fault's end).
    new_cusum : callable
        ``new_cusum(n_channels)``: a CUSUM bank with the diagnoser's thresholds.
    tol : float
        "Zero" of a statistic walked back (see :func:`~gyrodiag.df.onset.walk_back`).

    Attributes
    ----------
    test : CusumBank or None
        The running test (None: none running; the next sample starts one).
    zero : int
        The sample after the test's statistic was last zero before it cleared: where
        the fault ended.
    grew : bool
        At the last alarm of a mean model's test: the misfit since ``zero`` points the
        way of the fitted signature (the fault outgrew its model rather than ended).
    """

    def __init__(self, n_sensors: int, n_hist: int, new_cusum: Callable[[int], CusumBank],
                 tol: float) -> None:
        self.m, self._n_hist = n_sensors, n_hist
        self._new_cusum = new_cusum
        self._tol = tol

    def reset(self) -> None:
        """No test running, no inputs kept."""
        self.test: CusumBank | None = None
        self.zero = 0
        self.grew = False
        self._start = 0
        self._hist_c = np.zeros((self._n_hist, self.m))
        self._hist_p = np.zeros(self._n_hist)

    def stop(self) -> None:
        """No test running (the next sample starts one)."""
        self.test = None

    def at_least(self, fraction: float) -> bool:
        """A test is running and its largest statistic is at least ``fraction`` of its
        threshold."""
        return self.test is not None and float(self.test.statistic().max()) >= fraction

    def _ensure(self, k: int, in_alarm: bool) -> CusumBank:
        """The running test, started at sample k (in alarm: ``in_alarm``) if none."""
        if self.test is None:
            self.test = self._new_cusum(self.m)
            self.zero = self._start = k
            if in_alarm:
                self.test.start_in_alarm()
        return self.test

    def follow_model(self, k: int, misfit: _FloatArray, signature: _FloatArray) -> bool:
        """Test sample k's model misfit (z less the fitted fault's ``signature``); True
        when the test alarms: the model no longer fits, the fault is gone (``zero``
        dates its end) or outgrew it (``grew``)."""
        test = self._ensure(k, False)
        n = self._n_hist
        self._hist_c[k % n] = misfit
        self._hist_p[k % n] = float(misfit @ signature)
        if test.update(misfit):
            oldest = max(self._start, k - n + 1)
            self.zero = walk_back(test, self._hist_c, k, oldest, self._tol)
            self.grew = float(self._hist_p[np.arange(self.zero, k + 1) % n].sum()) > 0.0
            return True
        return False

    def follow_variance(self, k: int, z: _FloatArray) -> bool:
        """Test sample k's z for a noise increase (the test starts in alarm); True when
        it clears: the noise is back to nominal."""
        return not self._ensure(k, True).update(z)

    # ------------------------------------------------------------------------ state

    def get_state(self) -> dict[str, Any]:
        """The test's part of the diagnoser's state (deep copies)."""
        return {
            "presence": None if self.test is None else self.test.get_state(),
            "presence_zero": int(self.zero), "presence_start": int(self._start),
            "hist_c": self._hist_c.copy(), "hist_p": self._hist_p.copy(),
            "presence_grew": int(self.grew),
        }

    def check_state(self, state: dict[str, Any]) -> dict[str, Any]:
        """The test's part of a saved state, checked (ValueError; KeyError for a missing
        key)."""
        got: dict[str, Any] = {
            "hist_c": check_finite_array("state['hist_c']", state["hist_c"],
                                         shape=self._hist_c.shape),
            "hist_p": check_finite_array("state['hist_p']", state["hist_p"],
                                         shape=self._hist_p.shape),
            "presence_grew": bool(state["presence_grew"]),
            "presence_zero": int(state["presence_zero"]),
            "presence_start": int(state["presence_start"]),
            "presence": None,
        }
        if state["presence"] is not None:
            got["presence"] = self._new_cusum(self.m)
            got["presence"].set_state(state["presence"])
        return got

    def set_state(self, got: dict[str, Any]) -> None:
        """Install a state :meth:`check_state` returned."""
        self.test = got["presence"]
        self.zero, self._start = got["presence_zero"], got["presence_start"]
        self._hist_c, self._hist_p = got["hist_c"], got["hist_p"]
        self.grew = got["presence_grew"]
