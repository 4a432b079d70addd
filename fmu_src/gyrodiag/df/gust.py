"""Dryden turbulence as a disturbance model of the monitored plant (docs/methods.md §4.6).

A vertical gust w_g and the pitch-rate gust q_g act on the aircraft through a known
input matrix E (n × 2) on ``[α_g, q_g] = [w_g / V, q_g]``::

    ẋ = A x + B u + E Cg g,    ġ = Ag g + Bg n,    n white, unit intensity

with the Dryden shaping filter (Ag, Bg, Cg) of MIL-F-8785C (the Aircraft FMU's
``gd_aircraft_turbulence``; ``tests/test_df_gust.py`` checks that the two agree). For
the seed aircraft E holds the α and q columns of A in the α̇ and q̇ rows: the gust
changes the air-relative angle of attack and pitch rate, not the kinematics.

:meth:`GustModel.discrete` gives what a sampled observer needs: how the gust state
enters the state over one sample and the process-noise covariance, so that the
observer's residual can be whitened with the gust in its model
(:class:`~gyrodiag.df.residual.ResidualModel` ``disturbance``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import scipy.linalg
from numpy.typing import ArrayLike, NDArray

from ..common._validation import check_finite_array

__all__ = ["GustModel", "seed_gust_input"]

_FloatArray = NDArray[np.float64]

#: Airspeed of the seed aircraft, m/s (the ḣ = V (ϑ − α) coefficient of its A).
SEED_AIRSPEED = 272.24


#: Discretisations already computed (small: a diagnoser has one plant and period).
_CACHE: dict[tuple, tuple[_FloatArray, _FloatArray, _FloatArray]] = {}


def seed_gust_input(A: ArrayLike) -> _FloatArray:
    """E of a plant with the seed aircraft's state order [v, α, q, ϑ, h]: rows α̇, q̇
    of A's α and q columns (n × 2)."""
    a = np.asarray(A, dtype=float)
    if a.ndim != 2 or a.shape[0] < 3 or a.shape[0] != a.shape[1]:
        raise ValueError(f"A must be square with at least 3 states [v, α, q, …] for the "
                         f"seed gust input, got shape {a.shape}")
    e = np.zeros((a.shape[0], 2))
    e[1:3, :] = a[1:3, 1:3]
    return e


def _positive(name: str, value: float) -> float:
    v = float(value)
    if not math.isfinite(v) or v <= 0.0:
        raise ValueError(f"{name} must be finite and > 0, got {value!r}")
    return v


@dataclass(frozen=True)
class GustModel:
    """Dryden gust of design intensity ``sigma_w`` entering the plant through E.

    Parameters
    ----------
    sigma_w : float
        Vertical gust intensity σ_w the residual model assumes, m/s (> 0).
    scale_length : float
        Scale length L_w, m.
    airspeed : float
        True airspeed V, m/s.
    wingspan : float
        Span b of the pitch-rate gust filter 4b/(πV), m.
    input_matrix : array_like, shape (n, 2), optional
        E on [α_g, q_g]; default :func:`seed_gust_input` of the plant.
    """

    sigma_w: float = 2.3
    scale_length: float = 50.0
    airspeed: float = SEED_AIRSPEED
    wingspan: float = 10.0
    input_matrix: ArrayLike | None = None

    def __post_init__(self) -> None:
        for name in ("sigma_w", "scale_length", "airspeed", "wingspan"):
            _positive(name, getattr(self, name))

    def filter(self) -> tuple[_FloatArray, _FloatArray, _FloatArray]:
        """(Ag (3×3), Bg (3×1), Cg (2×3)) of the shaping filter, outputs [α_g, q_g] (rad,
        rad/s), for unit-intensity white noise; σ_w is in Bg."""
        tw = self.scale_length / self.airspeed
        tq = 4.0 * self.wingspan / (math.pi * self.airspeed)
        v = self.airspeed
        k = math.sqrt(tw) / tw**2
        s3 = math.sqrt(3.0) * tw
        a_w = np.array([[0.0, 1.0], [-1.0 / tw**2, -2.0 / tw]])
        c_w = k * np.array([1.0, s3])
        ag = np.zeros((3, 3))
        ag[:2, :2] = a_w
        ag[2, :2] = -(c_w @ a_w) / (v * tq)
        ag[2, 2] = -1.0 / tq
        bg = np.zeros((3, 1))
        bg[1, 0] = self.sigma_w
        bg[2, 0] = -self.sigma_w * k * s3 / (v * tq)
        cg = np.zeros((2, 3))
        cg[0, :2] = c_w / v
        cg[1, 2] = 1.0
        return ag, bg, cg

    def input_for(self, A: _FloatArray) -> _FloatArray:
        """E (n × 2) for the plant A."""
        if self.input_matrix is None:
            return seed_gust_input(A)
        return check_finite_array("gust input_matrix", self.input_matrix,
                                  shape=(A.shape[0], 2))

    def discrete(self, A: _FloatArray, sample_period_s: float
                 ) -> tuple[_FloatArray, _FloatArray, _FloatArray]:
        """(Φ_xg (n × 3), Φ_g (3 × 3), Q ((n+3) × (n+3))) over one sample.

        x⁺ = Φ x + Γ u + Φ_xg g + w_x, g⁺ = Φ_g g + w_g, cov([w_x; w_g]) = Q (Van Loan).
        Memoised per (model, A, period): every residual generator of a diagnoser asks.
        """
        a = np.ascontiguousarray(A, dtype=float)
        e = self.input_for(a)
        key = (self.sigma_w, self.scale_length, self.airspeed, self.wingspan, a.shape,
               a.tobytes(), e.tobytes(), float(sample_period_s))
        if key not in _CACHE:
            if len(_CACHE) >= 16:
                _CACHE.clear()
            _CACHE[key] = self._discrete(a, e, float(sample_period_s))
        phi_xg, phi_g, q = _CACHE[key]
        return phi_xg.copy(), phi_g.copy(), q.copy()

    def _discrete(self, A: _FloatArray, E: _FloatArray, sample_period_s: float
                  ) -> tuple[_FloatArray, _FloatArray, _FloatArray]:
        n = A.shape[0]
        ag, bg, cg = self.filter()
        f = np.zeros((n + 3, n + 3))
        f[:n, :n] = A
        f[:n, n:] = E @ cg
        f[n:, n:] = ag
        g = np.zeros((n + 3, 1))
        g[n:] = bg
        size = 2 * (n + 3)
        m = np.zeros((size, size))
        m[:n + 3, :n + 3] = -f
        m[:n + 3, n + 3:] = g @ g.T
        m[n + 3:, n + 3:] = f.T
        e = scipy.linalg.expm(m * sample_period_s)
        phi = e[n + 3:, n + 3:].T
        q = phi @ e[:n + 3, n + 3:]
        return phi[:n, n:].copy(), phi[n:, n:].copy(), 0.5 * (q + q.T)

    def output_std(self) -> _FloatArray:
        """Stationary standard deviations of [α_g (rad), q_g (rad/s)]."""
        ag, bg, cg = self.filter()
        p = scipy.linalg.solve_continuous_lyapunov(ag, -bg @ bg.T)
        return np.sqrt(np.diag(cg @ p @ cg.T))
