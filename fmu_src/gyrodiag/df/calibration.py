"""The detection-filter channel's design and its fault-free calibration window.

:class:`DFDesign` is what the channel designed (plant, gain, sample period, initial
estimate); the functions here run it over the stored window: residuals, the initial
state that best explains the window, and the choice of the input/measurement alignment
(module notes of :mod:`gyrodiag.df.channel`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from .filter import DetectionFilter
from .generators import _gust_disturbance
from .gust import GustModel
from .residual import ResidualModel, estimate_sensor_variances
from .sensor_dynamics import SensorDynamics

__all__ = ["CalibrationWindow", "DFDesign", "alignment_score",
           "equalised_noise_variances", "initial_state", "window_pairs"]

_Array = NDArray[np.float64]

#: White-noise variance the residual model gives an equalised sensor, per unit of the
#: variance its noise G·v shows: the model's white noise must not undercut the data at
#: high frequencies, where G·v has almost nothing and the whitening looks hardest.
EQUALISED_NOISE_FACTOR = 10.0


@dataclass(frozen=True)
class DFDesign:
    """The channel's plant (A, B, C), detection-filter gain K, sample period T, initial
    estimate x0 and its streaming main filter (whose matrices the fits use)."""

    A: _Array
    B: _Array
    C: _Array
    K: _Array
    T: float
    x0: _Array
    monitor: DetectionFilter

    @property
    def n(self) -> int:
        """Number of states."""
        return self.A.shape[0]

    @property
    def p(self) -> int:
        """Number of inputs."""
        return self.B.shape[1]

    @property
    def m(self) -> int:
        """Number of sensors."""
        return self.C.shape[0]

    def new_filter(self) -> DetectionFilter:
        """A fresh detection filter of this design."""
        return DetectionFilter(self.A, self.B, self.C, self.K, self.T)

    def residuals(self, u: _Array, y: _Array, x_start: _Array | None = None) -> _Array:
        """Residuals of a fresh filter, started at ``x_start`` (default x0), over the
        rows of (u, y)."""
        f = self.new_filter()
        f.reset(self.x0 if x_start is None else x_start)
        return np.array([f.advance(u[j], y[j]) for j in range(u.shape[0])])


@dataclass(frozen=True)
class CalibrationWindow:
    """The aligned fault-free window a decision rule is installed from: inputs ``u``,
    measurements ``y``, the rows ``burn`` to skip, and the configured burn-in
    ``n_burn`` (samples; ``burn`` is it, shortened for a short window). ``raw``: the
    sensors as read, before a read-out equaliser (None without one)."""

    u: _Array
    y: _Array
    burn: int
    n_burn: int
    raw: _Array | None = None


def window_pairs(u: _Array, y: _Array, d: int) -> tuple[_Array, _Array]:
    """Aligned (u, y) rows of a stored window for alignment d."""
    if d > 0:
        return u[:-d], y[d:]
    if d < 0:
        return u[-d:], y[:d]
    return u, y


def initial_state(design: DFDesign, window: CalibrationWindow) -> _Array:
    """The state at the window's first sample that best explains it.

    A host seldom starts the plant and the Diagnoser on the same sample from the
    same state (with Gauss-Seidel the plant has already moved one step, at the
    elevator's first value, when the Diagnoser sees its first sample: 0.26 rad/s of
    q error on the seed loop); the observers' transient (slowest pole 1/s, and the
    whitening filters' 10 s) would count as noise. The residual is linear in the
    initial error: γ_k = γ_k(x0) − C Fᵏ Δx0; Δx0 by weighted least squares over the
    window (weights: each channel's residual spread after the burn-in)."""
    res = design.residuals(window.u, window.y)
    closed = design.monitor.closed_loop_matrix
    n, m = design.n, design.m
    n_rows = res.shape[0]
    weight = 1.0 / np.maximum(res[window.n_burn:].std(axis=0), 1e-300)
    blocks = np.empty((n_rows, m, n))
    power = np.eye(n)
    for k in range(n_rows):
        blocks[k] = design.C @ power
        power = closed @ power
    lhs = (blocks * weight[None, :, None]).reshape(-1, n)
    rhs = (res * weight[None, :]).reshape(-1)
    delta = np.linalg.lstsq(lhs, rhs, rcond=None)[0]
    return design.x0 + delta


def alignment_score(design: DFDesign, res: _Array, gust: GustModel | None) -> float:
    """Score of one pairing's residuals ``res`` (lower: whiter): the summed log
    variance, or with a gust model the innovations' −2 log-likelihood per sample."""
    if gust is None:
        var = res.var(axis=0, ddof=1)
        return float(np.sum(np.log(np.maximum(var, 1e-300))))
    return _innovation_score(design, res, gust)


def _innovation_score(design: DFDesign, res: _Array, gust: GustModel) -> float:
    """−2 log-likelihood per sample of residuals ``res`` under the gust model.

    In turbulence the raw residual's variance is mostly the gust's, and the pitch
    controller answers the gust, so a wrong pairing can look smaller there; the
    innovations of the model with the gust leave only what it cannot explain."""
    var = res.var(axis=0, ddof=1)
    plain = float(np.sum(np.log(np.maximum(var, 1e-300))))
    monitor = design.monitor
    model = ResidualModel(monitor.closed_loop_matrix, monitor.discrete_gain, design.C,
                          _gust_disturbance(gust, design.A, design.T, np.eye(design.n)))
    variances = estimate_sensor_variances(res, model)
    rms = np.sqrt(np.mean(res**2, axis=0))
    variances = np.maximum(variances, (1e-3 * rms + 1e-12) ** 2)
    try:
        w = model.whitening(variances)
    except (ValueError, np.linalg.LinAlgError):
        return plain
    s_inv = np.linalg.inv(w.S)
    closed, gain = w.F - w.K @ w.C, w.K
    e = np.zeros(w.F.shape[0])
    total = 0.0
    for r in res:
        eps = r - w.C @ e
        total += float(eps @ s_inv @ eps)
        e = closed @ e + gain @ r
    return total / res.shape[0] + float(np.linalg.slogdet(w.S)[1])


def equalised_noise_variances(window: CalibrationWindow, dynamics: SensorDynamics
                              ) -> _Array | None:
    """Sensor noise variances for the residual model with a read-out equaliser, from
    the raw window; None without one.

    The sensors the equaliser filters show G·v: smooth, hidden under a gust in the
    residual, so the residual fit cannot see it; raw, their white v is the rough part
    of a smooth signal: robust variance of the second differences over 6 (their
    variance per unit white noise), times G's noise gain and EQUALISED_NOISE_FACTOR.
    The dynamic sensor's own read-out noise is taken the same way, as is."""
    raw = window.raw
    if raw is None or raw.shape[0] - window.burn < 10:
        return None
    d2 = np.diff(raw[window.burn:], n=2, axis=0)
    mad = np.median(np.abs(d2 - np.median(d2, axis=0)), axis=0)
    white = (1.482602218505602 * mad) ** 2 / 6.0
    out = white * (dynamics.noise_gain * EQUALISED_NOISE_FACTOR)
    out[dynamics.sensor] = white[dynamics.sensor]
    return out
