"""Isolability analysis: which sensor faults a model lets one detect and isolate.

The single Beard–Jones filter of the seed paper detects faults but cannot tell most
of them apart on the seed aircraft (docs/methods.md §4): constant-bias signatures of v
and h are zero, those of α, θ and γ nearly collinear. :func:`isolability_analysis`
works this out for a given model, for the main filter and for the observer bank of
:mod:`gyrodiag.df.isolation` (which re-exports these names).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from gyrodiag.common._validation import check_finite_array, check_positive
from gyrodiag.df.filter import (
    design_detection_filter,
    observability_matrix,
    observable_subspace,
    parity_space,
)
from gyrodiag.df.isolation import _bank_eigenvalues, place_observer_gain

__all__ = ["IsolabilityReport", "SensorIsolability", "isolability_analysis"]

_FloatArray = NDArray[np.float64]


@dataclass(frozen=True)
class SensorIsolability:
    """What the model allows for faults on one sensor.

    Attributes
    ----------
    name : str
        Sensor name.
    bias_signature : ndarray, shape (m,)
        Steady-state residual of the main filter per unit bias,
        ``s_i = (I + C (A − K C)⁻¹ K) q_i``.
    bias_steady_state_detectable : bool
        ``s_i`` is nonzero: the main filter keeps seeing a constant bias.
    bias_indistinguishable_from_state : bool
        ``q_i = C x̄`` for some equilibrium ``A x̄ = 0``: a constant bias looks
        exactly like a different initial state, so no observer of any gain sees it
        in steady state; only the step at onset (a transient) is detectable.
    transient_time_constant_s : float
        A fault step shows in full at onset (``γ(0⁺) = q_i f``) and then relaxes to
        ``s_i f`` through the filter modes it excites; this is the slowest of their
        time constants, s (0 if it excites none). For a sensor whose ``s_i`` is zero
        it bounds how long the fault stays visible: about τ·ln(f / threshold).
    redundant : bool
        (A, C without sensor i) is observable: the other sensors reproduce sensor i.
    direction_isolable_from : tuple of str
        Sensors whose main-filter bias signature is not nearly collinear
        (|cos| < the collinearity limit) with this one (both nonzero).
    bank_pattern : tuple of bool
        For each bank observer j: does a constant bias on this sensor change its
        residual in steady state?
    bank_isolable_from : tuple of str
        Sensors whose bank pattern differs from this one's (GOS can tell them apart).
    """

    name: str
    bias_signature: _FloatArray
    bias_steady_state_detectable: bool
    bias_indistinguishable_from_state: bool
    transient_time_constant_s: float
    redundant: bool
    direction_isolable_from: tuple[str, ...]
    bank_pattern: tuple[bool, ...]
    bank_isolable_from: tuple[str, ...]


@dataclass(frozen=True)
class IsolabilityReport:
    """Result of :func:`isolability_analysis`.

    Attributes
    ----------
    sensor_names : tuple of str
        Sensor names, in output order.
    K : ndarray
        Main detection-filter gain analysed.
    closed_loop_eigenvalues : ndarray
        eig(A − K C).
    signatures : ndarray, shape (m, m)
        Column i is the bias signature of sensor i.
    cosines : ndarray, shape (m, m)
        Cosine between signatures i and j (nan where one is zero).
    parity_relations : ndarray, shape (m − rank C, m)
        Rows ``w`` with ``w C = 0``: static parity checks of the outputs.
    bank_signatures : ndarray, shape (m, m)
        Norm of the steady-state residual of bank observer j (row) per unit bias on
        sensor i (column).
    sensors : tuple of SensorIsolability
        Per-sensor findings.
    collinear_cos : float
        Collinearity limit used.
    """

    sensor_names: tuple[str, ...]
    K: _FloatArray
    closed_loop_eigenvalues: NDArray[np.complex128]
    signatures: _FloatArray
    cosines: _FloatArray
    parity_relations: _FloatArray
    bank_signatures: _FloatArray
    sensors: tuple[SensorIsolability, ...]
    collinear_cos: float

    def sensor(self, name: str) -> SensorIsolability:
        """Return the entry of sensor ``name``."""
        for entry in self.sensors:
            if entry.name == name:
                return entry
        raise ValueError(f"name must be one of {self.sensor_names}, got {name!r}")

    def to_text(self) -> str:
        """Human-readable summary."""
        names = self.sensor_names
        lines = ["Sensor-fault isolability", ""]
        eig = ", ".join(f"{e.real:.4g}" if abs(e.imag) < 1e-12 else f"{e:.4g}"
                        for e in self.closed_loop_eigenvalues)
        lines.append(f"main filter eig(A - K C): {eig}")
        for w in self.parity_relations:
            terms = " ".join(f"{c:+.3f}*{nm}" for c, nm in zip(w, names, strict=True)
                             if abs(c) > 1e-9)
            lines.append(f"parity relation: {terms} = 0")
        lines.append("")
        lines.append("bias signature s_i (main filter, per unit bias), columns = faulty sensor")
        lines.append("        " + "".join(f"{nm:>10}" for nm in names))
        for r, nm in enumerate(names):
            lines.append(f"{nm:>8}" + "".join(f"{v:10.4f}" for v in self.signatures[r]))
        lines.append("")
        lines.append("|cos| between signatures (nan: zero signature)")
        lines.append("        " + "".join(f"{nm:>10}" for nm in names))
        for r, nm in enumerate(names):
            lines.append(
                f"{nm:>8}" + "".join(f"{abs(v):10.4f}" for v in self.cosines[r])
            )
        lines.append("")
        lines.append("bank: |steady residual| of observer without row-sensor, per unit bias")
        lines.append("        " + "".join(f"{nm:>10}" for nm in names))
        for r, nm in enumerate(names):
            lines.append(f"  -{nm:>6}" + "".join(f"{v:10.4f}" for v in self.bank_signatures[r]))
        lines.append("")
        for e in self.sensors:
            lines.append(f"{e.name}:")
            lines.append(
                f"  constant bias: steady-state detectable by main filter = "
                f"{e.bias_steady_state_detectable}, indistinguishable from an initial "
                f"state = {e.bias_indistinguishable_from_state}, onset transient time "
                f"constant = {e.transient_time_constant_s:.3g} s"
            )
            lines.append(f"  analytically redundant (observable without it) = {e.redundant}")
            lines.append(
                "  isolable by residual direction from: "
                + (", ".join(e.direction_isolable_from) or "none")
            )
            lines.append(
                "  isolable by observer bank from: " + (", ".join(e.bank_isolable_from) or "none")
            )
        return "\n".join(lines)


def _steady_signature(a_cl: _FloatArray, c: _FloatArray, gain: _FloatArray) -> _FloatArray:
    # Residual per unit constant bias on each output: I + C (A − K C)⁻¹ K.
    return np.eye(c.shape[0]) + c @ np.linalg.solve(a_cl, gain)


def isolability_analysis(
    A: ArrayLike,
    C: ArrayLike,
    sensor_names: tuple[str, ...] | list[str],
    *,
    K: ArrayLike | None = None,
    eigenvalues: ArrayLike | None = None,
    bank_eigenvalues: ArrayLike | None = None,
    collinear_cos: float = 0.98,
    zero_tol: float = 1e-9,
) -> IsolabilityReport:
    """Work out which sensor faults are detectable and isolable.

    Parameters
    ----------
    A, C : array_like
        Continuous model, n × n and m × n.
    sensor_names : sequence of str
        One name per output.
    K : array_like, optional
        Main detection-filter gain. Default: :func:`design_detection_filter` with
        ``F = I_n`` and ``eigenvalues``.
    eigenvalues : array_like, optional
        Eigenvalues for the default ``K``; default −1, …, −n.
    bank_eigenvalues : array_like, optional
        Continuous eigenvalues of the bank observers (as :func:`design_observer_bank`).
    collinear_cos : float
        |cos| at or above which two signatures count as collinear (not isolable by
        direction in the presence of noise).
    zero_tol : float
        Relative size below which a signature counts as zero.
    """
    a = check_finite_array("A", A, ndim=2)
    n = a.shape[0]
    c = check_finite_array("C", C, shape=(None, n))
    m = c.shape[0]
    names = tuple(str(s) for s in sensor_names)
    if len(names) != m:
        raise ValueError(f"sensor_names must have {m} entries, got {len(names)}")
    collinear_cos = float(collinear_cos)
    if not 0.0 < collinear_cos <= 1.0:
        raise ValueError(f"collinear_cos must be in (0, 1], got {collinear_cos}")
    zero_tol = check_positive("zero_tol", zero_tol)
    gain = _main_gain(a, c, K, eigenvalues)
    a_cl = a - gain @ c
    closed_eig = np.linalg.eigvals(a_cl)
    if np.any(closed_eig.real >= 0.0):
        raise ValueError(f"K must make A - K C stable, eig = {closed_eig}")

    sig = _steady_signature(a_cl, c, gain)
    nonzero, cos = _cosines(sig, zero_tol)
    as_states = _bias_as_state(a, c)
    bank_sig = _bank_signatures(a, c, bank_eigenvalues)
    bank_resp = bank_sig > zero_tol * max(1.0, float(bank_sig.max()))
    taus = _transient_time_constants(a_cl, c, gain, zero_tol)

    sensors = _sensors(names, a, c, sig=sig, nonzero=nonzero, cos=cos,
                       collinear_cos=collinear_cos, as_states=as_states,
                       bank_resp=bank_resp, taus=taus)
    return IsolabilityReport(
        sensor_names=names,
        K=gain,
        closed_loop_eigenvalues=closed_eig,
        signatures=sig,
        cosines=cos,
        parity_relations=parity_space(c),
        bank_signatures=bank_sig,
        sensors=tuple(sensors),
        collinear_cos=collinear_cos,
    )


def _sensors(names: tuple[str, ...], a: _FloatArray, c: _FloatArray, *, sig: _FloatArray,
             nonzero: NDArray[np.bool_], cos: _FloatArray, collinear_cos: float,
             as_states: list[bool], bank_resp: NDArray[np.bool_], taus: list[float],
             ) -> list[SensorIsolability]:
    """Each sensor's :class:`SensorIsolability` from the analyses of the whole set."""
    m = c.shape[0]
    sensors = []
    for i in range(m):
        redundant = _redundant(a, c, i)
        direction = tuple(
            names[j] for j in range(m)
            if j != i and nonzero[i] and nonzero[j] and abs(cos[i, j]) < collinear_cos
        )
        pattern = tuple(bool(v) for v in bank_resp[:, i])
        bank_iso = tuple(
            names[j] for j in range(m)
            if j != i and any(pattern) and pattern != tuple(bool(v) for v in bank_resp[:, j])
        )
        sensors.append(SensorIsolability(
            name=names[i], bias_signature=sig[:, i].copy(),
            bias_steady_state_detectable=bool(nonzero[i]),
            bias_indistinguishable_from_state=as_states[i],
            transient_time_constant_s=taus[i], redundant=redundant,
            direction_isolable_from=direction, bank_pattern=pattern,
            bank_isolable_from=bank_iso,
        ))
    return sensors


def _main_gain(a: _FloatArray, c: _FloatArray, K: ArrayLike | None,
               eigenvalues: ArrayLike | None) -> _FloatArray:
    """The given main-filter gain, or the detection filter's with ``eigenvalues``."""
    n, m = a.shape[0], c.shape[0]
    if K is None:
        lam = -np.arange(1.0, n + 1.0) if eigenvalues is None else eigenvalues
        return design_detection_filter(a, c, np.eye(n), lam)
    return check_finite_array("K", K, shape=(n, m))


def _cosines(sig: _FloatArray, zero_tol: float) -> tuple[NDArray[np.bool_], _FloatArray]:
    """Which bias signatures are nonzero, and the cosines between those that are."""
    m = sig.shape[1]
    norms = np.linalg.norm(sig, axis=0)
    nonzero = norms > zero_tol * max(1.0, float(norms.max()))
    cos = np.full((m, m), np.nan)
    for i in range(m):
        for j in range(m):
            if nonzero[i] and nonzero[j]:
                cos[i, j] = sig[:, i] @ sig[:, j] / (norms[i] * norms[j])
    return nonzero, cos


def _bias_as_state(a: _FloatArray, c: _FloatArray) -> list[bool]:
    """Per sensor: a bias on it equals C x̄ of an equilibrium (A x̄ = 0), i.e. a state."""
    n, m = a.shape[0], c.shape[0]
    _, s_a, vt_a = np.linalg.svd(a)
    ker_a = vt_a[np.sum(s_a > s_a.max(initial=0.0) * n * np.finfo(float).eps):].T
    c_ker = c @ ker_a
    out = []
    for i in range(m):
        q_i = np.eye(m)[i]
        if c_ker.shape[1]:
            coef = np.linalg.lstsq(c_ker, q_i, rcond=None)[0]
            out.append(bool(np.linalg.norm(c_ker @ coef - q_i) < 1e-9))
        else:
            out.append(False)
    return out


def _bank_signatures(a: _FloatArray, c: _FloatArray, bank_eigenvalues: ArrayLike | None
                     ) -> _FloatArray:
    """Row j: size of observer j's steady bias signature per sensor (continuous time,
    on the observable subspace of the sensors it uses)."""
    m = c.shape[0]
    bank_sig = np.zeros((m, m))
    for j in range(m):
        used = [i for i in range(m) if i != j]
        basis = observable_subspace(a, c[used])
        n_o = basis.shape[1]
        a_o, c_o = basis.T @ a @ basis, c[used] @ basis
        l_o = place_observer_gain(a_o, c_o, _bank_eigenvalues(bank_eigenvalues, n_o))
        s_j = _steady_signature(a_o - l_o @ c_o, c_o, l_o)
        for col, i in enumerate(used):
            bank_sig[j, i] = np.linalg.norm(s_j[:, col])
    return bank_sig


def _transient_time_constants(a_cl: _FloatArray, c: _FloatArray, gain: _FloatArray,
                              zero_tol: float) -> list[float]:
    """Per sensor: slowest time constant of the main filter's modes a fault step on it
    excites and the residual sees, s (modal form of the main filter)."""
    lam_cl, vec_cl = np.linalg.eig(a_cl)
    modal_in = np.linalg.solve(vec_cl, gain.astype(complex))
    modal_out_norm = np.linalg.norm(c @ vec_cl, axis=0)
    out = []
    for i in range(c.shape[0]):
        weight = np.abs(modal_in[:, i]) * modal_out_norm
        excited = weight > zero_tol * max(1.0, float(weight.max(initial=0.0)))
        out.append(float(np.max(1.0 / np.abs(lam_cl[excited].real), initial=0.0)))
    return out


def _redundant(a: _FloatArray, c: _FloatArray, i: int) -> bool:
    """The other sensors observe the whole state (sensor i has analytical redundancy)."""
    c_wo = np.delete(c, i, axis=0)
    return int(np.linalg.matrix_rank(observability_matrix(a, c_wo))) == a.shape[0]
