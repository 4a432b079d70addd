"""Hemispherical resonator gyro (HRG) output model (no FMI knowledge).

Output voltage in volts::

    u(t)  = scale_factor · ω(t) + bias                    (V)
    v'    = 2π·bandwidth_hz · (u − v)                      first-order read-out filter
    V(t)  = v(t) + noise_std · n,   n ~ N(0, 1)

with ω(t) = profile(t) + rate_in(t) (rad/s).  The filter is discretised exactly for an
input held over the step (ZOH): ``v_{k+1} = u_k + exp(−2π f h)·(v_k − u_k)``.  In floating
point this recursion can stall a few ulps short of u (when the update rounds back to v_k); the
model then snaps to u, so a constant rate gives an exactly constant output (the snap
error is below 0.5 ulp / (1 − exp(−2π f h))).  ``bandwidth_hz <= 0`` disables the
filter (``v_{k+1} = u_k``).  The filter starts in steady state for the initial rate.

Profiles (``profile``):

* 0 — none: ω = rate_in only;
* 1 — seed-001 timeline (default): a slowly varying positive rate of a few tenths of
  rad/s for 0–725 s, tapered with a raised cosine over 725–825 s, and **exactly
  constant** (``SEED001_FLAT_RATE``) for t >= 825 s; with the default scale factor
  10 V/(rad/s) the output spans about 1.2–3.9 V;
* 2 — constant: ω = rate_const + rate_in.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

PROFILE_NONE = 0
PROFILE_SEED001 = 1
PROFILE_CONSTANT = 2
PROFILES = (PROFILE_NONE, PROFILE_SEED001, PROFILE_CONSTANT)

SEED001_FLAT_RATE = 0.25  # rad/s
SEED001_TAPER_START = 725.0  # s
SEED001_FLAT_FROM = 825.0  # s


def seed001_rate(t: float) -> float:
    """Seed-001 rate profile ω(t) in rad/s (smooth, exactly flat for t >= 825 s)."""
    if t >= SEED001_FLAT_FROM:
        return SEED001_FLAT_RATE
    wave = 0.10 * math.sin(2.0 * math.pi * t / 500.0) + 0.04 * math.sin(
        2.0 * math.pi * t / 130.0 + 0.5)
    if t <= SEED001_TAPER_START:
        weight = 1.0
    else:
        span = SEED001_FLAT_FROM - SEED001_TAPER_START
        weight = 0.5 * (1.0 + math.cos(math.pi * (t - SEED001_TAPER_START) / span))
    return SEED001_FLAT_RATE + weight * wave


class HRGModel:
    """HRG voltage output with first-order bandwidth and seeded white noise.

    Parameters
    ----------
    scale_factor : float
        V/(rad/s), finite.
    bias : float
        V, finite.
    bandwidth_hz : float
        Read-out filter bandwidth in Hz; <= 0 disables the filter.
    noise_std : float
        Output noise standard deviation in V (>= 0).
    seed : int
        Seed of the noise generator (>= 0).
    profile : int
        Built-in rate profile code, one of :data:`PROFILES`.
    rate_const : float
        Constant rate of profile 2 in rad/s.
    """

    def __init__(self, scale_factor: float = 10.0, bias: float = 0.0,
                 bandwidth_hz: float = 10.0, noise_std: float = 0.0, seed: int = 0,
                 profile: int = PROFILE_SEED001, rate_const: float = 0.0) -> None:
        self.scale_factor = scale_factor
        self.bias = bias
        self.bandwidth_hz = bandwidth_hz
        self.noise_std = noise_std
        self.seed = seed
        self.profile = profile
        self.rate_const = rate_const
        self.check()
        self.reset(0.0, 0.0)

    def check(self) -> None:
        """Validate the parameters (they may be tuned between steps)."""
        for name in ("scale_factor", "bias", "bandwidth_hz", "rate_const"):
            if not math.isfinite(getattr(self, name)):
                raise ValueError(f"{name} must be finite, got {getattr(self, name)!r}")
        if not self.noise_std >= 0.0 or not math.isfinite(self.noise_std):
            raise ValueError(f"noise_std must be finite and >= 0 V, got {self.noise_std!r}")
        if isinstance(self.seed, bool) or not isinstance(self.seed, int) or self.seed < 0:
            raise ValueError(f"seed must be an integer >= 0, got {self.seed!r}")
        if self.profile not in PROFILES:
            raise ValueError(f"profile must be one of {PROFILES}, got {self.profile!r}")

    def rate(self, t: float, rate_in: float) -> float:
        """True angular rate ω(t) in rad/s."""
        if self.profile == PROFILE_SEED001:
            return seed001_rate(t) + rate_in
        if self.profile == PROFILE_CONSTANT:
            return self.rate_const + rate_in
        return rate_in

    def reset(self, t0: float, rate_in: float) -> None:
        """Start in steady state for ω(t0); reseed the noise generator."""
        self._rng = np.random.default_rng(self.seed)
        self.v = self.scale_factor * self.rate(t0, rate_in) + self.bias

    def step(self, t: float, h: float, rate_in: float) -> None:
        """Advance the filter from t to t + h with ω held at ω(t)."""
        if not h > 0.0:
            raise ValueError(f"step size h must be > 0 s, got {h!r}")
        self.check()
        u = self.scale_factor * self.rate(t, rate_in) + self.bias
        if self.bandwidth_hz > 0.0:
            v_next = u + math.exp(-2.0 * math.pi * self.bandwidth_hz * h) * (self.v - u)
            # rounding stall: the exact solution keeps converging, so settle on u
            self.v = u if v_next == self.v else v_next
        else:
            self.v = u

    def measure(self) -> float:
        """Output voltage sample (V): filter state plus one noise draw."""
        return self.v + self.noise_std * float(self._rng.standard_normal())

    def get_state(self) -> dict[str, Any]:
        return {"v": self.v, "rng": self._rng.bit_generator.state}

    def set_state(self, state: dict[str, Any]) -> None:
        self.v = float(state["v"])
        rng = np.random.default_rng()
        rng.bit_generator.state = dict(state["rng"])
        self._rng = rng
