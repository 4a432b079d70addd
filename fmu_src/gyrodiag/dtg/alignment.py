"""Alignment of the case rate with the DTG voltages (docs/dtg_case_rate.md §9).

The case-rate regression pairs the voltages of sample k with the case rate that drove
the rotor over that sample. A co-simulation master does not always deliver them so:
with Jacobi coupling (libcosim's default) the DTG plant sees the aircraft's rate one
step late, while the second gyro reaches the Diagnoser directly, so the case rate
arrives one sample *ahead* of the voltages it explains. At a manoeuvre edge the error
is the whole rate change of a step, and the ratio band alarms; between edges a wrong
pairing also biases θ beyond the ratio band (docs/notes.md, case-rate alignment).

:class:`CaseRateAligner` selects the pairing as a model-selection problem: for every
delay d = −``max_delay`` … ``max_delay`` of the case rate (d < 0: the case rate arrives
after the voltages it explains) it keeps the exponentially weighted normal equations of
the regression of both axes, and every ``check_every`` samples compares the residual sum
of squares of each candidate's *own* least-squares θ. A candidate replaces the pairing
in use when its RSS is below ``ratio`` times the current one's. Each candidate fits its
own θ, so a θ that has absorbed a wrong pairing cannot make that pairing look right, and
no reference is needed: the rule works from the first samples, before the learning
window. A physical fault changes θ, not the pairing, and every candidate refits alike.

Measured (library system chain, RSS over 1 s, relative to the right pairing): the
nearest wrong one 1.0025-1.03 in calm air, 1.02-1.09 in a sweep in σ_w 0.77 m/s, 1.14-1.24
in σ_w 1.5; an edge raises a wrong one's to several times the right one's within a few
samples. The rows of the regression are linear in the signals, so the rows of candidate
d are the voltage part of sample k − D plus the case-rate part of sample k − D − d (each
computed once per sample). The channel runs the aligner ``lookahead`` samples ahead of
its estimators, so that a new pairing applies before the edge that revealed it reaches
them.
"""

from __future__ import annotations

from collections import deque
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ..common._validation import check_finite_array, check_in_range, check_int, check_positive
from .case_rate import CaseRateDTGRegressor, CaseRateScheme

__all__ = ["CaseRateAligner"]

_WIDTH = 6  # five regressors and the target


class CaseRateAligner:
    """Choose the delay of the case rate against the DTG voltages from the data.

    Parameters
    ----------
    sample_period_s : float
        Sample period T, s.
    pickoff_scale : float
        Nominal pick-off scale KT, rad/V (as the channel's regression).
    scheme : {"central", "paper"}
        Discretisation of the case-rate regression.
    max_delay : int
        Largest |d| tried, samples (≥ 1).
    delay : int
        Delay in use at the start, samples (−``max_delay`` … ``max_delay``).
    window_samples : int
        Memory of the normal equations (forgetting 1 − 1/window), samples.
    ratio : float
        A candidate replaces the delay in use when its RSS is below ``ratio`` times the
        current one's (0 < ratio < 1).
    check_every : int
        Samples between comparisons.
    hold_samples : int
        After a switch no other for this long, samples (the transient after an edge
        has model errors of its own, 10-35 times the noise for ~0.3 s in calm air).

    Notes
    -----
    :meth:`update` takes one *prefiltered* sample (the channel's prefilter is linear and
    the same on every signal, so delaying the filtered case rate equals filtering the
    delayed one). The candidates are compared ``max_delay`` samples back (a negative
    delay needs the case rate of later samples), so the caller must hold its estimators
    at least that far behind.
    """

    def __init__(self, sample_period_s: float, pickoff_scale: float = 1.0e-3, *,
                 scheme: CaseRateScheme = "central", max_delay: int = 2, delay: int = 0,
                 window_samples: int = 1000, ratio: float = 0.98, check_every: int = 4,
                 hold_samples: int = 500) -> None:
        self.sample_period_s = check_positive("sample_period_s", sample_period_s)
        self.max_delay = check_int("max_delay", max_delay, minimum=1)
        self.initial_delay = check_int("delay", delay, minimum=-self.max_delay)
        if self.initial_delay > self.max_delay:
            raise ValueError(f"delay must be in [-max_delay, max_delay] "
                             f"([{-self.max_delay}, {self.max_delay}]), got {delay!r}")
        self.window_samples = check_int("window_samples", window_samples, minimum=10)
        self.ratio = check_in_range("ratio", ratio, 0.0, 1.0, low_open=True, high_open=True)
        self.check_every = check_int("check_every", check_every, minimum=1)
        self.hold_samples = check_int("hold_samples", hold_samples)
        self._voltages = CaseRateDTGRegressor(sample_period_s, pickoff_scale, scheme=scheme)
        self._rates = CaseRateDTGRegressor(sample_period_s, pickoff_scale, scheme=scheme)
        self.reset()

    @property
    def n_candidates(self) -> int:
        """Number of delays tried (2·max_delay + 1)."""
        return 2 * self.max_delay + 1

    def reset(self) -> None:
        """Forget everything; the delay returns to the initial one."""
        D = self.max_delay
        self._voltages.reset()
        self._rates.reset()
        # rows [φ, y] of both axes: the voltage part of the last D + 1 samples and the
        # case-rate part of the last 2D + 1, newest first
        self._volt_rows: deque[NDArray[np.float64]] = deque(maxlen=D + 1)
        self._rate_rows: deque[NDArray[np.float64]] = deque(maxlen=2 * D + 1)
        # normal equations per candidate (index d + D) and axis
        self._normal = np.zeros((2 * D + 1, 2, _WIDTH, _WIDTH))
        self._seen = 0
        self._hold = 0
        self.delay = self.initial_delay
        self.switches = 0
        self._rss = np.zeros(2 * D + 1)

    def restart(self) -> None:
        """Forget the sample history (a skipped sample), keep the normal equations and
        the delay."""
        self._voltages.reset()
        self._rates.reset()
        self._volt_rows.clear()
        self._rate_rows.clear()

    @property
    def rss(self) -> NDArray[np.float64]:
        """RSS of each candidate at the last comparison, d = −D … D (copy)."""
        return self._rss.copy()

    def update(self, sample: tuple[float, ...]) -> int:
        """Push one prefiltered sample (Utx, Uty, Ux, Uy, ωx, ωy) and return the delay.

        Parameters
        ----------
        sample : tuple of 6 floats
            Prefiltered voltages (V) and case rates (rad/s), unchecked (the channel has
            checked them).
        """
        tx, ty, ux, uy, wx, wy = sample
        rows_v = self._voltages.update(tx, ty, ux, uy, 0.0, 0.0, validate=False)
        rows_w = self._rates.update(0.0, 0.0, 0.0, 0.0, wx, wy, validate=False)
        if rows_v is None or rows_w is None:
            return self.delay
        self._volt_rows.appendleft(_stack(rows_v))
        self._rate_rows.appendleft(_stack(rows_w))
        D = self.max_delay
        if len(self._rate_rows) <= 2 * D:
            return self.delay
        # sample k − D against the case rate of sample k − D − d, d = j − D
        z = self._volt_rows[D][None, :, :] + np.array(self._rate_rows)
        lam = 1.0 - 1.0 / self.window_samples
        self._normal *= lam
        self._normal += z[:, :, :, None] * z[:, :, None, :]
        self._seen += 1
        if self._hold:
            self._hold -= 1
        if (self._hold or self._seen < self.window_samples // 2
                or self._seen % self.check_every):
            return self.delay
        self._rss = rss = _rss(self._normal)
        best = int(np.argmin(rss))
        now = self.delay + D
        if best != now and rss[best] < self.ratio * rss[now]:
            self.delay = best - D
            self.switches += 1
            self._hold = self.hold_samples
        return self.delay

    def get_state(self) -> dict[str, Any]:
        """Copy of the state (histories, normal equations, delay)."""
        return {"voltages": self._voltages.get_state(), "rates": self._rates.get_state(),
                "volt_rows": np.array(self._volt_rows, dtype=float).reshape(-1, 2, _WIDTH),
                "rate_rows": np.array(self._rate_rows, dtype=float).reshape(-1, 2, _WIDTH),
                "normal": self._normal.copy(), "rss": self._rss.copy(), "seen": self._seen,
                "hold": self._hold, "delay": self.delay, "switches": self.switches}

    def set_state(self, state: dict[str, Any]) -> None:
        """Restore a state produced by :meth:`get_state` of an identical aligner."""
        D = self.max_delay
        n = 2 * D + 1
        normal = check_finite_array("state['normal']", state["normal"],
                                    shape=(n, 2, _WIDTH, _WIDTH))
        rss = check_finite_array("state['rss']", state["rss"], shape=(n,))
        volt = check_finite_array("state['volt_rows']", state["volt_rows"], ndim=3)
        rate = check_finite_array("state['rate_rows']", state["rate_rows"], ndim=3)
        for name, arr, most in (("volt_rows", volt, D + 1), ("rate_rows", rate, n)):
            if arr.shape[0] > most or arr.shape[1:] != (2, _WIDTH):
                raise ValueError(f"state[{name!r}] must have shape (≤ {most}, 2, {_WIDTH}), "
                                 f"got {arr.shape}")
        delay = int(state["delay"])
        if not -D <= delay <= D:
            raise ValueError(f"state['delay'] must be in [{-D}, {D}], got {delay}")
        self._voltages.set_state(state["voltages"])
        self._rates.set_state(state["rates"])
        self._volt_rows = deque((r.copy() for r in volt), maxlen=D + 1)
        self._rate_rows = deque((r.copy() for r in rate), maxlen=n)
        self._normal = normal.copy()
        self._rss = rss.copy()
        self._seen = int(state["seen"])
        self._hold = int(state["hold"])
        self.delay = delay
        self.switches = int(state["switches"])


def _stack(rows: tuple[Any, float, Any, float]) -> NDArray[np.float64]:
    phi_x, y_x, phi_y, y_y = rows
    out = np.empty((2, _WIDTH))
    out[0, :5] = phi_x
    out[0, 5] = y_x
    out[1, :5] = phi_y
    out[1, 5] = y_y
    return out


def _rss(normal: NDArray[np.float64]) -> NDArray[np.float64]:
    """Residual sum of squares of each candidate's least-squares θ, summed over the
    axes, from the normal equations [[ΦᵀΦ, Φᵀy], [yᵀΦ, yᵀy]]."""
    a = normal[..., :5, :5]
    b = normal[..., :5, 5]
    c = normal[..., 5, 5]
    # a tiny ridge: the regressors of a gyro at rest are nearly collinear
    scale = np.trace(a, axis1=-2, axis2=-1)[..., None, None] * 1e-12 + 1e-300
    theta = np.linalg.solve(a + scale * np.eye(5), b[..., None])[..., 0]
    rss = c - np.einsum("...i,...i->...", b, theta)
    return np.maximum(rss, 0.0).sum(axis=-1)
