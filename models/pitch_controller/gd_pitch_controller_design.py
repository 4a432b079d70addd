"""LQR pitch-attitude controller for the seed-002 aircraft (no FMI knowledge).

Design model: the pitch subsystem z = [α, q, ϑ] of docs/methods.md §4 (v and h do not feed back
into it: columns 1 and 5 of A are zero), elevator δe as input, augmented with the
integral ξ of the pitch error ϑ − ϑ_cmd.  LQR on [α, q, ϑ, ξ] with Q = diag(q_alpha,
q_q, q_theta, q_int), R = r gives u = −K [α, q, ϑ, ξ]; reference tracking uses the exact
trim (N_x, N_u) for a commanded ϑ, so the integral only removes model/sensor offsets::

    δe = N_u ϑ_cmd − K_z (z − N_x ϑ_cmd) − K_i ξ,      ξ' = ϑ − ϑ_cmd

Trim per radian of command: N_u = 3.598 rad elevator, α = −12.0 rad — the seed model
holds ϑ only with a large negative α (so h, which integrates 272.24·(ϑ − α), moves by
≈ 885 m/s per 0.25 rad of command; a zero-mean square wave keeps it bounded).

Default weights (q_alpha, q_q, q_theta, q_int) = (1, 1, 10, 1e-3), r = 100.  Loop broken
at the elevator input, ``control.margin`` on L(s) = K (sI − A_aug)⁻¹ B_aug (continuous)::

    K = [K_α, K_q, K_ϑ, K_i] = [−0.1339, −0.2147, −1.3542, 0.00316]
    closed-loop poles −5.911, −2.160, −0.655, −0.00083 (1/s)
    phase margin 65.0° at 5.29 rad/s; gain margin: the loop gain may drop to 0.447
    (−7.0 dB) before instability (the open loop is unstable), no upper limit;
    delay margin 0.214 s.

Why so gentle: ϑ/δe of the seed model has a right-half-plane zero at +0.0833 1/s, which
bounds the achievable ϑ tracking bandwidth (any design shows a large initial wrong-way
ϑ swing, ≈ −1.1 rad for a +0.25 rad step here, and settles in ≈ 10 s); a stronger
integral only adds overshoot.  The integral (pole −0.00083) is kept weak on purpose:
with a 0.25 rad step ϑ is within 1.5 % of the command 10 s after the step.

The FMU computes δe in ``do_step`` from the sensor values of the step start and
publishes it one communication step later; with the ZOH this costs ≈ 1.5 h of delay, so
keep the communication step ≤ 0.05 s (0.075 s effective delay, inside 0.214 s).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.linalg import solve_continuous_are

_A = np.array([
    [0.0, -1.5122, 1.0],
    [-7.9101, -3.0241, 0.0],
    [0.0, 1.0, 0.0],
])  # rows/cols [α, q, ϑ] of docs/methods.md §4 A
_B = np.array([[-0.2779], [-26.3821], [0.0]])  # elevator column of docs/methods.md §4 B

DEFAULT_WEIGHTS = (1.0, 1.0, 10.0, 1.0e-3)
DEFAULT_R = 100.0


@dataclass(frozen=True)
class PitchDesign:
    """Gains of the LQR pitch controller.

    Attributes
    ----------
    k : ndarray, shape (4,)
        Feedback gains on [α (rad), q (rad/s), ϑ (rad), ξ (rad·s)], rad elevator per unit.
    n_x : ndarray, shape (3,)
        Trim [α, q, ϑ] per radian of pitch command.
    n_u : float
        Trim elevator (rad) per radian of pitch command.
    a_aug, b_aug : ndarray
        Augmented design model (4×4, 4×1) for margin checks.
    """

    k: NDArray[np.float64]
    n_x: NDArray[np.float64]
    n_u: float
    a_aug: NDArray[np.float64]
    b_aug: NDArray[np.float64]


def augmented_model() -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """[α, q, ϑ, ξ] model with ξ' = ϑ (the command enters only through the trim)."""
    a = np.zeros((4, 4))
    a[:3, :3] = _A
    a[3, 2] = 1.0
    b = np.vstack([_B, [[0.0]]])
    return a, b


def design_pitch_controller(q_alpha: float = 1.0, q_q: float = 1.0, q_theta: float = 10.0,
                            q_int: float = 1.0e-3, r: float = DEFAULT_R) -> PitchDesign:
    """LQR gains and trim for the pitch controller.

    Parameters
    ----------
    q_alpha, q_q, q_theta, q_int : float
        State weights (>= 0, q_theta and q_int > 0 so that ϑ and ξ are detectable).
    r : float
        Elevator weight (> 0).
    """
    for name, value in (("q_alpha", q_alpha), ("q_q", q_q)):
        if not (np.isfinite(value) and value >= 0.0):
            raise ValueError(f"{name} must be finite and >= 0, got {value!r}")
    for name, value in (("q_theta", q_theta), ("q_int", q_int), ("r", r)):
        if not (np.isfinite(value) and value > 0.0):
            raise ValueError(f"{name} must be finite and > 0, got {value!r}")
    a, b = augmented_model()
    q = np.diag([q_alpha, q_q, q_theta, q_int])
    p = solve_continuous_are(a, b, q, np.array([[r]]))
    k = (b.T @ p / r).ravel()
    # trim: A z + B δ = 0 with ϑ = 1
    m = np.zeros((4, 4))
    m[:3, :3] = _A
    m[:3, 3:] = _B
    m[3, 2] = 1.0
    sol = np.linalg.solve(m, np.array([0.0, 0.0, 0.0, 1.0]))
    return PitchDesign(k=k, n_x=sol[:3], n_u=float(sol[3]), a_aug=a, b_aug=b)


def loop_margins(design: PitchDesign) -> dict[str, float]:
    """Margins of the loop broken at the elevator (needs python-control).

    Returns
    -------
    dict
        ``gain_margin`` (factor, < 1 means a gain *reduction* destabilises),
        ``phase_margin_deg``, ``w_phase_crossover`` and ``w_gain_crossover`` (rad/s),
        ``delay_margin_s`` = phase margin / gain-crossover frequency.
    """
    import control

    loop = control.ss(design.a_aug, design.b_aug, design.k.reshape(1, 4), 0.0)
    gm, pm, wpc, wgc = control.margin(loop)
    return {
        "gain_margin": float(gm),
        "phase_margin_deg": float(pm),
        "w_phase_crossover": float(wpc),
        "w_gain_crossover": float(wgc),
        "delay_margin_s": float(np.deg2rad(pm) / wgc),
    }


class PitchController:
    """Sampled LQR pitch controller with explicit state (the error integral ξ).

    Parameters
    ----------
    design : PitchDesign
        Gains from :func:`design_pitch_controller`.
    """

    def __init__(self, design: PitchDesign) -> None:
        self.design = design
        self.reset()

    def reset(self) -> None:
        self.xi = 0.0

    def elevator(self, alpha: float, q: float, theta: float, theta_cmd: float) -> float:
        """Elevator command (rad) for the measured α (rad), q (rad/s), ϑ (rad)."""
        d = self.design
        z = np.array([alpha, q, theta]) - d.n_x * theta_cmd
        return float(d.n_u * theta_cmd - d.k[:3] @ z - d.k[3] * self.xi)

    def update(self, h: float, alpha: float, q: float, theta: float, theta_cmd: float) -> float:
        """Elevator for this sample, then integrate the pitch error over h seconds."""
        if not h > 0.0:
            raise ValueError(f"step size h must be > 0 s, got {h!r}")
        delta = self.elevator(alpha, q, theta, theta_cmd)
        self.xi += h * (theta - theta_cmd)
        return delta

    def get_state(self) -> dict[str, float]:
        return {"xi": self.xi}

    def set_state(self, state: dict[str, float]) -> None:
        self.xi = float(state["xi"])

