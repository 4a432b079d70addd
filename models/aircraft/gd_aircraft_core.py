"""Seed-002 longitudinal aircraft model (Ma 0.8, H 50 m), docs/methods.md §4 (no FMI knowledge).

States x = [v (m/s), α (rad), q (rad/s), ϑ (rad), h (m)], all perturbations from trim;
inputs u = [δ_throttle, δ_e (rad)]; sensor outputs y = C x + noise with
y = [v, α, q, ϑ, γ = ϑ − α, h].  ẋ = A x + B u is integrated exactly for an input held
over the step (ZOH) through the matrix exponential of the augmented matrix
[[A, B], [0, 0]]·h, recomputed whenever the step size changes.  Open-loop A has the
unstable eigenvalues +1.459 and +0.991, so long runs need a pitch controller.

Turbulence (optional, ``gust.sigma_w`` > 0): a Dryden gust angle of attack α_g and gust
pitch rate q_g (``gd_aircraft_turbulence``) act as the air-relative parts of α and q in
the force and moment rows (α̇, q̇) of A::

    ẋ = A x + B u + E [α_g, q_g],   E = rows α̇, q̇ of the α and q columns of A

The kinematic rows (ϑ̇ = q, ḣ = V (ϑ − α)) and the sensors see the aircraft's own
states.  Aircraft and gust filter are stepped together exactly: ZOH for u and, for the
white noise driving the filter, the one-step covariance of Van Loan's method, drawn
from its own seeded stream (so switching turbulence on never changes the sensor noise).
The gust state starts from its stationary distribution: turbulence is stationary from
t = 0.  With σ_w = 0 and no gust left the step is the plain 5-state ZOH, bit for bit.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from gd_aircraft_turbulence import DrydenGust, psd_factor, van_loan
from numpy.typing import NDArray
from scipy.linalg import expm

A = np.array([
    [0.0, 0.0, 0.0, 0.0, 0.0],
    [0.0, 0.0, -1.5122, 1.0, 0.0],
    [0.0, -7.9101, -3.0241, 0.0, 0.0],
    [0.0, 0.0, 1.0, 0.0, 0.0],
    [0.0, -272.24, 0.0, 272.24, 0.0],
])
B = np.array([
    [0.0, 0.0],
    [0.0, -0.2779],
    [0.0, -26.3821],
    [0.0, 0.0],
    [0.0, 0.0],
])
C = np.array([
    [1.0, 0.0, 0.0, 0.0, 0.0],
    [0.0, 1.0, 0.0, 0.0, 0.0],
    [0.0, 0.0, 1.0, 0.0, 0.0],
    [0.0, 0.0, 0.0, 1.0, 0.0],
    [0.0, -1.0, 0.0, 1.0, 0.0],
    [0.0, 0.0, 0.0, 0.0, 1.0],
])
STATE_NAMES = ("v", "alpha", "q", "theta", "h")
OUTPUT_NAMES = ("v", "alpha", "q", "theta", "gamma", "h")
INPUT_NAMES = ("throttle", "elevator")
#: Gust input matrix: the air-relative α and q enter the force (α̇) and moment (q̇) rows.
E_GUST = np.zeros((5, 2))
E_GUST[1:3, :] = A[1:3, 1:3]
#: Sub-stream of ``seed`` used for the turbulence (SeedSequence spawn key).
TURBULENCE_STREAM = 1


def zoh_discretise(a: NDArray[np.float64], b: NDArray[np.float64],
                   h: float) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Exact ZOH discretisation (Ad, Bd) of ẋ = a x + b u over a step h (s)."""
    n, m = b.shape
    aug = np.zeros((n + m, n + m))
    aug[:n, :n] = a
    aug[:n, n:] = b
    phi = expm(aug * h)
    return phi[:n, :n], phi[:n, n:]


class AircraftModel:
    """Longitudinal aircraft with exact ZOH stepping, seeded sensor noise and turbulence.

    Parameters
    ----------
    x0 : array_like, shape (5,)
        Initial state [v, α, q, ϑ, h] (m/s, rad, rad/s, rad, m).
    noise_std : array_like, shape (6,)
        Sensor noise standard deviations for y = [v, α, q, ϑ, γ, h], >= 0.
    seed : int
        Noise generator seed (>= 0).  Six normal deviates are drawn per sample whatever
        the standard deviations, so changing one std never changes another's noise.  The
        turbulence uses an independent stream spawned from the same seed.
    gust : DrydenGust, optional
        Turbulence model (default: none, σ_w = 0).  ``sigma_w`` may be changed between
        steps (``set_gust``); the other gust parameters are fixed at ``reset``.
    """

    def __init__(self, x0: Any = (0.0,) * 5, noise_std: Any = (0.0,) * 6, seed: int = 0,
                 gust: DrydenGust | None = None) -> None:
        self.x0 = np.array(x0, dtype=float)
        self.noise_std = np.array(noise_std, dtype=float)
        self.seed = seed
        self.gust = DrydenGust() if gust is None else gust
        self.check()
        self._h: float | None = None
        self._gust_key: tuple[float, DrydenGust] | None = None
        self.reset()

    def check(self) -> None:
        """Validate parameters (they may be tuned between steps)."""
        if self.x0.shape != (5,) or not np.all(np.isfinite(self.x0)):
            raise ValueError(f"x0 must be 5 finite values, got {self.x0!r}")
        if self.noise_std.shape != (6,) or not np.all(np.isfinite(self.noise_std)) \
                or np.any(self.noise_std < 0.0):
            raise ValueError(f"noise_std must be 6 finite values >= 0, got {self.noise_std!r}")
        if isinstance(self.seed, bool) or not isinstance(self.seed, int) or self.seed < 0:
            raise ValueError(f"seed must be an integer >= 0, got {self.seed!r}")
        if not isinstance(self.gust, DrydenGust):
            raise TypeError(f"gust must be a DrydenGust, got {type(self.gust).__name__}")

    def reset(self) -> None:
        """x = x0, reseed the sensor-noise and turbulence generators; gust stationary."""
        self.x = self.x0.copy()
        self._rng = np.random.default_rng(self.seed)
        self._rng_gust = np.random.default_rng(
            np.random.SeedSequence(self.seed, spawn_key=(TURBULENCE_STREAM,)))
        self.g = np.zeros(3)
        self._cg = self.gust.state_space()[2]
        if self.gust.sigma_w > 0.0:
            self.g = psd_factor(self.gust.stationary_covariance()) @ \
                self._rng_gust.standard_normal(3)

    def set_gust(self, gust: DrydenGust) -> None:
        """Change the turbulence model between steps (the gust state is kept)."""
        if not isinstance(gust, DrydenGust):
            raise TypeError(f"gust must be a DrydenGust, got {type(gust).__name__}")
        self.gust = gust
        self._cg = gust.state_space()[2]

    @property
    def gust_output(self) -> NDArray[np.float64]:
        """[α_g (rad), q_g (rad/s)] now."""
        return self._cg @ self.g

    def step(self, h: float, u: NDArray[np.float64]) -> None:
        """Advance the state by h seconds with u = [throttle, elevator] held."""
        if not h > 0.0:
            raise ValueError(f"step size h must be > 0 s, got {h!r}")
        u = np.asarray(u, dtype=float)
        if self.gust.sigma_w == 0.0 and not np.any(self.g):
            self._step_plain(h, u)
            return
        # the same jitter tolerance as the plain step (see there)
        if self._gust_key is None or self._gust_key[1] != self.gust \
                or abs(h - self._gust_key[0]) > 1e-9 * h:
            self._gust_matrices(h)
        z = np.concatenate([self.x, self.g])
        z = self._phi @ z + self._gam @ u + self._noise_factor @ self._rng_gust.standard_normal(8)
        self.x, self.g = z[:5], z[5:]

    def _step_plain(self, h: float, u: NDArray[np.float64]) -> None:
        # Masters compute steps as differences of communication points, so a "constant"
        # step jitters in the last bits; recomputing expm on every jitter cost 0.7 ms a
        # step under fmpy.simulate_fmu. A relative change below 1e-9 keeps the matrices
        # (the time error is then below 1e-9 of a step).
        if self._h is None or abs(h - self._h) > 1e-9 * h:
            self._ad, self._bd = zoh_discretise(A, B, h)
            self._h = h
        self.x = self._ad @ self.x + self._bd @ u

    def _gust_matrices(self, h: float) -> None:
        ag, bg, cg = self.gust.state_space()
        f = np.zeros((8, 8))
        f[:5, :5] = A
        f[:5, 5:] = E_GUST @ cg
        f[5:, 5:] = ag
        g = np.zeros((8, 1))
        g[5:, :] = bg
        bu = np.zeros((8, 2))
        bu[:5, :] = B
        self._phi, self._gam = zoh_discretise(f, bu, h)
        _, qd = van_loan(f, g, h)
        self._noise_factor = psd_factor(qd)
        self._gust_key = (h, self.gust)

    def measure(self) -> NDArray[np.float64]:
        """Sensor sample y = C x + noise_std · n (draws six deviates)."""
        return C @ self.x + self.noise_std * self._rng.standard_normal(6)

    def get_state(self) -> dict[str, Any]:
        return {"x": self.x.copy(), "rng": self._rng.bit_generator.state,
                "g": self.g.copy(), "rng_gust": self._rng_gust.bit_generator.state,
                "sigma_w": self.gust.sigma_w}

    def set_state(self, state: dict[str, Any]) -> None:
        self.x = np.array(state["x"], dtype=float)
        rng = np.random.default_rng()
        rng.bit_generator.state = dict(state["rng"])
        self._rng = rng
        self.g = np.array(state["g"], dtype=float)
        rng_gust = np.random.default_rng()
        rng_gust.bit_generator.state = dict(state["rng_gust"])
        self._rng_gust = rng_gust
        self.set_gust(DrydenGust(float(state["sigma_w"]), self.gust.scale_length,
                                 self.gust.airspeed, self.gust.wingspan))
