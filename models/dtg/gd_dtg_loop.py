"""Stability and margins of the rebalance loop (design check, used by README and tests).

Both axes are identical and the couplings are antisymmetric, so the real 2×2 loop is
exactly a complex SISO loop in z = α + iβ, u = Ux + iUy: the rotor is
Ku/(J s² + (c − iL) s + (k − iλ)) and the controller −e^{iψ}·C(s). The sampled loop
L(e^{jωTc}) is evaluated over negative and positive frequencies (a complex loop is not
conjugate-symmetric); the closed-loop poles come from the real-time-step matrices.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from gd_dtg_core import (
    DTGParameterSet,
    controller_matrices,
    rotor_coefficients,
    zoh_discretize,
)


@dataclass(frozen=True)
class LoopMargins:
    """Rebalance-loop figures.

    Attributes
    ----------
    spectral_radius : float
        Largest closed-loop pole magnitude per controller tick (-); < 1 is stable.
    slowest_time_constant : float
        −Tc / ln(spectral_radius) (s).
    modulus_margin : float
        min |1 + L| over frequency (-); guarantees gain margin ≥ 1/(1 − m) and phase
        margin ≥ 2·asin(m/2).
    phase_margin_deg : float
        Smallest phase margin over all gain crossovers (deg).
    crossover_hz : tuple of float
        Gain-crossover frequencies (Hz, signed: the complex loop has both signs).
    gain_margin_db : float
        Smallest −20·log10|L| where L crosses the negative real axis (dB); inf if never.
    """

    spectral_radius: float
    slowest_time_constant: float
    modulus_margin: float
    phase_margin_deg: float
    crossover_hz: tuple[float, ...]
    gain_margin_db: float


def _freqresp(A: np.ndarray, B: np.ndarray, C: np.ndarray, D: complex,
              z: np.ndarray) -> np.ndarray:
    mu, V = np.linalg.eig(A)
    left = C.reshape(1, -1) @ V
    right = np.linalg.solve(V, B.reshape(-1, 1))
    residues = (left.ravel() * right.ravel())[:, None]
    return np.sum(residues / (z[None, :] - mu[:, None]), axis=0) + D


def loop_margins(p: DTGParameterSet, n_freq: int = 20000, **faults: float) -> LoopMargins:
    """Closed-loop poles and margins of the rebalance loop of ``p`` with ``faults``.

    Parameters
    ----------
    p : DTGParameterSet
        Gyro and controller.
    n_freq : int
        Frequency points per sign (log-spaced from 1e-3 rad/s to Nyquist).
    **faults : float
        As for ``rotor_coefficients`` (the controller stays the nominal design).
    """
    r = rotor_coefficients(p, **faults)
    Tc = p.controller_sample_time
    A = np.array([[0.0, 1.0], [-(r.k - 1j * r.lam) / r.J, -(r.c - 1j * r.L) / r.J]])
    B = np.array([[0.0], [r.Ku / r.J]], dtype=complex)
    Ad, Bd = zoh_discretize(A, B, Tc)
    Cp = np.array([[1.0 / r.KT, 0.0]])
    Ac, Bc, Cc, Dc = controller_matrices(p)
    K = -np.exp(1j * p.loop_rotation)  # controller input e = K·y
    top = np.hstack([Ad + (Bd * Dc * K) @ Cp, Bd @ Cc.reshape(1, -1)])
    bottom = np.hstack([(Bc.reshape(-1, 1) * K) @ Cp, Ac])
    radius = float(np.max(np.abs(np.linalg.eigvals(np.vstack([top, bottom])))))

    w_pos = np.logspace(-3, np.log10(np.pi / Tc), n_freq)
    w = np.concatenate([-w_pos[::-1], w_pos])
    z = np.exp(1j * w * Tc)
    plant = _freqresp(Ad, Bd, Cp, 0.0, z)
    ctrl = _freqresp(Ac.astype(complex), Bc.astype(complex), Cc.astype(complex), Dc, z)
    loop = -K * ctrl * plant  # negative-feedback convention: closed loop 1/(1 + L)
    mag = np.abs(loop)
    cross = np.where(np.diff(np.sign(mag - 1.0)) != 0)[0]
    pm = [180.0 - abs(np.degrees(np.angle(loop[i]))) for i in cross]
    neg_axis = np.where((np.diff(np.sign(loop.imag)) != 0) & (loop.real[:-1] < 0))[0]
    gm = [-20 * np.log10(mag[i]) for i in neg_axis if mag[i] < 1.0]
    return LoopMargins(
        spectral_radius=radius,
        slowest_time_constant=float(-Tc / np.log(radius)) if radius < 1 else float("inf"),
        modulus_margin=float(np.min(np.abs(1.0 + loop))),
        phase_margin_deg=float(min(pm)) if pm else float("inf"),
        crossover_hz=tuple(float(w[i] / (2 * np.pi)) for i in cross),
        gain_margin_db=float(min(gm)) if gm else float("inf"),
    )
