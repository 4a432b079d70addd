"""Time stepping of the DTG rotor and its digital rebalance loop (no FMI in it).

Time base: controller ticks at t0 + m·Tc. At every tick the pick-offs are sampled
with fresh noise (held until the next tick, so the pick-off output between ticks is
α(t)/KT plus the held noise), a fresh torquer dither sample is drawn (held likewise)
and, with the loop on, the controller computes its voltages applied from that tick on.
The torquer voltage is controller output (loop on) + external input + dither; the
external inputs Ux_in, Uy_in are the torquer voltages with the loop off and additive
test voltages at the torquer summing junction with it on.

A communication step [t, t + h) is cut at the ticks it contains (sub-stepping when h
exceeds Tc; h need not be a multiple of Tc); each piece is integrated exactly (matrix
exponential, inputs held). The reported torquer voltages Ux, Uy are their mean over
the last communication step (what an integrating read-out of the torquer current
measures), so the value at t_k is the voltage that acted on [t_{k−1}, t_k], as the
regression of DESIGN §2 wants.
"""

from __future__ import annotations

import copy
import math
from dataclasses import asdict
from typing import Any

import numpy as np
from gd_dtg_core import (
    DTGParameterSet,
    RotorCoefficients,
    controller_matrices,
    rotor_coefficients,
    rotor_state_space,
    zoh_discretize,
)

#: Fault parameters and their nominal values (see rotor_coefficients for units).
NOMINAL_FAULTS: dict[str, float] = {
    "spin_fraction": 1.0,
    "k_offset": 0.0,
    "damping_scale": 1.0,
    "torquer_scale": 1.0,
    "pickoff_scale": 1.0,
}

_MAX_CACHE = 16


class DTGSimulator:
    """DTG rotor, pick-offs with noise, torquers and the rebalance loop.

    Parameters
    ----------
    params : DTGParameterSet
        The gyro and its loop design.
    rebalance : bool
        True: the internal loop drives Ux, Uy. False: Ux, Uy are inputs to ``advance``.
    noise_std : float
        Pick-off noise standard deviation per controller tick (V).
    dither_std : float
        Standard deviation of a white torquer dither per controller tick (V); the
        closed-loop identification needs it (README.md).
    seed : int
        Seed of the noise and dither generators (two independent streams).
    """

    def __init__(
        self,
        params: DTGParameterSet,
        *,
        rebalance: bool = True,
        noise_std: float = 1.0e-3,
        dither_std: float = 0.0,
        seed: int = 0,
    ) -> None:
        if not isinstance(params, DTGParameterSet):
            raise TypeError(f"params must be a DTGParameterSet, got {type(params).__name__}")
        if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
            raise ValueError(f"seed must be an integer >= 0, got {seed!r}")
        self.params = params
        self.rebalance = bool(rebalance)
        self.seed = int(seed)
        self._noise_std = 0.0
        self._dither_std = 0.0
        self.noise_std = noise_std
        self.dither_std = dither_std
        self._faults = dict(NOMINAL_FAULTS)
        self._Tc = params.controller_sample_time
        self._eps = 1e-9 * self._Tc
        self._Ac, self._Bc, self._Cc, self._Dc = controller_matrices(params)
        c, s = math.cos(params.loop_rotation), math.sin(params.loop_rotation)
        self._R = np.array([[c, -s], [s, c]])
        nominal = rotor_coefficients(params)
        # read-out scale: the electronics know only the nominal Ku and L
        self._readout_gain = params.Ku / nominal.L
        self._cache: dict[int, tuple[np.ndarray, np.ndarray]] = {}
        self._coeffs: RotorCoefficients = nominal
        self._A, self._B = rotor_state_space(nominal)
        self.reset()

    # ---------------------------------------------------------------- parameters
    @property
    def noise_std(self) -> float:
        """Pick-off noise standard deviation per tick (V)."""
        return self._noise_std

    @noise_std.setter
    def noise_std(self, value: float) -> None:
        v = float(value)
        if not math.isfinite(v) or v < 0.0:
            raise ValueError(f"noise_std must be finite and >= 0, got {value!r}")
        self._noise_std = v

    @property
    def dither_std(self) -> float:
        """Torquer dither standard deviation per tick (V)."""
        return self._dither_std

    @dither_std.setter
    def dither_std(self, value: float) -> None:
        v = float(value)
        if not math.isfinite(v) or v < 0.0:
            raise ValueError(f"dither_std must be finite and >= 0, got {value!r}")
        self._dither_std = v

    @property
    def faults(self) -> dict[str, float]:
        """Current fault parameters (copy)."""
        return dict(self._faults)

    @property
    def coefficients(self) -> RotorCoefficients:
        """Rotor coefficients with the current faults applied."""
        return self._coeffs

    def set_faults(self, **faults: float) -> None:
        """Change fault parameters (names as in NOMINAL_FAULTS); takes effect at once.

        Raises
        ------
        ValueError
            Unknown name, non-finite value, or a scale/spin fraction <= 0.
        """
        new = dict(self._faults)
        for name, value in faults.items():
            if name not in NOMINAL_FAULTS:
                raise ValueError(f"unknown fault parameter {name!r}")
            v = float(value)
            if not math.isfinite(v):
                raise ValueError(f"{name} must be finite, got {value!r}")
            if name != "k_offset" and v <= 0.0:
                raise ValueError(f"{name} must be > 0, got {value!r}")
            new[name] = v
        if new != self._faults:
            self._faults = new
            self._coeffs = rotor_coefficients(self.params, **new)
            self._A, self._B = rotor_state_space(self._coeffs)
            self._cache.clear()

    # --------------------------------------------------------------------- state
    def reset(self, start_time: float = 0.0, omega_x: float = 0.0, omega_y: float = 0.0,
              ux_in: float = 0.0, uy_in: float = 0.0) -> None:
        """Rotor at null and at rest relative to the case; first tick at ``start_time``.

        Parameters
        ----------
        start_time : float
            Start time (s).
        omega_x, omega_y : float
            Case rates at the start (rad/s).
        ux_in, uy_in : float
            External torquer voltages (V): the torquer voltage with the loop off, an
            additive test voltage with it on.
        """
        noise_seq, dither_seq = np.random.SeedSequence(self.seed).spawn(2)
        self._rng = np.random.default_rng(noise_seq)
        self._rng_dither = np.random.default_rng(dither_seq)
        self._t0 = float(start_time)
        self._t = float(start_time)
        self._m = 0
        self._x = np.array([0.0, 0.0, float(omega_x), float(omega_y)])
        self._xc = np.zeros((self._Ac.shape[0], 2))
        self._noise = np.zeros(2)
        self._dither = np.zeros(2)
        self._u_ctrl = np.zeros(2)
        self._u_in = np.array([float(ux_in), float(uy_in)])
        self._tick()
        self._u_mean = self._u.copy()

    def get_state(self) -> dict[str, Any]:
        """Full internal state as plain, JSON-serialisable Python values (deep copy)."""
        return {
            "t0": self._t0,
            "t": self._t,
            "m": self._m,
            "x": self._x.tolist(),
            "xc": self._xc.tolist(),
            "noise": self._noise.tolist(),
            "dither": self._dither.tolist(),
            "u_ctrl": self._u_ctrl.tolist(),
            "u_in": self._u_in.tolist(),
            "u_mean": self._u_mean.tolist(),
            "rng": copy.deepcopy(self._rng.bit_generator.state),
            "rng_dither": copy.deepcopy(self._rng_dither.bit_generator.state),
            "faults": dict(self._faults),
            "noise_std": self._noise_std,
            "dither_std": self._dither_std,
        }

    def set_state(self, state: dict[str, Any]) -> None:
        """Restore a state produced by ``get_state`` (matrices are recomputed)."""
        self.set_faults(**state["faults"])
        self.noise_std = state["noise_std"]
        self.dither_std = state["dither_std"]
        self._t0 = float(state["t0"])
        self._t = float(state["t"])
        self._m = int(state["m"])
        self._x = np.array(state["x"], dtype=float)
        self._xc = np.array(state["xc"], dtype=float).reshape(self._Ac.shape[0], 2)
        self._noise = np.array(state["noise"], dtype=float)
        self._dither = np.array(state["dither"], dtype=float)
        self._u_ctrl = np.array(state["u_ctrl"], dtype=float)
        self._u_in = np.array(state["u_in"], dtype=float)
        self._u_mean = np.array(state["u_mean"], dtype=float)
        self._rng = np.random.default_rng()
        self._rng.bit_generator.state = copy.deepcopy(state["rng"])
        self._rng_dither = np.random.default_rng()
        self._rng_dither.bit_generator.state = copy.deepcopy(state["rng_dither"])

    # ------------------------------------------------------------------- outputs
    @property
    def time(self) -> float:
        """Current time (s)."""
        return self._t

    @property
    def rotor_state(self) -> np.ndarray:
        """[α, β, p, q] (rad, rad, rad/s, rad/s), p, q the rotor's inertial rates (copy)."""
        return self._x.copy()

    @property
    def pickoff(self) -> tuple[float, float]:
        """(Utx, Uty) now (V): α/KT, β/KT plus the noise of the last tick."""
        kt = self._coeffs.KT
        return (self._x[0] / kt + self._noise[0], self._x[1] / kt + self._noise[1])

    @property
    def torquer_mean(self) -> tuple[float, float]:
        """(Ux, Uy) averaged over the last communication step (V)."""
        return float(self._u_mean[0]), float(self._u_mean[1])

    @property
    def rate_readout(self) -> tuple[float, float]:
        """(ωx, ωy) read out from the mean torquer voltages with nominal Ku, L (rad/s).

        At null Ku·Ux = L·ωy and Ku·Uy = −L·ωx.
        """
        ux, uy = self._u_mean
        return (-self._readout_gain * uy, self._readout_gain * ux)

    # ------------------------------------------------------------------ stepping
    def advance(self, t_end: float, omega_x: float, omega_y: float,
                ux_in: float = 0.0, uy_in: float = 0.0) -> None:
        """Advance to ``t_end`` (s) with the inputs held since the current time.

        Parameters
        ----------
        t_end : float
            End of the communication step (s), > current time.
        omega_x, omega_y : float
            Case rates (rad/s), held over the step.
        ux_in, uy_in : float
            External torquer voltages (V), held over the step: the torquer voltage with
            the loop off, an additive test voltage with it on.
        """
        h = t_end - self._t
        if not h > 0.0:
            raise ValueError(f"step must end after the current time {self._t}, got {t_end}")
        self._u_in = np.array([float(ux_in), float(uy_in)])
        w = np.array([float(omega_x), float(omega_y)])
        u_integral = np.zeros(2)
        covered = 0.0
        while True:
            next_tick = self._t0 + (self._m + 1) * self._Tc
            at_tick = next_tick <= t_end + self._eps
            target = next_tick if at_tick else t_end
            dt = target - self._t
            if dt > self._eps:
                u = self._u
                Ad, Bd = self._matrices(dt)
                self._x = Ad @ self._x + Bd @ np.concatenate((w, u))
                u_integral += u * dt
                covered += dt
            self._t = target
            if at_tick:
                self._m += 1
                self._tick()
            if self._t >= t_end - self._eps:
                break
        self._t = t_end
        # divide by the covered time, not h, so a constant voltage is reproduced exactly
        self._u_mean = u_integral / covered if covered > 0.0 else self._u

    @property
    def _u(self) -> np.ndarray:
        return self._u_ctrl + self._u_in + self._dither

    def _tick(self) -> None:
        if self._noise_std > 0.0:
            self._noise = self._noise_std * self._rng.standard_normal(2)
        else:
            self._noise = np.zeros(2)
        if self._dither_std > 0.0:
            self._dither = self._dither_std * self._rng_dither.standard_normal(2)
        else:
            self._dither = np.zeros(2)
        if self.rebalance:
            e = -self._R @ np.array(self.pickoff)
            self._u_ctrl = self._Cc @ self._xc + self._Dc * e
            self._xc = self._Ac @ self._xc + np.outer(self._Bc, e)

    def _matrices(self, dt: float) -> tuple[np.ndarray, np.ndarray]:
        if abs(dt - self._Tc) <= self._eps:
            dt = self._Tc
        key = round(dt / self._eps)
        hit = self._cache.get(key)
        if hit is None:
            if len(self._cache) >= _MAX_CACHE:
                self._cache.clear()
            hit = zoh_discretize(self._A, self._B, dt)
            self._cache[key] = hit
        return hit

    def describe(self) -> dict[str, Any]:
        """Parameter set and current coefficients, for logs and reports."""
        return {"params": asdict(self.params), "coefficients": asdict(self._coeffs),
                "faults": dict(self._faults), "rebalance": self.rebalance}
