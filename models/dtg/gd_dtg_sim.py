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
regression of docs/methods.md §2 wants.

The stepping runs at every controller tick (10 kHz for the production set), so it works
on plain Python floats: the rotor state, the per-axis controller states and the 2-vectors
are floats, and the discretised matrices are tuples of float rows made once per interval
length. numpy calls on 2- to 4-element arrays cost a microsecond each, which made the
DTG.fmu step several times the cost of its maths. The maths and the random draws (the
same Generator calls in the same order) are those of the numpy formulation
(tests/test_dtg_fast_path.py keeps it as the reference, equal to 1e-12).
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
        Ac, Bc, Cc, Dc = controller_matrices(params)
        self._nc = Ac.shape[0]
        # controller as float rows: xc⁺ = Ac·xc + Bc·e, u = Cc·xc + Dc·e (per axis)
        self._ctrl_rows = tuple(zip(map(tuple, Ac.tolist()), Bc.tolist(), strict=True))
        self._Cc = tuple(Cc.tolist())
        self._Dc = float(Dc)
        c, s = math.cos(params.loop_rotation), math.sin(params.loop_rotation)
        # e = −R(ψ)·[Utx, Uty]: the entries of −R
        self._neg_R = (-c, s, -s, -c)
        nominal = rotor_coefficients(params)
        # read-out scale: the electronics know only the nominal Ku and L
        self._readout_gain = params.Ku / nominal.L
        # interval length key → the 4 rows of [Ad | Bd] as float tuples
        self._cache: dict[int, tuple[tuple[float, ...], ...]] = {}
        self._tick_rows: tuple[tuple[float, ...], ...] | None = None
        self._set_coefficients(nominal)
        self.reset()

    def _set_coefficients(self, coeffs: RotorCoefficients) -> None:
        self._coeffs = coeffs
        self._KT = coeffs.KT
        self._A, self._B = rotor_state_space(coeffs)
        self._cache.clear()
        self._tick_rows = None

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
            self._set_coefficients(rotor_coefficients(self.params, **new))

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
        self._x = [0.0, 0.0, float(omega_x), float(omega_y)]
        self._xc_x = [0.0] * self._nc  # controller state of the x axis
        self._xc_y = [0.0] * self._nc
        self._noise = (0.0, 0.0)
        self._dither = (0.0, 0.0)
        self._u_ctrl = (0.0, 0.0)
        self._u_in = (float(ux_in), float(uy_in))
        self._tick()
        self._u_mean = self._u()

    def get_state(self) -> dict[str, Any]:
        """Full internal state as plain, JSON-serialisable Python values (deep copy)."""
        return {
            "t0": self._t0,
            "t": self._t,
            "m": self._m,
            "x": list(self._x),
            "xc": [[a, b] for a, b in zip(self._xc_x, self._xc_y, strict=True)],
            "noise": list(self._noise),
            "dither": list(self._dither),
            "u_ctrl": list(self._u_ctrl),
            "u_in": list(self._u_in),
            "u_mean": list(self._u_mean),
            "rng": copy.deepcopy(self._rng.bit_generator.state),
            "rng_dither": copy.deepcopy(self._rng_dither.bit_generator.state),
            "faults": dict(self._faults),
            "noise_std": self._noise_std,
            "dither_std": self._dither_std,
        }

    def set_state(self, state: dict[str, Any]) -> None:
        """Restore a state produced by ``get_state`` (matrices are recomputed)."""
        def pair(name: str) -> tuple[float, float]:
            a, b = np.asarray(state[name], dtype=float).reshape(2).tolist()
            return a, b

        self.set_faults(**state["faults"])
        self.noise_std = state["noise_std"]
        self.dither_std = state["dither_std"]
        self._t0 = float(state["t0"])
        self._t = float(state["t"])
        self._m = int(state["m"])
        self._x = np.asarray(state["x"], dtype=float).reshape(4).tolist()
        xc = np.asarray(state["xc"], dtype=float).reshape(self._nc, 2)
        self._xc_x = xc[:, 0].tolist()
        self._xc_y = xc[:, 1].tolist()
        self._noise = pair("noise")
        self._dither = pair("dither")
        self._u_ctrl = pair("u_ctrl")
        self._u_in = pair("u_in")
        self._u_mean = pair("u_mean")
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
        return np.array(self._x)

    @property
    def pickoff(self) -> tuple[float, float]:
        """(Utx, Uty) now (V): α/KT, β/KT plus the noise of the last tick."""
        kt = self._KT
        return (self._x[0] / kt + self._noise[0], self._x[1] / kt + self._noise[1])

    @property
    def torquer_mean(self) -> tuple[float, float]:
        """(Ux, Uy) averaged over the last communication step (V)."""
        return self._u_mean

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
        self._u_in = (float(ux_in), float(uy_in))
        wx, wy = float(omega_x), float(omega_y)
        eps, Tc, t0 = self._eps, self._Tc, self._t0
        ix = iy = covered = 0.0  # ∫U dt over the step (V·s) and the time it covers (s)
        while True:
            next_tick = t0 + (self._m + 1) * Tc
            at_tick = next_tick <= t_end + eps
            target = next_tick if at_tick else t_end
            dt = target - self._t
            if dt > eps:
                ux, uy = self._u()
                a, b, p, q = self._x
                self._x = [
                    (r0 * a + r1 * b + r2 * p + r3 * q)
                    + (r4 * wx + r5 * wy + r6 * ux + r7 * uy)
                    for r0, r1, r2, r3, r4, r5, r6, r7 in self._matrices(dt)
                ]
                ix += ux * dt
                iy += uy * dt
                covered += dt
            self._t = target
            if at_tick:
                self._m += 1
                self._tick()
            if self._t >= t_end - eps:
                break
        self._t = t_end
        # divide by the covered time, not h, so a constant voltage is reproduced exactly
        self._u_mean = (ix / covered, iy / covered) if covered > 0.0 else self._u()

    def _u(self) -> tuple[float, float]:
        """Torquer voltages now (V): controller + external + dither."""
        (cx, cy), (ix, iy), (dx, dy) = self._u_ctrl, self._u_in, self._dither
        return (cx + ix + dx, cy + iy + dy)

    def _tick(self) -> None:
        if self._noise_std > 0.0:
            nx, ny = self._rng.standard_normal(2).tolist()
            self._noise = (self._noise_std * nx, self._noise_std * ny)
        else:
            self._noise = (0.0, 0.0)
        if self._dither_std > 0.0:
            dx, dy = self._rng_dither.standard_normal(2).tolist()
            self._dither = (self._dither_std * dx, self._dither_std * dy)
        else:
            self._dither = (0.0, 0.0)
        if self.rebalance:
            utx, uty = self.pickoff
            r00, r01, r10, r11 = self._neg_R
            ex = r00 * utx + r01 * uty
            ey = r10 * utx + r11 * uty
            xc_x, xc_y = self._xc_x, self._xc_y
            cx = cy = 0.0
            for c, vx, vy in zip(self._Cc, xc_x, xc_y, strict=True):
                cx += c * vx
                cy += c * vy
            dc = self._Dc
            self._u_ctrl = (cx + dc * ex, cy + dc * ey)
            new_x = []
            new_y = []
            for row, bc in self._ctrl_rows:
                sx = sy = 0.0
                for a, vx, vy in zip(row, xc_x, xc_y, strict=True):
                    sx += a * vx
                    sy += a * vy
                new_x.append(sx + bc * ex)
                new_y.append(sy + bc * ey)
            self._xc_x, self._xc_y = new_x, new_y

    def _matrices(self, dt: float) -> tuple[tuple[float, ...], ...]:
        """Rows of [Ad | Bd] for an interval of ``dt`` (s), inputs [ωx, ωy, Ux, Uy]."""
        if abs(dt - self._Tc) <= self._eps:
            if self._tick_rows is None:
                self._tick_rows = self._discretise(self._Tc)
            return self._tick_rows
        return self._discretise(dt)

    def _discretise(self, dt: float) -> tuple[tuple[float, ...], ...]:
        key = round(dt / self._eps)
        hit = self._cache.get(key)
        if hit is None:
            if len(self._cache) >= _MAX_CACHE:
                self._cache.clear()
            Ad, Bd = zoh_discretize(self._A, self._B, dt)
            hit = tuple(map(tuple, np.hstack([Ad, Bd]).tolist()))
            self._cache[key] = hit
        return hit

    def describe(self) -> dict[str, Any]:
        """Parameter set and current coefficients, for logs and reports."""
        return {"params": asdict(self.params), "coefficients": asdict(self._coeffs),
                "faults": dict(self._faults), "rebalance": self.rebalance}
