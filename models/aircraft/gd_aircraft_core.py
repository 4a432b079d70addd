"""Seed-002 longitudinal aircraft model (Ma 0.8, H 50 m), DESIGN §4 (no FMI knowledge).

States x = [v (m/s), α (rad), q (rad/s), ϑ (rad), h (m)], all perturbations from trim;
inputs u = [δ_throttle, δ_e (rad)]; sensor outputs y = C x + noise with
y = [v, α, q, ϑ, γ = ϑ − α, h].  ẋ = A x + B u is integrated exactly for an input held
over the step (ZOH) through the matrix exponential of the augmented matrix
[[A, B], [0, 0]]·h, recomputed whenever the step size changes.  Open-loop A has the
unstable eigenvalues +1.459 and +0.991, so long runs need a pitch controller.
"""

from __future__ import annotations

from typing import Any

import numpy as np
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
    """Longitudinal aircraft with exact ZOH stepping and seeded sensor noise.

    Parameters
    ----------
    x0 : array_like, shape (5,)
        Initial state [v, α, q, ϑ, h] (m/s, rad, rad/s, rad, m).
    noise_std : array_like, shape (6,)
        Sensor noise standard deviations for y = [v, α, q, ϑ, γ, h], >= 0.
    seed : int
        Noise generator seed (>= 0).  Six normal deviates are drawn per sample whatever
        the standard deviations, so changing one std never changes another's noise.
    """

    def __init__(self, x0: Any = (0.0,) * 5, noise_std: Any = (0.0,) * 6, seed: int = 0) -> None:
        self.x0 = np.array(x0, dtype=float)
        self.noise_std = np.array(noise_std, dtype=float)
        self.seed = seed
        self.check()
        self._h: float | None = None
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

    def reset(self) -> None:
        """x = x0, reseed the sensor-noise generator."""
        self.x = self.x0.copy()
        self._rng = np.random.default_rng(self.seed)

    def step(self, h: float, u: NDArray[np.float64]) -> None:
        """Advance the state by h seconds with u = [throttle, elevator] held."""
        if not h > 0.0:
            raise ValueError(f"step size h must be > 0 s, got {h!r}")
        # Masters compute steps as differences of communication points, so a "constant"
        # step jitters in the last bits; recomputing expm on every jitter cost 0.7 ms a
        # step under fmpy.simulate_fmu. A relative change below 1e-9 keeps the matrices
        # (the time error is then below 1e-9 of a step).
        if self._h is None or abs(h - self._h) > 1e-9 * h:
            self._ad, self._bd = zoh_discretise(A, B, h)
            self._h = h
        self.x = self._ad @ self.x + self._bd @ np.asarray(u, dtype=float)

    def measure(self) -> NDArray[np.float64]:
        """Sensor sample y = C x + noise_std · n (draws six deviates)."""
        return C @ self.x + self.noise_std * self._rng.standard_normal(6)

    def get_state(self) -> dict[str, Any]:
        return {"x": self.x.copy(), "rng": self._rng.bit_generator.state}

    def set_state(self, state: dict[str, Any]) -> None:
        self.x = np.array(state["x"], dtype=float)
        rng = np.random.default_rng()
        rng.bit_generator.state = dict(state["rng"])
        self._rng = rng
