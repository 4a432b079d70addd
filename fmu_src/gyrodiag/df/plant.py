"""Seed longitudinal aircraft model of the pitch-rate sensor paper (seed 002, docs/methods.md §4).

Small-perturbation longitudinal dynamics at Ma 0.8, H 50 m::

    x' = A x + B u,   y = C x   (+ sensor faults)

* state  x = [v, alpha, q, theta, h]
* input  u = [throttle, elevator]
* output y = [v, alpha, q, theta, gamma, h] with the flight-path angle
  gamma = theta - alpha measured by its own sensor.

The throttle column of ``B`` is zero and the speed row of ``A`` is zero, exactly as
printed in the paper: speed is uncontrollable (ctrb rank 4) and, seen from the other
sensors, unobservable. ``A[4]`` is ``h' = V (theta - alpha)`` with V = 272.24 m/s.

The paper's printed detection-filter gain :data:`PAPER_PRINTED_K` is kept only to show
that it does not meet the paper's own specification (eig(A - K C) = {-1, ..., -5}).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

__all__ = [
    "PAPER_EIGENVALUES",
    "PAPER_PRINTED_K",
    "LongitudinalModel",
    "seed_aircraft",
]


def _frozen(array: NDArray[np.float64]) -> NDArray[np.float64]:
    array = np.array(array, dtype=float)
    array.setflags(write=False)
    return array


@dataclass(frozen=True)
class LongitudinalModel:
    """Continuous-time linear state-space model with named signals.

    Attributes
    ----------
    A : ndarray, shape (n, n)
        State matrix, 1/s.
    B : ndarray, shape (n, p)
        Input matrix (state units per input unit per second).
    C : ndarray, shape (m, n)
        Output matrix (sensor units per state unit).
    state_names, input_names, output_names : tuple of str
        Signal names, in the order of the matrix rows/columns.
    state_units, input_units, output_units : tuple of str
        SI units of the signals.

    The arrays are read-only so that a shared model cannot be altered by accident.
    """

    A: NDArray[np.float64]
    B: NDArray[np.float64]
    C: NDArray[np.float64]
    state_names: tuple[str, ...]
    input_names: tuple[str, ...]
    output_names: tuple[str, ...]
    state_units: tuple[str, ...] = field(default=())
    input_units: tuple[str, ...] = field(default=())
    output_units: tuple[str, ...] = field(default=())

    def __post_init__(self) -> None:
        for name in ("A", "B", "C"):
            object.__setattr__(self, name, _frozen(getattr(self, name)))
        n = self.A.shape[0]
        if self.A.shape != (n, n):
            raise ValueError(f"A must be square, got shape {self.A.shape}")
        if self.B.ndim != 2 or self.B.shape[0] != n:
            raise ValueError(f"B must have {n} rows, got shape {self.B.shape}")
        if self.C.ndim != 2 or self.C.shape[1] != n:
            raise ValueError(f"C must have {n} columns, got shape {self.C.shape}")
        checks = (
            ("state_names", self.state_names, n),
            ("input_names", self.input_names, self.B.shape[1]),
            ("output_names", self.output_names, self.C.shape[0]),
        )
        for name, names, size in checks:
            if len(names) != size:
                raise ValueError(f"{name} must have {size} entries, got {len(names)}")

    @property
    def n_states(self) -> int:
        """Number of states."""
        return self.A.shape[0]

    @property
    def n_inputs(self) -> int:
        """Number of inputs."""
        return self.B.shape[1]

    @property
    def n_outputs(self) -> int:
        """Number of sensors (outputs)."""
        return self.C.shape[0]

    def output_index(self, name: str) -> int:
        """Return the row of ``C`` that belongs to sensor ``name``."""
        try:
            return self.output_names.index(name)
        except ValueError:
            raise ValueError(
                f"name must be one of {self.output_names}, got {name!r}"
            ) from None


def seed_aircraft() -> LongitudinalModel:
    """Return the seed aircraft of docs/methods.md §4 (paper data, Ma 0.8, H 50 m).

    Returns
    -------
    LongitudinalModel
        x = [v (m/s), alpha (rad), q (rad/s), theta (rad), h (m)],
        u = [throttle (1), elevator (rad)],
        y = [v, alpha, q, theta, gamma = theta - alpha (rad), h].
    """
    a = np.array(
        [
            [0.0, 0.0, 0.0, 0.0, 0.0],
            [0.0, 0.0, -1.5122, 1.0, 0.0],
            [0.0, -7.9101, -3.0241, 0.0, 0.0],
            [0.0, 0.0, 1.0, 0.0, 0.0],
            [0.0, -272.24, 0.0, 272.24, 0.0],
        ]
    )
    b = np.array(
        [[0.0, 0.0], [0.0, -0.2779], [0.0, -26.3821], [0.0, 0.0], [0.0, 0.0]]
    )
    c = np.array(
        [
            [1.0, 0.0, 0.0, 0.0, 0.0],
            [0.0, 1.0, 0.0, 0.0, 0.0],
            [0.0, 0.0, 1.0, 0.0, 0.0],
            [0.0, 0.0, 0.0, 1.0, 0.0],
            [0.0, -1.0, 0.0, 1.0, 0.0],
            [0.0, 0.0, 0.0, 0.0, 1.0],
        ]
    )
    return LongitudinalModel(
        A=a,
        B=b,
        C=c,
        state_names=("v", "alpha", "q", "theta", "h"),
        input_names=("throttle", "elevator"),
        output_names=("v", "alpha", "q", "theta", "gamma", "h"),
        state_units=("m/s", "rad", "rad/s", "rad", "m"),
        input_units=("1", "rad"),
        output_units=("m/s", "rad", "rad/s", "rad", "rad", "m"),
    )


#: Eigenvalues the paper asks of A - K C (1/s), one per fault direction F = I5.
PAPER_EIGENVALUES: NDArray[np.float64] = _frozen(np.array([-1.0, -2.0, -3.0, -4.0, -5.0]))

#: Gain K (5 x 6) as printed in the paper (seed 002, section 4). It does NOT meet the
#: paper's specification: eig(A - K C) contains an unstable eigenvalue (about +2.47).
PAPER_PRINTED_K: NDArray[np.float64] = _frozen(
    np.array(
        [
            [1.0000, 0.0, 0.0, 0.0, 0.0, 0.0],
            [0.0, 0.3252, 1.0000, -0.1626, 0.1626, 0.0],
            [0.0, -5.2734, -0.0241, 2.6367, -2.6367, 0.0],
            [0.0, 1.3333, 1.0000, 1.3333, 2.6667, 0.0],
            [0.0, -90.7467, 0.0, 181.4933, 90.7467, 5.0000],
        ]
    )
)
