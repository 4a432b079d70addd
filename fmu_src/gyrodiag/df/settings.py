"""Settings, output record and codes of the sequential diagnosis
(:class:`~gyrodiag.df.sequential_diagnosis.SequentialDiagnoser`)."""

from __future__ import annotations

from dataclasses import dataclass
from enum import IntEnum

import numpy as np
from numpy.typing import NDArray

from ..common._records import fast_init
from ..common._validation import (
    check_finite_array,
    check_in_range,
    check_int,
    check_nonnegative,
    check_positive,
)

__all__ = ["MULTIPLE", "NOT_ISOLATED", "DiagnosisOutput", "FaultKind", "SequentialSettings"]

_FloatArray = NDArray[np.float64]

#: ``isolated`` value: a fault is (or was) detected but no single hypothesis is left.
NOT_ISOLATED = -1
#: ``isolated`` value: more than one sensor is faulty (see ``isolated_set``).
MULTIPLE = -2


class FaultKind(IntEnum):
    """Fault type codes of the sequential diagnosis (integer outputs)."""

    UNKNOWN = -1
    NONE = 0
    BIAS = 1
    GAIN = 2
    STUCK = 3
    FAILURE = 4
    NOISE = 5
    RAMP = 6
    INTERMITTENT = 7


@dataclass(frozen=True)
class SequentialSettings:
    """Settings of :class:`~gyrodiag.df.sequential_diagnosis.SequentialDiagnoser`
    (checked by :meth:`validate`).

    Attributes
    ----------
    false_alarms_per_h : float
        Design false-alarm rate of the detection (all main charts together), 1/h.
    cusum_k : float
        Mean-CUSUM reference, σ of the whitened residual (optimal for shifts of 2k).
    variance_ratio : float
        Variance increase the variance CUSUMs are designed for (> 1).
    release : float
        A channel's alarm clears below ``release`` × threshold (0 < release < 1).
    max_faults : int
        1: hypothesis generators for single faults; 2: also for every pair of sensors.
    history_s : float
        Samples kept to start the hypothesis generators before the change time, s.
    replay_margin_s : float
        The generators start this long before the estimated change time, s.
    memory_s : float
        The hypothesis generators stop this long after the last episode ended, s.
    regularisation : float
        Whitening regularisation (see :mod:`gyrodiag.df.residual`).
    bank_eigenvalues : tuple of float or None
        Continuous eigenvalues of the hypothesis observers, 1/s (default −1, −2, …).
    type_min_s : float
        Fault estimate needed before a type is given, s.
    type_period_s : float
        The type is refitted this often during an episode (and at every sample while
        it is still unknown), s.
    stuck_window_s : float
        Window of the constant-output (stuck/failure) test, s.
    type_significance : float
        Chi-square (1 dof) level a richer fault model must beat the bias by, in units
        of the long-run noise of the fault estimate.
    """

    false_alarms_per_h: float = 1e-3
    cusum_k: float = 0.5
    variance_ratio: float = 4.0
    release: float = 0.5
    max_faults: int = 2
    history_s: float = 4.0
    replay_margin_s: float = 0.5
    memory_s: float = 10.0
    regularisation: float = 0.01
    bank_eigenvalues: tuple[float, ...] | None = None
    type_min_s: float = 0.1
    type_period_s: float = 0.05
    stuck_window_s: float = 0.2
    type_significance: float = 25.0

    def validate(self) -> None:
        """Raise ValueError/TypeError naming the first invalid setting."""
        check_positive("false_alarms_per_h", self.false_alarms_per_h)
        check_in_range("cusum_k", self.cusum_k, 0.05, 5.0)
        check_in_range("variance_ratio", self.variance_ratio, 1.0, 1e6, low_open=True)
        check_in_range("release", self.release, 0.0, 1.0, low_open=True, high_open=True)
        if check_int("max_faults", self.max_faults, minimum=1) > 2:
            raise ValueError(f"max_faults must be 1 or 2, got {self.max_faults!r}")
        check_positive("history_s", self.history_s)
        check_nonnegative("replay_margin_s", self.replay_margin_s)
        check_nonnegative("memory_s", self.memory_s)
        check_in_range("regularisation", self.regularisation, 0.0, 1.0, low_open=True)
        if self.bank_eigenvalues is not None:
            lam = check_finite_array("bank_eigenvalues", self.bank_eigenvalues, ndim=1)
            if np.any(lam >= 0.0) or np.unique(lam).size != lam.size:
                raise ValueError("bank_eigenvalues must be distinct and < 0")
        check_positive("type_min_s", self.type_min_s)
        check_positive("type_period_s", self.type_period_s)
        check_positive("stuck_window_s", self.stuck_window_s)
        check_positive("type_significance", self.type_significance)


@fast_init
@dataclass(frozen=True)
class DiagnosisOutput:
    """Result of one
    :meth:`~gyrodiag.df.sequential_diagnosis.SequentialDiagnoser.update`.

    Attributes
    ----------
    residual : ndarray, shape (m,)
        Main detection-filter residual y − C x̂ (sensor units).
    alarms : ndarray of bool, shape (m,)
        Main CUSUM alarm per sensor channel.
    statistic : ndarray, shape (m,)
        Largest main CUSUM statistic per channel in units of its threshold (0–1).
    detected : bool
        A fault episode is in progress.
    episodes : int
        Episodes since reset.
    status : str
        "none" (never detected), "not isolated", "single", "pair" or "multiple": the
        current or, between episodes, the last diagnosis.
    isolated : tuple of int
        Sensors (0-based) of that diagnosis ("single": one, "pair": two, else none).
    fault_type : ndarray of int, shape (m,)
        :class:`FaultKind` per sensor (NONE for sensors not isolated).
    magnitude : ndarray, shape (m,)
        Per isolated sensor: bias or intermittent amplitude (sensor units), gain factor,
        stuck value, 0 for a failure, ramp rate (sensor units per s), total noise std
        as a multiple of the nominal; 0 where ``magnitude_valid`` is False.
    magnitude_valid : ndarray of bool, shape (m,)
    """

    residual: _FloatArray
    alarms: NDArray[np.bool_]
    statistic: _FloatArray
    detected: bool
    episodes: int
    status: str
    isolated: tuple[int, ...]
    fault_type: NDArray[np.int_]
    magnitude: _FloatArray
    magnitude_valid: NDArray[np.bool_]

