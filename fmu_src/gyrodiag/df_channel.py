"""The detection-filter diagnosis channel: design, calibration, detection, isolation.

One object per monitored linear plant, fed one sample of (u, y) per sample period. It
designs the Beard–Jones gain from (A, C, eigenvalues) with fault directions F = I,
builds a :class:`~gyrodiag.isolation.SensorFaultIsolator` (main detection filter plus
a bank of observers, each without one sensor), and either takes residual thresholds
as given or learns them from an initial fault-free calibration window (k·σ of the
residuals after a burn-in). The Diagnoser FMU only maps its variables onto this class.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ._validation import (
    check_finite_array,
    check_int,
    check_nonnegative,
    check_positive,
)
from .aircraft import seed_aircraft
from .detection_filter import ResidualThresholds, design_detection_filter
from .isolation import FaultType, SensorFaultIsolator

__all__ = ["DFChannel", "DFChannelConfig", "DFChannelOutput"]


def _seed_a() -> NDArray[np.float64]:
    return np.array(seed_aircraft().A)


def _seed_b() -> NDArray[np.float64]:
    return np.array(seed_aircraft().B)


def _seed_c() -> NDArray[np.float64]:
    return np.array(seed_aircraft().C)


@dataclass
class DFChannelConfig:
    """Settings of a :class:`DFChannel` (validated by :meth:`validate`).

    Attributes
    ----------
    A, B, C : array_like
        Continuous plant model (n × n, n × p, m × n); default the seed aircraft.
    eigenvalues : array_like, shape (n,)
        Eigenvalues of A − KC, 1/s (real, distinct, negative); default −1 … −n.
    sample_period_s : float
        Sample period, s.
    calibrate_s : float
        Length of the initial fault-free calibration window, s. 0: use the given
        thresholds instead.
    burn_in_s : float
        Start of the calibration window ignored while the observers converge, s.
    k_sigma : float
        Thresholds at k standard deviations of the calibration residuals.
    main_thresholds : array_like, shape (m,), optional
        Main-filter residual thresholds (sensor units), when ``calibrate_s`` = 0.
    bank_thresholds : array_like, shape (m, m − 1), optional
        Row j: thresholds of observer j (without sensor j) on the other sensors.
    noise_std : array_like, shape (m,), optional
        Sensor noise standard deviations for the stuck/failure tests; default
        ``main_thresholds / k_sigma``.
    persistence_k, persistence_n : int
        k-of-n persistence of every residual alarm.
    confirm_samples : int
        Consecutive samples of one isolation pattern before it is latched.
    x0 : array_like, shape (n,), optional
        Initial state estimate of every observer (default zeros).
    """

    A: ArrayLike = field(default_factory=_seed_a)
    B: ArrayLike = field(default_factory=_seed_b)
    C: ArrayLike = field(default_factory=_seed_c)
    eigenvalues: ArrayLike | None = None
    sample_period_s: float = 0.01
    calibrate_s: float = 10.0
    burn_in_s: float = 2.0
    k_sigma: float = 6.0
    main_thresholds: ArrayLike | None = None
    bank_thresholds: ArrayLike | None = None
    noise_std: ArrayLike | None = None
    persistence_k: int = 3
    persistence_n: int = 5
    confirm_samples: int = 5
    x0: ArrayLike | None = None

    def matrices(self) -> tuple[NDArray, NDArray, NDArray, NDArray, NDArray]:
        """Validated (A, B, C, eigenvalues, x0) as float arrays."""
        A = check_finite_array("A", self.A, ndim=2)
        n = A.shape[0]
        if A.shape != (n, n):
            raise ValueError(f"A must be square, got shape {A.shape}")
        B = check_finite_array("B", self.B, shape=(n, None))
        C = check_finite_array("C", self.C, shape=(None, n))
        eig = (
            -np.arange(1.0, n + 1.0)
            if self.eigenvalues is None
            else check_finite_array("eigenvalues", self.eigenvalues, shape=(n,))
        )
        x0 = np.zeros(n) if self.x0 is None else check_finite_array("x0", self.x0, shape=(n,))
        return A, B, C, eig, x0

    def validate(self) -> None:
        """Raise ValueError/TypeError naming the first invalid setting."""
        _, _, C, _, _ = self.matrices()
        m = C.shape[0]
        period = check_positive("sample_period_s", self.sample_period_s)
        calibrate = check_nonnegative("calibrate_s", self.calibrate_s)
        burn = check_nonnegative("burn_in_s", self.burn_in_s)
        check_positive("k_sigma", self.k_sigma)
        if calibrate > 0.0:
            if calibrate - burn < 10 * period:
                raise ValueError(
                    "calibrate_s must exceed burn_in_s by at least 10 samples, got "
                    f"calibrate_s={self.calibrate_s!r}, burn_in_s={self.burn_in_s!r}"
                )
        else:
            if self.main_thresholds is None or self.bank_thresholds is None:
                raise ValueError(
                    "main_thresholds and bank_thresholds are required when calibrate_s = 0"
                )
            main = check_finite_array("main_thresholds", self.main_thresholds, shape=(m,))
            bank = check_finite_array(
                "bank_thresholds", self.bank_thresholds, shape=(m, m - 1)
            )
            if np.any(main <= 0) or np.any(bank <= 0):
                raise ValueError("main_thresholds and bank_thresholds must be > 0")
            if self.noise_std is not None:
                std = check_finite_array("noise_std", self.noise_std, shape=(m,))
                if np.any(std <= 0):
                    raise ValueError("noise_std must be > 0 on every sensor")
        pk = check_int("persistence_k", self.persistence_k, minimum=1)
        pn = check_int("persistence_n", self.persistence_n, minimum=1)
        if pk > pn:
            raise ValueError(f"persistence_k must be <= persistence_n ({pn}), got {pk}")
        check_int("confirm_samples", self.confirm_samples, minimum=1)


@dataclass(frozen=True)
class DFChannelOutput:
    """Outputs of one :meth:`DFChannel.update`.

    Attributes
    ----------
    valid : bool
        False when u or y had NaN/Inf; the sample was skipped, state untouched.
    calibrating : bool
        Thresholds are still being learned; no decision yet.
    residual : ndarray, shape (m,)
        Main detection-filter residual γ = y − C x̂ (sensor units).
    alarms : ndarray of bool, shape (m,)
        Per-sensor residual alarms of the main filter at this sample.
    detected : bool
        A fault has been detected (latched until reset).
    isolated_sensor : int
        1-based index of the isolated sensor; 0 none detected; −1 detected, not isolated.
    fault_type : int
        :class:`~gyrodiag.isolation.FaultType` code (−1 unknown, 0 none, 1 bias,
        2 gain, 3 stuck, 4 complete failure).
    magnitude : float
        Bias (sensor units), gain factor, stuck value, 0 for failure; NaN if unknown.
    """

    valid: bool
    calibrating: bool
    residual: NDArray[np.float64]
    alarms: NDArray[np.bool_]
    detected: bool
    isolated_sensor: int
    fault_type: int
    magnitude: float

    @property
    def alarm(self) -> bool:
        """Detected fault (the channel's alarm)."""
        return self.detected


class DFChannel:
    """Streaming detection-filter diagnoser with isolation.

    Parameters
    ----------
    config : DFChannelConfig
        Settings; validated here (ValueError naming the setting, or the failed design
        condition of :func:`~gyrodiag.detection_filter.design_detection_filter`).
    """

    def __init__(self, config: DFChannelConfig) -> None:
        config.validate()
        self.config = config
        A, B, C, eig, x0 = config.matrices()
        self.n, self.p, self.m = A.shape[0], B.shape[1], C.shape[0]
        self.K = design_detection_filter(A, C, np.eye(self.n), eig)
        self._x0 = x0
        self._iso = SensorFaultIsolator(
            A, B, C, self.K, config.sample_period_s,
            persistence_k=config.persistence_k, persistence_n=config.persistence_n,
            confirm_samples=config.confirm_samples,
        )
        self.T = float(config.sample_period_s)
        self._n_cal = round(config.calibrate_s / self.T)
        self._n_burn = round(config.burn_in_s / self.T)
        self.reset()

    def reset(self) -> None:
        """Return to the state right after construction."""
        c = self.config
        self._n_samples = 0
        self._installed: dict[str, Any] | None = None
        self._cal_res: list[list[NDArray[np.float64]]] = [[] for _ in range(self.m + 1)]
        if self._n_cal > 0:
            self._calibrated = False
            self._reset_observers()
        else:
            k = float(c.k_sigma)
            main = np.asarray(c.main_thresholds, dtype=float)
            bank = np.asarray(c.bank_thresholds, dtype=float)
            std = (
                main / k if c.noise_std is None else np.asarray(c.noise_std, dtype=float)
            )
            self._install([_thresholds(main, k)] + [_thresholds(row, k) for row in bank], std)
            self._iso.reset(self._x0)
            self._calibrated = True
        self._last = DFChannelOutput(
            True, not self._calibrated, np.zeros(self.m), np.zeros(self.m, dtype=bool),
            False, 0, int(FaultType.NONE), 0.0,
        )

    def _reset_observers(self) -> None:
        self._iso.main_filter.reset(self._x0)
        for b in self._iso.bank:
            b.observer.reset(self._x0)

    def update(self, u: ArrayLike, y: ArrayLike) -> DFChannelOutput:
        """Process one sample of inputs ``u`` (p,) and measurements ``y`` (m,)."""
        uu = np.asarray(u, dtype=float).reshape(-1)
        yy = np.asarray(y, dtype=float).reshape(-1)
        if uu.shape != (self.p,):
            raise ValueError(f"u must have shape ({self.p},), got {uu.shape}")
        if yy.shape != (self.m,):
            raise ValueError(f"y must have shape ({self.m},), got {yy.shape}")
        if not (np.all(np.isfinite(uu)) and np.all(np.isfinite(yy))):
            self._last = DFChannelOutput(
                False, self._last.calibrating, self._last.residual, self._last.alarms,
                self._last.detected, self._last.isolated_sensor, self._last.fault_type,
                self._last.magnitude,
            )
            return self._last
        self._n_samples += 1
        if not self._calibrated:
            self._calibrate_step(uu, yy)
            return self._last
        res = self._iso.update(uu, yy)
        residual = self._iso.main_filter.residual.copy()
        if res.isolated >= 0:
            isolated = res.isolated + 1
        else:
            isolated = -1 if res.detected else 0
        self._last = DFChannelOutput(
            True, False, residual, res.main_alarms.copy(), res.detected, isolated,
            int(res.fault_type), float(res.magnitude),
        )
        return self._last

    def _calibrate_step(self, u: NDArray[np.float64], y: NDArray[np.float64]) -> None:
        main = self._iso.main_filter.update(u, y)
        self._cal_res[0].append(main)
        for j, b in enumerate(self._iso.bank):
            self._cal_res[j + 1].append(b.observer.update(u, y[b.used]))
        if self._n_samples >= self._n_cal:
            self._finish_calibration()
        self._last = DFChannelOutput(
            True, not self._calibrated, main, np.zeros(self.m, dtype=bool), False, 0,
            int(FaultType.NONE), 0.0,
        )

    def _finish_calibration(self) -> None:
        k = float(self.config.k_sigma)
        burn = min(self._n_burn, self._n_cal - 2)
        thresholds = [
            ResidualThresholds.from_fault_free(np.array(r), k_sigma=k, burn_in=burn)
            for r in self._cal_res
        ]
        # set_thresholds() restarts the observers: keep their converged states.
        saved = self._observer_states()
        self._install(thresholds, None)
        self._restore_observer_states(saved)
        self._cal_res = [[] for _ in range(self.m + 1)]
        self._calibrated = True

    def _install(
        self, thresholds: list[ResidualThresholds], noise_std: NDArray[np.float64] | None
    ) -> None:
        """Give the isolator its thresholds and remember them for the saved state."""
        self._iso.set_thresholds(thresholds[0], thresholds[1:], noise_std)
        self._installed = {
            "mean": [t.mean.copy() for t in thresholds],
            "std": [t.std.copy() for t in thresholds],
            "threshold": [t.threshold.copy() for t in thresholds],
            "k_sigma": float(thresholds[0].k_sigma),
            "noise_std": None if noise_std is None else np.asarray(noise_std).copy(),
        }

    def _observer_states(self) -> list[dict[str, Any]]:
        return [self._iso.main_filter.get_state()] + [
            b.observer.get_state() for b in self._iso.bank
        ]

    def _restore_observer_states(self, states: list[dict[str, Any]]) -> None:
        self._iso.main_filter.set_state(states[0])
        for b, s in zip(self._iso.bank, states[1:], strict=True):
            b.observer.set_state(s)

    @property
    def last_output(self) -> DFChannelOutput:
        """Outputs of the most recent update (the initial outputs before any)."""
        return self._last

    @property
    def thresholds(self) -> list[NDArray[np.float64]] | None:
        """Thresholds in use: main filter first, then observer j; None while calibrating."""
        if self._installed is None:
            return None
        return [t.copy() for t in self._installed["threshold"]]

    def get_state(self) -> dict[str, Any]:
        """Full internal state (observers, thresholds, decisions, calibration data)."""
        return {
            "iso": self._iso.get_state(),
            "observers": self._observer_states(),
            "n_samples": self._n_samples,
            "calibrated": self._calibrated,
            "installed": self._installed,
            "cal_res": [np.array(r).reshape(-1, self._res_width(j))
                        for j, r in enumerate(self._cal_res)],
            "last": {
                "valid": self._last.valid, "calibrating": self._last.calibrating,
                "residual": self._last.residual.copy(), "alarms": self._last.alarms.copy(),
                "detected": self._last.detected, "isolated": self._last.isolated_sensor,
                "fault_type": self._last.fault_type, "magnitude": self._last.magnitude,
            },
        }

    def _res_width(self, j: int) -> int:
        return self.m if j == 0 else self.m - 1

    def set_state(self, state: dict[str, Any]) -> None:
        """Restore a state produced by :meth:`get_state` of an identically configured
        channel."""
        inst = state["installed"]
        if inst is not None:
            thresholds = [
                ResidualThresholds(mean=mu, std=sd, threshold=th, k_sigma=inst["k_sigma"])
                for mu, sd, th in zip(inst["mean"], inst["std"], inst["threshold"], strict=True)
            ]
            self._install(thresholds, inst["noise_std"])
        self._iso.set_state(state["iso"])
        self._restore_observer_states(state["observers"])
        self._n_samples = int(state["n_samples"])
        self._calibrated = bool(state["calibrated"])
        self._cal_res = [list(np.asarray(r, dtype=float)) for r in state["cal_res"]]
        last = state["last"]
        self._last = DFChannelOutput(
            bool(last["valid"]), bool(last["calibrating"]),
            np.asarray(last["residual"], dtype=float).copy(),
            np.asarray(last["alarms"], dtype=bool).copy(), bool(last["detected"]),
            int(last["isolated"]), int(last["fault_type"]), float(last["magnitude"]),
        )


def _thresholds(threshold: NDArray[np.float64], k_sigma: float) -> ResidualThresholds:
    thr = np.asarray(threshold, dtype=float)
    return ResidualThresholds(
        mean=np.zeros_like(thr), std=thr / k_sigma, threshold=thr, k_sigma=k_sigma
    )
