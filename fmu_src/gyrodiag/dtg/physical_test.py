"""GLR test of the DTG's physical parameters: spin rate and torquer scale.

A spin change scales θ3 and θ4 of both axes by the spin fraction, a torquer scale
change θ5 (docs/methods.md §2). The test fits both fractions jointly, over windows of
1 to 10 s ending now, against a θ0 of its own, and alarms on the χ² (2 degrees of
freedom) of the fit. Its signals pass a narrow band-pass first (a fifth of the channel's
cut-off, high-pass at a fiftieth): the rotor's response to the dither is there, while
broadband noise and slow signal faults (offsets, drifts) are not. The score's spread
is measured on the learning window's blocks and refined by quiet blocks later, so
that coloured errors are judged by what they are, not by the textbook LS covariance.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ..common.prefilter import ButterworthPrefilter, ringing_samples
from .case_rate import CaseRateDTGRegressor
from .model import N_THETA, DTGRegressor

__all__ = ["PHYSICAL_KINDS", "PHYSICAL_SIGMA", "PhysicalResult", "PhysicalTest"]

#: The two parameter directions fitted, in this order.
PHYSICAL_KINDS = ("spin", "torquer")
#: Default alarm threshold, standard errors (χ² against its square).
PHYSICAL_SIGMA = 7.0
#: Block length of the scores, s.
BLOCK_S = 0.1
#: Test windows ending at the newest block, s.
WINDOWS_S = (1.0, 2.0, 5.0, 10.0)
#: The exceedance must hold this long before the test alarms, s: a signal fault reaches
#: the residual tests first, and those hold this test.
CONFIRM_S = 0.5
#: An alarm holds while the χ² stays beyond this fraction of the threshold (in standard
#: errors), so that the windows' fluctuation after an onset does not flicker it.
HOLD_FRACTION = 2.0 / 3.0
#: The band-pass corners as fractions of the channel's prefilter cut-off.
LOWPASS_FRACTION = 0.2
HIGHPASS_FRACTION = 0.02
#: The axes agree on a common shift while the χ² of their disagreement (2 degrees of
#: freedom) stays below this, or below this share of the whole χ².
AXES_AGREE_CHI2 = 9.21
AXES_AGREE_SHARE = 0.1
#: Blocks of a hold before :meth:`PhysicalTest.axis_evidence` answers (1 s).
HELD_MIN_BLOCKS = 10
#: Direction masks on θ (θ3, θ4 for the spin; θ5 for the torquer).
_MASKS = np.array([[0.0, 0.0, 1.0, 1.0, 0.0], [0.0, 0.0, 0.0, 0.0, 1.0]])


@dataclass(frozen=True)
class PhysicalResult:
    """The test's verdict at a block end.

    Attributes
    ----------
    alarm : bool
        The χ² exceeded the threshold for the confirmation time.
    kind : str
        "spin" or "torquer" (the better-determined shift common to both axes), ""
        without one or where the axes disagree (not a change of the rotor's spin or of
        the torquer scale: e.g. noise on one torquer read-out).
    ratio : float
        Estimated parameter ratio of ``kind`` (1 + fitted fraction), NaN without one.
    chi2 : float
        Largest χ² of the windows, 0 before the test runs.
    """

    alarm: bool = False
    kind: str = ""
    ratio: float = math.nan
    chi2: float = 0.0


class PhysicalTest:
    """Streaming GLR of a spin and a torquer scale change.

    Parameters
    ----------
    sample_period_s : float
        Sample period, s.
    cutoff_hz : float
        The channel's prefilter cut-off, Hz (the band-pass follows it).
    learn_start_s, learn_end_s : float
        The learning window, s from the first sample.
    sigma : float
        Alarm threshold, standard errors (> 0).
    case_rate : {"central", "paper"} or None
        The case-rate regression's scheme (samples then carry ωx, ωy, rad/s, after the
        voltages), None for the case at rest. Spin and torquer scale move the same θ
        components in every scheme.
    pickoff_scale : float
        Nominal pick-off scale KT, rad/V (case rate only).
    """

    def __init__(self, sample_period_s: float, cutoff_hz: float, learn_start_s: float,
                 learn_end_s: float, sigma: float = PHYSICAL_SIGMA,
                 case_rate: str | None = None, pickoff_scale: float = 1e-3) -> None:
        T = float(sample_period_s)
        self.T = T
        self._case_rate = case_rate
        self._pickoff_scale = pickoff_scale
        self._width = 4 if case_rate is None else 6
        self._lowpass = LOWPASS_FRACTION * cutoff_hz
        self._highpass = HIGHPASS_FRACTION * cutoff_hz
        self._nb = max(1, round(BLOCK_S / T))
        block = self._nb * T
        self._windows = sorted({max(1, round(w / block)) for w in WINDOWS_S})
        self._confirm = max(1, round(CONFIRM_S / block))
        self._n_start = math.ceil(learn_start_s / T - 1e-9)
        self._n_end = max(math.ceil(learn_end_s / T - 1e-9), self._n_start + 1)
        # the χ² tail (4 degrees of freedom) beyond σ²: the false-alarm rate per window
        h2 = float(sigma) ** 2
        self._h2 = h2
        self._log_alpha = -0.5 * h2 + math.log1p(0.5 * h2)
        hold2 = (HOLD_FRACTION * float(sigma)) ** 2
        self._log_alpha_hold = -0.5 * hold2 + math.log1p(0.5 * hold2)
        self._settle = ringing_samples(self._filter(), 20000)
        self.reset()

    def _filter(self) -> ButterworthPrefilter:
        return ButterworthPrefilter(6, self._lowpass, 1.0 / self.T, self._width,
                                    highpass_hz=self._highpass)

    def _make_regressor(self) -> DTGRegressor | CaseRateDTGRegressor:
        if self._case_rate is None:
            return DTGRegressor()
        return CaseRateDTGRegressor(self.T, self._pickoff_scale,
                                    scheme=self._case_rate)  # type: ignore[arg-type]

    def reset(self, samples: int = 0) -> None:
        """Return to the state right after construction, or as if ``samples`` samples
        had passed unseen (a learning window already past leaves the test quiet)."""
        self._prefilter = self._filter()
        self._regressor = self._make_regressor()
        self._n = int(samples)
        self._rows: list[tuple[float, ...]] = []
        self._skip = 0  # rows still to leave out (after a gap or a hold)
        self._learn: list[tuple[NDArray[np.float64], NDArray[np.float64]]] = []
        self._theta0: NDArray[np.float64] | None = None  # (2, 5)
        self._dirs: NDArray[np.float64] | None = None  # (2 kinds, 2 axes, 5)
        self._V: NDArray[np.float64] | None = None  # score covariance per block (2, 2)
        self._nV = 0
        self._ML: NDArray[np.float64] | None = None  # learning window's information
        self._nL = 0
        self._scores: deque[tuple[NDArray[np.float64], NDArray[np.float64]]] = deque(
            maxlen=self._windows[-1])
        self._streak = 0
        self.result = PhysicalResult()
        self._clear_held()
        self._holding = False

    def _clear_held(self) -> None:
        self._held_rows: list[tuple[float, ...]] = []
        self._held_skip = self._settle
        self._held_S = np.zeros(4)
        self._held_info = np.zeros((4, 4))
        self._held_n = 0
        self._evidence: tuple[int, tuple[float, float] | None] = (0, None)

    @property
    def ready(self) -> bool:
        """θ0 and the score spread are known."""
        return self._V is not None

    def standard_errors(self, window_s: float) -> NDArray[np.float64] | None:
        """Predicted standard errors of the spin and torquer fractions common to both
        axes over a window of ``window_s`` ending now (the reference's error included),
        at the learning window's excitation; None before θ0 and the spread are known."""
        if self._V is None or self._ML is None:
            return None
        w = max(1, round(window_s / (self._nb * self.T)))
        Mi = np.linalg.inv(self._ML * (w / self._nL))
        ref = self._nL * _sandwich(np.linalg.inv(self._ML), self._V)
        F = _H.T @ np.linalg.inv(_sandwich(Mi, w * self._V) + ref) @ _H
        return np.sqrt(np.diag(np.linalg.inv(F)))

    def window_fit(self, window_s: float
                   ) -> tuple[NDArray[np.float64], NDArray[np.float64]] | None:
        """The spin and torquer fractions common to both axes over the last
        ``window_s`` of blocks, and their covariance; None before a full window."""
        w = max(1, round(window_s / (self._nb * self.T)))
        if self._V is None or self._ML is None or len(self._scores) < w:
            return None
        recent = list(self._scores)[-w:]
        ref = self._nL * _sandwich(np.linalg.inv(self._ML), self._V)
        fit = _fit(sum(s for s, _ in recent), sum(i for _, i in recent), w * self._V, ref)
        return None if fit is None else (fit.delta, fit.cov)

    # -- streaming ------------------------------------------------------------
    def gap(self) -> None:
        """A skipped sample: the rows spanning it are left out."""
        self._skip = max(self._skip, 2)

    def update(self, sample: tuple[float, ...], held: bool) -> None:
        """Process one sample of finite values: (Utx, Uty, Ux, Uy) in V, then with the
        case rate (ωx, ωy) in rad/s. Any LTI filter applied to all of them alike (the
        channel's prefilter) keeps the regression.

        ``held``: another test is in alarm; the windows restart once it clears and the
        band-pass has settled.
        """
        n = self._n
        self._n += 1
        filtered = self._prefilter.step(sample)
        if self._case_rate is None:
            rows = self._regressor.step(*filtered)  # type: ignore[union-attr]
        else:
            rows = self._regressor.update(*filtered, validate=False)  # type: ignore[call-arg]
        if held and n >= self._n_end:
            if not self._holding:
                self._clear_held()
            self._hold()
            self._holding = True
            self._held_row(rows)
            return
        self._holding = False
        if n == self._n_start or n == self._n_end:
            self._rows = []
        if rows is None or n < self._n_start:
            return
        if self._skip > 0:
            self._skip -= 1
            return
        px, yx, py, yy = rows
        self._rows.append((*px, yx, *py, yy))  # type: ignore[arg-type]
        if len(self._rows) == self._nb:
            self._end_block(n)

    def _held_row(self, rows: Any) -> None:
        """Accumulate the hold's own fit (no alarm from it): which axis's θ moved."""
        if rows is None or self._theta0 is None or self._V is None:
            return
        if self._held_skip > 0:
            self._held_skip -= 1
            return
        px, yx, py, yy = rows
        self._held_rows.append((*px, yx, *py, yy))
        if len(self._held_rows) == self._nb:
            S, info = self._score(*_block_sums(self._held_rows))
            self._held_rows = []
            self._held_S = self._held_S + S
            self._held_info = self._held_info + info
            self._held_n += 1

    def axis_evidence(self) -> tuple[float, float] | None:
        """Largest |z| of the spin and torquer fractions on the x axis and on the y axis,
        fitted over the current hold (another test in alarm); None before a second of
        it. Noise on one read-out attenuates one axis's θ (Ux: x; Utx: y)."""
        if self._held_n < HELD_MIN_BLOCKS or self._V is None or self._ML is None:
            return None
        if self._evidence[0] == self._held_n:  # asked every sample, changes per block
            return self._evidence[1]
        self._evidence = (self._held_n, self._axis_evidence())
        return self._evidence[1]

    def _axis_evidence(self) -> tuple[float, float] | None:
        assert self._V is not None and self._ML is not None
        try:
            Mi = np.linalg.inv(self._held_info)
            ref = self._nL * _sandwich(np.linalg.inv(self._ML), self._V)
            var = np.diag(_sandwich(Mi, self._held_n * self._V) + ref)
        except np.linalg.LinAlgError:
            return None
        z = np.abs(Mi @ self._held_S) / np.sqrt(var)
        if not np.all(np.isfinite(z)):
            return None
        return float(max(z[0], z[1])), float(max(z[2], z[3]))

    def _hold(self) -> None:
        self._rows = []
        self._scores.clear()
        self._streak = 0
        self._skip = self._settle
        self.result = PhysicalResult(chi2=0.0)

    def _end_block(self, n: int) -> None:
        A, r = _block_sums(self._rows)
        self._rows = []
        if n < self._n_end:
            self._learn.append((A, r))
            if n + self._nb >= self._n_end:
                self._finish_learning()
            return
        if self._V is None:
            return
        self._push(*self._score(A, r))

    def _score(self, A: NDArray[np.float64], r: NDArray[np.float64]
               ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Score (4,) and information (4, 4) of one block against θ0: both directions
        on the x axis, then on the y axis (the information is block-diagonal)."""
        assert self._theta0 is not None and self._dirs is not None
        e = r - np.einsum("aij,aj->ai", A, self._theta0)
        G = self._dirs
        score = np.einsum("dai,ai->ad", G, e).ravel()
        per_axis = np.einsum("dai,aij,eaj->ade", G, A, G)
        info = np.zeros((4, 4))
        info[:2, :2] = per_axis[0]
        info[2:, 2:] = per_axis[1]
        return score, info

    def _finish_learning(self) -> None:
        """θ0 per axis and the score spread from the learning blocks."""
        blocks, self._learn = self._learn, []
        if len(blocks) < 3:
            return
        A = sum(b[0] for b in blocks)
        r = sum(b[1] for b in blocks)
        try:
            theta0 = np.array([np.linalg.solve(A[ax], r[ax]) for ax in range(2)])
        except np.linalg.LinAlgError:
            return
        dirs = theta0[None, :, :] * _MASKS[:, None, :]
        if not np.all(np.isfinite(theta0)) or np.any(np.abs(dirs).sum(axis=2) == 0.0):
            return
        self._theta0, self._dirs = theta0, dirs
        scores = [self._score(*b) for b in blocks]
        S = np.array([s for s, _ in scores])
        ML = sum(i for _, i in scores)
        V = S.T @ S / (len(blocks) - 1)
        if not (_positive_definite(ML) and _positive_definite(V)):
            self._theta0 = self._dirs = None
            return
        self._V, self._nV, self._ML, self._nL = V, len(blocks) - 1, ML, len(blocks)

    def _exceeds(self, t2: float, hold: bool = False) -> bool:
        """``t2`` lies beyond the threshold's (or the hold level's) tail probability,
        judged as Hotelling's T² of a spread estimated with ``nV`` degrees of freedom
        (χ² as nV grows)."""
        level = self._log_alpha_hold if hold else self._log_alpha
        return _log_t2_tail(t2, self._nV) < level

    def _push(self, S: NDArray[np.float64], info: NDArray[np.float64]) -> None:
        """Add a block's score; test every full window; refine the spread with the block
        that leaves the longest window unless the test exceeds its threshold."""
        assert self._V is not None and self._ML is not None
        if (len(self._scores) == self._scores.maxlen and not self.result.alarm
                and not self._exceeds(self.result.chi2)):
            old = self._scores[0][0]
            self._V = (self._V * self._nV + np.outer(old, old)) / (self._nV + 1)
            self._nV += 1
        self._scores.append((S, info))
        best: _Fit | None = None
        ref = self._nL * _sandwich(np.linalg.inv(self._ML), self._V)
        k = len(self._scores)
        s_sum = np.zeros(4)
        i_sum = np.zeros((4, 4))
        w_index = 0
        for j in range(1, k + 1):
            s, info_j = self._scores[k - j]
            s_sum = s_sum + s
            i_sum = i_sum + info_j
            if w_index < len(self._windows) and j == self._windows[w_index]:
                w_index += 1
                fit = _fit(s_sum, i_sum, j * self._V, ref)
                if fit is not None and (best is None or fit.chi2 > best.chi2):
                    best = fit
        chi2 = 0.0 if best is None else best.chi2
        if self._exceeds(chi2):
            self._streak += 1
        elif not (self.result.alarm and self._exceeds(chi2, hold=True)):
            self._streak = 0
        if best is None:
            self.result = PhysicalResult(chi2=chi2)
            return
        alarm = self._streak >= self._confirm
        if not best.common:
            self.result = PhysicalResult(alarm=alarm, chi2=chi2)
            return
        z = np.abs(best.delta) / np.sqrt(np.diag(best.cov))
        kind = int(np.argmax(z))
        self.result = PhysicalResult(alarm=alarm, kind=PHYSICAL_KINDS[kind],
                                     ratio=1.0 + float(best.delta[kind]), chi2=chi2)

    # -- state ----------------------------------------------------------------
    def get_state(self) -> dict[str, Any]:
        """Internal state (filters, learning blocks, reference, windows, verdict)."""
        return {
            "prefilter": self._prefilter.get_state(),
            "regressor": self._regressor.get_state(),
            "n": self._n, "rows": [list(r) for r in self._rows], "skip": self._skip,
            "learn": [(A.tolist(), r.tolist()) for A, r in self._learn],
            "theta0": None if self._theta0 is None else self._theta0.tolist(),
            "V": None if self._V is None else self._V.tolist(), "nV": self._nV,
            "ML": None if self._ML is None else self._ML.tolist(), "nL": self._nL,
            "scores": [(s.tolist(), i.tolist()) for s, i in self._scores],
            "streak": self._streak,
            "result": [self.result.alarm, self.result.kind, self.result.ratio,
                       self.result.chi2],
            "held": {"holding": self._holding, "rows": [list(r) for r in self._held_rows],
                     "skip": self._held_skip, "S": self._held_S.tolist(),
                     "info": self._held_info.tolist(), "n": self._held_n},
        }

    def set_state(self, state: dict[str, Any]) -> None:
        """Restore a state of :meth:`get_state` (same configuration)."""
        self._prefilter.set_state(state["prefilter"])
        self._regressor.set_state(state["regressor"])
        self._n = int(state["n"])
        self._rows = [tuple(float(v) for v in r) for r in state["rows"]]
        self._skip = int(state["skip"])
        self._learn = [(np.array(A, dtype=float), np.array(r, dtype=float))
                       for A, r in state["learn"]]
        t0 = state["theta0"]
        self._theta0 = None if t0 is None else np.array(t0, dtype=float).reshape(2, N_THETA)
        self._dirs = (None if self._theta0 is None
                      else self._theta0[None, :, :] * _MASKS[:, None, :])
        self._V = None if state["V"] is None else np.array(state["V"], dtype=float)
        self._nV = int(state["nV"])
        self._ML = None if state["ML"] is None else np.array(state["ML"], dtype=float)
        self._nL = int(state["nL"])
        self._scores.clear()
        for s, i in state["scores"]:
            self._scores.append((np.array(s, dtype=float), np.array(i, dtype=float)))
        self._streak = int(state["streak"])
        alarm, kind, ratio, chi2 = state["result"]
        self.result = PhysicalResult(bool(alarm), str(kind), float(ratio), float(chi2))
        held = state["held"]
        self._clear_held()
        self._holding = False
        if held is not None:
            self._holding = bool(held["holding"])
            self._held_rows = [tuple(float(v) for v in r) for r in held["rows"]]
            self._held_skip = int(held["skip"])
            self._held_S = np.array(held["S"], dtype=float).reshape(4)
            self._held_info = np.array(held["info"], dtype=float).reshape(4, 4)
            self._held_n = int(held["n"])


def _block_sums(rows: list[tuple[float, ...]]
                ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Per axis, the normal matrix (5, 5) and right-hand side (5,) of a block's rows."""
    a = np.array(rows)
    A = np.stack([a[:, 0:5].T @ a[:, 0:5], a[:, 6:11].T @ a[:, 6:11]])
    r = np.stack([a[:, 0:5].T @ a[:, 5], a[:, 6:11].T @ a[:, 11]])
    return A, r


def _sandwich(Mi: NDArray[np.float64], V: NDArray[np.float64]) -> NDArray[np.float64]:
    return Mi @ V @ Mi


@dataclass(frozen=True)
class _Fit:
    """A window's fit: the χ² of both axes' shifts (4 degrees of freedom), the shift
    common to both axes (spin, torquer) and its covariance, and whether the axes agree
    on it (a spin or torquer scale change moves both alike)."""

    chi2: float
    delta: NDArray[np.float64]
    cov: NDArray[np.float64]
    common: bool


#: The common shift seen from both axes' four components.
_H = np.array([[1.0, 0.0], [0.0, 1.0], [1.0, 0.0], [0.0, 1.0]])


def _fit(s: NDArray[np.float64], info: NDArray[np.float64], V: NDArray[np.float64],
         ref: NDArray[np.float64]) -> _Fit | None:
    """Both axes' fractions of a window (covariance: window plus reference), their χ²
    and the generalised-LS shift common to both axes."""
    try:
        Mi = np.linalg.inv(info)
        d4 = Mi @ s
        Ci = np.linalg.inv(_sandwich(Mi, V) + ref)
        F = _H.T @ Ci @ _H
        cov = np.linalg.inv(F)
        delta = cov @ (_H.T @ Ci @ d4)
    except np.linalg.LinAlgError:
        return None
    chi2 = float(d4 @ Ci @ d4)
    disagree = chi2 - float(delta @ F @ delta)
    if not (math.isfinite(chi2) and math.isfinite(disagree)):
        return None
    return _Fit(chi2, delta, cov, disagree <= max(AXES_AGREE_CHI2, AXES_AGREE_SHARE * chi2))


def _log_t2_tail(t2: float, nu: int, p: int = 4) -> float:
    """log P(T² > t2) for Hotelling's T² of dimension 4 with a covariance estimated with
    ``nu`` degrees of freedom: T²·m/(p·ν) is F(4, m), m = ν − 3, whose tail has the
    closed form x^(m/2)·(1 + m/2·(1 − x)), x = m/(m + 4F)."""
    m = nu - p + 1
    if m < 1:
        return 0.0
    f = t2 * m / (p * nu)
    x = m / (m + p * f)
    return 0.5 * m * math.log(x) + math.log1p(0.5 * m * (1.0 - x))


def _positive_definite(M: NDArray[np.float64]) -> bool:
    try:
        np.linalg.cholesky(M)
    except np.linalg.LinAlgError:
        return False
    return bool(np.all(np.isfinite(M)))
