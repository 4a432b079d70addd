"""The fault-free residual of a discrete observer as a linear model of sensor noise, and
the filter that whitens it.

An observer ``x̂_{k+1} = Φ x̂_k + Γ u_k + L (y_k − C x̂_k)`` of a plant that its model
describes exactly (same Φ, Γ, C, inputs aligned) has the error ``e = x − x̂`` and the
residual ``r = y − C x̂``::

    e_{k+1} = F e_k − L v_k,    r_k = C e_k + v_k,    F = Φ − L C,

driven only by the sensor noise ``v`` (white, covariance R). The residual is therefore a
known Gaussian process given R: :class:`ResidualModel` gives its covariance, the map from
sensor variances to residual variances (to estimate R from a fault-free window,
:func:`estimate_sensor_variances`), and its innovations form (:class:`Whitening`): the
steady-state one-step predictor of ``r`` from its own past, whose prediction error
``ε = r − C ê`` is white with covariance S. The detection filter's residual is
slightly coloured (docs/methods.md §4: lag-1 autocorrelation 0.06 on q, but a long-run variance
5.3 times the variance, which is what a CUSUM integrates); the whitened residual makes
the CUSUM thresholds of :mod:`gyrodiag.common.cusum` exact.

Sensors that no other sensor observes (v, h of the seed aircraft) give residual channels
with no power at frequency 0 (a constant offset of them is a state, docs/methods.md §4): their
innovations form has a zero on the unit circle and no stable whitening filter. The
model is therefore regularised by an extra white noise of ``regularisation``·R on the
residual: the whitening filter is stable, and the real (unregularised) residual comes
out of it slightly *below* unit variance at low frequencies, i.e. on the safe side of
the false-alarm rate.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.linalg
from numpy.typing import ArrayLike, NDArray

from ..common._validation import check_finite_array, check_in_range

#: Lags (samples) whose autocovariances separate a disturbance from sensor noise.
DISTURBANCE_LAGS = (0, 1, 2, 3, 5, 8, 13, 21)

__all__ = ["Disturbance", "ResidualModel", "Whitening", "estimate_sensor_variances"]

_FloatArray = NDArray[np.float64]


@dataclass(frozen=True)
class Whitening:
    """Steady-state innovations filter of a residual: ê_{k+1} = F ê_k + K ε_k,
    ε_k = r_k − C ê_k.

    Attributes
    ----------
    F, C : ndarray
        The residual model's error matrix and output matrix.
    K : ndarray, shape (n, m)
        Gain of the innovations filter.
    S : ndarray, shape (m, m)
        Covariance of ε under the (regularised) model, residual units squared.
    scale : ndarray, shape (m,)
        √diag(S): divide ε by it for unit-variance channels.
    """

    F: _FloatArray
    C: _FloatArray
    K: _FloatArray
    S: _FloatArray
    scale: _FloatArray

    @property
    def closed_loop(self) -> _FloatArray:
        """F − K C, the dynamics of the whitening filter (stable)."""
        return self.F - self.K @ self.C


@dataclass(frozen=True)
class Disturbance:
    """A coloured disturbance that drives the observer error: e⁺ = F e + G g + …,
    g⁺ = Fd g + w_g, with Q the covariance of the white noise [w_e; w_g] it adds to
    [e; g] per sample (e.g. :meth:`gyrodiag.df.gust.GustModel.discrete`).

    Attributes
    ----------
    G : ndarray, shape (n, d)
    Fd : ndarray, shape (d, d)
        Stable disturbance dynamics.
    Q : ndarray, shape (n + d, n + d)
    """

    G: _FloatArray
    Fd: _FloatArray
    Q: _FloatArray

    def check(self, n: int) -> None:
        """Raise ValueError unless the shapes fit an n-state error and Fd is stable."""
        d = self.Fd.shape[0]
        if self.G.shape != (n, d) or self.Fd.shape != (d, d) or self.Q.shape != (n + d,) * 2:
            raise ValueError(f"disturbance shapes G {self.G.shape}, Fd {self.Fd.shape}, "
                             f"Q {self.Q.shape} do not fit {n} states")
        radius = float(np.max(np.abs(np.linalg.eigvals(self.Fd)), initial=0.0))
        if not radius < 1.0:
            raise ValueError(f"disturbance Fd must be stable, spectral radius {radius:.6g}")


class ResidualModel:
    """Fault-free residual of a discrete observer: e⁺ = F e − L v, r = C e + v.

    Parameters
    ----------
    F : array_like, shape (n, n)
        Error dynamics Φ − L C (stable, spectral radius < 1).
    L : array_like, shape (n, m)
        Observer gain.
    C : array_like, shape (m, n)
        Output matrix of the sensors the observer uses.
    disturbance : Disturbance, optional
        A coloured process disturbance (e.g. turbulence) that also drives e; the
        whitening then models it (the innovations of the plant's Kalman filter
        augmented with the disturbance).
    """

    def __init__(self, F: ArrayLike, L: ArrayLike, C: ArrayLike,
                 disturbance: Disturbance | None = None) -> None:
        f = check_finite_array("F", F, ndim=2)
        n = f.shape[0]
        if f.shape != (n, n):
            raise ValueError(f"F must be square, got shape {f.shape}")
        c = check_finite_array("C", C, shape=(None, n))
        m = c.shape[0]
        gain = check_finite_array("L", L, shape=(n, m))
        radius = float(np.max(np.abs(np.linalg.eigvals(f)), initial=0.0))
        if not radius < 1.0:
            raise ValueError(f"F must be stable (spectral radius < 1), got {radius:.6g}")
        self.F, self.L, self.C = f, gain, c
        self.n, self.m = n, m
        self.disturbance = disturbance
        # augmented state [e; g]: the disturbance state g drives e and is not observed
        d = 0 if disturbance is None else disturbance.Fd.shape[0]
        self._fa = np.zeros((n + d, n + d))
        self._fa[:n, :n] = f
        self._la = np.zeros((n + d, m))
        self._la[:n] = gain
        self._ca = np.zeros((m, n + d))
        self._ca[:, :n] = c
        self._qa = np.zeros((n + d, n + d))
        if disturbance is not None:
            disturbance.check(n)
            self._fa[:n, n:] = disturbance.G
            self._fa[n:, n:] = disturbance.Fd
            self._qa = disturbance.Q.copy()

    def _noise_cov(self, sensor_variances: ArrayLike) -> _FloatArray:
        var = check_finite_array("sensor_variances", sensor_variances, shape=(self.m,))
        if np.any(var < 0.0):
            raise ValueError("sensor_variances must be >= 0")
        return np.diag(var)

    def _augmented_covariance(self, sensor_variances: ArrayLike,
                              disturbance_scale: float = 1.0) -> _FloatArray:
        r = self._noise_cov(sensor_variances)
        q = self._la @ r @ self._la.T + disturbance_scale * self._qa
        return scipy.linalg.solve_discrete_lyapunov(self._fa, q)

    def state_covariance(self, sensor_variances: ArrayLike) -> _FloatArray:
        """Stationary covariance of e for white sensor noise of the given variances
        (and the disturbance, if any)."""
        return self._augmented_covariance(sensor_variances)[:self.n, :self.n]

    def residual_covariance(self, sensor_variances: ArrayLike,
                            disturbance_scale: float = 1.0) -> _FloatArray:
        """Stationary covariance of r (lag 0), residual units squared;
        ``disturbance_scale`` multiplies the disturbance's covariance."""
        r = self._noise_cov(sensor_variances)
        p = self._augmented_covariance(sensor_variances, disturbance_scale)
        return self._ca @ p @ self._ca.T + r

    def autocovariance(self, sensor_variances: ArrayLike, lag: int,
                       disturbance_scale: float = 1.0) -> _FloatArray:
        """E[r_{k+lag} r_kᵀ] for lag >= 0."""
        if lag == 0:
            return self.residual_covariance(sensor_variances, disturbance_scale)
        r = self._noise_cov(sensor_variances)
        p = self._augmented_covariance(sensor_variances, disturbance_scale)
        f_pow = np.linalg.matrix_power(self._fa, lag - 1)
        return self._ca @ f_pow @ (self._fa @ p @ self._ca.T - self._la @ r)

    def variance_map(self) -> _FloatArray:
        """M with diag(residual covariance) = M @ sensor_variances (linear in them);
        without the disturbance (see :meth:`disturbance_variances`)."""
        cols = []
        for j in range(self.m):
            unit = np.zeros(self.m)
            unit[j] = 1.0
            cols.append(np.diag(self.residual_covariance(unit, disturbance_scale=0.0)))
        return np.column_stack(cols)

    def disturbance_variances(self) -> _FloatArray:
        """diag of the residual covariance the disturbance alone causes (zeros without
        one)."""
        if self.disturbance is None:
            return np.zeros(self.m)
        return np.diag(self.residual_covariance(np.zeros(self.m)))

    def dc_gain(self) -> _FloatArray:
        """Steady residual per unit constant offset on each sensor: I − C (I − F)⁻¹ L."""
        return np.eye(self.m) - self.C @ np.linalg.solve(np.eye(self.n) - self.F, self.L)

    def whitening(self, sensor_variances: ArrayLike, regularisation: float = 0.01
                  ) -> Whitening:
        """Innovations filter of r for the given sensor variances (module notes).

        Parameters
        ----------
        sensor_variances : array_like, shape (m,)
            Variances of the sensor noise, sensor units squared (> 0 each).
        regularisation : float
            Extra white residual noise, as a fraction of R, that keeps the filter stable
            when some channel has no power at frequency 0 (in (0, 1]).
        """
        r = self._noise_cov(sensor_variances)
        if np.any(np.diag(r) <= 0.0):
            raise ValueError("sensor_variances must be > 0 to whiten the residual")
        rho = check_in_range("regularisation", regularisation, 0.0, 1.0, low_open=True)
        # The Riccati equation is homogeneous in r: solve it for r scaled to unit size so
        # that tiny noise (a noise-free sensor's floor, 1e-24) is not lost in its
        # tolerances, then scale P back (the gain does not change).
        size = float(np.max(np.diag(r)))
        r_unit = r / size
        fa, ca, la = self._fa, self._ca, self._la
        cross = -la @ r_unit  # E[(−L v_k) (v_k)ᵀ]: process and measurement noise share v
        q = la @ r_unit @ la.T + self._qa / size
        p = size * scipy.linalg.solve_discrete_are(
            fa.T, ca.T, 0.5 * (q + q.T), r_unit * (1.0 + rho), s=cross
        )
        cross = cross * size
        s = ca @ p @ ca.T + r * (1.0 + rho)
        s = 0.5 * (s + s.T)
        gain = (fa @ p @ ca.T + cross) @ np.linalg.inv(s)
        closed = fa - gain @ ca
        radius = float(np.max(np.abs(np.linalg.eigvals(closed)), initial=0.0))
        if not radius < 1.0:
            raise ValueError(f"whitening filter is not stable (spectral radius {radius:.6g}); "
                             "increase the regularisation")
        return Whitening(F=fa.copy(), C=ca.copy(), K=gain, S=s,
                         scale=np.sqrt(np.diag(s)))


def estimate_sensor_variances(residuals: ArrayLike, model: ResidualModel,
                              known: ArrayLike | None = None) -> _FloatArray:
    """Sensor noise variances that explain the variances of fault-free residuals.

    The residual variances are linear in the sensor variances (``model.variance_map()``)
    and, with a disturbance model, in its intensity squared (estimated alongside);
    solved by non-negative least squares, relative to each channel's variance so that
    channels of different units weigh alike.

    Parameters
    ----------
    residuals : array_like, shape (N, m)
        Fault-free residual samples (after the observer's start-up transient).
    model : ResidualModel
        The observer's residual model.
    known : array_like, shape (m,), optional
        Variances already known (sensor units squared; NaN where unknown): kept, and
        only the others (and the disturbance) fitted.

    Returns
    -------
    ndarray, shape (m,)
        Variances, sensor units squared (>= 0; 0 where the data show no noise).
    """
    res = check_finite_array("residuals", residuals, shape=(None, model.m))
    if res.shape[0] < 10:
        raise ValueError(f"residuals must have at least 10 samples, got {res.shape[0]}")
    var = res.var(axis=0, ddof=1)
    top = float(var.max())
    if not top > 0.0:
        return np.zeros(model.m)  # a window without noise (a constant or ideal input)
    # A channel 30 decades quieter than the noisiest (or below 1e-250) weighs as if at
    # that floor: 1/var of a noise-free channel overflowed the weighted map to inf.
    weight = 1.0 / np.maximum(var, max(top * 1e-30, 1e-250))
    # imported here: the paper rule never fits variances, and scipy.optimize is 0.3 s of
    # a Diagnoser's start-up
    from scipy.optimize import nnls

    given = np.full(model.m, np.nan) if known is None else np.asarray(known, dtype=float)
    if given.shape != (model.m,) or np.any(np.isinf(given)) or np.any(given < 0.0):
        raise ValueError(f"known must be {model.m} variances >= 0 or NaN, got {known!r}")
    free = np.isnan(given)
    fixed = np.where(free, 0.0, given)
    m = model.variance_map()
    if model.disturbance is None:
        out = fixed.copy()
        if np.any(free):
            rhs = (var - m @ fixed) * weight
            out[free], _ = nnls(m[:, free] * weight[:, None], rhs)
        return out
    # The disturbance's intensity is unknown too. Lag-0 variances cannot tell it from
    # sensor noise (each sensor's noise alone explains its channel); its colour can:
    # fit the autocovariances at lags 0 … DISTURBANCE_LAGS as well.
    # Fit the first differences' auto-covariances (lags 0, 1, all channel pairs): the
    # disturbance is smooth, so they weigh sensor noise far more than lag 0 does.
    diff = np.diff(res, axis=0)
    n = diff.shape[0]
    eye = np.eye(model.m)

    def model_cov(var: _FloatArray, scale: float, lag: int) -> _FloatArray:
        g = [model.autocovariance(var, j, scale) for j in range(lag + 2)]
        back = g[lag - 1].T if lag == 1 else g[lag - 1]
        return 2.0 * g[lag] - g[lag + 1] - back

    rows, target, offset = [], [], []
    for lag in (0, 1):
        cols = [model_cov(eye[j], 0.0, lag).ravel() for j in np.flatnonzero(free)]
        cols.append(model_cov(np.zeros(model.m), 1.0, lag).ravel())
        rows.append(np.column_stack(cols))
        target.append((diff[lag:].T @ diff[:n - lag]).ravel() / n)
        offset.append(model_cov(fixed, 0.0, lag).ravel())
    a, b = np.vstack(rows), np.concatenate(target) - np.concatenate(offset)
    dw = 1.0 / np.sqrt(np.maximum(np.diag(target[0].reshape(model.m, model.m)), 1e-300))
    pair = np.tile(np.outer(dw, dw).ravel(), 2)
    sol, _ = nnls(a * pair[:, None], b * pair)
    out = fixed.copy()
    out[free] = sol[:-1]
    return out
