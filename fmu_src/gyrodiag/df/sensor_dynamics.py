"""Sensor dynamics in the detection filter's sensor model, by matched filtering.

The detection filter (docs/methods.md §4) models every sensor as y_i = C_i x.  A rate gyro whose
read-out is a closed rebalance loop reports a filtered rate instead, y_j = G(z)·C_j x:
for the paper DTG the read-out has a gain of 0.74 at 1 Hz and settles in ~1 s, so any
manoeuvre gives residuals of 50–100 thresholds and the filter reports a "q gain 0.85"
without a fault (docs/notes.md, System).

Matched filtering keeps the filter's model exact without touching its design: pass every
*other* sensor and every input through the same G(z).  With x_f = G·x (a linear filter
commutes with the plant's linear dynamics, state by state),

    x_f(k+1) = Φ x_f(k) + Γ (G·u)(k),      G·y_i = C_i x_f  (i ≠ j),    y_j = C_j x_f,

so the equalised samples ((G·u), (G·y_i), y_j) obey the filter's own model, sensor faults
included (G·f_i on the other sensors, f_j unfiltered on sensor j).  The plant, the
filter's design, its calibration and isolation stay as they are; the price is that faults
of the other sensors reach the filter through G (G(1) = 1: a bias stays a bias once G has
settled, a gain a gain).  Exact for a linear G given in discrete time at the filter's
sample period with the same sample alignment as the sensor; a continuous G is discretised
with a zero-order hold (exact for inputs held over the sample).

:class:`SensorDynamics` holds G(z) = C_g (zI − A_g)⁻¹ B_g + D_g (SISO, discrete);
:class:`SensorDynamicsEqualiser` runs one copy per equalised channel, sample by sample.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import scipy.linalg
from numpy.typing import ArrayLike, NDArray

from ..common._validation import check_finite_array, check_int, check_positive

__all__ = ["SensorDynamics", "SensorDynamicsEqualiser"]

_FloatArray = NDArray[np.float64]


@dataclass(frozen=True)
class SensorDynamics:
    """Discrete SISO dynamics G(z) of one sensor, at the filter's sample period.

    Attributes
    ----------
    sensor : int
        0-based index of the sensor with dynamics (in the filter's output vector y).
    A : ndarray, shape (n, n)
        State matrix of G (1).
    B : ndarray, shape (n,)
        Input vector (state units per sensor unit).
    C : ndarray, shape (n,)
        Output vector.
    D : float
        Direct feed-through (1).
    sample_period_s : float
        Sample period of G, s; must equal the filter's.
    """

    sensor: int
    A: _FloatArray
    B: _FloatArray
    C: _FloatArray
    D: float
    sample_period_s: float

    def __post_init__(self) -> None:
        check_int("sensor", self.sensor, minimum=0)
        a = check_finite_array("A", self.A, ndim=2)
        n = a.shape[0]
        if a.shape != (n, n) or n < 1:
            raise ValueError(f"A must be square and non-empty, got shape {a.shape}")
        object.__setattr__(self, "A", a.copy())
        object.__setattr__(self, "B", check_finite_array("B", np.ravel(self.B), shape=(n,)))
        object.__setattr__(self, "C", check_finite_array("C", np.ravel(self.C), shape=(n,)))
        object.__setattr__(self, "D", float(check_finite_array("D", self.D, ndim=0)))
        check_positive("sample_period_s", self.sample_period_s)
        radius = float(np.max(np.abs(np.linalg.eigvals(a))))
        if radius >= 1.0:
            raise ValueError(f"A must be stable (spectral radius < 1), got {radius:.6g}: "
                             "the equaliser would diverge")

    @property
    def order(self) -> int:
        """Number of states n."""
        return self.A.shape[0]

    @property
    def dc_gain(self) -> float:
        """G(1): 1 for a rate read-out that is exact at steady state."""
        n = self.order
        return float(self.C @ np.linalg.solve(np.eye(n) - self.A, self.B) + self.D)

    @property
    def noise_gain(self) -> float:
        """Variance of G·v per unit variance of white v (squared H2 norm)."""
        p = scipy.linalg.solve_discrete_lyapunov(self.A, np.outer(self.B, self.B))
        return float(self.C @ p @ self.C + self.D**2)

    def frequency_response(self, frequency_hz: ArrayLike) -> NDArray[np.complex128]:
        """G(e^{jωT}) at the given frequencies (Hz)."""
        f = np.atleast_1d(np.asarray(frequency_hz, dtype=float))
        z = np.exp(2j * np.pi * f * self.sample_period_s)
        n = self.order
        return np.array([self.C @ np.linalg.solve(zi * np.eye(n) - self.A, self.B) + self.D
                         for zi in z])

    @classmethod
    def from_continuous(cls, sensor: int, A: ArrayLike, B: ArrayLike, C: ArrayLike,
                        D: float, sample_period_s: float) -> SensorDynamics:
        """Discretise G(s) with a zero-order hold at ``sample_period_s`` (s)."""
        a = check_finite_array("A", A, ndim=2)
        n = a.shape[0]
        b = check_finite_array("B", np.ravel(B), shape=(n,))
        T = check_positive("sample_period_s", sample_period_s)
        aug = np.zeros((n + 1, n + 1))
        aug[:n, :n] = a * T
        aug[:n, n] = b * T
        e = scipy.linalg.expm(aug)
        return cls(sensor, e[:n, :n], e[:n, n], np.ravel(C), D, T)

    @classmethod
    def from_dict(cls, data: dict[str, Any], sample_period_s: float) -> SensorDynamics:
        """From ``{"sensor": j (1-based), "discrete": {...}}`` or ``{..., "continuous": {...}}``.

        ``discrete`` holds ``sample_period_s``, ``A``, ``B``, ``C``, ``D`` and must be at
        the filter's ``sample_period_s``; ``continuous`` holds ``A``, ``B``, ``C``, ``D``
        and is discretised (zero-order hold).

        Raises
        ------
        ValueError
            Naming the missing or invalid key.
        """
        if not isinstance(data, dict):
            raise ValueError(f"sensor dynamics must be a JSON object, got {type(data).__name__}")
        if "sensor" not in data:
            raise ValueError("sensor dynamics: key 'sensor' (1-based sensor index) is missing")
        sensor = check_int("sensor", data["sensor"], minimum=1) - 1
        kinds = [k for k in ("discrete", "continuous") if k in data]
        if len(kinds) != 1:
            raise ValueError("sensor dynamics: give exactly one of 'discrete' or 'continuous', "
                             f"got {kinds or 'neither'}")
        body = data[kinds[0]]
        missing = [k for k in ("A", "B", "C", "D") if k not in body]
        if missing:
            raise ValueError(f"sensor dynamics: {kinds[0]} lacks {', '.join(missing)}")
        T = check_positive("sample_period_s", sample_period_s)
        if kinds[0] == "continuous":
            return cls.from_continuous(sensor, body["A"], body["B"], body["C"], body["D"], T)
        own = check_positive("discrete.sample_period_s", body.get("sample_period_s", np.nan))
        if abs(own - T) > 1e-9 * T:
            raise ValueError(f"sensor dynamics: discrete model at {own} s, the filter samples "
                             f"at {T} s (give a continuous model or one at the filter's rate)")
        return cls(sensor, np.asarray(body["A"], dtype=float), np.asarray(body["B"], dtype=float),
                   np.asarray(body["C"], dtype=float), body["D"], T)

    @classmethod
    def from_json(cls, path: str | Path, sample_period_s: float) -> SensorDynamics:
        """Read :meth:`from_dict`'s format from a JSON file (errors name the file)."""
        p = Path(path)
        try:
            data = json.loads(p.read_text(encoding="utf-8"))
            return cls.from_dict(data, sample_period_s)
        except FileNotFoundError:
            raise ValueError(f"sensor dynamics file {str(p)!r} not found") from None
        except (json.JSONDecodeError, ValueError, TypeError) as exc:
            raise ValueError(f"sensor dynamics file {str(p)!r}: {exc}") from None

    def to_dict(self) -> dict[str, Any]:
        """The discrete form, for :meth:`from_dict` (sensor 1-based)."""
        return {"sensor": self.sensor + 1,
                "discrete": {"sample_period_s": self.sample_period_s,
                             "A": self.A.tolist(), "B": self.B.tolist(), "C": self.C.tolist(),
                             "D": self.D}}


class SensorDynamicsEqualiser:
    """Pass every input and every sensor but the dynamic one through its G(z).

    Parameters
    ----------
    dynamics : SensorDynamics
        The dynamic sensor and its G(z).
    n_inputs, n_outputs : int
        Sizes of u and y of the filter.

    Notes
    -----
    ``update(u, y)`` returns ``(G·u, y_eq)`` with ``y_eq[j] = y[j]`` for the dynamic sensor
    j and ``G·y_i`` for the others: the output equation of G uses the filter state before
    this sample's update (``C x(k) + D v(k)``), as a sampled read-out does.  The filter
    states start at zero (the plant at rest); a plant starting elsewhere gives a transient
    that decays with G.
    """

    def __init__(self, dynamics: SensorDynamics, n_inputs: int, n_outputs: int) -> None:
        if not isinstance(dynamics, SensorDynamics):
            raise TypeError(f"dynamics must be a SensorDynamics, got {type(dynamics).__name__}")
        self.dynamics = dynamics
        self.n_inputs = check_int("n_inputs", n_inputs, minimum=0)
        self.n_outputs = check_int("n_outputs", n_outputs, minimum=1)
        if dynamics.sensor >= self.n_outputs:
            raise ValueError(f"sensor index {dynamics.sensor + 1} (1-based) exceeds the "
                             f"{self.n_outputs} outputs")
        self._others = np.array([i for i in range(self.n_outputs) if i != dynamics.sensor],
                                dtype=int)
        self._n_ch = self.n_inputs + self._others.size
        self.reset()

    def reset(self) -> None:
        """Filter states to zero."""
        self._x = np.zeros((self.dynamics.order, self._n_ch))

    def update(self, u: ArrayLike, y: ArrayLike, *, validate: bool = True
               ) -> tuple[_FloatArray, _FloatArray]:
        """Equalise one sample; return ``(u_eq, y_eq)``.

        Raises
        ------
        ValueError
            Naming ``u`` or ``y`` on a wrong shape or a non-finite value (state untouched).
        """
        if validate:
            u = check_finite_array("u", u, shape=(self.n_inputs,))
            y = check_finite_array("y", y, shape=(self.n_outputs,))
        else:
            u, y = np.asarray(u, dtype=float), np.asarray(y, dtype=float)
        g = self.dynamics
        v = np.concatenate([u, y[self._others]])
        out = g.C @ self._x + g.D * v
        self._x = g.A @ self._x + np.outer(g.B, v)
        y_eq = y.copy()
        y_eq[self._others] = out[self.n_inputs:]
        return out[:self.n_inputs].copy(), y_eq

    def get_state(self) -> dict[str, Any]:
        """Copy of the filter states."""
        return {"x": self._x.copy()}

    def set_state(self, state: dict[str, Any]) -> None:
        """Restore a state produced by :meth:`get_state` of an identical equaliser."""
        x = check_finite_array("state['x']", state["x"], shape=self._x.shape)
        self._x = x.copy()
