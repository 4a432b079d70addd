"""What sensor faults stay detectable and isolable once a disturbance is decoupled.

A disturbance d entering the plant through E (``ẋ = A x + B u + E d``, e.g. the gust of
:mod:`gyrodiag.df.gust`) reaches the sensors through ``G_d(s) = C (sI − A)⁻¹ E``. A
residual generator that ignores d entirely (an unknown-input observer, or a detection
filter decoupled from E) can only use the output directions orthogonal to the range of
G_d(jω). A bias on sensor i enters y as the unit vector e_i, so at frequency ω

* its *visibility* is ‖P⊥(ω) e_i‖ ∈ [0, 1] (P⊥ the projector on that orthogonal
  complement): 1 means the disturbance never hides it, 0 that the disturbance can
  imitate it exactly;
* sensors i and j are isolable when their projections are not collinear.

This is the worst case: the gust model of :class:`~gyrodiag.df.gust.GustModel` does
better where the gust is weak (it weighs the gust by its spectrum instead of ignoring it
in every direction it reaches), docs/methods.md §4.6.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..common._validation import check_finite_array

__all__ = ["DecouplingReport", "decoupled_isolability"]

_FloatArray = NDArray[np.float64]

#: Frequencies (rad/s) the analysis looks at by default: slow drifts, manoeuvres, gusts.
DEFAULT_FREQUENCIES = (0.05, 0.5, 5.0)


@dataclass(frozen=True)
class DecouplingReport:
    """Result of :func:`decoupled_isolability`.

    Attributes
    ----------
    sensor_names : tuple of str
    frequencies : ndarray, shape (f,)
        rad/s.
    disturbance_rank : ndarray of int, shape (f,)
        Rank of G_d(jω): output directions the disturbance takes.
    visibility : ndarray, shape (f, m)
        ‖P⊥ e_i‖ per frequency and sensor.
    isolable : ndarray of bool, shape (m, m)
        Sensors i, j told apart at some frequency (both visible, projections not
        collinear).
    collinear_cos : float
    """

    sensor_names: tuple[str, ...]
    frequencies: _FloatArray
    disturbance_rank: NDArray[np.int_]
    visibility: _FloatArray
    isolable: NDArray[np.bool_]
    collinear_cos: float

    def isolable_from(self, name: str) -> tuple[str, ...]:
        """Sensors the fault of ``name`` is isolable from with the disturbance decoupled."""
        i = self.sensor_names.index(name)
        return tuple(n for j, n in enumerate(self.sensor_names) if self.isolable[i, j])

    def to_text(self) -> str:
        """Human-readable table."""
        names = self.sensor_names
        head = "".join(f"  w={w:g} rad/s" for w in self.frequencies)
        lines = ["With the disturbance decoupled (visibility of a sensor bias, 0-1)",
                 f"{'sensor':>8}{head}   isolable from"]
        for i, name in enumerate(names):
            vis = "".join(f"{v:>{len(f'  w={w:g} rad/s')}.3f}"
                          for v, w in zip(self.visibility[:, i], self.frequencies,
                                          strict=True))
            lines.append(f"{name:>8}{vis}   {', '.join(self.isolable_from(name)) or 'none'}")
        ranks = ", ".join(str(int(r)) for r in self.disturbance_rank)
        lines.append(f"disturbance rank per frequency: {ranks}")
        return "\n".join(lines)


def _orth_complement_projector(g: NDArray[np.complex128], tol: float
                               ) -> tuple[NDArray[np.complex128], int]:
    u, s, _ = np.linalg.svd(g, full_matrices=True)
    rank = int(np.count_nonzero(s > tol * max(float(s.max(initial=0.0)), 1e-300)))
    basis = u[:, rank:]
    return basis @ basis.conj().T, rank


def decoupled_isolability(A: ArrayLike, C: ArrayLike, E: ArrayLike,
                          sensor_names: tuple[str, ...] | list[str], *,
                          frequencies: ArrayLike = DEFAULT_FREQUENCIES,
                          collinear_cos: float = 0.98, visible: float = 0.05,
                          rank_tol: float = 1e-9) -> DecouplingReport:
    """Visibility and isolability of sensor biases with the disturbance E decoupled.

    Parameters
    ----------
    A, C, E : array_like
        Continuous plant (n × n, m × n) and disturbance input (n × d).
    sensor_names : sequence of str
        One per output.
    frequencies : array_like
        Angular frequencies to look at, rad/s (> 0; s = jω).
    collinear_cos : float
        |cos| at or above which two projected fault directions count as collinear.
    visible : float
        Visibility below which a fault counts as hidden.
    rank_tol : float
        Relative singular-value tolerance of the rank of G_d.
    """
    a = check_finite_array("A", A, ndim=2)
    n = a.shape[0]
    c = check_finite_array("C", C, shape=(None, n))
    e = check_finite_array("E", E, shape=(n, None))
    m = c.shape[0]
    names = tuple(sensor_names)
    if len(names) != m:
        raise ValueError(f"sensor_names must have {m} entries, got {len(names)}")
    w = check_finite_array("frequencies", frequencies, ndim=1)
    if w.size == 0 or np.any(w <= 0.0):
        raise ValueError("frequencies must be > 0 rad/s")
    vis = np.zeros((w.size, m))
    ranks = np.zeros(w.size, dtype=int)
    isolable = np.zeros((m, m), dtype=bool)
    for k, omega in enumerate(w):
        g = c @ np.linalg.solve(1j * omega * np.eye(n) - a, e)
        proj, ranks[k] = _orth_complement_projector(g, rank_tol)
        cols = proj  # P⊥ e_i is column i of P⊥
        norms = np.linalg.norm(cols, axis=0)
        vis[k] = norms
        for i in range(m):
            for j in range(m):
                if i == j or norms[i] < visible or norms[j] < visible:
                    continue
                cos = abs(np.vdot(cols[:, i], cols[:, j])) / (norms[i] * norms[j])
                if cos < collinear_cos:
                    isolable[i, j] = True
    return DecouplingReport(sensor_names=names, frequencies=w, disturbance_rank=ranks,
                            visibility=vis, isolable=isolable, collinear_cos=collinear_cos)
