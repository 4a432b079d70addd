"""Which sensor failed: observer banks and a streaming sensor-fault isolator.

The single Beard–Jones filter of the seed paper detects faults but cannot tell most
of them apart on the seed aircraft (docs/methods.md §4): constant-bias signatures of v and h
are zero, those of α, θ and γ nearly collinear. The isolability analysis
(:mod:`gyrodiag.df.isolability`; its names are importable from here too) works out,
for a given model, what is detectable and what is isolable;
:class:`SensorFaultIsolator` isolates by a generalised observer scheme (GOS):

* observer ``j`` of the bank is driven by every sensor except ``j``, so a fault on
  sensor ``i`` leaves observer ``i`` silent and (where the model allows) makes every
  other observer alarm: the silent observer names the faulty sensor;
* the main detection filter gives the detection alarm;
* observer ``i`` also gives a fault-free estimate ``ŷ_i`` of the isolated sensor, from
  which fault type and size are estimated (bias: y − ŷ ≈ b, gain: y ≈ g ŷ,
  stuck: y constant, complete failure: y ≡ 0).

Observers for sensors without analytical redundancy (v, h on the seed aircraft: the
rest of the sensors do not observe them) run on the observable subspace of their
sensor set; they cannot estimate the excluded sensor, so type and size of its fault
are reported as unknown.
"""

from __future__ import annotations

import importlib
import warnings
from dataclasses import dataclass
from enum import IntEnum
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from gyrodiag.common._validation import (
    check_finite_array,
    check_in_range,
    check_int,
    check_positive,
)
from gyrodiag.df import gains
from gyrodiag.df.filter import (
    DetectionFilter,
    DiscreteObserver,
    ResidualEvaluator,
    ResidualThresholds,
    observable_subspace,
    zoh_discretise,
)
from gyrodiag.df.isolation_state import isolator_state, restore_isolator_state

__all__ = [
    "BankObserver",
    "FaultType",
    "IsolationResult",
    "SensorFaultIsolator",
    "design_observer_bank",
    "place_observer_gain",
]

#: Names of :mod:`gyrodiag.df.isolability` importable from here (they lived here): it
#: imports this module, so they are looked up at first use (PEP 562), not imported.
_ISOLABILITY_NAMES = ("IsolabilityReport", "SensorIsolability", "isolability_analysis")


def __getattr__(name: str) -> Any:
    """The isolability analysis' names, from :mod:`gyrodiag.df.isolability`."""
    if name in _ISOLABILITY_NAMES:
        return getattr(importlib.import_module("gyrodiag.df.isolability"), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")

_FloatArray = NDArray[np.float64]

#: ``isolated`` value when no fault is detected.
NO_FAULT = -1
#: Fewest samples the energy isolation averages before it may decide.
ENERGY_MIN_SAMPLES = 10
#: ``isolated`` value when a fault is detected but the alarm pattern names no sensor.
AMBIGUOUS = -2


class FaultType(IntEnum):
    """Estimated sensor fault type (integer codes for FMI outputs)."""

    UNKNOWN = -1
    NONE = 0
    BIAS = 1
    GAIN = 2
    STUCK = 3
    FAILURE = 4


# -------------------------------------------------------------------- observer design


def place_observer_gain(A: ArrayLike, C: ArrayLike, poles: ArrayLike) -> _FloatArray:
    """Observer gain ``L`` with eig(A − L C) = ``poles`` (continuous or discrete).

    Pole placement is ``scipy.signal.place_poles`` (Tits–Yang, what ``control.place``
    wraps, so the FMU's host needs no python-control). It needs the "input" matrix Cᵀ
    to have full column rank; with
    redundant sensors it has not, so the design is done on an orthonormal basis ``P``
    of the output space reached by ``C`` and mapped back, ``L = L_r P``. Output
    combinations in the left null space of ``C`` (parity relations) get no gain and
    stay visible in the residual.

    A design already made in this process, or shipped in the Diagnoser's table of
    default designs, is not computed again (:mod:`gyrodiag.df.gains`: importing
    ``scipy.signal`` is most of the detection filter's start-up).
    """
    a = check_finite_array("A", A, ndim=2)
    c = check_finite_array("C", C, shape=(None, a.shape[0]))
    p = np.asarray(poles)
    key = gains.design_key(a, c, p)
    want = np.sort_complex(p.astype(complex))
    gain = gains.lookup(key)
    if gain is not None and not _places(a, c, gain, want):
        gains.drop(key)  # a damaged table entry: design it
        gain = None
    if gain is None:
        gain = _placed_gain(a, c, p)
        if not _places(a, c, gain, want):
            got = np.sort_complex(np.linalg.eigvals(a - gain @ c))
            raise ValueError(f"poles could not be placed: wanted {want}, got {got}")
        gains.remember(key, gain)  # a hit is remembered already
    return gain


def _places(a: _FloatArray, c: _FloatArray, gain: _FloatArray,
            want: NDArray[np.complex128]) -> bool:
    """True if eig(A − L C) are the wanted poles (sorted), to 1e-4 relative or 1e-6
    absolute (slow sample periods give ill-conditioned placements that are still
    sound observers)."""
    if gain.shape != (a.shape[0], c.shape[0]) or not np.all(np.isfinite(gain)):
        return False
    got = np.sort_complex(np.linalg.eigvals(a - gain @ c))
    return bool(np.allclose(got, want, rtol=1e-4, atol=1e-6))


def _placed_gain(a: _FloatArray, c: _FloatArray, p: NDArray[Any]) -> _FloatArray:
    from scipy.signal import place_poles  # only a new design needs it (start-up time)

    u, s, _ = np.linalg.svd(c)
    rank = int(np.sum(s > s.max(initial=0.0) * max(c.shape) * np.finfo(float).eps))
    if rank == 0:
        raise ValueError("C must not be zero")
    proj = u[:, :rank].T
    with warnings.catch_warnings():
        # YT iterations that stop early still place the poles; checked by the caller.
        warnings.simplefilter("ignore", UserWarning)
        gain_r = np.asarray(place_poles(a.T, (proj @ c).T, p, method="YT").gain_matrix).T
    return gain_r @ proj


@dataclass(frozen=True)
class BankObserver:
    """One observer of the generalised observer scheme.

    Attributes
    ----------
    excluded : int
        Index of the sensor this observer does not use.
    used : ndarray of int
        Indices of the sensors it uses, in order.
    observer : DiscreteObserver
        The streaming observer on the observable subspace of (A, C_used).
    n_observable : int
        Dimension of that subspace.
    estimates_excluded : bool
        True if the excluded sensor's value is observable from the used sensors, so
        ``C[excluded] @ observer.state_estimate`` is a fault-free estimate of it.
    """

    excluded: int
    used: NDArray[np.int_]
    observer: DiscreteObserver
    n_observable: int
    estimates_excluded: bool


def _bank_eigenvalues(eigenvalues: ArrayLike | None, n_o: int) -> _FloatArray:
    if eigenvalues is None:
        return -np.arange(1.0, n_o + 1.0)
    lam = check_finite_array("bank_eigenvalues", eigenvalues, ndim=1)
    if lam.size < n_o:
        raise ValueError(f"bank_eigenvalues must have at least {n_o} entries, got {lam.size}")
    if np.any(lam >= 0.0):
        raise ValueError("bank_eigenvalues must all be < 0")
    return lam[:n_o]


def design_observer_bank(
    A: ArrayLike,
    B: ArrayLike,
    C: ArrayLike,
    sample_period_s: float,
    eigenvalues: ArrayLike | None = None,
) -> list[BankObserver]:
    """Design the GOS bank: observer ``j`` uses all sensors except ``j``.

    Each observer is designed in discrete time on the exact ZOH model of the
    observable subspace of (A, C without row j), with poles ``exp(λ T)``.

    Parameters
    ----------
    A, B, C : array_like
        Continuous plant model.
    sample_period_s : float
        Sample period T, s.
    eigenvalues : array_like, optional
        Continuous observer eigenvalues λ (1/s), distinct and < 0; the first n_o are
        used for an n_o-dimensional observable subspace. Default −1, −2, …, −n_o.
        Slow poles keep a larger steady-state fault signature in the residual.
    """
    a = check_finite_array("A", A, ndim=2)
    n = a.shape[0]
    b = check_finite_array("B", B, shape=(n, None))
    c = check_finite_array("C", C, shape=(None, n))
    t = check_positive("sample_period_s", sample_period_s)
    m = c.shape[0]
    bank = []
    for j in range(m):
        used = np.array([i for i in range(m) if i != j], dtype=int)
        c_used = c[used]
        basis = observable_subspace(a, c_used)
        n_o = basis.shape[1]
        a_o, b_o, c_o = basis.T @ a @ basis, basis.T @ b, c_used @ basis
        phi, gam = zoh_discretise(a_o, b_o, t)
        lam = _bank_eigenvalues(eigenvalues, n_o)
        gain = place_observer_gain(phi, c_o, np.exp(lam * t))
        row = c[j] @ basis
        # Sensor j is estimable iff its row has no component along the unobservable
        # subspace, i.e. projecting onto the observable basis keeps its full norm.
        estimable = bool(
            np.linalg.norm(row) >= (1.0 - 1e-9) * np.linalg.norm(c[j]) > 0.0
        )
        bank.append(
            BankObserver(
                excluded=j,
                used=used,
                observer=DiscreteObserver(phi, gam, c_o, gain, basis),
                n_observable=n_o,
                estimates_excluded=estimable,
            )
        )
    return bank


# ------------------------------------------------------------------ streaming isolator


@dataclass(frozen=True)
class IsolationResult:
    """Output of :meth:`SensorFaultIsolator.update` for one sample.

    Attributes
    ----------
    detected : bool
        Latched: the main detection filter alarmed, or an isolation was confirmed.
    isolated : int
        Index of the isolated sensor, ``-1`` none detected, ``-2`` detected but not
        (yet) isolated.
    main_alarms : ndarray of bool, shape (m,)
        Per-channel alarms of the main filter at this sample.
    main_normalised : ndarray, shape (m,)
        Main residual divided by its threshold (|·| > 1 exceeds).
    observer_alarms : ndarray of bool, shape (m,)
        Alarm of bank observer j (the one without sensor j) at this sample.
    onset_sensor : int
        Channel with the largest normalised main residual at the detection sample
        (residual direction at onset); -1 before detection.
    fault_type : FaultType
        Estimated type of the isolated sensor's fault.
    magnitude : float
        Bias (sensor units), gain factor, stuck value (sensor units) or 0 for a
        complete failure; nan when unknown.
    """

    detected: bool
    isolated: int
    main_alarms: NDArray[np.bool_]
    main_normalised: _FloatArray
    observer_alarms: NDArray[np.bool_]
    onset_sensor: int
    fault_type: FaultType
    magnitude: float


class _StackedBank:
    """The main filter and the bank stepped as one block-diagonal observer.

    One sample of seven small observers and evaluators was ~100 numpy calls; stacked
    it is about fifteen (the paper rule's per-sample cost, most of a 1 kHz system
    run's detection filter).  The observer and evaluator objects stay the owners of
    their state: ``step`` reads their states, advances them together and writes the
    new states back, so get/set_state, reset and the per-observer properties see
    exactly what the separate updates would have left (to the rounding of the
    block-diagonal products).
    """

    def __init__(self, main: DiscreteObserver, bank: list[BankObserver],
                 c: _FloatArray) -> None:
        observers = [main] + [b.observer for b in bank]
        used = [np.arange(main.n_outputs)] + [b.used for b in bank]
        ns = [o._phi.shape[0] for o in observers]
        ms = [o._c.shape[0] for o in observers]
        n_tot, m_tot, p = sum(ns), sum(ms), main.n_inputs
        self.phi = np.zeros((n_tot, n_tot))
        self.gamma = np.zeros((n_tot, p))
        self.c = np.zeros((m_tot, n_tot))
        self.l = np.zeros((n_tot, m_tot))
        # ŷ_j = C[j] · basis_j · z_j for the bank (a-priori estimate of sensor j)
        self.h = np.zeros((len(bank), n_tot))
        self.z_slices: list[slice] = []
        self.r_slices: list[slice] = []
        a = r = 0
        for k, (o, n_k, m_k) in enumerate(zip(observers, ns, ms, strict=True)):
            zs, rs = slice(a, a + n_k), slice(r, r + m_k)
            self.phi[zs, zs] = o._phi
            self.gamma[zs] = o._gamma
            self.c[rs, zs] = o._c
            self.l[zs, rs] = o._l
            if k > 0:
                self.h[k - 1, zs] = c[bank[k - 1].excluded] @ o._basis
            self.z_slices.append(zs)
            self.r_slices.append(rs)
            a, r = a + n_k, r + m_k
        self.observers = observers
        self.select = np.concatenate(used)
        self.bank_starts = np.array([s.start for s in self.r_slices[1:]]) - ms[0]
        self.mean = np.zeros(m_tot)
        self.threshold = np.ones(m_tot)
        self.history = np.zeros((1, m_tot), dtype=bool)
        self.residual = np.zeros(m_tot)
        self.bank_sizes = np.array([rs.stop - rs.start for rs in self.r_slices[1:]])
        self.energy_mean = np.zeros(m_tot - ms[0])
        self.energy_scale = np.ones(m_tot - ms[0])

    def set_thresholds(self, evaluators: list[ResidualEvaluator]) -> None:
        self.mean = np.concatenate([e.thresholds.mean for e in evaluators])
        self.threshold = np.concatenate([e.thresholds.threshold for e in evaluators])
        bank = [e.thresholds for e in evaluators[1:]]
        self.energy_mean = np.concatenate([t.mean for t in bank])
        # a noise-free channel (std 0) is scaled by its threshold floor instead
        self.energy_scale = np.concatenate([np.where(t.std > 0.0, t.std, t.threshold)
                                            for t in bank])

    def bank_energy(self) -> _FloatArray:
        """Per bank observer: the mean over its channels of ((r − mean) / std)² of the
        last step's residual against its calibration (1 on average when fault-free)."""
        z = (self.residual[self.r_slices[0].stop:] - self.energy_mean) / self.energy_scale
        return np.add.reduceat(z * z, self.bank_starts) / self.bank_sizes

    def _histories_shared(self, evaluators: list[ResidualEvaluator]) -> bool:
        """Point the evaluators' histories at one stacked array (again after a reset
        or set_state replaced them); False if they are not in step (then the caller
        steps them one by one)."""
        pos = evaluators[0]._pos
        if any(e._pos != pos for e in evaluators):
            return False
        if all(e._history.base is self.history for e in evaluators):
            return True
        self.history = np.concatenate([e._history for e in evaluators], axis=1)
        for e, rs in zip(evaluators, self.r_slices, strict=True):
            e._history = self.history[:, rs]
        return True

    def run(self, u: _FloatArray, y: _FloatArray) -> list[_FloatArray]:
        """Advance every observer over a checked window (N, p), (N, m) from the states
        they hold; return each one's residuals (N, m_k), main filter first.

        The window runs as one closed-loop recursion z ← (Φ − L C) z + Γ u + L y of
        the stacked observer (one product per sample instead of seven observers'
        four each: a 10 s calibration at 1 kHz took a second); equal to streaming
        the samples through :meth:`step` to rounding."""
        obs = self.observers
        n = u.shape[0]
        ys = y[:, self.select]
        closed = self.phi - self.l @ self.c
        drive = u @ self.gamma.T + ys @ self.l.T
        states = np.empty((n + 1, self.phi.shape[0]))
        z = states[0] = np.concatenate([o._z for o in obs])
        for k in range(n):
            z = states[k + 1] = closed @ z + drive[k]
        residuals = ys - states[:n] @ self.c.T
        for o, zs, rs in zip(obs, self.z_slices, self.r_slices, strict=True):
            o._z = states[n, zs].copy()
            if n:
                o._residual = residuals[n - 1, rs].copy()
            o._n_updates += n
        return [residuals[:, rs] for rs in self.r_slices]

    def step(self, u: _FloatArray, y: _FloatArray, evaluators: list[ResidualEvaluator],
             k_needed: int) -> tuple[_FloatArray, NDArray[np.bool_], _FloatArray,
                                     NDArray[np.bool_]]:
        """Advance every observer and evaluator by one checked sample.

        Returns ``(ŷ of the bank before the step, main alarms, main normalised
        residual, per-bank-observer "any alarm")``.
        """
        obs = self.observers
        z = np.concatenate([o._z for o in obs])
        y_hat = self.h @ z
        residual = y[self.select] - self.c @ z
        z_new = self.phi @ z + self.gamma @ u + self.l @ residual
        self.residual = residual
        for o, zs, rs in zip(obs, self.z_slices, self.r_slices, strict=True):
            o._z = z_new[zs]
            o._residual = residual[rs]
            o._n_updates += 1
        normalised = (residual - self.mean) / self.threshold
        if self._histories_shared(evaluators):
            pos = evaluators[0]._pos
            self.history[pos] = np.abs(normalised) > 1.0
            alarms = self.history.sum(axis=0) >= k_needed
            new_pos = (pos + 1) % self.history.shape[0]
            for e, rs in zip(evaluators, self.r_slices, strict=True):
                e._pos = new_pos
                e._alarms = alarms[rs]
                e._normalised = normalised[rs]
        else:
            alarms = np.concatenate([e._record(normalised[rs])
                                     for e, rs in zip(evaluators, self.r_slices,
                                                      strict=True)])
        m = self.r_slices[0].stop
        bank_any = np.logical_or.reduceat(alarms[m:], self.bank_starts)
        return y_hat, alarms[:m].copy(), normalised[:m].copy(), bank_any


class SensorFaultIsolator:
    """Detection filter + generalised observer scheme + fault type estimation.

    Call :meth:`calibrate` with fault-free data (or :meth:`set_thresholds`) before
    :meth:`update`.

    Parameters
    ----------
    A, B, C : array_like
        Continuous plant model.
    K : array_like
        Main detection-filter gain (n × m).
    sample_period_s : float
        Sample period, s.
    bank_eigenvalues : array_like, optional
        Continuous eigenvalues of the bank observers (default −1, −2, …).
    persistence_k, persistence_n : int
        k-of-n persistence of every residual alarm.
    confirm_samples : int
        The same "all observers but one alarm" pattern must hold this many
        consecutive samples before the isolation is latched.
    type_min_samples : int
        Samples after detection before a fault type is estimated.
    gain_tolerance : float
        |g − 1| below which a fitted gain counts as 1 (bias fault); a gain must also
        differ from 1 by 4 standard errors, and its part of the deviation,
        (g − 1)²·var(ŷ), must exceed the fit's squared offset (b of y = g ŷ + b): in a
        closed loop a bias moves the fitted g too (docs/notes.md, isolation).
    stuck_noise_ratio : float
        Output std below this fraction of the sensor's fault-free noise std means
        "constant output" (stuck or failed).
    energy_window_s : float
        Isolation by residual energy when the alarm pattern does not isolate, s after
        detection (0: off, the alarm pattern alone).  Each bank observer's energy is
        the mean over its channels of ((r − mean)/std)² against its calibration,
        averaged since detection; from a quarter of the window (at least 10 samples) to
        its end, sensor j is isolated when observer ¬j's energy is at most
        ``energy_ok`` (consistent with fault-free) and every other observer's is
        ``energy_ratio`` times higher.  Small faults in turbulence need it: the
        calibration's gust response widens the bank's per-sample thresholds, so a
        3-5 % q scale error can leave most of the bank silent; without turbulence the
        pattern isolates at once (figures: docs/notes.md, isolation).
    energy_ok, energy_ratio : float
        Thresholds of that test (fault-free energy is 1 on average).
    energy_baseline_s : float
        Time constant of each bank observer's fault-free energy baseline, s (0: off,
        the baseline is the calibration's 1).  Before detection the baseline follows
        the per-sample energy (exponential mean); after it the energies are measured
        against the larger of 1 and the baseline.  Turbulence stronger than in the
        calibration window raises the energy of the observers that are most sensitive
        to gusts before any fault, and the energy test then takes the least
        gust-sensitive observer for the faultless one (docs/notes.md, isolation).  It
        can only make the energy test abstain more, never isolate more.

    Notes
    -----
    The isolation, once latched, is kept until :meth:`reset` (one fault at a time).
    Fault type and size are estimated from the samples since detection, comparing the
    sensor with observer ``i``'s fault-free estimate ``ŷ_i``: constant output →
    stuck, or complete failure if it is within 3 noise std of 0; otherwise a least
    squares fit ``y = g ŷ + b``: gain if ``|g − 1|`` exceeds ``gain_tolerance`` and
    4 standard errors and ``(g − 1)² var(ŷ) > b²``, else bias ``mean(y − ŷ)``.
    """

    def __init__(
        self,
        A: ArrayLike,
        B: ArrayLike,
        C: ArrayLike,
        K: ArrayLike,
        sample_period_s: float,
        *,
        bank_eigenvalues: ArrayLike | None = None,
        persistence_k: int = 3,
        persistence_n: int = 5,
        confirm_samples: int = 5,
        type_min_samples: int = 50,
        gain_tolerance: float = 0.01,
        stuck_noise_ratio: float = 0.1,
        energy_window_s: float = 0.0,
        energy_ok: float = 2.0,
        energy_ratio: float = 2.5,
        energy_baseline_s: float = 0.0,
    ) -> None:
        self._main = DetectionFilter(A, B, C, K, sample_period_s)
        self._bank = design_observer_bank(A, B, C, sample_period_s, bank_eigenvalues)
        self._m = self._main.n_outputs
        self._c = check_finite_array("C", C, shape=(self._m, None))
        self._stack = _StackedBank(self._main, self._bank, self._c)
        self._pk = check_int("persistence_k", persistence_k, minimum=1)
        self._pn = check_int("persistence_n", persistence_n, minimum=1)
        if self._pk > self._pn:
            raise ValueError(f"persistence_k must be <= persistence_n ({self._pn})")
        self._confirm = check_int("confirm_samples", confirm_samples, minimum=1)
        self._type_min = check_int("type_min_samples", type_min_samples, minimum=2)
        self._gain_tol = check_positive("gain_tolerance", gain_tolerance)
        self._stuck_ratio = check_positive("stuck_noise_ratio", stuck_noise_ratio)
        window = check_in_range("energy_window_s", energy_window_s, 0.0, 3600.0)
        period = check_positive("sample_period_s", sample_period_s)
        self._energy_window = round(window / period)
        if 0.0 < window and self._energy_window < ENERGY_MIN_SAMPLES:
            raise ValueError(
                f"energy_window_s must be 0 (off) or at least {ENERGY_MIN_SAMPLES} samples "
                f"({ENERGY_MIN_SAMPLES * period:g} s at sample_period_s={period:g}), got "
                f"{window:g}: a shorter window never isolates")
        self._energy_min = max(ENERGY_MIN_SAMPLES, self._energy_window // 4)
        self._energy_ok = check_positive("energy_ok", energy_ok)
        self._energy_ratio = check_in_range("energy_ratio", energy_ratio, 1.0, 1e6,
                                            low_open=True)
        baseline = check_in_range("energy_baseline_s", energy_baseline_s, 0.0, 3600.0)
        self._baseline_alpha = 0.0 if baseline == 0.0 else float(-np.expm1(-period
                                                                           / baseline))
        self._main_eval: ResidualEvaluator | None = None
        self._bank_eval: list[ResidualEvaluator] | None = None
        self._noise_std: _FloatArray | None = None
        self.reset()

    # ---------------------------------------------------------------- configuration

    @property
    def n_sensors(self) -> int:
        """Number of sensors."""
        return self._m

    @property
    def bank(self) -> list[BankObserver]:
        """The observer bank (observer j excludes sensor j)."""
        return self._bank

    @property
    def main_filter(self) -> DetectionFilter:
        """The main detection filter."""
        return self._main

    @property
    def calibrated(self) -> bool:
        """True once thresholds are set."""
        return self._main_eval is not None

    @property
    def main_thresholds(self) -> ResidualThresholds:
        """Main-filter thresholds (RuntimeError before they are set)."""
        if self._main_eval is None:
            raise RuntimeError("SensorFaultIsolator is not calibrated")
        return self._main_thr

    @property
    def bank_thresholds(self) -> list[ResidualThresholds]:
        """Observer j's thresholds, in bank order (RuntimeError before they are set)."""
        if self._bank_eval is None:
            raise RuntimeError("SensorFaultIsolator is not calibrated")
        return list(self._bank_thr)

    @property
    def noise_std(self) -> _FloatArray:
        """Sensor noise std of the stuck/failure tests (RuntimeError before set)."""
        if self._noise_std is None:
            raise RuntimeError("SensorFaultIsolator is not calibrated")
        return self._noise_std.copy()

    def set_thresholds(
        self,
        main: ResidualThresholds,
        bank: list[ResidualThresholds],
        noise_std: ArrayLike | None = None,
    ) -> None:
        """Set residual thresholds explicitly.

        ``bank[j]`` has one channel per sensor used by observer j. ``noise_std``
        (per sensor, sensor units) scales the stuck/failure tests; default the main
        residual std.
        """
        if not isinstance(main, ResidualThresholds) or main.n_channels != self._m:
            raise ValueError(f"main must be ResidualThresholds with {self._m} channels")
        if len(bank) != self._m:
            raise ValueError(f"bank must hold {self._m} ResidualThresholds")
        for j, thr in enumerate(bank):
            if not isinstance(thr, ResidualThresholds) or thr.n_channels != self._m - 1:
                raise ValueError(f"bank[{j}] must be ResidualThresholds with {self._m - 1} "
                                 "channels")
        noise = main.std if noise_std is None else noise_std
        self._noise_std = check_finite_array("noise_std", noise, shape=(self._m,))
        self._main_thr, self._bank_thr = main, list(bank)
        self._main_eval = ResidualEvaluator(main, self._pk, self._pn)
        self._bank_eval = [ResidualEvaluator(t, self._pk, self._pn) for t in bank]
        self._stack.set_thresholds([self._main_eval, *self._bank_eval])
        self.reset()

    def calibrate(
        self,
        u: ArrayLike,
        y: ArrayLike,
        *,
        k_sigma: float | None = None,
        false_alarm_rate: float | None = None,
        burn_in: int = 0,
        x0: ArrayLike | None = None,
        continue_after: bool = False,
    ) -> None:
        """Set thresholds from a fault-free run.

        Parameters
        ----------
        u : array_like, shape (N, p)
            Inputs, one row per sample.
        y : array_like, shape (N, m)
            Fault-free measurements.
        k_sigma, false_alarm_rate : float
            Threshold rule, see :meth:`ResidualThresholds.from_fault_free`.
        burn_in : int
            Samples skipped while the observers converge.
        x0 : array_like, optional
            Initial state estimate of all observers.
        continue_after : bool
            False (default): every observer restarts from ``x0``. True: the observers
            stay where the window left them, as if it had been streamed through them,
            for a caller that goes on with the samples after the window (decisions
            and alarm histories start afresh either way).
        """
        u_arr = check_finite_array("u", u, shape=(None, self._main.n_inputs))
        y_arr = check_finite_array("y", y, shape=(u_arr.shape[0], self._m))
        residuals = self._run_observers(u_arr, y_arr, x0)
        main = ResidualThresholds.from_fault_free(
            residuals[0], k_sigma=k_sigma, false_alarm_rate=false_alarm_rate, burn_in=burn_in
        )
        bank = [
            ResidualThresholds.from_fault_free(
                r, k_sigma=k_sigma, false_alarm_rate=false_alarm_rate, burn_in=burn_in
            )
            for r in residuals[1:]
        ]
        observers = [self._main] + [b.observer for b in self._bank]
        ends = [o.get_state() for o in observers] if continue_after else None
        self.set_thresholds(main, bank)
        self.reset(x0)
        if ends is not None:
            for o, state in zip(observers, ends, strict=True):
                o.set_state(state)

    def _run_observers(
        self, u: _FloatArray, y: _FloatArray, x0: ArrayLike | None
    ) -> list[_FloatArray]:
        """Every observer from ``x0`` over a checked window; its residuals, main first.
        The observers are left where the window ends."""
        self._main.reset(x0)
        for b in self._bank:
            b.observer.reset(x0)
        return self._stack.run(u, y)

    # -------------------------------------------------------------------- streaming

    def reset(self, x0: ArrayLike | None = None) -> None:
        """Restart every observer from ``x0`` (zeros if None) and clear decisions."""
        self._main.reset(x0)
        for b in self._bank:
            b.observer.reset(x0)
        if self._main_eval is not None and self._bank_eval is not None:
            self._main_eval.reset()
            for ev in self._bank_eval:
                ev.reset()
        self._detected = False
        self._isolated = NO_FAULT
        self._onset = NO_FAULT
        self._candidate = NO_FAULT
        self._candidate_count = 0
        # Running sums per sensor since detection: n, Σy, Σy², Σŷ, Σŷ², Σyŷ, of the
        # deviations from the first sample (``_ref``) so that large signals such as h
        # do not lose the noise-sized variance to cancellation.
        self._sums = np.zeros((self._m, 6))
        self._ref = np.zeros((self._m, 2))
        # per bank observer: sum of the normalised squared residual since detection
        self._energy = np.zeros(self._m)
        self._energy_n = 0
        # per bank observer: fault-free energy before detection (exponential mean)
        self._baseline = np.ones(self._m)

    @property
    def energy_baseline(self) -> _FloatArray:
        """Each bank observer's fault-free energy baseline (1 = the calibration's)."""
        return self._baseline.copy()

    def update(self, u: ArrayLike, y: ArrayLike) -> IsolationResult:
        """Process one sample and return the decision.

        Raises ``ValueError`` naming ``u`` or ``y`` (shape or non-finite value) and
        leaves every state untouched; ``RuntimeError`` if not calibrated.
        """
        if self._main_eval is None or self._bank_eval is None or self._noise_std is None:
            raise RuntimeError("SensorFaultIsolator is not calibrated: call calibrate() or "
                               "set_thresholds() first")
        return self.advance(check_finite_array("u", u, shape=(self._main.n_inputs,)),
                            check_finite_array("y", y, shape=(self._m,)))

    def advance(self, u_arr: _FloatArray, y_arr: _FloatArray) -> IsolationResult:
        """:meth:`update` for a caller that checked the sample (finite float64 arrays of
        shapes (p,) and (m,)) and calibrated the isolator."""
        assert self._main_eval is not None and self._bank_eval is not None

        # u and y are checked once above; every observer and evaluator steps in one
        # stacked product.  y_hat: the fault-free estimate of each sensor from the
        # observer that ignores it, before the step (a-priori, like the residuals).
        y_hat, main_alarms, main_norm, obs_alarms = self._stack.step(
            u_arr, y_arr, [self._main_eval, *self._bank_eval], self._pk)
        if self._baseline_alpha > 0.0 and not self._detected:
            self._baseline += self._baseline_alpha * (self._stack.bank_energy()
                                                      - self._baseline)

        if not self._detected and main_alarms.any():
            self._detected = True
            self._onset = int(np.argmax(np.abs(main_norm)))
        if self._detected:
            if self._sums[0, 0] == 0:
                self._ref = np.column_stack([y_arr, y_hat])
            dy, dh = y_arr - self._ref[:, 0], y_hat - self._ref[:, 1]
            self._sums += np.column_stack([np.ones(self._m), dy, dy**2, dh, dh**2, dy * dh])

        if self._isolated < 0:
            silent = np.flatnonzero(~obs_alarms)
            candidate = int(silent[0]) if silent.size == 1 else NO_FAULT
            if candidate >= 0 and candidate == self._candidate:
                self._candidate_count += 1
            else:
                self._candidate, self._candidate_count = candidate, int(candidate >= 0)
            if self._candidate >= 0 and self._candidate_count >= self._confirm:
                self._isolated = self._candidate
                if not self._detected:
                    # The bank can be more sensitive than the main filter for some
                    # faults; an isolation is a detection.
                    self._detected = True
                    self._onset = int(np.argmax(np.abs(main_norm)))
        if (self._isolated < 0 and self._detected
                and self._energy_n < self._energy_window):
            self._isolate_by_energy()

        if self._isolated >= 0:
            isolated = self._isolated
            fault_type, magnitude = self._estimate_type(isolated)
        else:
            isolated = AMBIGUOUS if self._detected else NO_FAULT
            fault_type, magnitude = (
                (FaultType.UNKNOWN, float("nan")) if self._detected else (FaultType.NONE, 0.0)
            )
        return IsolationResult(
            detected=self._detected,
            isolated=isolated,
            main_alarms=main_alarms,
            main_normalised=main_norm,
            observer_alarms=obs_alarms,
            onset_sensor=self._onset,
            fault_type=fault_type,
            magnitude=magnitude,
        )

    def _isolate_by_energy(self) -> None:
        self._energy += self._stack.bank_energy()
        self._energy_n += 1
        if self._energy_n < self._energy_min:
            return
        e = self._energy / self._energy_n / np.maximum(self._baseline, 1.0)
        order = np.argsort(e)
        best, second = e[order[0]], e[order[1]]
        if best <= self._energy_ok and second >= self._energy_ratio * best:
            self._isolated = int(order[0])

    def _estimate_type(self, i: int) -> tuple[FaultType, float]:
        """Type and size of sensor i's fault (:func:`_fit_fault_type`)."""
        assert self._noise_std is not None
        return _fit_fault_type(self._sums[i], self._ref[i], float(self._noise_std[i]),
                               self._bank[i].estimates_excluded, self._type_min,
                               self._stuck_ratio, self._gain_tol)

    # ------------------------------------------------------------------------ state

    def get_state(self) -> dict[str, Any]:
        """Flat dict of numpy arrays / ints with every dynamic state (deep copies;
        :mod:`~gyrodiag.df.isolation_state`)."""
        return isolator_state(self)

    def set_state(self, state: dict[str, Any]) -> None:
        """Restore a state produced by :meth:`get_state` of an identically built object."""
        restore_isolator_state(self, state)


def _fit_fault_type(sums: _FloatArray, ref: _FloatArray, noise_std: float,
                    estimates_excluded: bool, type_min: int, stuck_ratio: float,
                    gain_tol: float) -> tuple[FaultType, float]:
    """Type and size of one sensor's fault from its running sums since detection and
    their reference ``ref`` = (y, ŷ) (:class:`SensorFaultIsolator` notes)."""
    n, sy, syy, sh, shh, syh = sums
    if n < type_min:
        return FaultType.UNKNOWN, float("nan")
    noise = max(float(noise_std), np.finfo(float).tiny)
    mean_dy, mean_dh = sy / n, sh / n
    mean_y = ref[0] + mean_dy
    var_y = max(syy / n - mean_dy**2, 0.0)
    if np.sqrt(var_y) < stuck_ratio * noise:
        if abs(mean_y) <= 3.0 * noise:
            return FaultType.FAILURE, 0.0
        return FaultType.STUCK, float(mean_y)
    if not estimates_excluded:
        return FaultType.UNKNOWN, float("nan")
    var_h = max(shh / n - mean_dh**2, 0.0)
    cov = syh / n - mean_dy * mean_dh
    bias = mean_y - (ref[1] + mean_dh)
    if var_h > 0.0:
        g = cov / var_h
        resid_var = max(var_y - g * cov, 0.0)
        se_g = np.sqrt(resid_var / (n * var_h))
        # A gain must be significant and explain more of the deviation y − ŷ than
        # the fit's offset does: in a closed loop a bias fault moves the fitted g by
        # ~1.5 % (the controller answers the biased sensor).  The offset is the
        # intercept y − g ŷ, not the mean deviation: a pure gain on a signal with a
        # mean (θ flown at 0.15 rad) has mean deviation (g − 1)·mean(ŷ) and was typed
        # a bias that way.
        intercept = mean_y - g * (ref[1] + mean_dh)
        if (abs(g - 1.0) > max(gain_tol, 4.0 * se_g)
                and (g - 1.0) ** 2 * var_h > intercept**2):
            return FaultType.GAIN, float(g)
    return FaultType.BIAS, float(bias)
