"""Test-only DTG data generators: the difference equation itself and the continuous
rotor sampled with a zero-order hold (exact matrix exponential)."""

from __future__ import annotations

import numpy as np
from scipy.linalg import expm

from gyrodiag.dtg.model import DTGParameters, rotor_state_space

#: A stable open-loop rotor, J-normalised, with the paper's order of magnitude for
#: L/J and k/J (θ_nom inverted at T = 1 ms gives L/J ≈ −30 rad/s, k/J ≈ 800 1/s²);
#: Ku/KT makes θ5 ≈ 1e−3 so that pick-off and torquer voltages are of one magnitude.
STABLE_ROTOR = DTGParameters(J=1.0, c=40.0, k=800.0, L=-30.0, lam=50.0, Ku=500.0, KT=0.5)


def simulate_difference_equation(theta, ux, uy):
    """Utx, Uty generated exactly by the backward-difference regression model."""
    t1, t2, t3, t4, t5 = theta
    n = len(ux)
    tx = np.zeros(n)
    ty = np.zeros(n)
    # x: tx + t3*ty = rhs_x ; y: -t3*tx + ty = rhs_y  (both contain the current sample)
    Minv = np.linalg.inv(np.array([[1.0, t3], [-t3, 1.0]]))
    for k in range(n):
        tx1 = tx[k - 1] if k >= 1 else 0.0
        tx2 = tx[k - 2] if k >= 2 else 0.0
        ty1 = ty[k - 1] if k >= 1 else 0.0
        ty2 = ty[k - 2] if k >= 2 else 0.0
        rx = t1 * tx1 - t2 * tx2 + t4 * ty1 + t5 * ux[k]
        ry = t1 * ty1 - t2 * ty2 - t4 * tx1 + t5 * uy[k]
        tx[k], ty[k] = Minv @ np.array([rx, ry])
    return tx, ty


def simulate_continuous(p: DTGParameters, ux, uy, T):
    """Sample the continuous rotor at period T.

    ``ux[k]`` is the torquer voltage held over (t_{k−1}, t_k], i.e. the voltage that drove
    the rotor up to the sample instant t_k, as when both are sampled together from
    continuous signals; the samples Utx(k) are taken at t_k.
    """
    A, B, C = rotor_state_space(p)
    n = A.shape[0]
    aug = np.zeros((n + 2, n + 2))
    aug[:n, :n] = A * T
    aug[:n, n:] = B * T
    E = expm(aug)
    Ad, Bd = E[:n, :n], E[:n, n:]
    x = np.zeros(n)
    out = np.zeros((len(ux), 2))
    for k in range(len(ux)):
        x = Ad @ x + Bd @ np.array([ux[k], uy[k]])
        out[k] = C @ x
    return out[:, 0], out[:, 1]
