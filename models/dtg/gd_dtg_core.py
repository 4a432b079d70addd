"""Dynamically tuned gyro (DTG) rotor with its digital rebalance loop, no FMI in it.

The rotor (docs/methods.md §2), with the case turning at ωx, ωy about the case axes::

    J(α'' + ω̇x) + c α' + k α + L(β' + ωy) + λ β = Ku·Ux
    J(β'' + ω̇y) + c β' + k β − L(α' + ωx) − λ α = Ku·Uy

α, β are rotor tilts relative to the case (rad); J(α''+ω̇x) and L(β'+ωy) act on the
rotor's inertial rates, the springs and dampers on the relative motion. State
``x = [α, β, p, q]`` with the rotor's inertial transverse rates ``p = α' + ωx``,
``q = β' + ωy``: with ω held (zero-order hold) over an interval the system is LTI, and a
step of ω between intervals leaves p, q continuous and makes α' jump by −Δω — exactly
the impulse J·ω̇ of a step in case rate. So ω is treated as piecewise constant; no
slope estimate is needed.

Pick-offs ``Utx = α/KT + nx``, ``Uty = β/KT + ny`` (V). Torquers ``M = Ku·U``. The
rebalance loop is a discrete controller at its own sample time ``Tc``: at each tick it
samples the pick-offs (noise drawn per tick and held until the next one), forms
``e = −R(ψ)·[Utx, Uty]`` with R a rotation by the loop phasing angle ψ
(ψ = −sign(L)·90° is the classic cross-axis rebalance ``ex = −sign(L)·Uty``,
``ey = +sign(L)·Utx``; ψ = 0 direct-axis feedback) and applies ``U = C(z)·e`` at once,
held until the next tick. ``C`` is a PI with lead and a second-order low-pass, designed
in continuous time and discretised by Tustin. At steady state the rotor sits at null
and ``Ku·Ux = L·ωy``, ``Ku·Uy = −L·ωx``: the torquer voltages are the rate read-out.

Between ticks the plant is integrated exactly with the matrix exponential; matrices are
cached per interval length and dropped whenever a fault parameter changes.

No scipy here: the matrix exponential (scaling and squaring with Padé approximants,
Higham 2005) and the Tustin discretisation of the controller (controllable canonical
form, the formulas of ``scipy.signal.tf2ss`` and ``cont2discrete(method="bilinear")``)
are a few lines of numpy, and importing scipy.signal and scipy.linalg would cost about
2 s of every DTG.fmu instantiation (tests/test_dtg_fast_path.py checks both against
scipy).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields

import numpy as np
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]

@dataclass(frozen=True)
class DTGParameterSet:
    """Physical constants, pick-off/torquer scales and rebalance-loop design of one gyro.

    Parameters
    ----------
    name : str
        Short name of the set.
    J : float
        Rotor transverse inertia (kg·m²).
    Jz : float
        Rotor polar inertia (kg·m²).
    Ie : float
        Gimbal transverse inertia entering L and the dynamic spring (kg·m²).
    Iz : float
        Gimbal polar inertia entering the dynamic spring (kg·m²).
    K : float
        Flexure torsional stiffness (N·m/rad); tuned when K = (Ie − Iz/2)·Ω².
    c : float
        Flexure damping (N·m·s/rad).
    D : float
        Windage damping of the spinning rotor (N·m·s/rad); λ = (c + D)·Ω.
    spin_rate : float
        Nominal spin rate Ω (rad/s); its sign is the spin direction and sets the signs of
        L and λ.
    KT : float
        Pick-off scale (rad/V): α = KT·Utx.
    Ku : float
        Torquer scale (N·m/V): M = Ku·U.
    controller_sample_time : float
        Sample time Tc of the digital rebalance loop (s).
    kp : float
        Proportional gain of the rebalance controller (V/V).
    ki : float
        Integral corner of the PI, C ∝ (1 + ki/s) (rad/s).
    lead_zero, lead_pole : float
        Lead corner frequencies (rad/s); equal values mean no lead.
    filter_corner, filter_damping : float
        Second-order low-pass 1/(s²/ωf² + 2ζ s/ωf + 1) of the loop (pick-off demodulator
        ripple filter): corner ωf (rad/s) and damping ζ (-).
    loop_rotation : float
        Phasing angle ψ (rad) of the loop: the controller input is −R(ψ)·[Utx, Uty] with
        R the rotation matrix, so ψ = −sign(L)·π/2 is the pure cross-axis rebalance
        ``ex = −sign(L)·Uty``, ``ey = +sign(L)·Utx`` and ψ = 0 pure direct-axis feedback.
    """

    name: str
    J: float
    Jz: float
    Ie: float
    Iz: float
    K: float
    c: float
    D: float
    spin_rate: float
    KT: float
    Ku: float
    controller_sample_time: float
    kp: float
    ki: float
    lead_zero: float
    lead_pole: float
    filter_corner: float
    filter_damping: float
    loop_rotation: float

    def __post_init__(self) -> None:
        for f in fields(self):
            value = getattr(self, f.name)
            if f.name == "name":
                continue
            if not math.isfinite(value):
                raise ValueError(f"{f.name} must be finite, got {value!r}")
            if f.name in {"spin_rate", "K", "loop_rotation"}:
                continue
            if f.name in {"c", "D", "ki", "Ie", "Iz"}:
                if value < 0.0:
                    raise ValueError(f"{f.name} must be >= 0, got {value!r}")
            elif value <= 0.0:
                raise ValueError(f"{f.name} must be > 0, got {value!r}")


@dataclass(frozen=True)
class RotorCoefficients:
    """Coefficients of the rotor equations at one operating point (SI units)."""

    J: float
    c: float
    k: float
    L: float
    lam: float
    Ku: float
    KT: float


def rotor_coefficients(
    p: DTGParameterSet,
    *,
    spin_fraction: float = 1.0,
    k_offset: float = 0.0,
    damping_scale: float = 1.0,
    torquer_scale: float = 1.0,
    pickoff_scale: float = 1.0,
) -> RotorCoefficients:
    """Rotor coefficients with the physical faults applied.

    Parameters
    ----------
    p : DTGParameterSet
        The gyro.
    spin_fraction : float
        Ω/Ω_nominal (-); scales L and λ linearly and k through the dynamic spring.
    k_offset : float
        Detuning added to k (N·m/rad).
    damping_scale : float
        Multiplies the flexure damping c (-) (also inside λ).
    torquer_scale, pickoff_scale : float
        Multiply Ku and KT (-).

    Returns
    -------
    RotorCoefficients
    """
    omega = spin_fraction * p.spin_rate
    c = damping_scale * p.c
    return RotorCoefficients(
        J=p.J,
        c=c,
        k=p.K - (p.Ie - p.Iz / 2) * omega**2 + k_offset,
        L=(p.Jz + p.Ie) * omega,
        lam=(c + p.D) * omega,
        Ku=torquer_scale * p.Ku,
        KT=pickoff_scale * p.KT,
    )


def rotor_state_space(r: RotorCoefficients) -> tuple[FloatArray, FloatArray]:
    """Continuous state space of the rotor.

    Returns
    -------
    A : ndarray, shape (4, 4)
        For x = [α, β, p, q] (rad, rad, rad/s, rad/s).
    B : ndarray, shape (4, 4)
        For inputs [ωx, ωy, Ux, Uy] (rad/s, rad/s, V, V).
    """
    J, c, k, L, lam = r.J, r.c, r.k, r.L, r.lam
    A = np.array(
        [
            [0.0, 0.0, 1.0, 0.0],
            [0.0, 0.0, 0.0, 1.0],
            [-k / J, -lam / J, -c / J, -L / J],
            [lam / J, -k / J, L / J, -c / J],
        ]
    )
    B = np.array(
        [
            [-1.0, 0.0, 0.0, 0.0],
            [0.0, -1.0, 0.0, 0.0],
            [c / J, 0.0, r.Ku / J, 0.0],
            [0.0, c / J, 0.0, r.Ku / J],
        ]
    )
    return A, B


#: Padé coefficients b_0..b_m of exp and the 1-norm bounds θ_m up to which the degree-m
#: approximant is accurate to double precision (Higham 2005, Table 2.3 and eq. 2.1).
_PADE_COEFFICIENTS: dict[int, tuple[float, ...]] = {
    3: (120.0, 60.0, 12.0, 1.0),
    5: (30240.0, 15120.0, 3360.0, 420.0, 30.0, 1.0),
    7: (17297280.0, 8648640.0, 1995840.0, 277200.0, 25200.0, 1512.0, 56.0, 1.0),
    9: (17643225600.0, 8821612800.0, 2075673600.0, 302702400.0, 30270240.0, 2162160.0,
        110880.0, 3960.0, 90.0, 1.0),
    13: (64764752532480000.0, 32382376266240000.0, 7771770303897600.0,
         1187353796428800.0, 129060195264000.0, 10559470521600.0, 670442572800.0,
         33522128640.0, 1323241920.0, 40840800.0, 960960.0, 16380.0, 182.0, 1.0),
}
_PADE_THETA = {3: 1.495585217958292e-2, 5: 2.539398330063230e-1, 7: 9.504178996162932e-1,
               9: 2.097847961257068e0, 13: 5.371920351148152e0}


def expm(a: NDArray) -> NDArray:
    """Matrix exponential of a square real or complex matrix.

    Scaling and squaring with the [m/m] Padé approximant of the lowest degree m in
    {3, 5, 7, 9, 13} that is accurate for the 1-norm of ``a`` (N. J. Higham, "The scaling
    and squaring method for the matrix exponential revisited", SIAM J. Matrix Anal. Appl.
    26(4), 2005, Algorithm 2.3). Agrees with ``scipy.linalg.expm`` to rounding.
    """
    a = np.asarray(a)
    if a.ndim != 2 or a.shape[0] != a.shape[1]:
        raise ValueError(f"a must be a square matrix, got shape {a.shape}")
    if not np.issubdtype(a.dtype, np.inexact):
        a = a.astype(float)
    n = a.shape[0]
    ident = np.eye(n, dtype=a.dtype)
    norm = float(np.max(np.sum(np.abs(a), axis=0))) if n else 0.0
    if not math.isfinite(norm):
        raise ValueError("a must be finite")
    squarings = 0
    for m in (3, 5, 7, 9):
        if norm <= _PADE_THETA[m]:
            b = _PADE_COEFFICIENTS[m]
            powers = [ident, a @ a]
            while len(powers) <= m // 2:
                powers.append(powers[-1] @ powers[1])
            u = a @ sum(b[2 * j + 1] * powers[j] for j in range(m // 2 + 1))
            v = sum(b[2 * j] * powers[j] for j in range(m // 2 + 1))
            break
    else:
        if norm > _PADE_THETA[13]:
            squarings = max(0, math.ceil(math.log2(norm / _PADE_THETA[13])))
            a = a / 2.0**squarings
        b = _PADE_COEFFICIENTS[13]
        a2 = a @ a
        a4 = a2 @ a2
        a6 = a4 @ a2
        u = a @ (a6 @ (b[13] * a6 + b[11] * a4 + b[9] * a2)
                 + b[7] * a6 + b[5] * a4 + b[3] * a2 + b[1] * ident)
        v = (a6 @ (b[12] * a6 + b[10] * a4 + b[8] * a2)
             + b[6] * a6 + b[4] * a4 + b[2] * a2 + b[0] * ident)
    result = np.linalg.solve(v - u, v + u)
    for _ in range(squarings):
        result = result @ result
    return result


def zoh_discretize(A: FloatArray, B: FloatArray, dt: float) -> tuple[FloatArray, FloatArray]:
    """Exact discretisation with inputs held over ``dt`` (s): x⁺ = Ad·x + Bd·u."""
    n, m = B.shape
    aug = np.zeros((n + m, n + m), dtype=np.result_type(A, B))
    aug[:n, :n] = A * dt
    aug[:n, n:] = B * dt
    e = expm(aug)
    return e[:n, :n], e[:n, n:]


def controller_matrices(
    p: DTGParameterSet,
) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
    """Discrete (Tustin) state space of the rebalance controller.

    C(s) = kp·(1 + ki/s)·(1 + s/ωz)/(1 + s/ωp) / (s²/ωf² + 2ζ·s/ωf + 1).

    Returns
    -------
    Ac, Bc, Cc, Dc : ndarray
        xc⁺ = Ac·xc + Bc·e, u = Cc·xc + Dc·e, one SISO copy per axis (e in V, u in V).
    """
    num = p.kp * np.array([1.0, p.ki])
    den = np.array([1.0, 0.0])
    if p.lead_zero != p.lead_pole:
        num = np.polymul(num, [1.0 / p.lead_zero, 1.0])
        den = np.polymul(den, [1.0 / p.lead_pole, 1.0])
    wf = p.filter_corner
    den = np.polymul(den, [1.0 / wf**2, 2.0 * p.filter_damping / wf, 1.0])
    # controllable canonical form of num/den (what scipy.signal.tf2ss returns)
    num, den = num / den[0], den / den[0]
    order = len(den) - 1
    num = np.concatenate([np.zeros(order + 1 - len(num)), num])
    A = np.vstack([-den[1:], np.eye(order - 1, order)])
    B = np.eye(order, 1)
    C = (num[1:] - num[0] * den[1:]).reshape(1, -1)
    D = num[0]
    # Tustin (scipy.signal.cont2discrete, method="bilinear": gbt with alpha = 1/2)
    Tc = p.controller_sample_time
    ident = np.eye(order)
    ima = ident - 0.5 * Tc * A
    Ac = np.linalg.solve(ima, ident + 0.5 * Tc * A)
    Bc = np.linalg.solve(ima, Tc * B)
    Cc = np.linalg.solve(ima.T, C.T).T
    Dc = D + 0.5 * (C @ Bc)
    return (
        np.asarray(Ac, dtype=float),
        np.asarray(Bc, dtype=float).reshape(-1),
        np.asarray(Cc, dtype=float).reshape(-1),
        np.asarray(Dc, dtype=float).reshape(()),
    )
