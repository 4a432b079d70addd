"""Sensor fault injection on N independent channels (no FMI knowledge).

Fault codes (``fault_type``), applied while the fault is *active*, i.e. for sample times
``t_start <= t < t_end`` (STEP ignores ``t_end``), each time compared within the
tolerance ``t_tol`` of :meth:`FaultInjectorCore.update` (the FMU: half a communication
step).  ``u`` is the channel input, ``t`` the sample time (s), ``m`` the channel's
``magnitude``:

====  ============  ======================================================================
code  name          output while active
====  ============  ======================================================================
0     NONE          u (bit-exact pass-through; the channel is never active)
1     BIAS          u + m
2     GAIN          gain · u
3     STUCK_VALUE   stuck_value
4     STUCK_LAST    u at the first active sample, held until the window ends
5     FAILURE       0.0 (complete failure)
6     STEP          u + m for every t >= t_start (latching bias jump, t_end ignored)
7     RAMP          u + m · max(t − t_start, 0)  (drift; m in units per second)
8     NOISE         u + noise_std · n,  n ~ N(0, 1)
9     SIGNAL_LOSS   noise_std · n  (zero-mean random replacement of the signal)
10    INTERMITTENT  u + m while ((t − t_start) mod period) < duty · period, else u
11    SATURATION    min(max(u, sat_min), sat_max)
12    NAN_DROPOUT   NaN
====  ============  ======================================================================

Idle channels (code 0, or outside the window) return the input object unchanged, so the
output is bit-identical to the input.  Each channel owns a ``numpy.random.Generator``
(PCG64) seeded with ``seed + channel_index`` (index from 0); a normal deviate is drawn
only at samples where NOISE or SIGNAL_LOSS is active, so one channel's schedule never
changes another channel's noise.  ``active`` is True where the output differs from the
pass-through by construction (INTERMITTENT: only in its on-phase).
"""

from __future__ import annotations

import copy
import math
from enum import IntEnum
from typing import Any

import numpy as np
from numpy.typing import NDArray


class FaultType(IntEnum):
    """Integer fault codes of the injector (see module docstring for formulas)."""

    NONE = 0
    BIAS = 1
    GAIN = 2
    STUCK_VALUE = 3
    STUCK_LAST = 4
    FAILURE = 5
    STEP = 6
    RAMP = 7
    NOISE = 8
    SIGNAL_LOSS = 9
    INTERMITTENT = 10
    SATURATION = 11
    NAN_DROPOUT = 12


#: Real-valued per-channel parameters and their defaults.
REAL_PARAMETERS: dict[str, float] = {
    "t_start": 0.0,
    "t_end": 1.0e9,
    "magnitude": 0.0,
    "gain": 1.0,
    "stuck_value": 0.0,
    "noise_std": 0.0,
    "period": 1.0,
    "duty": 0.5,
    "sat_min": -1.0,
    "sat_max": 1.0,
}


class FaultInjectorCore:
    """N-channel fault injector with explicit state.

    Parameters
    ----------
    n_channels : int
        Number of independent channels (>= 1).
    seed : int
        Base seed; channel ``i`` (from 0) uses ``seed + i``.

    Attributes
    ----------
    fault_type : ndarray of int, shape (n_channels,)
        Fault code per channel (see :class:`FaultType`); tunable between samples.
    params : dict of str to ndarray, shape (n_channels,)
        Real-valued parameters per channel, keys of :data:`REAL_PARAMETERS`
        (times in s, magnitude in signal units, RAMP magnitude in units/s, period in s).
    """

    def __init__(self, n_channels: int, seed: int = 0) -> None:
        if isinstance(n_channels, bool) or not isinstance(n_channels, int) or n_channels < 1:
            raise ValueError(f"n_channels must be an integer >= 1, got {n_channels!r}")
        if isinstance(seed, bool) or not isinstance(seed, int) or seed < 0:
            raise ValueError(f"seed must be an integer >= 0, got {seed!r}")
        self.n_channels = n_channels
        self.seed = seed
        self.fault_type = np.zeros(n_channels, dtype=np.int64)
        self.params = {k: np.full(n_channels, v, dtype=float) for k, v in REAL_PARAMETERS.items()}
        self.reset()

    def reset(self, seed: int | None = None) -> None:
        """Clear latches and held values, reseed the generators (optionally a new seed)."""
        if seed is not None:
            if isinstance(seed, bool) or not isinstance(seed, int) or seed < 0:
                raise ValueError(f"seed must be an integer >= 0, got {seed!r}")
            self.seed = seed
        self._rngs = [np.random.default_rng(self.seed + i) for i in range(self.n_channels)]
        self._held = np.zeros(self.n_channels)
        self._holding = np.zeros(self.n_channels, dtype=bool)
        self._step_latched = np.zeros(self.n_channels, dtype=bool)
        self._flags_clear = True  # _holding and _step_latched are all False

    def check_channel(self, i: int) -> None:
        """Validate the parameters that the channel's current fault type uses."""
        code = int(self.fault_type[i])
        ch = f"channel {i + 1}"
        if code not in FaultType._value2member_map_:
            raise ValueError(f"fault_type of {ch} must be in 0..{max(FaultType)}, got {code}")
        p = {k: float(v[i]) for k, v in self.params.items()}
        if math.isnan(p["t_start"]) or math.isnan(p["t_end"]):
            raise ValueError(f"t_start/t_end of {ch} must not be NaN")
        if code in (FaultType.NOISE, FaultType.SIGNAL_LOSS) and not p["noise_std"] >= 0.0:
            raise ValueError(f"noise_std of {ch} must be >= 0, got {p['noise_std']}")
        if code == FaultType.INTERMITTENT:
            if not p["period"] > 0.0:
                raise ValueError(f"period of {ch} must be > 0 s, got {p['period']}")
            if not 0.0 <= p["duty"] <= 1.0:
                raise ValueError(f"duty of {ch} must be in [0, 1], got {p['duty']}")
        if code == FaultType.SATURATION and not p["sat_min"] <= p["sat_max"]:
            raise ValueError(f"sat_min of {ch} must be <= sat_max, got {p['sat_min']} > "
                             f"{p['sat_max']}")

    def update(self, t: float, u: NDArray[np.float64] | list[float],
               t_tol: float = 0.0) -> tuple[list[float], list[bool]]:
        """Apply each channel's fault to one input sample.

        Parameters
        ----------
        t : float
            Sample time (s).
        u : array_like, shape (n_channels,)
            Channel inputs (any unit).
        t_tol : float
            Time tolerance (s, >= 0) of the time events (t_start, t_end, the
            intermittent edges): an event at T happens at the first sample with
            t >= T - t_tol. The FMU passes half its communication step, so that a master
            whose time drifts by rounding (t += h) sees the event at the same step as
            one with t = k·h (docs/fmu.md, "Time events").

        Returns
        -------
        y : list of float
            Channel outputs; idle channels return their input unchanged.
        active : list of bool
            Whether each channel's fault altered the sample.
        """
        if len(u) != self.n_channels:
            raise ValueError(f"u must have {self.n_channels} entries, got {len(u)}")
        if not self.fault_type.any():  # every channel idle: the same as _apply's NONE case
            if not self._flags_clear:
                self._holding[:] = False
                self._step_latched[:] = False
                self._flags_clear = True
            return list(u), [False] * self.n_channels
        self._flags_clear = False
        y: list[float] = []
        active: list[bool] = []
        for i in range(self.n_channels):
            out, act = self._apply(i, t, u[i], t_tol)
            y.append(out)
            active.append(act)
        return y, active

    def _apply(self, i: int, t: float, u: float, t_tol: float) -> tuple[float, bool]:
        code = int(self.fault_type[i])
        if code == FaultType.NONE:
            self._holding[i] = False
            self._step_latched[i] = False
            return u, False
        self.check_channel(i)
        p = self.params
        t_start = float(p["t_start"][i])
        if code == FaultType.STEP:
            if t >= t_start - t_tol:
                self._step_latched[i] = True
            if self._step_latched[i]:
                return u + float(p["magnitude"][i]), True
            return u, False
        self._step_latched[i] = False
        in_window = t_start - t_tol <= t < float(p["t_end"][i]) - t_tol
        if not in_window:
            self._holding[i] = False
            return u, False
        m = float(p["magnitude"][i])
        if code == FaultType.BIAS:
            return u + m, True
        if code == FaultType.GAIN:
            return float(p["gain"][i]) * u, True
        if code == FaultType.STUCK_VALUE:
            return float(p["stuck_value"][i]), True
        if code == FaultType.STUCK_LAST:
            if not self._holding[i]:
                self._held[i] = u
                self._holding[i] = True
            return float(self._held[i]), True
        if code == FaultType.FAILURE:
            return 0.0, True
        if code == FaultType.RAMP:
            return u + m * max(t - t_start, 0.0), True
        if code == FaultType.NOISE:
            return u + float(p["noise_std"][i]) * float(self._rngs[i].standard_normal()), True
        if code == FaultType.SIGNAL_LOSS:
            return float(p["noise_std"][i]) * float(self._rngs[i].standard_normal()), True
        if code == FaultType.INTERMITTENT:
            period = float(p["period"][i])
            if (t - t_start + t_tol) % period < float(p["duty"][i]) * period:
                return u + m, True
            return u, False
        if code == FaultType.SATURATION:
            return min(max(u, float(p["sat_min"][i])), float(p["sat_max"][i])), True
        return math.nan, True  # NAN_DROPOUT (codes were validated above)

    def get_state(self) -> dict[str, Any]:
        """Deep copy of the full state (parameters, latches, generator states)."""
        return {
            "seed": self.seed,
            "fault_type": self.fault_type.copy(),
            "params": {k: v.copy() for k, v in self.params.items()},
            "held": self._held.copy(),
            "holding": self._holding.copy(),
            "step_latched": self._step_latched.copy(),
            "rng": [copy.deepcopy(r.bit_generator.state) for r in self._rngs],
        }

    def set_state(self, state: dict[str, Any]) -> None:
        """Restore a state produced by :meth:`get_state` (arrays may be given as lists)."""
        self.seed = int(state["seed"])
        self.fault_type = np.array(state["fault_type"], dtype=np.int64)
        self.params = {k: np.array(v, dtype=float) for k, v in state["params"].items()}
        self._held = np.array(state["held"], dtype=float)
        self._holding = np.array(state["holding"], dtype=bool)
        self._step_latched = np.array(state["step_latched"], dtype=bool)
        self._flags_clear = not (self._holding.any() or self._step_latched.any())
        rngs = []
        for s in state["rng"]:
            rng = np.random.default_rng()
            rng.bit_generator.state = copy.deepcopy(s)
            rngs.append(rng)
        self._rngs = rngs
