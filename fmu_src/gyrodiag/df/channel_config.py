"""Settings of the detection-filter channel and the choice of its decision rule.

:class:`DFChannelConfig` holds what :class:`~gyrodiag.df.channel.DFChannel` and its two
decision rules (:mod:`gyrodiag.df.paper_rule`, :mod:`gyrodiag.df.sequential_rule`) are
built from; :func:`decision_rule` maps the FMU's ``df.decision`` code to a rule.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..common._validation import (
    check_finite_array,
    check_in_range,
    check_int,
    check_nonnegative,
    check_positive,
)
from .gust import GustModel
from .isolation import ENERGY_MIN_SAMPLES
from .plant import seed_aircraft
from .sensor_dynamics import SensorDynamics
from .sequential_diagnosis import SequentialSettings

__all__ = ["CAL_MIN_SAMPLES", "DECISIONS", "DECISION_AUTO", "DFChannelConfig",
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
        (:mod:`gyrodiag_harness.cosim.timing`).
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
