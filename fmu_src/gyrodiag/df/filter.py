"""Beard–Jones fault detection filter, its sampled-data form and residual alarms.

Continuous filter (docs/methods.md §4, with the paper's sign typo corrected)::

    x̂' = A x̂ + B u + K (y − C x̂),    γ = y − C x̂,
    e'  = (A − K C) e − K Q f,         γ = C e + Q f.

:func:`design_detection_filter` picks ``K`` so that every fault direction ``f_i`` is
an eigenvector of ``A − K C`` with its own stable eigenvalue ``λ_i``.
:class:`DetectionFilter` runs it per sample, :class:`ResidualThresholds` derives
per-channel thresholds from fault-free residual statistics and
:class:`ResidualEvaluator` turns residuals into alarms (optionally k-of-n persistent).

Sampled-data form
-----------------
A sample period ``T`` and zero-order-held ``u`` are assumed (what a co-simulation
master delivers). Two exact discretisations are offered:

``"exact_error"`` (default)
    The plant model is discretised exactly by ZOH (Φ = e^{AT}, Γ = ∫ e^{As} ds B)
    and the discrete gain ``L`` is chosen so that the sampled error dynamics are
    exactly e^{(A−KC)T}: ``L C = Φ − e^{(A−KC)T}``. Fault directions stay
    eigenvectors with eigenvalues e^{λ_i T}, and a noise-free ZOH plant with matched
    initial state gives residuals that are zero to rounding. Needs ``L`` to be
    solvable (always so if ``C`` has full column rank, as on the seed aircraft).
``"zoh"``
    The continuous filter itself is discretised by ZOH, treating the sampled
    measurement ``y`` as a held input too. Exact for held ``y``, but the real ``y``
    moves inside a step, so a fault-free plant leaves an O(T) residual; kept for
    comparison and for ``C`` without a solvable ``L``.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import scipy.linalg
from numpy.typing import ArrayLike, NDArray

from gyrodiag.common._distributions import normal_isf
from gyrodiag.common._validation import (
    check_finite_array,
    check_in_range,
    check_int,
    check_positive,
)

__all__ = [
    "DetectionFilter",
    "DiscreteObserver",
    "ResidualEvaluator",
    "ResidualThresholds",
    "design_detection_filter",
    "gaussian_k_sigma",
    "observability_matrix",
    "observable_subspace",
    "parity_space",
    "zoh_discretise",
]

_FloatArray = NDArray[np.float64]


# --------------------------------------------------------------------------- helpers


def observability_matrix(A: ArrayLike, C: ArrayLike) -> _FloatArray:
    """Return [C; C A; …; C A^{n−1}] (same as MATLAB/``control.obsv``)."""
    a = np.asarray(A, dtype=float)
    c = np.asarray(C, dtype=float)
    blocks = [c]
    for _ in range(a.shape[0] - 1):
        blocks.append(blocks[-1] @ a)
    return np.vstack(blocks)


def _rank_tol(matrix: _FloatArray) -> float:
    # numpy's default rank tolerance, kept explicit so callers can report it.
    s = np.linalg.svd(matrix, compute_uv=False)
    return float(s.max(initial=0.0) * max(matrix.shape) * np.finfo(float).eps)


def observable_subspace(A: ArrayLike, C: ArrayLike) -> _FloatArray:
    """Orthonormal basis ``T`` (n × n_o) of the observable subspace of (A, C).

    The unobservable subspace is A-invariant and orthogonal to ``T``, so with
    ``x = T z + (unobservable part)`` the reduced model ``z' = Tᵀ A T z + Tᵀ B u``,
    ``y = C T z`` is exact.
    """
    obs = observability_matrix(A, C)
    _, s, vt = np.linalg.svd(obs)
    rank = int(np.sum(s > _rank_tol(obs)))
    return vt[:rank].T.copy()


def parity_space(C: ArrayLike) -> _FloatArray:
    """Orthonormal basis (rows) of the left null space of ``C``: ``W C = 0``.

    Each row ``w`` is a static parity relation ``w·y = 0`` of fault-free outputs and is
    also the free part of the detection-filter gain: any ``N = Z W`` with ``N C = 0``
    can be added to ``K`` without changing ``A − K C``. For the seed aircraft ``W`` is
    ±[0, 1, 0, −1, 1, 0]/√3, i.e. α − θ + γ = 0.
    """
    c = np.asarray(C, dtype=float)
    u, s, _ = np.linalg.svd(c)
    rank = int(np.sum(s > _rank_tol(c)))
    return u[:, rank:].T.copy()


def zoh_discretise(A: ArrayLike, B: ArrayLike, sample_period_s: float) -> tuple[
    _FloatArray, _FloatArray
]:
    """Exact zero-order-hold discretisation ``(Φ, Γ)`` of ``x' = A x + B u``.

    Computed from the matrix exponential of the augmented matrix [[A, B], [0, 0]]·T.
    """
    t = check_positive("sample_period_s", sample_period_s)
    a = np.asarray(A, dtype=float)
    b = np.asarray(B, dtype=float)
    n, p = b.shape
    aug = np.zeros((n + p, n + p))
    aug[:n, :n] = a * t
    aug[:n, n:] = b * t
    expo = scipy.linalg.expm(aug)
    return expo[:n, :n].copy(), expo[:n, n:].copy()


def as_state_int(name: str, value: Any, minimum: int = 0) -> int:
    """Integer from a saved state; accepts 0-d arrays (state dicts may hold them)."""
    if isinstance(value, np.ndarray) and value.ndim == 0:
        value = value.item()
    return check_int(name, value, minimum=minimum)


# ---------------------------------------------------------------------------- design


def _design_inputs(A: ArrayLike, C: ArrayLike, fault_directions: ArrayLike,
                   eigenvalues: ArrayLike, tol: float,
                   ) -> tuple[_FloatArray, _FloatArray, _FloatArray, _FloatArray, float]:
    """The design inputs as arrays, with their shapes and eigenvalues' type checked."""
    a = check_finite_array("A", A, ndim=2)
    n = a.shape[0]
    if a.shape != (n, n):
        raise ValueError(f"A must be square, got shape {a.shape}")
    c = check_finite_array("C", C, shape=(None, n))
    f = check_finite_array("fault_directions", fault_directions, ndim=2)
    if f.shape[0] != n:
        raise ValueError(
            f"fault_directions must have shape ({n}, r) (one state-space direction per "
            f"column), got {f.shape}"
        )
    r = f.shape[1]
    lam_in = np.asarray(eigenvalues)
    if np.iscomplexobj(lam_in) and np.any(np.imag(lam_in) != 0.0):
        raise ValueError(
            "eigenvalues must be real: complex pairs need a two-dimensional fault plane, "
            "which this design does not support"
        )
    lam = check_finite_array("eigenvalues", np.real(lam_in), shape=(r,))
    tol = check_positive("tol", tol)
    return a, c, f, lam, tol


def _check_design_conditions(a: _FloatArray, c: _FloatArray, f: _FloatArray,
                             lam: _FloatArray) -> _FloatArray:
    """The paper's conditions (1), (2), (4), stable eigenvalues and independent fault
    directions, each with its own message; returns ``C F``."""
    n = a.shape[0]
    m = c.shape[0]
    r = f.shape[1]
    obs_rank = int(np.linalg.matrix_rank(observability_matrix(a, c)))
    if obs_rank < n:
        raise ValueError(
            f"(A, C) must be observable (paper condition 1): rank obsv(A, C) = "
            f"{obs_rank} < n = {n}"
        )
    if np.any(lam >= 0.0):
        raise ValueError(
            f"eigenvalues must all be stable (< 0), got unstable {lam[lam >= 0.0].tolist()}"
        )
    if np.unique(lam).size != r:
        raise ValueError(
            f"eigenvalues must be distinct (paper condition 4), got repeated values in "
            f"{lam.tolist()}"
        )
    f_rank = int(np.linalg.matrix_rank(f))
    if f_rank < r:
        raise ValueError(
            f"fault_directions must be linearly independent: rank(F) = {f_rank} < r = {r}"
        )
    cf = c @ f
    cf_rank = int(np.linalg.matrix_rank(cf))
    if cf_rank < r:
        raise ValueError(
            f"rank(C F) must equal the number of fault directions (paper condition 2, "
            f"outputs must separate the faults): rank(C F) = {cf_rank} < r = {r}"
            + (f" (r > m = {m} outputs)" if r > m else "")
        )
    return cf


def _verify_gain(a: _FloatArray, c: _FloatArray, f: _FloatArray, lam: _FloatArray,
                 gain: _FloatArray, tol: float) -> None:
    """Condition (5) on the solved gain, and the stability of the modes it leaves free."""
    n = a.shape[0]
    r = f.shape[1]
    closed = a - gain @ c
    scale = np.linalg.norm(a @ f) + np.linalg.norm(f * lam) + 1.0
    spec_error = np.linalg.norm(closed @ f - f * lam) / scale
    if not spec_error <= tol:
        raise ValueError(
            f"eigenvector condition (A − K C) f_i = λ_i f_i not met by the solved K: "
            f"relative residual {spec_error:.3g} > tol {tol:.3g}"
        )
    if r < n:
        eig = np.linalg.eigvals(closed)
        if np.any(eig.real >= 0.0):
            raise ValueError(
                f"the {n - r} modes left free by the specification are not stable with "
                f"the minimum-norm K: eig(A − K C) = {np.round(eig, 6).tolist()}; "
                f"add fault directions or assign them separately"
            )


def design_detection_filter(
    A: ArrayLike,
    C: ArrayLike,
    fault_directions: ArrayLike,
    eigenvalues: ArrayLike,
    *,
    tol: float = 1e-9,
) -> _FloatArray:
    """Beard–Jones detection-filter gain: ``(A − K C) f_i = λ_i f_i``.

    Solves ``K (C F) = A F − F Λ`` with ``Λ = diag(λ)``. When ``rank(C F) = r`` this
    always has solutions ``K = (A F − F Λ)(C F)⁺ + Z (I − (C F)(C F)⁺)`` for any
    ``Z``; the returned one is the minimum-Frobenius-norm solution (``Z = 0``). The
    free part ``Z (I − C F (C F)⁺)`` contains, for ``F = I``, every ``N`` with
    ``N C = 0`` (rows in :func:`parity_space`); it changes the residual's response
    to sensor faults but not the error dynamics.

    Conditions checked up front (from the paper, section 3), each with its own
    message: shapes; (1) (A, C) observable; eigenvalues real, finite, strictly stable
    (< 0) and (4) pairwise distinct; fault directions linearly independent;
    (2) rank(C F) = r (which implies r ≤ m, the paper's condition (3)). After solving,
    (5) the eigenvector relation is verified to ``tol`` (relative to ‖A F‖ + ‖F Λ‖)
    and, when r < n, that the ``n − r`` modes the specification leaves free are stable.

    Complex eigenvalues are rejected: a complex pair would need a two-dimensional
    fault plane (paper: "限定在一个平面内"), which this function does not design.

    Parameters
    ----------
    A : array_like, shape (n, n)
        State matrix, 1/s.
    C : array_like, shape (m, n)
        Output matrix.
    fault_directions : array_like, shape (n, r)
        Fault directions ``F = [f_1 … f_r]`` in state space, one per column.
    eigenvalues : array_like, shape (r,)
        Desired eigenvalue ``λ_i`` of ``A − K C`` for each direction, 1/s.
    tol : float
        Relative tolerance of the verification of the solved ``K``.

    Returns
    -------
    ndarray, shape (n, m)
        Gain ``K`` (state units per output unit per second).

    Raises
    ------
    ValueError
        Naming the failed condition (shape, observability, eigenvalue, fault
        direction, rank(C F), verification).
    """
    a, c, f, lam, tol = _design_inputs(A, C, fault_directions, eigenvalues, tol)
    cf = _check_design_conditions(a, c, f, lam)

    target = a @ f - f * lam  # A F − F Λ
    gain = target @ np.linalg.pinv(cf)

    _verify_gain(a, c, f, lam, gain, tol)
    return gain


# ------------------------------------------------------------------ streaming observer


class DiscreteObserver:
    """Discrete-time Luenberger observer on a (possibly reduced) state basis.

    ``γ_k = y_k − C_o z_k`` (a-priori residual, ``z_k`` built from samples up to k−1),
    then ``z_{k+1} = Φ z_k + Γ u_k + L γ_k``. The full-state estimate is ``T z``
    (``T`` = basis, identity by default; unobservable components are reported as 0).

    Parameters
    ----------
    phi : array_like, shape (n_o, n_o)
        Discrete state matrix.
    gamma : array_like, shape (n_o, p)
        Discrete input matrix.
    C : array_like, shape (m, n_o)
        Output matrix in the observer's coordinates.
    L : array_like, shape (n_o, m)
        Discrete observer gain.
    basis : array_like, shape (n, n_o), optional
        Map from observer coordinates to the full state.
    """

    def __init__(
        self,
        phi: ArrayLike,
        gamma: ArrayLike,
        C: ArrayLike,
        L: ArrayLike,
        basis: ArrayLike | None = None,
    ) -> None:
        self._phi = check_finite_array("phi", phi, ndim=2)
        n_o = self._phi.shape[0]
        if self._phi.shape != (n_o, n_o):
            raise ValueError(f"phi must be square, got shape {self._phi.shape}")
        self._gamma = check_finite_array("gamma", gamma, shape=(n_o, None))
        self._c = check_finite_array("C", C, shape=(None, n_o))
        m = self._c.shape[0]
        self._l = check_finite_array("L", L, shape=(n_o, m))
        if basis is None:
            self._basis = np.eye(n_o)
        else:
            self._basis = check_finite_array("basis", basis, shape=(None, n_o))
        self._z = np.zeros(n_o)
        self._residual = np.zeros(m)
        self._n_updates = 0

    @property
    def n_inputs(self) -> int:
        """Number of inputs ``u``."""
        return self._gamma.shape[1]

    @property
    def n_outputs(self) -> int:
        """Number of measurements ``y``."""
        return self._c.shape[0]

    @property
    def closed_loop_matrix(self) -> _FloatArray:
        """Discrete error dynamics ``Φ − L C``."""
        return self._phi - self._l @ self._c

    @property
    def state_estimate(self) -> _FloatArray:
        """Current a-priori full-state estimate ``T z_k`` (state units)."""
        return self._basis @ self._z

    @property
    def output_estimate(self) -> _FloatArray:
        """Current a-priori output estimate ``C_o z_k`` (sensor units)."""
        return self._c @ self._z

    @property
    def residual(self) -> _FloatArray:
        """Residual of the last :meth:`update` (zeros before the first)."""
        return self._residual.copy()

    def reset(self, x0: ArrayLike | None = None) -> None:
        """Restart from full-state estimate ``x0`` (zeros if None)."""
        if x0 is None:
            self._z = np.zeros_like(self._z)
        else:
            x = check_finite_array("x0", x0, shape=(self._basis.shape[0],))
            # Least squares: exact for an orthonormal or square basis, and drops the
            # unobservable components of x0 otherwise.
            self._z = np.linalg.lstsq(self._basis, x, rcond=None)[0]
        self._residual = np.zeros(self.n_outputs)
        self._n_updates = 0

    def update(self, u: ArrayLike, y: ArrayLike) -> _FloatArray:
        """Process one sample; return the a-priori residual ``y_k − C z_k``.

        Raises ``ValueError`` naming ``u`` or ``y`` for a wrong shape or a non-finite
        value, leaving the state untouched.
        """
        u_arr = check_finite_array("u", u, shape=(self.n_inputs,))
        y_arr = check_finite_array("y", y, shape=(self.n_outputs,))
        return self.advance(u_arr, y_arr).copy()

    def advance(self, u: _FloatArray, y: _FloatArray) -> _FloatArray:
        """:meth:`update` without the checks, for callers that validated the sample.

        ``u`` and ``y`` must be finite float64 arrays of shapes (p,) and (m,); the
        returned residual is the observer's own array (do not modify it).  A bank of
        observers fed one validated sample pays the checks once instead of per
        observer (they were a third of a 1 kHz system run's cost).
        """
        residual = y - self._c @ self._z
        self._z = self._phi @ self._z + self._gamma @ u + self._l @ residual
        self._residual = residual
        self._n_updates += 1
        return residual

    def get_state(self) -> dict[str, Any]:
        """Return a deep copy of the dynamic state."""
        return {
            "z": self._z.copy(),
            "residual": self._residual.copy(),
            "n_updates": int(self._n_updates),
        }

    def set_state(self, state: dict[str, Any]) -> None:
        """Restore a state produced by :meth:`get_state`."""
        if not isinstance(state, dict):
            raise TypeError(f"state must be a dict, got {type(state).__name__}")
        missing = {"z", "residual", "n_updates"} - set(state)
        if missing:
            raise ValueError(f"state is missing keys {sorted(missing)}")
        z = check_finite_array("state['z']", state["z"], shape=(self._z.size,))
        res = check_finite_array(
            "state['residual']", state["residual"], shape=(self.n_outputs,)
        )
        n_upd = as_state_int("state['n_updates']", state["n_updates"])
        self._z, self._residual, self._n_updates = z.copy(), res.copy(), n_upd


class DetectionFilter(DiscreteObserver):
    """Streaming sampled-data detection filter ``x̂' = A x̂ + B u + K (y − C x̂)``.

    Parameters
    ----------
    A, B, C : array_like
        Continuous plant model (n × n, n × p, m × n).
    K : array_like, shape (n, m)
        Continuous detection-filter gain, e.g. from :func:`design_detection_filter`.
    sample_period_s : float
        Sample period T, s. ``u`` is assumed held (ZOH) over each period.
    discretisation : {"exact_error", "zoh"}
        See the module docstring. ``"exact_error"`` gives error dynamics exactly
        e^{(A−KC)T} and zero fault-free residual on an exact ZOH plant.

    Notes
    -----
    :meth:`update` returns the a-priori residual ``γ_k = y_k − C x̂_k`` where ``x̂_k``
    was propagated from samples up to k−1 (the value *before* the step); then it
    advances ``x̂`` to k+1 using ``u_k`` and ``y_k``. A sensor step at sample k shows
    fully in ``γ_k``, unfiltered: ``γ_k = Q f`` at fault onset.
    """

    def __init__(
        self,
        A: ArrayLike,
        B: ArrayLike,
        C: ArrayLike,
        K: ArrayLike,
        sample_period_s: float,
        discretisation: str = "exact_error",
    ) -> None:
        a = check_finite_array("A", A, ndim=2)
        n = a.shape[0]
        if a.shape != (n, n):
            raise ValueError(f"A must be square, got shape {a.shape}")
        b = check_finite_array("B", B, shape=(n, None))
        c = check_finite_array("C", C, shape=(None, n))
        k = check_finite_array("K", K, shape=(n, c.shape[0]))
        t = check_positive("sample_period_s", sample_period_s)
        if discretisation not in ("exact_error", "zoh"):
            raise ValueError(
                f"discretisation must be 'exact_error' or 'zoh', got {discretisation!r}"
            )
        phi_cl = scipy.linalg.expm((a - k @ c) * t)
        if discretisation == "exact_error":
            phi, gam = zoh_discretise(a, b, t)
            lhs = phi - phi_cl
            gain = lhs @ np.linalg.pinv(c)
            err = np.linalg.norm(gain @ c - lhs) / (np.linalg.norm(lhs) + 1e-300)
            if err > 1e-9:
                raise ValueError(
                    "discretisation='exact_error' needs L C = e^{AT} − e^{(A−KC)T} "
                    f"solvable (relative residual {err:.3g}); use discretisation='zoh'"
                )
        else:
            _, gam_all = zoh_discretise(a - k @ c, np.hstack([b, k]), t)
            gam, gain = gam_all[:, : b.shape[1]], gam_all[:, b.shape[1]:]
            phi = phi_cl + gain @ c
        super().__init__(phi, gam, c, gain)
        self._sample_period_s = t
        self._continuous_gain = k
        self._discretisation = discretisation

    @property
    def sample_period_s(self) -> float:
        """Sample period, s."""
        return self._sample_period_s

    @property
    def discrete_gain(self) -> _FloatArray:
        """Discrete gain ``L`` of ``x̂_{k+1} = Φ x̂_k + Γ u_k + L γ_k``."""
        return self._l.copy()

    @property
    def discretisation(self) -> str:
        """Discretisation method in use."""
        return self._discretisation


# ---------------------------------------------------------------- thresholds, alarms


@dataclass(frozen=True)
class ResidualThresholds:
    """Per-channel residual statistics and alarm thresholds.

    An alarm is raised when ``|γ − mean| > threshold`` with ``threshold = k·std``.

    Attributes
    ----------
    mean, std, threshold : ndarray, shape (m,)
        Fault-free residual mean and standard deviation and the alarm threshold,
        residual units.
    k_sigma : float
        Threshold in standard deviations.
    """

    mean: _FloatArray
    std: _FloatArray
    threshold: _FloatArray
    k_sigma: float

    def __post_init__(self) -> None:
        mean = check_finite_array("mean", self.mean, ndim=1)
        std = check_finite_array("std", self.std, shape=mean.shape)
        thr = check_finite_array("threshold", self.threshold, shape=mean.shape)
        if np.any(thr <= 0.0):
            raise ValueError("threshold must be > 0 on every channel")
        object.__setattr__(self, "mean", mean)
        object.__setattr__(self, "std", std)
        object.__setattr__(self, "threshold", thr)

    @classmethod
    def from_fault_free(
        cls,
        residuals: ArrayLike,
        *,
        false_alarm_rate: float | None = None,
        k_sigma: float | None = None,
        burn_in: int = 0,
        min_threshold: float | Sequence[float] = 1e-12,
    ) -> ResidualThresholds:
        """Estimate thresholds from fault-free residuals.

        Parameters
        ----------
        residuals : array_like, shape (N, m)
            Fault-free residual samples, one row per sample.
        false_alarm_rate : float, optional
            Per-sample, per-channel false-alarm probability in (0, 0.5); the
            threshold is the two-sided Gaussian quantile ``k = Φ⁻¹(1 − rate/2)``.
            Residuals of a filter are correlated and not exactly Gaussian: treat it
            as a design figure and verify the false-alarm rate on separate data.
        k_sigma : float, optional
            Threshold in standard deviations. Exactly one of the two must be given.
        burn_in : int
            Initial samples to skip (filter start-up transient).
        min_threshold : float or sequence of float
            Floor of the threshold per channel, residual units (a noise-free channel
            would otherwise alarm on rounding).
        """
        if (false_alarm_rate is None) == (k_sigma is None):
            raise ValueError("give exactly one of false_alarm_rate or k_sigma")
        if false_alarm_rate is not None:
            k = gaussian_k_sigma(false_alarm_rate)
        else:
            k = check_positive("k_sigma", k_sigma)  # type: ignore[arg-type]
        burn = check_int("burn_in", burn_in)
        res = check_finite_array("residuals", residuals, ndim=2)
        if res.shape[0] - burn < 2:
            raise ValueError(
                f"residuals must have at least 2 samples after burn_in={burn}, "
                f"got {res.shape[0]}"
            )
        used = res[burn:]
        mean = used.mean(axis=0)
        std = used.std(axis=0, ddof=1)
        floor = np.broadcast_to(
            check_finite_array("min_threshold", min_threshold), mean.shape
        )
        if np.any(floor <= 0.0):
            raise ValueError("min_threshold must be > 0")
        return cls(mean=mean, std=std, threshold=np.maximum(k * std, floor), k_sigma=k)

    @property
    def n_channels(self) -> int:
        """Number of residual channels."""
        return self.mean.size

    def normalise(self, residual: ArrayLike) -> _FloatArray:
        """Return ``(γ − mean) / threshold``: magnitude > 1 means alarm."""
        r = check_finite_array("residual", residual, shape=(self.n_channels,))
        return (r - self.mean) / self.threshold


class ResidualEvaluator:
    """Per-channel alarm logic on residuals, with optional k-of-n persistence.

    A channel alarms at sample k when at least ``persistence_k`` of its last
    ``persistence_n`` normalised residuals exceeded 1 in magnitude (1-of-1 = plain
    threshold test). Persistence trades detection delay (at least k−1 samples) for
    fewer false alarms from isolated noise spikes.

    Parameters
    ----------
    thresholds : ResidualThresholds
        Channel statistics.
    persistence_k, persistence_n : int
        Exceedances needed within the window, and the window length (1 ≤ k ≤ n).
    """

    def __init__(
        self, thresholds: ResidualThresholds, persistence_k: int = 1, persistence_n: int = 1
    ) -> None:
        if not isinstance(thresholds, ResidualThresholds):
            raise TypeError(
                f"thresholds must be a ResidualThresholds, got {type(thresholds).__name__}"
            )
        self._thr = thresholds
        self._n = check_int("persistence_n", persistence_n, minimum=1)
        self._k = check_int("persistence_k", persistence_k, minimum=1)
        if self._k > self._n:
            raise ValueError(
                f"persistence_k must be <= persistence_n ({self._n}), got {self._k}"
            )
        self.reset()

    @property
    def thresholds(self) -> ResidualThresholds:
        """Thresholds in use."""
        return self._thr

    def reset(self) -> None:
        """Clear the persistence history."""
        self._history = np.zeros((self._n, self._thr.n_channels), dtype=bool)
        self._pos = 0
        self._alarms = np.zeros(self._thr.n_channels, dtype=bool)
        self._normalised = np.zeros(self._thr.n_channels)

    def update(self, residual: ArrayLike) -> tuple[NDArray[np.bool_], _FloatArray]:
        """Return ``(alarms, normalised residual)`` for one residual sample."""
        normalised = self._thr.normalise(residual)
        alarms = self._record(normalised)
        return alarms.copy(), normalised.copy()

    def advance(self, residual: _FloatArray) -> tuple[NDArray[np.bool_], _FloatArray]:
        """:meth:`update` without the checks, for a residual known finite, shape (m,).

        Returns the evaluator's own arrays (do not modify them).
        """
        return self._record((residual - self._thr.mean) / self._thr.threshold), \
            self._normalised

    def _record(self, normalised: _FloatArray) -> NDArray[np.bool_]:
        self._history[self._pos] = np.abs(normalised) > 1.0
        self._pos = (self._pos + 1) % self._n
        self._alarms = self._history.sum(axis=0) >= self._k
        self._normalised = normalised
        return self._alarms

    @property
    def alarms(self) -> NDArray[np.bool_]:
        """Alarm flags of the last update."""
        return self._alarms.copy()

    def get_state(self) -> dict[str, Any]:
        """Return a deep copy of the persistence history."""
        return {
            "history": self._history.astype(float),
            "pos": int(self._pos),
            "alarms": self._alarms.astype(float),
            "normalised": self._normalised.copy(),
        }

    def set_state(self, state: dict[str, Any]) -> None:
        """Restore a state produced by :meth:`get_state`."""
        if not isinstance(state, dict):
            raise TypeError(f"state must be a dict, got {type(state).__name__}")
        m = self._thr.n_channels
        hist = check_finite_array("state['history']", state["history"], shape=(self._n, m))
        pos = as_state_int("state['pos']", state["pos"])
        if pos >= self._n:
            raise ValueError(f"state['pos'] must be < {self._n}, got {pos}")
        alarms = check_finite_array("state['alarms']", state["alarms"], shape=(m,))
        norm = check_finite_array("state['normalised']", state["normalised"], shape=(m,))
        self._history = hist != 0.0
        self._pos = pos
        self._alarms = alarms != 0.0
        self._normalised = norm.copy()


def gaussian_k_sigma(false_alarm_rate: float) -> float:
    """Two-sided Gaussian threshold factor for a per-sample false-alarm rate."""
    rate = check_in_range(
        "false_alarm_rate", false_alarm_rate, 0.0, 0.5, low_open=True, high_open=True
    )
    return normal_isf(rate / 2.0)

