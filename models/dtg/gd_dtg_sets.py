"""The two documented DTG parameter sets (reasoning for every value in README.md)."""

from __future__ import annotations

import math

from gd_dtg_core import DTGParameterSet

#: Index of each set, the FMU's Integer parameter ``parameter_set``.
PAPER = 1
PRODUCTION = 2

#: The paper's measured nominal θ (docs/methods.md §2) and its sample time (s).
PAPER_THETA_NOM = (1.9951, 0.9959, -0.0288, -0.0303, 0.0002)
PAPER_SAMPLE_TIME = 1.0e-3


def paper_set() -> DTGParameterSet:
    """Set (a): the rotor whose backward-difference θ at T = 1 ms is the paper's θ_nom.

    Inverting θ_nom (docs/methods.md §2) gives, per unit J: c/J = 3.314 1/s, k/J = 803.3 1/s²,
    L/J = −30.42 rad/s, |λ|/J = 1506 1/s², Ku/(KT·J) = 200.8 1/s². J, Jz, Ie, Iz and KT
    are chosen; c, k (hence K), L (hence Ω), |λ| (hence D) and Ku follow.
    """
    t1, t2, t3, t4, t5 = PAPER_THETA_NOM
    T = PAPER_SAMPLE_TIME
    J = 1.0e-5
    Jz = 1.5e-5
    Ie = 2.0e-8
    Iz = 1.0e-8
    KT = 1.0e-3
    c = J * (t1 - 2 * t2) / (t2 * T)
    k = J * (1 - t1 + t2) / (t2 * T**2)
    L = J * t4 / (t2 * T)
    lam_abs = J * abs(t3 - t4) / (t2 * T**2)
    Ku = KT * J * t5 / (t2 * T**2)
    spin = L / (Jz + Ie)
    # λ = (c + D)·Ω carries the sign of Ω like L does: only |λ| can be matched.
    D = lam_abs / abs(spin) - c
    K = k + (Ie - Iz / 2) * spin**2
    return DTGParameterSet(
        name="paper", J=J, Jz=Jz, Ie=Ie, Iz=Iz, K=K, c=c, D=D, spin_rate=spin,
        KT=KT, Ku=Ku, controller_sample_time=1.0e-3,
        kp=10.0, ki=5.0, lead_zero=30.0, lead_pole=600.0,
        filter_corner=2 * math.pi * 300.0, filter_damping=0.7, loop_rotation=0.0,

    )


def production_set() -> DTGParameterSet:
    """Set (b): a tuned production-like DTG, nutation ≈ 300 Hz, 10 kHz digital loop."""
    spin = 2 * math.pi * 200.0  # 12 000 rpm
    J = 2.0e-6
    Jz = 3.0e-6
    Ie = 2.0e-8
    Iz = 1.0e-8
    KT = 1.0e-3
    Ku = 5.0e-5
    L = (Jz + Ie) * spin
    crossover = 2 * math.pi * 20.0
    return DTGParameterSet(
        name="production", J=J, Jz=Jz, Ie=Ie, Iz=Iz,
        K=(Ie - Iz / 2) * spin**2,  # tuned: k = 0 at nominal spin
        c=2.0e-8, D=1.0e-8, spin_rate=spin, KT=KT, Ku=Ku,
        controller_sample_time=1.0e-4,
        # low-frequency loop ≈ kp·Ku/(KT·L·s): kp sets the 20 Hz crossover
        kp=crossover * KT * L / Ku, ki=crossover / 4, lead_zero=1.0, lead_pole=1.0,
        filter_corner=2 * math.pi * 150.0, filter_damping=0.7,
        loop_rotation=-math.copysign(math.pi / 2, L),

    )


PARAMETER_SETS = {PAPER: paper_set, PRODUCTION: production_set}


def parameter_set(index: int) -> DTGParameterSet:
    """The parameter set numbered ``index`` (1 = paper, 2 = production)."""
    try:
        return PARAMETER_SETS[int(index)]()
    except KeyError:
        raise ValueError(
            f"parameter_set must be one of {sorted(PARAMETER_SETS)}, got {index!r}"
        ) from None
