"""The detection-filter diagnosis channel: design, calibration, alignment, decisions.

One object per monitored linear plant, fed one sample of (u, y) per sample period. It
designs the Beard–Jones gain from (A, C, eigenvalues) with fault directions F = I and
decides in one of two ways:

``decision="sequential"`` (default)
    :class:`~gyrodiag.df.sequential_diagnosis.SequentialDiagnoser`: whitened residuals,
    CUSUM tests with thresholds for a stated false-alarm rate, isolation of one or two
    faulty sensors by hypothesis observers, fault typing by a likelihood ratio on the
    residual, episodes that end when the fault does.
``decision="paper"``
    The paper's rule: per-sample k·σ thresholds with k-of-n persistence on the
    detection filter's residual, isolation by the generalised observer scheme,
    detection latched (:class:`~gyrodiag.df.isolation.SensorFaultIsolator`).

Calibration and alignment
-------------------------
The first ``calibrate_s`` seconds are assumed fault-free and only stored. When they end,
the channel (1) chooses the *alignment* of inputs and measurements, (2) estimates the
sensor noise and (3) sets its thresholds, all from the stored window, then goes on with
the filters in the state they reach at the end of it.

The filter pairs the measurement y_k with the input u_k that drives the plant from that
sample on. A co-simulation master delivers them as the coupling order makes them: with
Gauss-Seidel and the Diagnoser after the plant they arrive together; with Jacobi
coupling (libcosim's default) every FMU boundary adds a step, so y arrives one or more
steps after its u. ``input_delay_samples`` d pairs y_k with u_{k−d} (d < 0: with a later
input, i.e. y is held back |d| samples and the outputs describe the sample |d| steps
before the current one). With ``align_auto`` the channel tries every d in
[−align_max, align_max] on the stored window and keeps the one whose residual has the
least variance (summed log variance over the sensors): a wrong pairing adds the input's
step-to-step change, through the input matrix, to the residual, so the right one is the
whitest. It looks at the data only, not at the master: any host works. If the inputs did
not move in the window, every d scores the same; the configured d is kept then.

Noise: ``noise_std`` if given, else the sensor variances that explain the residual
variances of the window (:func:`~gyrodiag.df.residual.estimate_sensor_variances`).
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..common._records import fast_init
from ..common._validation import (
    check_finite_array,
    check_in_range,
    check_int,
    check_nonnegative,
    check_positive,
)
from ..common.state import migrate, stamp
from .filter import DetectionFilter, ResidualThresholds, design_detection_filter
from .generators import _gust_disturbance
from .gust import GustModel
from .isolation import ENERGY_MIN_SAMPLES, FaultType, SensorFaultIsolator
from .plant import seed_aircraft
from .residual import ResidualModel, estimate_sensor_variances
from .sensor_dynamics import SensorDynamics, SensorDynamicsEqualiser
from .sequential_diagnosis import FaultKind, SequentialDiagnoser, SequentialSettings

__all__ = ["DECISIONS", "DECISION_AUTO", "DFChannel", "DFChannelConfig", "DFChannelOutput",
           "decision_rule"]

#: Decision rules, by FMU code (``df.decision``).
DECISIONS = ("paper", "sequential")
#: FMU code of the automatic choice (the Diagnoser's default ``df.decision``).
DECISION_AUTO = 2
#: Fewest calibration samples after the burn-in (the window is lengthened to leave them).
CAL_MIN_SAMPLES = 10


def decision_rule(code: int, has_sensor_dynamics: bool) -> str:
    """The rule that FMU code ``code`` selects: 0 paper, 1 sequential, 2 (auto) the
    sequential rule unless a read-out model is given: with one the sequential rule's
    whitening sees coloured noise and does not isolate (measured, docs/notes.md
    System), the paper's does."""
    if code == DECISION_AUTO:
        return "paper" if has_sensor_dynamics else "sequential"
    if code not in (0, 1):
        raise ValueError(f"decision code must be 0 (paper), 1 (sequential) or "
                         f"{DECISION_AUTO} (auto), got {code}")
    return DECISIONS[code]
#: ``isolated_sensor`` values besides a sensor number (1-based).
NONE_DETECTED, NOT_ISOLATED, MULTIPLE = 0, -1, -2


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
    decision : {"sequential", "paper"}
        Decision rule (module notes).
    calibrate_s : float
        Length of the initial fault-free window, s. 0: no window; then the paper rule
        needs ``main_thresholds``/``bank_thresholds`` and the sequential rule
        ``noise_std``, and the alignment is ``input_delay_samples``.
        A window that leaves fewer than ``CAL_MIN_SAMPLES`` samples after the burn-in
        is lengthened to leave that many (slow sample rates).
    burn_in_s : float
        Start of the window ignored while the observers converge, s.
    k_sigma : float
        Paper rule: thresholds at k standard deviations of the window's residuals.
    main_thresholds, bank_thresholds : array_like, optional
        Paper rule with ``calibrate_s`` = 0: main-filter thresholds (m,) and row j the
        thresholds of observer j (m × (m − 1)), sensor units.
    noise_std : array_like, shape (m,), optional
        Sensor noise standard deviations, sensor units. Paper rule: for the
        stuck/failure tests (default thresholds / k_sigma). Sequential rule: the noise
        model (default estimated from the window).
    persistence_k, persistence_n : int
        Paper rule: k-of-n persistence of every residual alarm.
    confirm_samples : int
        Paper rule: consecutive samples of one isolation pattern before it is latched.
    isolation_window_s : float
        Paper rule: when the alarm pattern does not isolate, isolate by the bank's
        residual energy within this time after detection, s (0: off, the pattern
        alone as the paper's filter; :class:`~gyrodiag.df.isolation.SensorFaultIsolator`
        ``energy_window_s``). A window shorter than ``ENERGY_MIN_SAMPLES`` samples, which
        never isolates, is lengthened to that (:attr:`isolation_window_in_use`).
    isolation_baseline_s : float
        Paper rule: time constant of the bank's fault-free energy baseline, s; the
        energy test measures against the larger of the calibration and the last
        ~``isolation_baseline_s`` before detection, so turbulence stronger than in the
        calibration window does not make it isolate the least gust-sensitive observer's
        sensor (0: off, against the calibration alone; ``energy_baseline_s`` of
        :class:`~gyrodiag.df.isolation.SensorFaultIsolator`).
    false_alarms_per_h : float
        Sequential rule: design false-alarm rate of the detection, 1/h.
    cusum_k : float
        Sequential rule: CUSUM reference, σ of the whitened residual.
    variance_ratio : float
        Sequential rule: variance increase the variance CUSUMs are designed for.
    max_faults : int
        Sequential rule: 1 or 2 simultaneously faulty sensors to isolate.
    history_s, memory_s : float
        Sequential rule: samples kept to start isolation before the change, s; how long
        after the last episode the isolation keeps running, s.
    input_delay_samples : int
        Alignment d (module notes), used as is unless ``align_auto``.
    align_auto : bool
        Choose the alignment on the calibration window; not with ``sensor_dynamics``,
        whose read-out model sets the timing (a search there picks a pairing that fits
        the calibration manoeuvre and false-alarms in the next; :attr:`aligns`).
    align_max : int
        Largest |d| tried.
    x0 : array_like, shape (n,), optional
        Initial state estimate of every observer (default zeros).
    sensor_dynamics : SensorDynamics, optional
        Read-out dynamics G(z) of one sensor (e.g. the DTG's rebalance loop on q), at
        ``sample_period_s``: every input and every other sensor are passed through the
        same G before the filter (matched filtering, :mod:`gyrodiag.df.sensor_dynamics`,
        docs/readout_dynamics.md), so that a manoeuvre seen through the sensor's lag is
        not a fault of it. None (default): every sensor is y = Cx.
    sensor_delay_samples : sequence of m ints ≥ 0, optional
        Sensor j's sample arrives this many samples after the others' of the same
        instant (a master that routes it through one FMU more, e.g. the DTG read-out
        under Jacobi coupling: 1). Every other channel, inputs included, is held back to
        match, before anything else (so the outputs describe the sample max(e) earlier).
        None (default): all zeros. The harness sets it from its coupling plan
        (:mod:`harness.cosim.timing`).
    gust : GustModel or None
        Sequential rule: turbulence its residual model includes (the whitened residual
        is then the innovation of the plant augmented with the Dryden filter, white in
        turbulence of the design intensity, and smaller in calmer air). Default: severe
        turbulence (σ_w 2.3 m/s) through the seed aircraft's gust input, as the FMU;
        a plant of another state layout gives ``input_matrix`` or None (sensor noise
        only).
    """

    A: ArrayLike = field(default_factory=_seed_a)
    B: ArrayLike = field(default_factory=_seed_b)
    C: ArrayLike = field(default_factory=_seed_c)
    eigenvalues: ArrayLike | None = None
    sample_period_s: float = 0.01
    decision: str = "sequential"
    calibrate_s: float = 10.0
    burn_in_s: float = 2.0
    k_sigma: float = 6.0
    main_thresholds: ArrayLike | None = None
    bank_thresholds: ArrayLike | None = None
    noise_std: ArrayLike | None = None
    persistence_k: int = 3
    persistence_n: int = 5
    confirm_samples: int = 5
    isolation_window_s: float = 4.0
    isolation_baseline_s: float = 10.0
    false_alarms_per_h: float = 1e-3
    cusum_k: float = 0.5
    variance_ratio: float = 4.0
    max_faults: int = 2
    history_s: float = 4.0
    memory_s: float = 10.0
    input_delay_samples: int = 0
    align_auto: bool = True
    align_max: int = 2
    x0: ArrayLike | None = None
    sensor_dynamics: SensorDynamics | None = None
    sensor_delay_samples: Sequence[int] | None = None
    gust: GustModel | None = field(default_factory=GustModel)

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

    @property
    def aligns(self) -> bool:
        """The alignment is searched on the calibration window (``align_auto`` without
        a read-out model)."""
        return self.align_auto and self.sensor_dynamics is None

    @property
    def isolation_window_in_use(self) -> float:
        """``isolation_window_s``, lengthened to ``ENERGY_MIN_SAMPLES`` samples if
        shorter (0 stays off), s."""
        window = self.isolation_window_s
        if window <= 0.0:
            return 0.0
        return max(window, ENERGY_MIN_SAMPLES * self.sample_period_s)

    def settings(self) -> SequentialSettings:
        """The sequential rule's settings."""
        return SequentialSettings(
            false_alarms_per_h=self.false_alarms_per_h, cusum_k=self.cusum_k,
            variance_ratio=self.variance_ratio, max_faults=self.max_faults,
            history_s=self.history_s, memory_s=self.memory_s,
        )

    def _check_given_noise(self, m: int) -> None:
        """Without a calibration window: the paper rule's thresholds, or the noise."""
        if self.decision == "paper":
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
        elif self.noise_std is None:
            raise ValueError("noise_std is required by the sequential decision when "
                             "calibrate_s = 0 (no window to estimate the noise from)")

    def validate(self) -> None:
        """Raise ValueError/TypeError naming the first invalid setting."""
        _, _, C, _, _ = self.matrices()
        m = C.shape[0]
        period = check_positive("sample_period_s", self.sample_period_s)
        if self.decision not in DECISIONS:
            raise ValueError(f"decision must be one of {DECISIONS}, got {self.decision!r}")
        calibrate = check_nonnegative("calibrate_s", self.calibrate_s)
        check_nonnegative("burn_in_s", self.burn_in_s)
        check_positive("k_sigma", self.k_sigma)
        if self.noise_std is not None:
            std = check_finite_array("noise_std", self.noise_std, shape=(m,))
            if np.any(std <= 0):
                raise ValueError("noise_std must be > 0 on every sensor")
        if calibrate == 0.0:  # no window: thresholds or noise must be given
            self._check_given_noise(m)
        pk = check_int("persistence_k", self.persistence_k, minimum=1)
        pn = check_int("persistence_n", self.persistence_n, minimum=1)
        if pk > pn:
            raise ValueError(f"persistence_k must be <= persistence_n ({pn}), got {pk}")
        check_int("confirm_samples", self.confirm_samples, minimum=1)
        check_in_range("isolation_window_s", self.isolation_window_s, 0.0, 3600.0)
        check_in_range("isolation_baseline_s", self.isolation_baseline_s, 0.0, 3600.0)
        self.settings().validate()
        limit = check_int("align_max", self.align_max, minimum=0)
        if limit > 50:
            raise ValueError(f"align_max must be <= 50, got {limit}")
        d = self.input_delay_samples
        if isinstance(d, bool) or not isinstance(d, (int, np.integer)):
            raise TypeError(f"input_delay_samples must be an integer, got {d!r}")
        check_in_range("input_delay_samples", float(d), -50.0, 50.0)
        if self.sensor_delay_samples is not None:
            skew = self.sensor_delay_samples
            if len(skew) != m:
                raise ValueError(f"sensor_delay_samples must have {m} entries (one per "
                                 f"sensor), got {len(skew)}")
            for i, e in enumerate(skew):
                if check_int(f"sensor_delay_samples[{i}]", e) > 50:
                    raise ValueError(f"sensor_delay_samples[{i}] must be <= 50, got {e!r}")
        if self.sensor_dynamics is not None:
            g = self.sensor_dynamics
            if not isinstance(g, SensorDynamics):
                raise TypeError("sensor_dynamics must be a SensorDynamics, got "
                                f"{type(g).__name__}")
            if abs(g.sample_period_s - period) > 1e-9 * period:
                raise ValueError(f"sensor_dynamics is given at {g.sample_period_s!r} s, the "
                                 f"filter samples at sample_period_s = {period!r} s")
            if g.sensor >= m:
                raise ValueError(f"sensor_dynamics: sensor {g.sensor + 1} (1-based) exceeds "
                                 f"the {m} sensors of C")
        if self.gust is not None:
            if not isinstance(self.gust, GustModel):
                raise TypeError(f"gust must be a GustModel or None, got "
                                f"{type(self.gust).__name__}")
            A, _, _, _, _ = self.matrices()
            if self.gust.input_matrix is None and A.shape != (5, 5):
                raise ValueError("gust: the seed gust input needs the seed aircraft's "
                                 "5 states [v, alpha, q, theta, h]; give "
                                 "GustModel(input_matrix=...) or gust=None")
            self.gust.input_for(A)
        if self.aligns and calibrate == 0.0:
            raise ValueError("align_auto needs a calibration window (calibrate_s > 0); "
                             "set input_delay_samples and align_auto = False")


@fast_init
@dataclass(frozen=True)
class DFChannelOutput:
    """Outputs of one :meth:`DFChannel.update`.

    Attributes
    ----------
    valid : bool
        False when u or y had NaN/Inf; the sample was skipped, state untouched.
    calibrating : bool
        The calibration window is still being recorded; no decision yet.
    residual : ndarray, shape (m,)
        Main detection-filter residual γ = y − C x̂ (sensor units).
    alarms : ndarray of bool, shape (m,)
        Per-sensor alarm of the main residual (paper: k-of-n threshold test;
        sequential: CUSUM).
    statistic : ndarray, shape (m,)
        Per sensor, the alarm statistic in units of its threshold (alarm at 1).
    detected : bool
        Paper: a fault was detected (latched). Sequential: a fault episode is on.
    episodes : int
        Fault episodes since reset.
    isolated_sensor : int
        1-based sensor of the diagnosis; 0 nothing detected; −1 detected, not
        isolated; −2 several sensors (see ``isolated_mask``; 0 there when they could
        not be told apart).
    isolated_mask : int
        Bit i−1 set for every isolated sensor i.
    fault_type : int
        Type of the isolated sensor's fault (:class:`FaultKind` code; for two sensors
        their common type, else −1).
    magnitude : float
        Its size (bias, gain factor, stuck value, 0 for failure, ramp rate per s, noise
        std ratio); 0 when ``magnitude_valid`` is False.
    magnitude_valid : bool
    sensor_fault_type : ndarray of int, shape (m,)
        Type per sensor (0 where none).
    sensor_magnitude : ndarray, shape (m,)
        Size per sensor (0 where none or unknown).
    input_delay : int
        Alignment in use (module notes).
    """

    valid: bool
    calibrating: bool
    residual: NDArray[np.float64]
    alarms: NDArray[np.bool_]
    statistic: NDArray[np.float64]
    detected: bool
    episodes: int
    isolated_sensor: int
    isolated_mask: int
    fault_type: int
    magnitude: float
    magnitude_valid: bool
    sensor_fault_type: NDArray[np.int_]
    sensor_magnitude: NDArray[np.float64]
    input_delay: int

    @property
    def alarm(self) -> bool:
        """Detected fault (the channel's alarm)."""
        return self.detected


class DFChannel:
    """Streaming detection-filter diagnoser (module notes).

    Parameters
    ----------
    config : DFChannelConfig
        Settings; validated here (ValueError naming the setting, or the failed design
        condition of :func:`~gyrodiag.df.filter.design_detection_filter`).
    """

    def __init__(self, config: DFChannelConfig) -> None:
        config.validate()
        self.config = config
        A, B, C, eig, x0 = config.matrices()
        self.A, self.B, self.C = A, B, C
        self.n, self.p, self.m = A.shape[0], B.shape[1], C.shape[0]
        self.K = design_detection_filter(A, C, np.eye(self.n), eig)
        self.T = float(config.sample_period_s)
        self._x0 = x0
        self._n_burn = round(config.burn_in_s / self.T)
        self._n_cal = (0 if config.calibrate_s == 0.0 else
                       max(round(config.calibrate_s / self.T), self._n_burn + CAL_MIN_SAMPLES))
        self._monitor = DetectionFilter(A, B, C, self.K, self.T)
        self._equaliser = (None if config.sensor_dynamics is None else
                           SensorDynamicsEqualiser(config.sensor_dynamics, self.p, self.m))
        # sensor skew: where each channel is read in the line, u first (module notes)
        skew = (np.zeros(self.m, dtype=int) if config.sensor_delay_samples is None
                else np.array([int(e) for e in config.sensor_delay_samples]))
        self._skew_max = int(skew.max()) if skew.size else 0
        self._skew = skew
        self.reset()

    # ------------------------------------------------------------------ set-up

    def reset(self) -> None:
        """Return to the state right after construction."""
        c = self.config
        m, p = self.m, self.p
        self._n_samples = 0
        self._delay = int(c.input_delay_samples)
        self._u_line: list[NDArray[np.float64]] = []
        self._y_line: list[NDArray[np.float64]] = []
        self._cal_u = np.zeros((self._n_cal, p))
        self._cal_y = np.zeros((self._n_cal, m))
        self._skew_line: deque[tuple[NDArray[np.float64], NDArray[np.float64]]] = deque(
            maxlen=self._skew_max + 1)
        self._engine: SensorFaultIsolator | SequentialDiagnoser | None = None
        self._thresholds: list[NDArray[np.float64]] | None = None
        self._noise_std: NDArray[np.float64] | None = None
        self._gust_note = ""
        self._monitor.reset(self._x0)
        if self._equaliser is not None:
            self._equaliser.reset()
        self._calibrated = False
        self._last = self._initial_output()
        if self._n_cal == 0:
            self._install(None, None)

    def _initial_output(self) -> DFChannelOutput:
        m = self.m
        return DFChannelOutput(
            True, self._n_cal > 0, np.zeros(m), np.zeros(m, dtype=bool), np.zeros(m),
            False, 0, NONE_DETECTED, 0, int(FaultType.NONE), 0.0, False,
            np.zeros(m, dtype=int), np.zeros(m), self._delay,
        )

    @property
    def last_output(self) -> DFChannelOutput:
        """Outputs of the most recent update (the initial outputs before any)."""
        return self._last

    @property
    def input_delay(self) -> int:
        """Alignment in use (chosen when the calibration window ends)."""
        return self._delay

    @property
    def thresholds(self) -> list[NDArray[np.float64]] | None:
        """Paper rule: residual thresholds, main filter first, then observer j. None
        while calibrating and with the sequential rule (see :attr:`cusum_thresholds`)."""
        if self._thresholds is None:
            return None
        return [t.copy() for t in self._thresholds]

    @property
    def cusum_thresholds(self) -> tuple[float, float] | None:
        """Sequential rule: (mean-CUSUM threshold σ, variance-CUSUM threshold)."""
        if isinstance(self._engine, SequentialDiagnoser):
            return self._engine.thresholds
        return None

    @property
    def noise_std(self) -> NDArray[np.float64] | None:
        """Sensor noise standard deviations in use (sensor units), once calibrated."""
        return None if self._noise_std is None else self._noise_std.copy()

    @property
    def gust_note(self) -> str:
        """Why the gust model is not in use after calibration ("" when it is, or when
        none is configured)."""
        return self._gust_note

    @property
    def gust_in_use(self) -> bool:
        """The sequential engine models the turbulence."""
        return isinstance(self._engine, SequentialDiagnoser) and self._engine.gust is not None

    @property
    def engine(self) -> SensorFaultIsolator | SequentialDiagnoser | None:
        """The decision object (None while calibrating)."""
        return self._engine

    # ------------------------------------------------------------------ streaming

    def update(self, u: ArrayLike, y: ArrayLike) -> DFChannelOutput:
        """Process one sample of inputs ``u`` (p,) and measurements ``y`` (m,).

        Shapes are checked (ValueError); a non-finite value skips the sample, leaves the
        state untouched and clears ``valid``.
        """
        uu = np.asarray(u, dtype=float).reshape(-1)
        yy = np.asarray(y, dtype=float).reshape(-1)
        if uu.shape != (self.p,):
            raise ValueError(f"u must have shape ({self.p},), got {uu.shape}")
        if yy.shape != (self.m,):
            raise ValueError(f"y must have shape ({self.m},), got {yy.shape}")
        if not (math.isfinite(float(uu.sum())) and math.isfinite(float(yy.sum()))):
            if not (np.all(np.isfinite(uu)) and np.all(np.isfinite(yy))):
                self._last = _invalid(self._last)
                return self._last
        if self._skew_max:
            line = self._skew_line
            line.append((uu, yy))
            if len(line) <= self._skew_max:
                return self._last
            # u and the on-time sensors from max(e) samples back, sensor j from e_j
            uu = line[0][0]
            yy = np.array([line[e][1][i] for i, e in enumerate(self._skew)])
        if self._equaliser is not None:
            uu, yy = self._equaliser.update(uu, yy, validate=False)
        k = self._n_samples
        self._n_samples = k + 1
        if not self._calibrated:
            self._cal_u[k], self._cal_y[k] = uu, yy
            res = self._monitor_step(uu, yy)
            if self._n_samples >= self._n_cal:
                self._finish_calibration()
            self._last = DFChannelOutput(
                True, not self._calibrated, res, np.zeros(self.m, dtype=bool),
                np.zeros(self.m), False, 0, NONE_DETECTED, 0, int(FaultType.NONE), 0.0,
                False, np.zeros(self.m, dtype=int), np.zeros(self.m), self._delay,
            )
            return self._last
        pair = self._aligned(uu, yy)
        if pair is None:
            return self._last
        self._last = self._decide(*pair)
        return self._last

    def update_floats(self, u: Sequence[float], y: Sequence[float]) -> DFChannelOutput:
        """:meth:`update` for a host that holds the sample as plain floats (``p`` and
        ``m`` of them; the lengths are the caller's to get right): the same outputs and
        state change, without the array conversions on the per-sample path of the
        calibrated sequential decision."""
        total = sum(u) + sum(y)
        if not (total - total == 0.0 and self._calibrated and self._delay == 0
                and self._equaliser is None and not self._skew_max
                and isinstance(self._engine, SequentialDiagnoser)):
            return self.update(u, y)  # NaN/inf, calibration, a delay line, the paper rule
        self._n_samples += 1
        self._last = self._decide_sequential(self._engine, np.array((*u, *y)))
        return self._last

    def _monitor_step(self, u: NDArray[np.float64], y: NDArray[np.float64]
                      ) -> NDArray[np.float64]:
        """Residual shown while the window is recorded (configured alignment)."""
        pair = self._aligned(u, y)
        if pair is None:
            return np.zeros(self.m)
        return self._monitor.update(*pair)

    def _aligned(self, u: NDArray[np.float64], y: NDArray[np.float64]
                 ) -> tuple[NDArray[np.float64], NDArray[np.float64]] | None:
        """Apply the alignment: None while the delay line fills."""
        d = self._delay
        if d == 0:
            return u, y
        if d > 0:
            self._u_line.append(u)
            if len(self._u_line) <= d:
                return None
            return self._u_line.pop(0), y
        self._y_line.append(y)
        if len(self._y_line) <= -d:
            return None
        return u, self._y_line.pop(0)

    def _decide_sequential(self, engine: SequentialDiagnoser,
                           w: NDArray[np.float64]) -> DFChannelOutput:
        out = engine.update(w)
        if out.status == "none":  # the per-sample case, without the lookups below
            return DFChannelOutput(
                True, False, out.residual, out.alarms, out.statistic, out.detected,
                out.episodes, NONE_DETECTED, 0, 0, 0.0, False, out.fault_type,
                out.magnitude, self._delay,
            )
        if out.status == "single":
            iso = out.isolated[0] + 1
        else:
            iso = {"none": NONE_DETECTED, "not isolated": NOT_ISOLATED,
                   "pair": MULTIPLE, "multiple": MULTIPLE}[out.status]
        mask = sum(1 << i for i in out.isolated)
        types = out.fault_type
        if out.isolated:
            kinds = {int(types[i]) for i in out.isolated}
            ftype = kinds.pop() if len(kinds) == 1 else int(FaultKind.UNKNOWN)
        else:
            ftype = int(FaultKind.UNKNOWN) if out.status != "none" else 0
        valid = len(out.isolated) == 1 and bool(out.magnitude_valid[out.isolated[0]])
        mag = float(out.magnitude[out.isolated[0]]) if valid else 0.0
        return DFChannelOutput(
            True, False, out.residual, out.alarms, out.statistic, out.detected,
            out.episodes, iso, mask, ftype, mag, valid, types, out.magnitude,
            self._delay,
        )

    def _decide(self, u: NDArray[np.float64], y: NDArray[np.float64]) -> DFChannelOutput:
        engine = self._engine
        m = self.m
        if isinstance(engine, SequentialDiagnoser):
            return self._decide_sequential(engine, np.concatenate((u, y)))
        assert isinstance(engine, SensorFaultIsolator)
        res = engine.advance(u, y)  # the channel checked the sample
        residual = engine.main_filter.residual
        if res.isolated >= 0:
            iso = res.isolated + 1
        else:
            iso = NOT_ISOLATED if res.detected else NONE_DETECTED
        mask = (1 << res.isolated) if res.isolated >= 0 else 0
        sensor_types = np.zeros(m, dtype=int)
        sensor_mags = np.zeros(m)
        valid = bool(math.isfinite(res.magnitude)) and res.isolated >= 0
        if res.isolated >= 0:
            sensor_types[res.isolated] = int(res.fault_type)
            sensor_mags[res.isolated] = res.magnitude if valid else 0.0
        return DFChannelOutput(
            True, False, residual, res.main_alarms, np.abs(res.main_normalised),
            res.detected, int(res.detected), iso, mask, int(res.fault_type),
            float(res.magnitude) if valid else 0.0, valid, sensor_types, sensor_mags,
            self._delay,
        )

    # ------------------------------------------------------------------ calibration

    def _pairs(self, d: int) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Aligned (u, y) rows of the stored window for alignment d."""
        u, y = self._cal_u, self._cal_y
        if d > 0:
            return u[:-d], y[d:]
        if d < 0:
            return u[-d:], y[:d]
        return u, y

    def _residuals(self, u: NDArray[np.float64], y: NDArray[np.float64],
                   x_start: NDArray[np.float64] | None = None) -> NDArray[np.float64]:
        f = DetectionFilter(self.A, self.B, self.C, self.K, self.T)
        f.reset(self._x0 if x_start is None else x_start)
        return np.array([f.advance(u[j], y[j]) for j in range(u.shape[0])])

    def _initial_state(self, u: NDArray[np.float64], y: NDArray[np.float64]
                       ) -> NDArray[np.float64]:
        """The state at the window's first sample that best explains it.

        A host seldom starts the plant and the Diagnoser on the same sample from the
        same state (with Gauss-Seidel the plant has already moved one step, at the
        elevator's first value, when the Diagnoser sees its first sample: 0.26 rad/s of
        q error on the seed loop); the observers' transient (slowest pole 1/s, and the
        whitening filters' 10 s) would count as noise. The residual is linear in the
        initial error: γ_k = γ_k(x0) − C Fᵏ Δx0; Δx0 by weighted least squares over the
        window (weights: each channel's residual spread after the burn-in)."""
        res = self._residuals(u, y)
        f = self._monitor
        closed = f.closed_loop_matrix
        n_rows = res.shape[0]
        weight = 1.0 / np.maximum(res[self._n_burn:].std(axis=0), 1e-300)
        blocks = np.empty((n_rows, self.m, self.n))
        power = np.eye(self.n)
        for k in range(n_rows):
            blocks[k] = self.C @ power
            power = closed @ power
        lhs = (blocks * weight[None, :, None]).reshape(-1, self.n)
        rhs = (res * weight[None, :]).reshape(-1)
        delta = np.linalg.lstsq(lhs, rhs, rcond=None)[0]
        return self._x0 + delta

    def _choose_alignment(self) -> int:
        c = self.config
        if not c.aligns:
            return int(c.input_delay_samples)
        scores = {}
        # every pairing scored alike: by the gust model's innovations when each window
        # is long enough to fit a noise model to, else by the residual variance
        by_model = (c.gust is not None and
                    self._n_cal - self._n_burn - int(c.align_max) >= 4 * CAL_MIN_SAMPLES)
        for d in range(-int(c.align_max), int(c.align_max) + 1):
            u, y = self._pairs(d)
            burn = min(self._n_burn, max(u.shape[0] - 10, 0))
            res = self._residuals(u, y)[burn:]
            if by_model:
                scores[d] = self._innovation_score(res)
                continue
            var = res.var(axis=0, ddof=1)
            scores[d] = float(np.sum(np.log(np.maximum(var, 1e-300))))
        best = min(scores.values())
        configured = int(c.input_delay_samples)
        # equal within rounding: the inputs did not move; keep the configured pairing
        if configured in scores and scores[configured] - best <= 1e-9 * max(1.0, abs(best)):
            return configured
        return min(scores, key=scores.__getitem__)

    def _variances(self, u: NDArray[np.float64] | None, y: NDArray[np.float64] | None,
                   x_start: NDArray[np.float64], burn: int, gust: GustModel | None
                   ) -> NDArray[np.float64]:
        """Sensor noise variances: given, or those that explain the window's residuals
        (with the gust model ``gust`` if any)."""
        c = self.config
        if c.noise_std is not None:
            return np.asarray(c.noise_std, dtype=float) ** 2
        assert u is not None and y is not None
        f = DetectionFilter(self.A, self.B, self.C, self.K, self.T)
        model = ResidualModel(f.closed_loop_matrix, f.discrete_gain, self.C,
                              _gust_disturbance(gust, self.A, self.T, np.eye(self.n)))
        variances = estimate_sensor_variances(self._residuals(u, y, x_start)[burn:], model)
        # A noise-free sensor would make rounding look like faults: floor at 1e−7 of the
        # signal's RMS (plus 1e−12 absolute).
        rms = np.sqrt(np.mean(y**2, axis=0))
        return np.maximum(variances, (1e-7 * rms + 1e-12) ** 2)

    def _innovation_score(self, res: NDArray[np.float64]) -> float:
        """−2 log-likelihood per sample of residuals ``res`` under the gust model.

        In turbulence the raw residual's variance is mostly the gust's, and the pitch
        controller answers the gust, so a wrong pairing can look smaller there; the
        innovations of the model with the gust leave only what it cannot explain."""
        c = self.config
        var = res.var(axis=0, ddof=1)
        plain = float(np.sum(np.log(np.maximum(var, 1e-300))))
        model = ResidualModel(self._monitor.closed_loop_matrix, self._monitor.discrete_gain,
                              self.C, _gust_disturbance(c.gust, self.A, self.T, np.eye(self.n)))
        variances = estimate_sensor_variances(res, model)
        rms = np.sqrt(np.mean(res**2, axis=0))
        variances = np.maximum(variances, (1e-3 * rms + 1e-12) ** 2)
        try:
            w = model.whitening(variances)
        except (ValueError, np.linalg.LinAlgError):
            return plain
        s_inv = np.linalg.inv(w.S)
        closed, gain = w.F - w.K @ w.C, w.K
        e = np.zeros(w.F.shape[0])
        total = 0.0
        for r in res:
            eps = r - w.C @ e
            total += float(eps @ s_inv @ eps)
            e = closed @ e + gain @ r
        return total / res.shape[0] + float(np.linalg.slogdet(w.S)[1])

    def _finish_calibration(self) -> None:
        self._delay = self._choose_alignment()
        u, y = self._pairs(self._delay)
        burn = min(self._n_burn, max(u.shape[0] - 10, 0))
        self._install(u, y, burn)
        # the delay line continues from the end of the window
        d = self._delay
        self._u_line = [row for row in self._cal_u[self._n_cal - d:]] if d > 0 else []
        self._y_line = [row for row in self._cal_y[self._n_cal + d:]] if d < 0 else []
        self._cal_u = np.zeros((0, self.p))
        self._cal_y = np.zeros((0, self.m))
        self._calibrated = True

    def _install(self, u: NDArray[np.float64] | None, y: NDArray[np.float64] | None,
                 burn: int = 0) -> None:
        """Build the decision engine from the aligned window (or from the given
        thresholds / noise when there is no window)."""
        c = self.config
        if c.decision == "paper":
            iso = self._paper_isolator()
            if u is None or y is None:
                k = float(c.k_sigma)
                main = np.asarray(c.main_thresholds, dtype=float)
                bank = np.asarray(c.bank_thresholds, dtype=float)
                std = main / k if c.noise_std is None else np.asarray(c.noise_std, float)
                thresholds = [_thresholds(main, k)] + [_thresholds(row, k) for row in bank]
                iso.set_thresholds(thresholds[0], thresholds[1:], std)
                iso.reset(self._x0)
                self._noise_std = std
            else:
                # The same computation the streaming filters would do: run them over the
                # window, thresholds from the residuals after the burn-in, then go on.
                iso.calibrate(u, y, k_sigma=c.k_sigma, burn_in=burn, x0=self._x0,
                              continue_after=True)
                self._noise_std = iso.noise_std
            self._thresholds = [iso.main_thresholds.threshold] + [
                t.threshold for t in iso.bank_thresholds]
            self._engine = iso
            self._calibrated = True
            return
        x_start = self._x0 if u is None or y is None else self._initial_state(u, y)
        variances = self._variances(u, y, x_start, burn, c.gust)
        self._noise_std = np.sqrt(variances)
        try:
            engine = SequentialDiagnoser(self.A, self.B, self.C, self.K, self.T,
                                         variances, c.settings(), x0=self._x0, gust=c.gust)
            self._gust_note = ""
        except (ValueError, np.linalg.LinAlgError) as exc:
            if c.gust is None:
                raise
            # a gust far above the noise (a noise-free window, very slow sampling)
            # leaves no stable whitening: monitor without the turbulence model, with the
            # noise as that model explains the window
            variances = self._variances(u, y, x_start, burn, None)
            self._noise_std = np.sqrt(variances)
            engine = SequentialDiagnoser(self.A, self.B, self.C, self.K, self.T,
                                         variances, c.settings(), x0=self._x0)
            self._gust_note = (f"gust model not used (its whitening filter failed: {exc}); "
                               "turbulence may raise alarms")
        if u is not None and y is not None:
            engine.calibrate_scales(np.hstack([u, y]), burn, x_start=x_start)
        self._engine = engine
        self._thresholds = None
        self._calibrated = True

    # ------------------------------------------------------------------ state

    def get_state(self) -> dict[str, Any]:
        """Full internal state (engine, alignment, window, outputs)."""
        engine = self._engine
        return stamp({
            "n_samples": self._n_samples,
            "calibrated": self._calibrated,
            "delay": self._delay,
            "u_line": np.array(self._u_line).reshape(-1, self.p),
            "y_line": np.array(self._y_line).reshape(-1, self.m),
            "cal_u": self._cal_u.copy(), "cal_y": self._cal_y.copy(),
            "monitor": self._monitor.get_state(),
            "noise_std": None if self._noise_std is None else self._noise_std.copy(),
            # the variances the engine was built from, exactly (σ² of a saved σ may
            # differ in the last bit, and so would every matrix designed from it)
            "gust_note": self._gust_note,
            "noise_var": (engine.sensor_variances.copy()
                          if isinstance(engine, SequentialDiagnoser) else None),
            "engine": None if engine is None else engine.get_state(),
            "thresholds": None if self._thresholds is None else [
                t.copy() for t in self._thresholds],
            # the paper rule's residual statistics (mean, std) beside the thresholds: the
            # evaluators normalise by the mean, the energy isolation by the std as well
            "threshold_stats": (
                [[t.mean.copy(), t.std.copy()] for t in
                 [engine.main_thresholds, *engine.bank_thresholds]]
                if isinstance(engine, SensorFaultIsolator) and self._thresholds is not None
                else None),
            "last": _output_state(self._last),
            "equaliser": None if self._equaliser is None else self._equaliser.get_state(),
            "skew_u": np.array([e[0] for e in self._skew_line]).reshape(-1, self.p),
            "skew_y": np.array([e[1] for e in self._skew_line]).reshape(-1, self.m),
        }, STATE_VERSION)

    def set_state(self, state: dict[str, Any]) -> None:
        """Restore a state produced by :meth:`get_state` of an identically configured
        channel (the engine is rebuilt from the saved noise and thresholds)."""
        snapshot = self.get_state() if self._calibrated or self._n_samples else None
        try:
            self._apply_state(migrate(state, STATE_VERSION, _MIGRATIONS, "detection-filter "
                                      "channel"))
        except (KeyError, TypeError, ValueError) as exc:
            if snapshot is not None:
                self._apply_state(snapshot)
            else:
                self.reset()
            if isinstance(exc, KeyError):
                raise ValueError(f"state is missing key {exc}") from None
            raise

    def _apply_state(self, state: dict[str, Any]) -> None:
        c = self.config
        eq = state["equaliser"]
        if (eq is None) != (self._equaliser is None):
            raise ValueError("state['equaliser'] does not match sensor_dynamics (a state of "
                             "a channel with other read-out dynamics)")
        if self._equaliser is not None:
            self._equaliser.set_state(eq)
        calibrated = bool(state["calibrated"])
        delay = int(state["delay"])
        noise = state["noise_std"]
        if calibrated:
            self._delay = delay
            if c.decision == "paper":
                self._install(None, None) if self._n_cal == 0 else self._rebuild_paper(state)
            else:
                variances = np.asarray(state["noise_var"], dtype=float)
                self._gust_note = str(state.get("gust_note", ""))
                self._engine = SequentialDiagnoser(
                    self.A, self.B, self.C, self.K, self.T, variances, c.settings(),
                    x0=self._x0, gust=None if self._gust_note else c.gust)
                self._noise_std = np.asarray(noise, dtype=float).copy()
                self._thresholds = None
            assert self._engine is not None
            self._engine.set_state(state["engine"])
        else:
            self._engine, self._thresholds, self._noise_std = None, None, None
        self._calibrated = calibrated
        self._delay = delay
        self._n_samples = int(state["n_samples"])
        self._u_line = list(np.asarray(state["u_line"], dtype=float).reshape(-1, self.p))
        self._y_line = list(np.asarray(state["y_line"], dtype=float).reshape(-1, self.m))
        cal_u = np.asarray(state["cal_u"], dtype=float)
        cal_y = np.asarray(state["cal_y"], dtype=float)
        if not calibrated and (cal_u.shape != (self._n_cal, self.p)
                               or cal_y.shape != (self._n_cal, self.m)):
            raise ValueError("state['cal_u'] / state['cal_y'] do not fit the calibration "
                             "window of this channel")
        self._cal_u, self._cal_y = cal_u.copy(), cal_y.copy()
        self._monitor.set_state(state["monitor"])
        self._last = _output_from_state(state["last"])
        su = np.asarray(state["skew_u"], dtype=float)
        sy = np.asarray(state["skew_y"], dtype=float)
        if su.size == 0 and sy.size == 0:  # no skew line (also a version-0 state)
            su, sy = np.zeros((0, self.p)), np.zeros((0, self.m))
        if (su.ndim != 2 or su.shape[1:] != (self.p,) or sy.shape != (su.shape[0], self.m)
                or su.shape[0] > (self._skew_max + 1 if self._skew_max else 0)):
            raise ValueError("state['skew_u'] / state['skew_y'] do not fit this channel's "
                             "sensor_delay_samples")
        self._skew_line.clear()
        self._skew_line.extend((a.copy(), b.copy()) for a, b in zip(su, sy, strict=True))

    def _paper_isolator(self) -> SensorFaultIsolator:
        c = self.config
        return SensorFaultIsolator(
            self.A, self.B, self.C, self.K, self.T, persistence_k=c.persistence_k,
            persistence_n=c.persistence_n, confirm_samples=c.confirm_samples,
            energy_window_s=c.isolation_window_in_use,
            energy_baseline_s=c.isolation_baseline_s)

    def _rebuild_paper(self, state: dict[str, Any]) -> None:
        c = self.config
        thresholds = [np.asarray(t, dtype=float) for t in state["thresholds"]]
        noise = np.asarray(state["noise_std"], dtype=float)
        iso = self._paper_isolator()
        k = float(c.k_sigma)
        stats = state["threshold_stats"]
        if stats is None:  # none saved (state version 0): rebuilt from the thresholds
            rebuilt = [_thresholds(t, k) for t in thresholds]
        else:
            if len(stats) != len(thresholds):
                raise ValueError("state['threshold_stats'] must hold one (mean, std) per "
                                 "threshold vector")
            rebuilt = [ResidualThresholds(mean=np.asarray(ms[0], dtype=float),
                                          std=np.asarray(ms[1], dtype=float),
                                          threshold=t, k_sigma=k)
                       for ms, t in zip(stats, thresholds, strict=True)]
        iso.set_thresholds(rebuilt[0], rebuilt[1:], noise)
        self._engine, self._thresholds, self._noise_std = iso, thresholds, noise


def _thresholds(threshold: NDArray[np.float64], k_sigma: float) -> ResidualThresholds:
    thr = np.asarray(threshold, dtype=float)
    return ResidualThresholds(
        mean=np.zeros_like(thr), std=thr / k_sigma, threshold=thr, k_sigma=k_sigma
    )


def _invalid(last: DFChannelOutput) -> DFChannelOutput:
    d = dict(last.__dict__)
    d["valid"] = False
    return DFChannelOutput(**d)


def _output_state(out: DFChannelOutput) -> dict[str, Any]:
    return {k: (v.copy() if isinstance(v, np.ndarray) else v)
            for k, v in out.__dict__.items()}


def _output_from_state(state: dict[str, Any]) -> DFChannelOutput:
    d = dict(state)
    for key, dtype in (("residual", float), ("alarms", bool), ("statistic", float),
                       ("sensor_fault_type", int), ("sensor_magnitude", float)):
        d[key] = np.asarray(d[key], dtype=dtype).copy()
    for key in ("valid", "calibrating", "detected", "magnitude_valid"):
        d[key] = bool(d[key])
    for key in ("episodes", "isolated_sensor", "isolated_mask", "fault_type",
                "input_delay"):
        d[key] = int(d[key])
    d["magnitude"] = float(d["magnitude"])
    return DFChannelOutput(**d)


#: Version of :meth:`DFChannel.get_state`'s format (1: tagged; equaliser,
#: sensor skew and threshold statistics always present).
STATE_VERSION = 1


def _from_version_0(state: dict[str, Any]) -> dict[str, Any]:
    """Unversioned states may lack the equaliser, the sensor skew line and the
    threshold statistics."""
    out = dict(state)
    out.setdefault("equaliser", None)
    out.setdefault("skew_u", [])
    out.setdefault("skew_y", [])
    out.setdefault("threshold_stats", None)
    return out


_MIGRATIONS = {0: _from_version_0}
