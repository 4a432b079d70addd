"""Dynamically tuned gyro (DTG) rotor model for parameter identification.

Rotor equations (docs/methods.md §2, the paper's eq. 2 with its typo corrected)::

    J α'' + c α' + k α + L β' + λ β = Ku·Ux
    J β'' + c β' + k β − L α' − λ α = Ku·Uy

with pick-offs α = KT·Utx, β = KT·Uty. Backward differences at sample time T give the
regression used for identification (x axis; y axis symmetric)::

    Utx(k) = θ1·Utx(k−1) − θ2·Utx(k−2) − θ3·Uty(k) + θ4·Uty(k−1) + θ5·Ux(k)
    Uty(k) = θ1·Uty(k−1) − θ2·Uty(k−2) + θ3·Utx(k) − θ4·Utx(k−1) + θ5·Uy(k)

    θ = [a2/a1, a3/a1, b1/a1, b2/a1, Ku/(KT·a1)]
    a1 = J/T² + c/T + k,  a2 = 2J/T² + c/T,  a3 = J/T²,  b1 = L/T + λ,  b2 = L/T

Both axes share θ. The inversion gives the physical parameters relative to J, which
is what makes the method diagnostic: faults have physical causes.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from gyrodiag.common._validation import check_finite_array, check_positive

__all__ = [
    "N_THETA",
    "THETA_NAMES",
    "DTGParameters",
    "DTGRegressor",
    "PhysicalRatios",
    "dtg_regression",
    "physical_from_theta",
    "rotor_state_space",
    "theta_from_physical",
]

N_THETA = 5
THETA_NAMES = ("theta1", "theta2", "theta3", "theta4", "theta5")


@dataclass(frozen=True)
class DTGParameters:
    """Physical rotor parameters of a DTG.

    Attributes
    ----------
    J : float
        Transverse moment of inertia, kg·m².
    c : float
        Flexure (internal) damping, N·m·s/rad.
    k : float
        Residual (direct) spring stiffness, N·m/rad; ≈ 0 when tuned.
    L : float
        Angular momentum of the rotor, N·m·s (sign gives the spin direction).
    lam : float
        Quadrature spring stiffness λ, N·m/rad.
    Ku : float
        Torquer gain, N·m/V.
    KT : float
        Pick-off gain, rad/V (α = KT·Utx).
    """

    J: float
    c: float
    k: float
    L: float
    lam: float
    Ku: float
    KT: float

    def __post_init__(self) -> None:
        check_positive("J", self.J)
        check_positive("KT", self.KT)
        for name in ("c", "k", "L", "lam", "Ku"):
            check_finite_array(name, getattr(self, name), ndim=0)


@dataclass(frozen=True)
class PhysicalRatios:
    """Physical parameters relative to the transverse inertia J.

    Attributes
    ----------
    c_over_J : float
        Damping ratio c/J, 1/s.
    k_over_J : float
        Spring ratio k/J, 1/s².
    L_over_J : float
        Momentum ratio L/J, rad/s (the nutation frequency for a tuned rotor).
    lam_over_J : float
        Quadrature-spring ratio λ/J, 1/s².
    Ku_over_KT_J : float
        Input gain Ku/(KT·J), 1/(s²) per volt ratio (V/V/s²).
    """

    c_over_J: float
    k_over_J: float
    L_over_J: float
    lam_over_J: float
    Ku_over_KT_J: float

    def as_array(self) -> NDArray[np.float64]:
        """The five ratios in declaration order."""
        return np.array(
            [self.c_over_J, self.k_over_J, self.L_over_J, self.lam_over_J, self.Ku_over_KT_J]
        )


def theta_from_physical(params: DTGParameters, sample_period_s: float) -> NDArray[np.float64]:
    """Regression parameters θ (5,) of the backward-difference model.

    Parameters
    ----------
    params : DTGParameters
        Physical rotor parameters.
    sample_period_s : float
        Sample period T in s.
    """
    T = check_positive("sample_period_s", sample_period_s)
    p = params
    a1 = p.J / T**2 + p.c / T + p.k
    a2 = 2.0 * p.J / T**2 + p.c / T
    a3 = p.J / T**2
    b1 = p.L / T + p.lam
    b2 = p.L / T
    if a1 == 0.0:
        raise ValueError("params give a1 = J/T² + c/T + k = 0: θ is undefined")
    return np.array([a2 / a1, a3 / a1, b1 / a1, b2 / a1, p.Ku / (p.KT * a1)])


def physical_from_theta(theta: ArrayLike, sample_period_s: float) -> PhysicalRatios:
    """Invert θ to the physical parameters relative to J.

    Parameters
    ----------
    theta : array_like, shape (5,)
        Regression parameters.
    sample_period_s : float
        Sample period T in s.

    Raises
    ------
    ValueError
        If θ2 = 0 (the inversion divides by it).
    """
    th = check_finite_array("theta", theta, shape=(N_THETA,))
    T = check_positive("sample_period_s", sample_period_s)
    t1, t2, t3, t4, t5 = th
    if t2 == 0.0:
        raise ValueError("theta[1] (θ2) must be non-zero to invert to physical parameters")
    return PhysicalRatios(
        c_over_J=(t1 - 2.0 * t2) / (t2 * T),
        k_over_J=(1.0 - t1 + t2) / (t2 * T**2),
        L_over_J=t4 / (t2 * T),
        lam_over_J=(t3 - t4) / (t2 * T**2),
        Ku_over_KT_J=t5 / (t2 * T**2),
    )


def dtg_regression(
    Utx: ArrayLike, Uty: ArrayLike, Ux: ArrayLike, Uy: ArrayLike
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """Regressor matrices and targets of both axes for whole records.

    Parameters
    ----------
    Utx, Uty : array_like, shape (n,)
        Pick-off output voltages, V.
    Ux, Uy : array_like, shape (n,)
        Torquer input voltages, V.

    Returns
    -------
    phi_x, y_x, phi_y, y_y : ndarray
        ``phi_*`` has shape (n − 2, 5), ``y_*`` shape (n − 2,): rows for k = 2 … n−1,
        such that ``y_x ≈ phi_x @ θ`` and ``y_y ≈ phi_y @ θ``.
    """
    tx = check_finite_array("Utx", Utx, ndim=1)
    n = tx.shape[0]
    ty = check_finite_array("Uty", Uty, shape=(n,))
    ux = check_finite_array("Ux", Ux, shape=(n,))
    uy = check_finite_array("Uy", Uy, shape=(n,))
    if n < 3:
        raise ValueError(f"records must have at least 3 samples, got {n}")
    k = slice(2, n)
    k1 = slice(1, n - 1)
    k2 = slice(0, n - 2)
    phi_x = np.column_stack([tx[k1], -tx[k2], -ty[k], ty[k1], ux[k]])
    phi_y = np.column_stack([ty[k1], -ty[k2], tx[k], -tx[k1], uy[k]])
    return phi_x, tx[k].copy(), phi_y, ty[k].copy()


class DTGRegressor:
    """Streaming builder of the per-sample regressors of both axes.

    Keeps the two previous pick-off samples. After at least three samples,
    :meth:`update` returns the regressor rows; before that it returns ``None``.
    """

    def __init__(self) -> None:
        self._hist = np.zeros((2, 2))  # rows: k−1, k−2; cols: Utx, Uty
        self._count = 0

    def reset(self) -> None:
        """Forget the sample history."""
        self._hist[...] = 0.0
        self._count = 0

    @property
    def ready(self) -> bool:
        """True once two previous samples are available."""
        return self._count >= 2

    def update(
        self, Utx: float, Uty: float, Ux: float, Uy: float, *, validate: bool = True
    ) -> (
        tuple[NDArray[np.float64], float, NDArray[np.float64], float] | None
    ):
        """Push one sample (volts) and return ``(phi_x, y_x, phi_y, y_y)`` or None.

        Raises
        ------
        ValueError
            On a non-finite value; the history is untouched.
        """
        v = (
            check_finite_array("(Utx, Uty, Ux, Uy)", [Utx, Uty, Ux, Uy], shape=(4,))
            if validate
            else np.array([Utx, Uty, Ux, Uy], dtype=float)
        )
        tx, ty, ux, uy = v
        (tx1, ty1), (tx2, ty2) = self._hist
        out = None
        if self.ready:
            phi_x = np.array([tx1, -tx2, -ty, ty1, ux])
            phi_y = np.array([ty1, -ty2, tx, -tx1, uy])
            out = (phi_x, float(tx), phi_y, float(ty))
        self._hist[1] = self._hist[0]
        self._hist[0] = (tx, ty)
        self._count = min(self._count + 1, 2)
        return out

    def get_state(self) -> dict[str, Any]:
        """Copy of the sample history."""
        return {"hist": self._hist.copy(), "count": self._count}

    def set_state(self, state: dict[str, Any]) -> None:
        """Restore a state produced by :meth:`get_state`."""
        self._hist = check_finite_array("state['hist']", state["hist"], shape=(2, 2)).copy()
        self._count = int(state["count"])


def rotor_state_space(
    params: DTGParameters,
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """Continuous state space (A, B, C) of the rotor without case rates.

    State x = [α, β, α', β'] (rad, rad/s), input u = [Ux, Uy] (V), output
    y = [Utx, Uty] (V). Used to generate reference data; the plant FMU has its own.
    """
    p = params
    J = p.J
    A = np.array(
        [
            [0.0, 0.0, 1.0, 0.0],
            [0.0, 0.0, 0.0, 1.0],
            [-p.k / J, -p.lam / J, -p.c / J, -p.L / J],
            [p.lam / J, -p.k / J, p.L / J, -p.c / J],
        ]
    )
    B = np.array([[0.0, 0.0], [0.0, 0.0], [p.Ku / J, 0.0], [0.0, p.Ku / J]])
    C = np.array([[1.0 / p.KT, 0.0, 0.0, 0.0], [0.0, 1.0 / p.KT, 0.0, 0.0]])
    return A, B, C
