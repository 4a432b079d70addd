"""Dryden vertical-gust and pitch-rate-gust shaping filters for the seed aircraft.

Continuous Dryden model (MIL-F-8785C form) for an aircraft at airspeed V flying through
a frozen turbulence field, driven by unit-intensity white noise n(t),
E[n(t) n(s)] = δ(t − s)::

    w_g = H_w(s) n,   H_w(s) = σ_w √τ_w · (1 + √3 τ_w s) / (1 + τ_w s)²,   τ_w = L_w / V
    q_g = H_q(s) w_g, H_q(s) = −(s / V) / (1 + τ_q s),                    τ_q = 4 b / (π V)
    α_g = w_g / V

w_g (m/s) is the vertical gust velocity, α_g (rad) the gust angle of attack, q_g (rad/s)
the gust pitch rate (gust gradient along the fuselage; the sign is MIL-F-8785C's, the
handbook MIL-HDBK-1797 uses +).  The specification writes H_w with the factor
σ_w √(L_w/(π V)) for white noise of one-sided spectral density 1 in rad/s; with the
unit-intensity noise used here the factor σ_w √τ_w gives the same spectrum, and the
stationary variance of w_g is exactly σ_w² (∫|H_w(jω)|² dω / 2π = K²/τ_w).

Low altitude (h < 1000 ft) MIL-F-8785C: L_w = h and σ_w = 0.1·W20 (W20 the wind speed at
20 ft: light 15 kt ≈ 0.77 m/s, moderate 30 kt ≈ 1.5 m/s, severe 45 kt ≈ 2.3 m/s).  The
seed aircraft flies at H = 50 m, so the defaults are L_w = 50 m, V = 272.24 m/s (the
kinematic coefficient of ḣ in docs/methods.md §4's A) and a span b of 10 m.

State space of the filter: g = [w-filter state (2), q-filter state (1)], output
[α_g, q_g]; ``g' = Ag g + Bg n``, ``[α_g, q_g] = Cg g`` (no feed-through: H_w has
relative degree 1).  ``σ_w`` sits in Bg only, so a change of intensity during a run acts
on the noise to come and the gust already present decays with the filter's own
dynamics.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.linalg import expm, solve_continuous_lyapunov

FloatArray = NDArray[np.float64]

#: Airspeed of the seed aircraft (m/s): the ḣ = V (ϑ − α) coefficient of docs/methods.md §4's A.
SEED_AIRSPEED = 272.24
DEFAULT_SCALE_LENGTH = 50.0
DEFAULT_WINGSPAN = 10.0


def _check(name: str, value: float, *, positive: bool) -> float:
    v = float(value)
    if not math.isfinite(v) or (v <= 0.0 if positive else v < 0.0):
        raise ValueError(f"{name} must be finite and {'> 0' if positive else '>= 0'}, "
                         f"got {value!r}")
    return v


@dataclass(frozen=True)
class DrydenGust:
    """Dryden shaping filter of the vertical gust and the pitch-rate gust.

    Parameters
    ----------
    sigma_w : float
        Vertical gust intensity σ_w (m/s, >= 0; 0 = no turbulence).
    scale_length : float
        Scale length L_w (m, > 0).
    airspeed : float
        True airspeed V (m/s, > 0).
    wingspan : float
        Span b (m, > 0) of the pitch-rate gust filter.
    """

    sigma_w: float = 0.0
    scale_length: float = DEFAULT_SCALE_LENGTH
    airspeed: float = SEED_AIRSPEED
    wingspan: float = DEFAULT_WINGSPAN

    def __post_init__(self) -> None:
        _check("sigma_w", self.sigma_w, positive=False)
        _check("scale_length", self.scale_length, positive=True)
        _check("airspeed", self.airspeed, positive=True)
        _check("wingspan", self.wingspan, positive=True)

    @property
    def tau_w(self) -> float:
        """Time constant L_w / V of the vertical gust filter (s)."""
        return self.scale_length / self.airspeed

    @property
    def tau_q(self) -> float:
        """Time constant 4 b / (π V) of the pitch-rate gust filter (s)."""
        return 4.0 * self.wingspan / (math.pi * self.airspeed)

    def state_space(self) -> tuple[FloatArray, FloatArray, FloatArray]:
        """(Ag (3×3), Bg (3×1), Cg (2×3)) for unit-intensity white noise, outputs [α_g, q_g].

        Controllable canonical form of H_w with states [w1, w2] (w1' = w2), w_g =
        K (w1 + √3 τ_w w2) with K = σ_w √τ_w / τ_w²; the q filter state r obeys
        r' = (−r − w_g' / V) / τ_q and q_g = r.  w_g' has no white-noise part (relative
        degree 1 of H_w), so it is a combination of w1, w2.
        """
        tw, tq, V = self.tau_w, self.tau_q, self.airspeed
        k = math.sqrt(tw) / tw**2  # σ_w is in Bg
        s3 = math.sqrt(3.0) * tw
        # (1 + τ s)² = τ² (s² + 2 s/τ + 1/τ²)
        a_w = np.array([[0.0, 1.0], [-1.0 / tw**2, -2.0 / tw]])
        c_w = k * np.array([1.0, s3])          # w_g = c_w · [w1, w2]
        c_wdot = c_w @ a_w                     # w_g' = c_wdot · [w1, w2] (+ k s3 n, see below)
        # w_g' = c_w (a_w w + b_w n) contains k·s3·n: a white part.  It enters q_g through
        # 1/(1 + τ_q s), which is proper, so write r = q_g and r' = (−r − w_g'/V)/τ_q: the
        # white part goes into Bg of the r state.
        ag = np.zeros((3, 3))
        ag[:2, :2] = a_w
        ag[2, :2] = -c_wdot / (V * tq)
        ag[2, 2] = -1.0 / tq
        bg = np.zeros((3, 1))
        bg[1, 0] = self.sigma_w
        bg[2, 0] = -self.sigma_w * k * s3 / (V * tq)
        cg = np.zeros((2, 3))
        cg[0, :2] = c_w / V
        cg[1, 2] = 1.0
        return ag, bg, cg

    def frequency_response(self, omega: NDArray[np.float64]) -> FloatArray:
        """Analytic H(jω) of [α_g, q_g] per unit white noise (complex, shape (2, n))."""
        s = 1j * np.asarray(omega, dtype=float)
        tw, tq, V = self.tau_w, self.tau_q, self.airspeed
        hw = self.sigma_w * math.sqrt(tw) * (1.0 + math.sqrt(3.0) * tw * s) / (1.0 + tw * s) ** 2
        hq = -(s / V) / (1.0 + tq * s) * hw
        return np.vstack([hw / V, hq])

    def stationary_covariance(self) -> FloatArray:
        """Stationary covariance of the filter state g (3×3)."""
        ag, bg, _ = self.state_space()
        return solve_continuous_lyapunov(ag, -bg @ bg.T)

    def output_std(self) -> FloatArray:
        """Stationary standard deviations of [α_g (rad), q_g (rad/s)]."""
        _, _, cg = self.state_space()
        return np.sqrt(np.diag(cg @ self.stationary_covariance() @ cg.T))


def van_loan(f: FloatArray, g: FloatArray, h: float) -> tuple[FloatArray, FloatArray]:
    """(Φ, Qd) of x' = F x + G n over h for unit-intensity white noise n (Van Loan 1978).

    Qd = ∫₀ʰ e^{F s} G Gᵀ e^{Fᵀ s} ds, the covariance the noise adds over one step.
    """
    n = f.shape[0]
    m = np.zeros((2 * n, 2 * n))
    m[:n, :n] = -f
    m[:n, n:] = g @ g.T
    m[n:, n:] = f.T
    e = expm(m * h)
    phi = e[n:, n:].T
    qd = phi @ e[:n, n:]
    return phi, 0.5 * (qd + qd.T)


def psd_factor(q: FloatArray) -> FloatArray:
    """S with S Sᵀ = q for a symmetric positive semi-definite q (eigen-decomposition;
    directions the noise does not reach, e.g. airspeed, get exactly zero)."""
    w, v = np.linalg.eigh(0.5 * (q + q.T))
    tol = max(float(w.max(initial=0.0)), 0.0) * q.shape[0] * np.finfo(float).eps
    w = np.where(w > tol, w, 0.0)
    return v * np.sqrt(w)
