"""Residual generators of the sequential diagnosis and their joint simulation.

* A :class:`ResidualGenerator` is an observer of the plant driven by a subset of the
  sensors, followed by the filter that whitens its residual
  (:mod:`gyrodiag.df.residual`): its output is a vector of standardised innovations,
  white N(0, 1) per channel when the sensors it uses are fault-free. The *main*
  generator is the Beard–Jones detection filter on all sensors; generator ``¬S`` leaves
  out the sensors of S (one or two) and so cannot see their faults.
* :class:`ObserverStack` runs any set of generators as one linear system
  (one matrix–vector product per sample).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from .filter import DetectionFilter, observable_subspace, zoh_discretise
from .gust import GustModel
from .isolation import place_observer_gain
from .residual import Disturbance, ResidualModel, Whitening

__all__ = ["ObserverStack", "ResidualGenerator", "design_residual_generator"]

_FloatArray = NDArray[np.float64]


@dataclass(frozen=True)
class ResidualGenerator:
    """An observer on a subset of the sensors plus the whitening of its residual.

    In full state coordinates (n): ``x̂⁺ = Φ x̂ + Γ u + L (y_used − C_used x̂)``; the
    residual's whitening filter runs on the observable coordinates (n_o) of
    (A, C_used) with state ê: ``ε = r − C_o ê``, ``ê⁺ = F_o ê + K_w ε``. Standardised
    output z = ε / scale.

    Attributes
    ----------
    excluded : tuple of int
        Sensors the observer does not use (empty for the main filter).
    used : ndarray of int
        Sensors it uses, in order; its output channels.
    phi, gamma, gain, c_used : ndarray
        Φ (n × n), Γ (n × p), L (n × m_used, zero on unobservable directions), C_used.
    whitening : Whitening
        Innovations filter of the residual (on n_o observable coordinates).
    estimates : tuple of bool
        Per excluded sensor: its value is observable from the used sensors, so
        ``C_i x̂`` is a fault-free estimate of it.
    estimate_std : tuple of float
        Per excluded sensor: standard deviation of ``y_i − C_i x̂`` when fault-free
        (sensor noise and estimation error), sensor units; for an unobservable sensor,
        the sensor noise alone (its estimate's error grows with time).
    c_excluded : ndarray, shape (len(excluded), n)
        Output rows of the excluded sensors.
    basis : ndarray, shape (n, n_o)
        Orthonormal basis of the observable subspace of (A, C_used).
    dc_noise_std : tuple of float
        Per excluded sensor: square root of the long-run variance (spectral density at
        frequency 0) of ``y_i − C_i x̂`` when fault-free: the noise a mean over many
        samples of the fault estimate sees, sensor units.
    """

    excluded: tuple[int, ...]
    used: NDArray[np.int_]
    phi: _FloatArray
    gamma: _FloatArray
    gain: _FloatArray
    c_used: _FloatArray
    whitening: Whitening
    estimates: tuple[bool, ...]
    estimate_std: tuple[float, ...]
    c_excluded: _FloatArray
    dc_noise_std: tuple[float, ...]
    basis: _FloatArray

    @property
    def n_states(self) -> int:
        """Observer plus whitening states."""
        return self.phi.shape[0] + self.whitening.F.shape[0]

    @property
    def n_channels(self) -> int:
        """Output channels (sensors used)."""
        return self.used.size

    def matrices(self, n_sensors: int) -> tuple[_FloatArray, _FloatArray, _FloatArray,
                                                  _FloatArray]:
        """(A_g, B_g, Cz_g, Dz_g) of the composite ``X⁺ = A X + B w``, ``z = Cz X + Dz w``
        with X = [x̂; ê], w = [u; y] (all sensors), z standardised."""
        n, p = self.gamma.shape
        wh = self.whitening
        n_o = wh.F.shape[0]
        sel = np.zeros((self.used.size, n_sensors))
        sel[np.arange(self.used.size), self.used] = 1.0
        a = np.zeros((n + n_o, n + n_o))
        a[:n, :n] = self.phi - self.gain @ self.c_used
        a[n:, :n] = -wh.K @ self.c_used
        a[n:, n:] = wh.F - wh.K @ wh.C
        b = np.zeros((n + n_o, p + n_sensors))
        b[:n, :p] = self.gamma
        b[:n, p:] = self.gain @ sel
        b[n:, p:] = wh.K @ sel
        inv = 1.0 / wh.scale
        cz = np.zeros((self.used.size, n + n_o))
        cz[:, :n] = -inv[:, None] * self.c_used
        cz[:, n:] = -inv[:, None] * wh.C
        dz = np.zeros((self.used.size, p + n_sensors))
        dz[:, p:] = inv[:, None] * sel
        return a, b, cz, dz


def design_residual_generator(
    A: _FloatArray, B: _FloatArray, C: _FloatArray, sample_period_s: float,
    excluded: tuple[int, ...], sensor_variances: _FloatArray, *,
    main_gain: _FloatArray | None = None, eigenvalues: _FloatArray | None = None,
    regularisation: float = 0.01, gust: GustModel | None = None,
) -> ResidualGenerator:
    """Design one generator (inputs are assumed validated by the caller).

    The main generator (``excluded = ()``) takes the Beard–Jones gain ``main_gain``
    discretised as :class:`~gyrodiag.df.filter.DetectionFilter` does; the others
    place the poles exp(λ T) of their observable subspace, λ = ``eigenvalues`` (default
    −1, −2, …). With ``gust`` the whitening models the turbulence too (its residual is
    the innovation of the Kalman filter of the plant augmented with the gust filter).
    """
    m = C.shape[0]
    used = np.array([i for i in range(m) if i not in excluded], dtype=int)
    c_used = C[used]
    phi, gamma = zoh_discretise(A, B, sample_period_s)
    if not excluded:
        if main_gain is None:
            raise ValueError("main_gain is required for the main generator")
        df = DetectionFilter(A, B, C, main_gain, sample_period_s)
        basis = np.eye(A.shape[0])
        gain_o = df.discrete_gain
        phi_o = phi
        c_o = c_used
    else:
        basis = observable_subspace(A, c_used)
        n_o = basis.shape[1]
        phi_o, _ = zoh_discretise(basis.T @ A @ basis, basis.T @ B, sample_period_s)
        c_o = c_used @ basis
        lam = -np.arange(1.0, n_o + 1.0) if eigenvalues is None else eigenvalues[:n_o]
        gain_o = place_observer_gain(phi_o, c_o, np.exp(lam * sample_period_s))
    gain = basis @ gain_o
    f_o = phi_o - gain_o @ c_o
    model = ResidualModel(f_o, gain_o, c_o, _gust_disturbance(gust, A, sample_period_s, basis))
    var_used = sensor_variances[used]
    whitening = model.whitening(var_used, regularisation)
    estimates, stds, dc_stds = [], [], []
    p_o = model.state_covariance(var_used)
    # fault-free y_i − C_i x̂ = v_i + C_i T e_o; at frequency 0, e_o = −(I − F_o)⁻¹ L_o v
    dc_map = np.linalg.solve(np.eye(f_o.shape[0]) - f_o, gain_o)
    for i in excluded:
        row = C[i] @ basis
        ok = bool(np.linalg.norm(row) >= (1.0 - 1e-9) * np.linalg.norm(C[i]) > 0.0)
        estimates.append(ok)
        est_var = float(row @ p_o @ row) if ok else 0.0
        stds.append(math.sqrt(sensor_variances[i] + est_var))
        g = row @ dc_map if ok else np.zeros(used.size)
        dc_stds.append(math.sqrt(sensor_variances[i] + float(g**2 @ var_used)))
    return ResidualGenerator(
        excluded=tuple(excluded), used=used, phi=phi, gamma=gamma, gain=gain,
        c_used=c_used, whitening=whitening, estimates=tuple(estimates),
        estimate_std=tuple(stds), c_excluded=C[list(excluded)].reshape(len(excluded), C.shape[1]),
        dc_noise_std=tuple(dc_stds), basis=basis,
    )


def _gust_disturbance(gust: GustModel | None, A: _FloatArray, sample_period_s: float,
                      basis: _FloatArray) -> Disturbance | None:
    """The gust as a disturbance of the observer error in the coordinates ``basis``."""
    if gust is None:
        return None
    phi_xg, phi_g, q = gust.discrete(A, sample_period_s)
    n, n_o, d = A.shape[0], basis.shape[1], phi_g.shape[0]
    proj = np.zeros((n_o + d, n + d))
    proj[:n_o, :n] = basis.T
    proj[n_o:, n:] = np.eye(d)
    return Disturbance(G=basis.T @ phi_xg, Fd=phi_g, Q=proj @ q @ proj.T)


class ObserverStack:
    """Several residual generators run as one linear system.

    ``update(w)`` returns the standardised innovations of every generator (concatenated
    in order) for the sample w = [u; y] and advances the state; the a-priori estimates
    ``C_i x̂`` of every generator's excluded sensors are returned beside them.

    Parameters
    ----------
    generators : list of ResidualGenerator
    n_inputs, n_sensors : int
        p and m of the plant.
    channel_scale : list of array_like, optional
        Per generator, per channel: extra division of z (>= 1), from an empirical check
        of the whitened variance (see
        :meth:`~gyrodiag.df.sequential_diagnosis.SequentialDiagnoser.calibrate_scales`).
    """

    def __init__(self, generators: list[ResidualGenerator], n_inputs: int, n_sensors: int,
                 channel_scale: list[_FloatArray] | None = None,
                 residuals: bool = False) -> None:
        self.generators = generators
        self.p, self.m = n_inputs, n_sensors
        self.n_state = sum(g.n_states for g in generators)
        self.n_out = sum(g.n_channels for g in generators)
        self.n_est = sum(len(g.excluded) for g in generators)
        n_res = self.n_out if residuals else 0
        n_all = self.n_state + self.p + self.m
        ab = np.zeros((self.n_state, n_all))
        cd = np.zeros((self.n_out + self.n_est + n_res, n_all))
        self.state_slices: list[slice] = []
        self.out_slices: list[slice] = []
        self.est_slices: list[slice] = []
        s0 = o0 = e0 = 0
        n = generators[0].phi.shape[0] if generators else 0
        self.n = n
        for g in generators:
            a, b, cz, dz = g.matrices(self.m)
            ns, nc, ne = g.n_states, g.n_channels, len(g.excluded)
            ab[s0:s0 + ns, s0:s0 + ns] = a
            ab[s0:s0 + ns, self.n_state:] = b
            cd[o0:o0 + nc, s0:s0 + ns] = cz
            cd[o0:o0 + nc, self.n_state:] = dz
            # a-priori estimates C_i x̂ of the excluded sensors (sensor units)
            cd[self.n_out + e0:self.n_out + e0 + ne, s0:s0 + n] = g.c_excluded
            if residuals:
                # raw residual y_used − C_used x̂ (sensor units)
                row = self.n_out + self.n_est + o0
                cd[row:row + nc, s0:s0 + n] = -g.c_used
                cd[row + np.arange(nc), self.n_state + self.p + g.used] = 1.0
            self.state_slices.append(slice(s0, s0 + ns))
            self.out_slices.append(slice(o0, o0 + nc))
            self.est_slices.append(slice(e0, e0 + ne))
            s0, o0, e0 = s0 + ns, o0 + nc, e0 + ne
        self._ab0, self._cd0 = ab, cd
        self.set_channel_scale(channel_scale)
        self.reset()

    def set_channel_scale(self, channel_scale: list[_FloatArray] | None) -> None:
        """Divide each generator's z by these per-channel factors (None: by 1)."""
        cd = self._cd0.copy()
        scales = []
        for k, g in enumerate(self.generators):
            f = (np.ones(g.n_channels) if channel_scale is None
                 else np.asarray(channel_scale[k], dtype=float))
            cd[self.out_slices[k]] /= f[:, None]
            scales.append(f.copy())
        self.channel_scale = scales
        self._ab = self._ab0
        self._cd = cd
        # [A B; Cz Dz] stacked: one matrix-vector product per sample instead of two
        self._abcd = np.vstack([self._ab, cd])

    def reset(self) -> None:
        """All states zero."""
        self.x = np.zeros(self.n_state)

    def system(self) -> tuple[_FloatArray, _FloatArray, _FloatArray, _FloatArray]:
        """(A, B, Cz, Dz) of ``X⁺ = A X + B w``, ``z = Cz X + Dz w`` (copies, with the
        channel scales)."""
        ns = self.n_state
        return (self._ab[:, :ns].copy(), self._ab[:, ns:].copy(),
                self._cd[:self.n_out, :ns].copy(), self._cd[:self.n_out, ns:].copy())

    def set_observer_state(self, index: int, xhat: _FloatArray,
                           disturbance: _FloatArray | None = None) -> None:
        """Observer of generator ``index`` to the full-state estimate ``xhat``, its
        whitening state to zero, or with ``disturbance`` (the main generator's whitening
        state [ê; ĝ], with a gust model) to the same error and gust estimates."""
        sl = self.state_slices[index]
        self.x[sl] = 0.0
        self.x[sl.start:sl.start + self.n] = xhat
        if disturbance is not None and disturbance.size:
            # the main filter's whitening state [ê (n); ĝ]: its error estimate in this
            # generator's observable coordinates, and the disturbance estimate as is
            gen = self.generators[index]
            n_d = disturbance.size - self.n
            start = sl.start + self.n
            self.x[start:start + gen.basis.shape[1]] = gen.basis.T @ disturbance[:self.n]
            self.x[sl.stop - n_d:sl.stop] = disturbance[self.n:]

    def observer_state(self, index: int) -> _FloatArray:
        """Full-state estimate x̂ of generator ``index`` (a-priori for the next sample)."""
        sl = self.state_slices[index]
        return self.x[sl.start:sl.start + self.n].copy()

    def update(self, w: _FloatArray) -> tuple[_FloatArray, _FloatArray]:
        """(z of all generators, a-priori estimates of all excluded sensors, and the raw
        residuals when built with ``residuals``) for the sample ``w = [u; y]``; then
        advance. ``w`` is not validated."""
        full = self._abcd @ np.concatenate((self.x, w))
        ns = self.n_state
        self.x = full[:ns]
        return full[ns:ns + self.n_out], full[ns + self.n_out:]

