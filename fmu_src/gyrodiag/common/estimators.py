"""Linear-regression estimators: batch least squares, RLS, RLS with forgetting.

All estimators fit ``y(k) ≈ φ(k)ᵀ θ`` one sample at a time through ``update(phi, y)``
and expose ``theta``, ``converged`` (the DTG paper's criterion: the largest change of
any parameter in one update below ``convergence_tol``, default 1e−5) and ``reset()``.

Batch least squares is solved by an orthogonal factorisation (``numpy.linalg.lstsq``),
never by inverting the normal matrix, whose condition number is the square of the
regressor's: DTG regressors at 1 kHz are nearly collinear (θ1 ≈ 2, θ2 ≈ 1).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from . import _accel
from ._validation import check_finite_array, check_in_range, check_int, check_positive

__all__ = ["RLS", "ForgettingRLS", "SlidingWindowLS", "batch_ls"]


def batch_ls(phi: ArrayLike, y: ArrayLike) -> NDArray[np.float64]:
    """Least-squares θ minimising ‖y − Φθ‖₂ for a whole record.

    Parameters
    ----------
    phi : array_like, shape (n_samples, n_params)
        Regressor matrix Φ.
    y : array_like, shape (n_samples,)
        Targets.

    Raises
    ------
    ValueError
        If Φ is rank deficient (the parameters are not identifiable from the record).
    """
    Phi = check_finite_array("phi", phi, ndim=2)
    yy = check_finite_array("y", y, shape=(Phi.shape[0],))
    theta, _, rank, _ = np.linalg.lstsq(Phi, yy, rcond=None)
    if rank < Phi.shape[1]:
        raise ValueError(
            f"phi has rank {rank} < n_params {Phi.shape[1]}: the record does not excite "
            "all parameters"
        )
    return theta


class _Estimator:
    """Common bookkeeping: θ, convergence flag, sample counter, argument checks."""

    def __init__(
        self, n_params: int, theta0: ArrayLike | None, convergence_tol: float,
        convergence_hold: int,
    ) -> None:
        self.n_params = check_int("n_params", n_params, minimum=1)
        self.convergence_tol = check_positive("convergence_tol", convergence_tol)
        self.convergence_hold = check_int("convergence_hold", convergence_hold, minimum=1)
        self._theta_init = (
            np.zeros(self.n_params)
            if theta0 is None
            else check_finite_array("theta0", theta0, shape=(self.n_params,))
        )
        self._reset_common()

    def _reset_common(self) -> None:
        self.theta = self._theta_init.copy()
        self.n_updates = 0
        self._quiet_count = 0
        self.converged_at: int | None = None

    @property
    def converged(self) -> bool:
        """True while the last ``convergence_hold`` updates each moved θ by < tol."""
        return self._quiet_count >= self.convergence_hold

    def _check_sample(
        self, phi: ArrayLike, y: float, validate: bool = True
    ) -> tuple[NDArray[np.float64], float]:
        if not validate:
            # the caller (e.g. a channel) has already checked the raw sample
            return np.asarray(phi, dtype=float), float(y)
        p = check_finite_array("phi", phi, shape=(self.n_params,))
        yy = check_finite_array("y", y, ndim=0)
        return p, float(yy)

    def _track_convergence(self, theta_new: NDArray[np.float64]) -> None:
        step = float(np.max(np.abs(theta_new - self.theta)))
        self.theta = theta_new
        self.n_updates += 1
        self._quiet_count = self._quiet_count + 1 if step < self.convergence_tol else 0
        if self.converged and self.converged_at is None:
            self.converged_at = self.n_updates

    def _common_state(self) -> dict[str, Any]:
        return {
            "theta": self.theta.copy(),
            "n_updates": self.n_updates,
            "quiet_count": self._quiet_count,
            "converged_at": -1 if self.converged_at is None else self.converged_at,
        }

    def _set_common_state(self, state: dict[str, Any]) -> None:
        self.theta = check_finite_array(
            "state['theta']", state["theta"], shape=(self.n_params,)
        ).copy()
        self.n_updates = int(state["n_updates"])
        self._quiet_count = int(state["quiet_count"])
        ca = int(state["converged_at"])
        self.converged_at = None if ca < 0 else ca


class RLS(_Estimator):
    """Recursive least squares (no forgetting), in square-root form.

    The covariance is carried as a factor S with P = S·Sᵀ and updated by Potter's
    square-root algorithm, so P stays symmetric positive definite by construction.
    The textbook update P − K·φᵀ·P loses that property through cancellation when P0
    is large and the regressors are nearly collinear, which is the normal case for
    DTG data at 1 kHz (θ1 ≈ 2, θ2 ≈ 1).

    Parameters
    ----------
    n_params : int
        Number of parameters.
    p0 : float, optional
        Initial covariance P(0) = p0·I. Large p0 makes RLS equal batch least squares up
        to a ridge term ‖θ − θ0‖²/p0; "large" is relative to 1/σ_min(Φ)², so scale the
        regressors to comparable magnitudes.
    theta0 : array_like, optional
        Initial estimate (default zeros).
    convergence_tol : float, optional
        Convergence threshold on max |Δθ| per update (paper: 1e−5).
    convergence_hold : int, optional
        Number of consecutive quiet updates required (default 1, the paper's criterion).

    Notes
    -----
    The per-sample arithmetic runs in a kernel on plain floats (compiled, or its
    plain-Python fallback, see :mod:`gyrodiag.common._accel`); :meth:`step` is the unchecked
    hot path for callers that validated the sample already.
    """

    _forgetting = 1.0

    def __init__(
        self, n_params: int, p0: float = 1e6, theta0: ArrayLike | None = None,
        convergence_tol: float = 1e-5, convergence_hold: int = 1,
    ) -> None:
        self.p0 = check_positive("p0", p0)
        super().__init__(n_params, theta0, convergence_tol, convergence_hold)
        self._kernel = _accel.kernels.PotterRLS(
            self.n_params, self._forgetting, self._kernel_max_trace())
        self._kernel_reset()

    def _kernel_max_trace(self) -> float:
        return math.inf

    def _kernel_reset(self) -> None:
        n = self.n_params
        s0 = math.sqrt(self.p0)
        self._kernel.set(self._theta_init.tolist(),
                         [s0 if i == j else 0.0 for i in range(n) for j in range(n)])

    @property
    def _S(self) -> NDArray[np.float64]:
        """Covariance factor S (P = S·Sᵀ), a copy."""
        return np.array(self._kernel.get_S()).reshape(self.n_params, self.n_params)

    @property
    def P(self) -> NDArray[np.float64]:
        """Parameter covariance (up to the noise variance), P = S·Sᵀ."""
        S = self._S
        return S @ S.T

    @property
    def theta(self) -> NDArray[np.float64]:
        """Current estimate θ (a new array; :meth:`step` returns it as a tuple)."""
        return np.array(self._kernel.theta)

    @theta.setter
    def theta(self, value: ArrayLike) -> None:
        # set by the common bookkeeping at reset/set_state only
        if hasattr(self, "_kernel"):
            self._kernel.set(np.asarray(value, dtype=float).tolist(), self._kernel.get_S())

    def reset(self) -> None:
        """Back to θ0 and P(0)."""
        self._reset_common()
        self._kernel_reset()

    def update(
        self, phi: ArrayLike, y: float, *, validate: bool = True
    ) -> NDArray[np.float64]:
        """Incorporate one sample and return the new θ (a new array).

        ``validate=False`` skips the shape/finiteness checks, for callers that have
        checked the sample already (hot path of a channel).

        Raises
        ------
        ValueError
            On a wrong shape or non-finite value; the state is untouched.
        """
        p, yy = self._check_sample(phi, y, validate)
        self.step(p.tolist(), yy)
        return self.theta

    def step(self, phi: Sequence[float], y: float) -> tuple[float, ...]:
        """Incorporate one sample of plain floats, unchecked, and return θ as a tuple.

        Parameters
        ----------
        phi : sequence of float
            ``n_params`` finite regressors (the caller has checked them).
        y : float
            Finite target.
        """
        kernel = self._kernel
        moved = kernel.step(phi, y)
        self.n_updates += 1
        if moved < self.convergence_tol:
            self._quiet_count += 1
            if self.converged_at is None and self._quiet_count >= self.convergence_hold:
                self.converged_at = self.n_updates
        else:
            self._quiet_count = 0
        return tuple(kernel.theta)

    def get_state(self) -> dict[str, Any]:
        """Copy of θ, the covariance factor S (P = S·Sᵀ) and the counters."""
        return {**self._common_state(), "S": self._S}

    def set_state(self, state: dict[str, Any]) -> None:
        """Restore a state produced by :meth:`get_state`."""
        n = self.n_params
        S = check_finite_array("state['S']", state["S"], shape=(n, n))
        theta = check_finite_array("state['theta']", state["theta"], shape=(n,))
        self._set_common_state(state)
        self._kernel.set(theta.tolist(), S.ravel().tolist())


class ForgettingRLS(RLS):
    """RLS with exponential forgetting and a bounded covariance.

    With forgetting factor ``forgetting`` < 1 the update divides P by the factor at every
    sample. In a quiet closed loop the regressor carries no new information, so P grows
    as ``forgetting**-n`` without bound (wind-up) and the next disturbance throws θ
    far off. The trace of P is therefore capped at ``max_trace``: when it is exceeded,
    P is scaled back to that trace (the constant-trace remedy), which keeps P bounded,
    finite and positive definite for any input, including zero excitation forever.

    Parameters
    ----------
    n_params : int
        Number of parameters.
    forgetting : float, optional
        Forgetting factor in (0, 1]; the paper uses 0.99 (memory ≈ 1/(1 − 0.99) = 100
        samples).
    p0 : float, optional
        Initial covariance P(0) = p0·I.
    max_trace : float, optional
        Upper bound on trace(P); default ``n_params * p0``.
    theta0, convergence_tol, convergence_hold
        As in :class:`RLS`.
    """

    def __init__(
        self, n_params: int, forgetting: float = 0.99, p0: float = 1e6,
        max_trace: float | None = None, theta0: ArrayLike | None = None,
        convergence_tol: float = 1e-5, convergence_hold: int = 1,
    ) -> None:
        self.forgetting = check_in_range("forgetting", forgetting, 0.0, 1.0, low_open=True)
        self._forgetting = self.forgetting
        p0_checked = check_positive("p0", p0)
        n_checked = check_int("n_params", n_params, minimum=1)
        self.max_trace = (
            n_checked * p0_checked
            if max_trace is None
            else check_positive("max_trace", max_trace)
        )
        if self.max_trace < n_checked * p0_checked * (1.0 - 1e-12):
            raise ValueError(
                f"max_trace must be >= n_params * p0 = {n_checked * p0_checked}, "
                f"got {max_trace!r}"
            )
        super().__init__(n_params, p0, theta0, convergence_tol, convergence_hold)

    def _kernel_max_trace(self) -> float:
        return self.max_trace


class SlidingWindowLS(_Estimator):
    """Batch least squares over the most recent ``window`` samples.

    Parameters
    ----------
    n_params : int
        Number of parameters.
    window : int
        Window length in samples (>= n_params).
    solve_every : int, optional
        Re-solve every this many samples (default 1); θ is held in between. Solving
        costs O(window · n_params²).
    theta0, convergence_tol, convergence_hold
        As in :class:`RLS`. θ stays at θ0 until the window holds enough samples to
        make the problem full rank.

    Attributes
    ----------
    well_posed : bool
        False when the last solve found the window rank deficient (θ was held).
    """

    def __init__(
        self, n_params: int, window: int, solve_every: int = 1,
        theta0: ArrayLike | None = None, convergence_tol: float = 1e-5,
        convergence_hold: int = 1,
    ) -> None:
        super().__init__(n_params, theta0, convergence_tol, convergence_hold)
        self.window = check_int("window", window, minimum=self.n_params)
        self.solve_every = check_int("solve_every", solve_every, minimum=1)
        self.reset()

    def reset(self) -> None:
        """Empty the window and return to θ0."""
        self._reset_common()
        self._phi = np.zeros((self.window, self.n_params))
        self._y = np.zeros(self.window)
        self._head = 0  # next row to overwrite
        self._filled = 0
        self._since_solve = 0
        self.well_posed = False

    def update(
        self, phi: ArrayLike, y: float, *, validate: bool = True
    ) -> NDArray[np.float64]:
        """Push one sample into the window, re-solve when due, and return θ.

        ``validate=False`` skips the shape/finiteness checks, for callers that have
        checked the sample already (hot path of a channel).

        Raises
        ------
        ValueError
            On a wrong shape or non-finite value; the state is untouched.
        """
        p, yy = self._check_sample(phi, y, validate)
        self._phi[self._head] = p
        self._y[self._head] = yy
        self._head = (self._head + 1) % self.window
        self._filled = min(self._filled + 1, self.window)
        self._since_solve += 1
        theta_new = self.theta
        if self._filled >= self.n_params and self._since_solve >= self.solve_every:
            self._since_solve = 0
            rows = slice(0, self._filled)
            sol, _, rank, _ = np.linalg.lstsq(self._phi[rows], self._y[rows], rcond=None)
            self.well_posed = rank == self.n_params
            if self.well_posed:
                theta_new = sol
        self._track_convergence(theta_new.copy())
        return self.theta

    def step(self, phi: Sequence[float], y: float) -> tuple[float, ...]:
        """:meth:`update` for a checked sample of plain floats; θ as a tuple.

        The same interface as :meth:`RLS.step`, so a channel can drive any estimator the
        same way; the cost is the window's least-squares solve, not the call.
        """
        return tuple(self.update(np.asarray(phi, dtype=float), y, validate=False).tolist())

    def get_state(self) -> dict[str, Any]:
        """Copy of the window contents, θ and the counters."""
        return {
            **self._common_state(),
            "phi": self._phi.copy(),
            "y": self._y.copy(),
            "head": self._head,
            "filled": self._filled,
            "since_solve": self._since_solve,
            "well_posed": bool(self.well_posed),
        }

    def set_state(self, state: dict[str, Any]) -> None:
        """Restore a state produced by :meth:`get_state`."""
        phi = check_finite_array(
            "state['phi']", state["phi"], shape=(self.window, self.n_params)
        )
        y = check_finite_array("state['y']", state["y"], shape=(self.window,))
        self._set_common_state(state)
        self._phi, self._y = phi.copy(), y.copy()
        self._head = int(state["head"])
        self._filled = int(state["filled"])
        self._since_solve = int(state["since_solve"])
        self.well_posed = bool(state["well_posed"])
