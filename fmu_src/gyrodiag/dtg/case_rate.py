"""DTG identification with the case rate: regressors with ω and Δω (docs/dtg_case_rate.md).

With the case turning at ωx, ωy (rad/s) the rotor equations of docs/methods.md §2 read::

    J (α'' + ω̇x) + c α' + k α + L (β' + ωy) + λ β = Ku·Ux
    J (β'' + ω̇y) + c β' + k β − L (α' + ωx) − λ α = Ku·Uy

(the x line sees J·ω̇x and L·ωy, the y line J·ω̇y and −L·ωx; signs as in
models/dtg/gd_dtg_core.py).  Inertia and angular momentum act on the rotor's inertial
rates, so the case rate folds into the pick-off regressors with the known scale
s = T/KT (V per rad/s) and no new parameter.  ω(k) is the case rate held over
[t(k−1), t(k)] (what a zero-order-hold master gives the gyro), Δω(k) = ω(k) − ω(k−1), and
Ū(k) = ½(U(k) + U(k−1)).  Two discretisations:

``"central"`` (default).  Every term is taken at t(k−1), where the backward second
difference of the inertial angle is exact for held inputs: J Δ²(angle)/T² equals the
triangle-weighted mean of the torques over [t(k−2), t(k)], which is exactly ½(U(k) +
U(k−1)) for the held torquer voltage and ½(ω(k) + ω(k−1)) for the held gyroscopic term,
and to O(T²) the centred differences for the rotor's own (smooth) motion::

    Utx(k) + ½sΔωx = θ1 Utx(k−1) − θ2 [Utx(k−2) + ½sΔωx]
                     − θL [Uty(k) − Uty(k−2) + s(ωy(k) + ωy(k−1))] − θλ Uty(k−1) + θ5 Ūx(k)
    Uty(k) + ½sΔωy = θ1 Uty(k−1) − θ2 [Uty(k−2) + ½sΔωy]
                     + θL [Utx(k) − Utx(k−2) + s(ωx(k) + ωx(k−1))] + θλ Utx(k−1) + θ5 Ūy(k)

    a1 = J/T² + c/(2T):  θ = [(2J/T² − k)/a1, (J/T² − c/(2T))/a1, L/(2T·a1), λ/a1, Ku/(KT·a1)]

(J/(T²·a1) = (1 + θ2)/2 splits the J·Δω/T term into a known part and a θ2 part.)

``"paper"``.  The paper's backward-difference θ = [a2/a1, a3/a1, b1/a1, b2/a1, Ku/(KT·a1)]
(docs/methods.md §2) with the case rate folded in the same way::

    Utx(k) = θ1 Utx(k−1) − θ2 [Utx(k−2) + sΔωx] − θ3 Uty(k) + θ4 [Uty(k−1) − s ωy(k)] + θ5 Ū
    Uty(k) = θ1 Uty(k−1) − θ2 [Uty(k−2) + sΔωy] + θ3 Utx(k) − θ4 [Utx(k−1) − s ωx(k)] + θ5 Ū

with Ū = ½(U(k) + U(k−1)) (``torquer_average``, default) or the paper's U(k).  The paper's
form evaluates the springs at t(k), the damper and gyroscopic terms at t(k−½) and the
inertia at t(k−1); its θ3/θ4 at rest carry that truncation error, and a manoeuvre, which
pins them through the large L·ω term, moves them toward the physical values (more than
the central form does: docs/notes.md, case-rate schemes).

The pick-off scale KT (rad/V) is the nominal gyro's (a datasheet value).  ω must be an
estimate that does not come from the gyro under test; its noise enters a regressor
(errors in variables), which biases θ by about var(noise)/var(rotor relative rate) in the
prefilter band (docs/dtg_case_rate.md).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..common._validation import check_finite_array, check_positive

__all__ = [
    "CASE_RATE_SCHEMES",
    "CaseRateDTGRegressor",
    "CentralPhysicalRatios",
    "dtg_case_rate_regression",
    "physical_from_theta_central",
    "theta_central_from_physical",
]

CaseRateScheme = Literal["central", "paper"]
#: Discretisations of the case-rate regression, with their FMU codes 1, 2 (0: no case rate).
CASE_RATE_SCHEMES: tuple[CaseRateScheme, ...] = ("central", "paper")


def _check_scheme(scheme: str) -> CaseRateScheme:
    if scheme not in CASE_RATE_SCHEMES:
        raise ValueError(f"scheme must be one of {CASE_RATE_SCHEMES}, got {scheme!r}")
    return scheme  # type: ignore[return-value]


@dataclass(frozen=True)
class CentralPhysicalRatios:
    """Physical rotor parameters relative to J from the central-scheme θ.

    Attributes
    ----------
    c_over_J : float
        1/s.
    k_over_J : float
        1/s².
    L_over_J : float
        rad/s.
    lam_over_J : float
        1/s².
    Ku_over_KT_J : float
        1/s² (per V/V).
    """

    c_over_J: float
    k_over_J: float
    L_over_J: float
    lam_over_J: float
    Ku_over_KT_J: float

    def as_array(self) -> NDArray[np.float64]:
        """The five ratios in declaration order."""
        return np.array([self.c_over_J, self.k_over_J, self.L_over_J, self.lam_over_J,
                         self.Ku_over_KT_J])


def theta_central_from_physical(J: float, c: float, k: float, L: float, lam: float,
                                Ku: float, KT: float, sample_period_s: float
                                ) -> NDArray[np.float64]:
    """θ (5,) of the central scheme for physical rotor parameters (SI units)."""
    T = check_positive("sample_period_s", sample_period_s)
    check_positive("J", J)
    check_positive("KT", KT)
    a1 = J / T**2 + c / (2.0 * T)
    if a1 == 0.0:
        raise ValueError("J/T² + c/(2T) = 0: θ is undefined")
    return np.array([(2.0 * J / T**2 - k) / a1, (J / T**2 - c / (2.0 * T)) / a1,
                     L / (2.0 * T * a1), lam / a1, Ku / (KT * a1)])


def physical_from_theta_central(theta: ArrayLike, sample_period_s: float
                                ) -> CentralPhysicalRatios:
    """Invert central-scheme θ to the physical parameters relative to J.

    With J/a1 = T²(1 + θ2)/2: c/J = 2(1 − θ2)/(T(1 + θ2)), k/J = (1 + θ2 − θ1)/d,
    L/J = 4θL/(T(1 + θ2)), λ/J = θλ/d, Ku/(KT·J) = θ5/d, d = T²(1 + θ2)/2.

    Raises
    ------
    ValueError
        If θ2 = −1 (the inversion divides by 1 + θ2).
    """
    th = check_finite_array("theta", theta, shape=(5,))
    T = check_positive("sample_period_s", sample_period_s)
    t1, t2, tl, tlam, t5 = th
    if 1.0 + t2 == 0.0:
        raise ValueError("theta[1] (θ2) must not be -1 to invert the central scheme")
    d = T * T * (1.0 + t2) / 2.0
    return CentralPhysicalRatios(
        c_over_J=2.0 * (1.0 - t2) / (T * (1.0 + t2)), k_over_J=(1.0 + t2 - t1) / d,
        L_over_J=4.0 * tl / (T * (1.0 + t2)), lam_over_J=tlam / d, Ku_over_KT_J=t5 / d)


def _rows(scheme: str, torquer_average: bool, s: float, tx: Any, ty: Any, tx1: Any,
          ty1: Any, tx2: Any, ty2: Any, ux: Any, uy: Any, ux1: Any, uy1: Any, wx: Any,
          wy: Any, wx1: Any, wy1: Any) -> tuple[list[Any], Any, list[Any], Any]:
    """Regressor columns and targets; works on floats and on arrays alike."""
    dwx, dwy = wx - wx1, wy - wy1
    if scheme == "central":
        ubx, uby = 0.5 * (ux + ux1), 0.5 * (uy + uy1)
        hx, hy = 0.5 * s * dwx, 0.5 * s * dwy
        phi_x = [tx1, -(tx2 + hx), -(ty - ty2 + s * (wy + wy1)), -ty1, ubx]
        phi_y = [ty1, -(ty2 + hy), tx - tx2 + s * (wx + wx1), tx1, uby]
        return phi_x, tx + hx, phi_y, ty + hy
    if torquer_average:
        ubx, uby = 0.5 * (ux + ux1), 0.5 * (uy + uy1)
    else:
        ubx, uby = ux, uy
    phi_x = [tx1, -(tx2 + s * dwx), -ty, ty1 - s * wy, ubx]
    phi_y = [ty1, -(ty2 + s * dwy), tx, -(tx1 - s * wx), uby]
    return phi_x, tx, phi_y, ty


def dtg_case_rate_regression(
    Utx: ArrayLike, Uty: ArrayLike, Ux: ArrayLike, Uy: ArrayLike,
    omega_x: ArrayLike, omega_y: ArrayLike, sample_period_s: float,
    pickoff_scale: float = 1.0e-3, *, scheme: CaseRateScheme = "central",
    torquer_average: bool = True,
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """Regressor matrices and targets of both axes for whole records.

    Parameters
    ----------
    Utx, Uty : array_like, shape (n,)
        Pick-off voltages, V.
    Ux, Uy : array_like, shape (n,)
        Torquer voltages, V (sample k: the voltage that acted on [t(k−1), t(k)]).
    omega_x, omega_y : array_like, shape (n,)
        Case rates held over [t(k−1), t(k)], rad/s.
    sample_period_s : float
        T, s.
    pickoff_scale : float
        Nominal pick-off scale KT, rad/V.
    scheme : {"central", "paper"}
        See the module docstring.
    torquer_average : bool
        Paper scheme only: torquer regressor ½(U(k) + U(k−1)) instead of U(k).

    Returns
    -------
    phi_x, y_x, phi_y, y_y : ndarray
        Rows for k = 2 … n−1: ``phi_*`` shape (n − 2, 5), ``y_*`` shape (n − 2,), such
        that ``y_x ≈ phi_x @ θ`` and ``y_y ≈ phi_y @ θ``.
    """
    tx = check_finite_array("Utx", Utx, ndim=1)
    n = tx.shape[0]
    ty = check_finite_array("Uty", Uty, shape=(n,))
    ux = check_finite_array("Ux", Ux, shape=(n,))
    uy = check_finite_array("Uy", Uy, shape=(n,))
    wx = check_finite_array("omega_x", omega_x, shape=(n,))
    wy = check_finite_array("omega_y", omega_y, shape=(n,))
    T = check_positive("sample_period_s", sample_period_s)
    s = T / check_positive("pickoff_scale", pickoff_scale)
    _check_scheme(scheme)
    if n < 3:
        raise ValueError(f"records must have at least 3 samples, got {n}")
    k, k1, k2 = slice(2, n), slice(1, n - 1), slice(0, n - 2)
    phi_x, y_x, phi_y, y_y = _rows(
        scheme, torquer_average, s, tx[k], ty[k], tx[k1], ty[k1], tx[k2], ty[k2], ux[k],
        uy[k], ux[k1], uy[k1], wx[k], wy[k], wx[k1], wy[k1])
    return np.column_stack(phi_x), np.array(y_x), np.column_stack(phi_y), np.array(y_y)


class CaseRateDTGRegressor:
    """Streaming regressors of both axes with the case rate (see the module docstring).

    Parameters
    ----------
    sample_period_s : float
        T, s.
    pickoff_scale : float
        Nominal pick-off scale KT, rad/V (default 1e−3, the project's gyros).
    scheme : {"central", "paper"}
        Discretisation; θ has five parameters in both.
    torquer_average : bool
        Paper scheme only: torquer regressor ½(U(k) + U(k−1)) (default) instead of U(k).

    Notes
    -----
    After at least three samples :meth:`update` returns the rows of sample k, equal to
    row k − 2 of :func:`dtg_case_rate_regression` on the record; before that, ``None``.
    """

    n_theta = 5

    def __init__(self, sample_period_s: float, pickoff_scale: float = 1.0e-3, *,
                 scheme: CaseRateScheme = "central", torquer_average: bool = True) -> None:
        self.sample_period_s = check_positive("sample_period_s", sample_period_s)
        self.pickoff_scale = check_positive("pickoff_scale", pickoff_scale)
        self.scheme = _check_scheme(scheme)
        self.torquer_average = bool(torquer_average)
        self._s = self.sample_period_s / self.pickoff_scale
        self.reset()

    def reset(self) -> None:
        """Forget the sample history."""
        # [Utx(k−1), Uty(k−1), Utx(k−2), Uty(k−2), Ux(k−1), Uy(k−1), ωx(k−1), ωy(k−1)]
        self._hist = [0.0] * 8
        self._count = 0

    @property
    def ready(self) -> bool:
        """True once two previous samples are available."""
        return self._count >= 2

    def update(
        self, Utx: float, Uty: float, Ux: float, Uy: float, omega_x: float, omega_y: float,
        *, validate: bool = True,
    ) -> tuple[NDArray[np.float64], float, NDArray[np.float64], float] | None:
        """Push one sample (V, V, V, V, rad/s, rad/s); return ``(phi_x, y_x, phi_y, y_y)``.

        Raises
        ------
        ValueError
            On a non-finite value; the history is untouched.
        """
        if validate:
            check_finite_array("(Utx, Uty, Ux, Uy, omega_x, omega_y)",
                               [Utx, Uty, Ux, Uy, omega_x, omega_y], shape=(6,))
        tx, ty, ux, uy = float(Utx), float(Uty), float(Ux), float(Uy)
        wx, wy = float(omega_x), float(omega_y)
        tx1, ty1, tx2, ty2, ux1, uy1, wx1, wy1 = self._hist
        out = None
        if self._count >= 2:
            phi_x, y_x, phi_y, y_y = _rows(self.scheme, self.torquer_average, self._s, tx,
                                           ty, tx1, ty1, tx2, ty2, ux, uy, ux1, uy1, wx,
                                           wy, wx1, wy1)
            out = (np.array(phi_x), float(y_x), np.array(phi_y), float(y_y))
        self._hist = [tx, ty, tx1, ty1, ux, uy, wx, wy]
        self._count = min(self._count + 1, 2)
        return out

    def get_state(self) -> dict[str, Any]:
        """Copy of the sample history."""
        return {"hist": np.array(self._hist), "count": self._count}

    def set_state(self, state: dict[str, Any]) -> None:
        """Restore a state produced by :meth:`get_state`."""
        hist = check_finite_array("state['hist']", state["hist"], shape=(8,))
        count = int(state["count"])
        if not 0 <= count <= 2:
            raise ValueError(f"state['count'] must be 0, 1 or 2, got {count}")
        self._hist = [float(v) for v in hist]
        self._count = count
