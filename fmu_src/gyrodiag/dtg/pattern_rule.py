"""The pattern classifier of the DTG channel (``classifier="pattern"``, the default).

The learning window is checked and frozen as a nominal reference
(:mod:`gyrodiag.dtg.reference`); residual tests against it keep an alarm for as long as
a fault lasts; an alarm is classified by fitting the learned response patterns of every
fault type on every signal (:mod:`gyrodiag.dtg.patterns`), which names the fault type,
the signal and axis, a distance and the fault's size. The ratio band on η still alarms
too (physical faults move θ without changing the residuals much) and such an alarm is
classified against the physical classes.
"""

from __future__ import annotations

import functools
import math
from collections import deque
from collections.abc import Sequence
from dataclasses import replace
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from .classifier import ChannelClassifier, Confirm, names_class
from .decision import UNKNOWN_CODE
from .model import N_THETA
from .outputs import NO_FEATURE, STATUS_FAILED, DTGDiagnosis
from .patterns import (
    FAULT_TYPES,
    SEVERAL_CODE,
    PatternClassifier,
    PatternResult,
    physical_class,
)
from .physical_test import PhysicalResult
from .readout_noise import attenuated_axis, renamed_noise
from .reference import (
    REFERENCE_STATUS,
    ClassificationStatistics,
    NominalReference,
    ReferenceLearner,
    ResidualMonitor,
)

if TYPE_CHECKING:
    from .channel import DTGChannel

STEP_TYPE = FAULT_TYPES.index("step") + 1
DRIFT_TYPE = FAULT_TYPES.index("drift") + 1
NOISE_TYPE = FAULT_TYPES.index("noise") + 1
#: With a spin or torquer change named, a noise class must raise its own signal's
#: variance by this many standard errors: the change alone raises the residuals'.
HELD_NOISE_Z = 3.0

__all__ = ["MASKED_SIGNAL_FIT", "OMEGA_EXCITATION_Z", "PatternRule"]

#: Case rate: a block whose filtered ω lies more than this many learning-window spreads
#: from the learning mean is a manoeuvre block; a classification window holding one
#: compares only the residuals with the library (ClassificationStatistics.raw_signals).
OMEGA_EXCITATION_Z = 6.0
#: Case rate in a manoeuvre: a signal-fault fit to the residuals alone worse than this
#: (distance per library component) leaves a band alarm to the physical classes
#: (measured fits in docs/dtg_case_rate.md and docs/notes.md).
MASKED_SIGNAL_FIT = 1.0
#: A drift stays a drift while its residual level keeps growing this many standard
#: errors of the window's slope: the learned growth threshold reads the window's
#: relative growth, which falls once the window no longer starts at the onset.
DRIFT_HOLD_T = 4.0
#: Slope of the residual level over every block since the alarm, in standard errors:
#: above the first a step class is read as its signal's drift, and a drift stays one
#: while above the second (a step's stays under about 2 on the bench; a drift's grows
#: as the 1.5th power of its age, so the decision has hysteresis and never flips back).
DRIFT_SPAN_T, DRIFT_SPAN_HOLD_T = 5.0, 2.5
#: Two faults are named once the pair fit has won this many classifications in a row
#: (0.5 s of 25 ms blocks): in manoeuvres it wins alone for up to 0.3 s.
PAIR_CONFIRM = 20


class PatternRule(ChannelClassifier):
    """Residual tests against the frozen reference, classified by the pattern library.

    Parameters
    ----------
    host : DTGChannel
        The channel it classifies for; its estimators are rolled back when the residual
        tests clear, and with the case rate its band needs significance
        (``band_sigma``).
    """

    kind = "pattern"
    # no reference to test against: no alarm rather than a failure of every later
    # sample (see reference_failed)
    failed_status = STATUS_FAILED

    def __init__(self, host: DTGChannel) -> None:
        super().__init__(host)
        c = host.config
        self._pattern = PatternClassifier(c.patterns) if c.patterns is not None else None
        # the estimate's covariance per unit v·P: 1/(1 + λ) for exponentially weighted
        # LS with white-equivalent errors, 1 for plain RLS; 0: no significance test (the
        # paper's regression has no reference information, the window LS no P)
        self._band_factor = 0.0
        if c.band_sigma > 0.0 and c.case_rate is not None and c.estimator != "batch":
            self._band_factor = (1.0 / (1.0 + c.forgetting)
                                 if c.estimator == "forgetting" else 1.0)
        # the decisions' confirm hooks, made once (they read the current θ)
        self._confirm = (functools.partial(self._significant, 0),
                         functools.partial(self._significant, 1))
        self.reset()

    def reset(self) -> None:
        """Return to the state right after construction."""
        self.monitor: ResidualMonitor | None = None
        # when the residual tests clear, the fast estimators are rolled back to their
        # state half a test window before the alarm rose (a fault's data would take them
        # seconds to forget: a 0.3 V noise burst on a pick-off raises their information
        # ~1000-fold, i.e. ~7 s of forgetting 0.999, and the ratio band would hold the
        # alarm that long); during the alarm they go on tracking, so that a physical
        # fault shows in η
        self._rollback: tuple[Any, ...] | None = None
        self._snapshots: deque[tuple[Any, ...]] = deque(
            maxlen=self.host._short_blocks + 1)
        self._pair_streak = 0  # classifications in a row won by a pair of faults
        # the physical test's last verdict, kept while the residual tests hold the test
        self._held_physical: PhysicalResult | None = None

    def reference_failed(self) -> bool:
        """True once learning has ended without any usable reference."""
        return self.host.diagnosis.reference_status == STATUS_FAILED

    # -- ratio band significance (case rate) ------------------------------------
    def confirm_hooks(self) -> tuple[Confirm, Confirm]:
        """Significance hooks once the monitor holds the refined band reference."""
        return self._confirm if self._band_sigma_active() else (None, None)

    def _band_sigma_active(self) -> bool:
        """The band's violations need significance (config ``band_sigma``): only once
        the monitor holds the case rate's refined band reference."""
        return (self._band_factor > 0.0 and self.monitor is not None
                and self.monitor.refines)

    def _band_z2(self, axis: int, theta: Sequence[float]) -> list[float]:
        """Squared distance of each θ of ``axis`` from the band's θ0, in standard errors
        (estimate's v·P/(1 + λ) plus θ0's v·A⁻¹)."""
        mon = self.monitor
        ref = self.host.reference
        assert mon is not None and ref is not None and ref.error_variance is not None
        theta0, var0 = mon.band_arrays()
        S = self.host._estimators[axis]._S  # type: ignore[union-attr]
        p_diag = (S * S).sum(axis=1)
        var = ref.error_variance[axis] * p_diag * self._band_factor + var0[axis]
        d = np.asarray(theta, dtype=float) - theta0[axis]
        return (d * d / var).tolist()

    def _significant(self, axis: int, eta: list[float]) -> bool:
        """A ratio outside the band whose θ (the current estimate) is also band_sigma
        standard errors off."""
        decision = self.host._decisions[axis]  # type: ignore[index]
        z2 = self._band_z2(axis, self.host._theta_now[axis])
        limit = self.host.config.band_sigma ** 2
        return any(z2[i] > limit for i in decision.out_of_band(eta))

    def _band_quiet(self, theta: tuple[float, ...]) -> bool:
        """Every monitored θ of both axes within half band_sigma standard errors of the
        band's θ0 (the block may refine it)."""
        limit = (0.5 * self.host.config.band_sigma) ** 2
        mon = self.host.config.monitored
        for axis in range(2):
            z2 = self._band_z2(axis, theta[axis * N_THETA:(axis + 1) * N_THETA])
            if any(z > limit for z, m in zip(z2, mon, strict=True) if m):
                return False
        return True

    def _refine_band(self) -> None:
        """Take the monitor's refined band reference as the decisions' θ0."""
        mon = self.monitor
        host = self.host
        assert mon is not None and host._decisions is not None
        ref = mon.band_reference
        assert ref is not None
        host.theta0 = ref[0].copy()
        for axis, decision in enumerate(host._decisions):
            decision.set_theta0(ref[0][axis])

    # -- blocks -----------------------------------------------------------------
    def on_reference(self, reference: NominalReference, learner: ReferenceLearner) -> None:
        """Start the residual monitor on the reference; θ0 from it unless given."""
        host = self.host
        mon = ResidualMonitor(reference, host._nb, host._nb * host.T, host._short_blocks,
                              host._long_blocks, host.config.thresholds, host._clear_blocks,
                              host._model)
        mon.prefill(*learner.reference_blocks(reference, host._long_blocks))
        self.monitor = mon
        if host.theta0 is None:
            host.adopt_theta0(reference.theta0_eta.reshape(host.theta0_shape).copy())

    def end_block(self, theta: tuple[float, ...]) -> bool:
        """Push the host's block to the residual monitor (True), nothing before it
        exists (False)."""
        mon = self.monitor
        if mon is None:
            return False
        host = self.host
        was = mon.alarm
        active = self._band_sigma_active()
        quiet = self._band_quiet(theta) if active else True
        now = mon.push_block(*host._blocks.arrays(with_history=True), band_quiet=quiet)
        if active and quiet and not now:
            self._refine_band()
        self._hold_estimators(was, now)
        return True

    def _hold_estimators(self, was: bool, now: bool) -> None:
        """Snapshot the estimators at quiet block ends; keep the oldest snapshot when the
        residual tests alarm and restore it when they clear."""
        est = self.host._estimators
        if now:
            if not was and self._snapshots:
                self._rollback = self._snapshots[0]
            return
        if was and self._rollback is not None:
            sx, sy, theta = self._rollback
            est[0].set_state(sx)
            est[1].set_state(sy)
            self.host._theta_now = theta
            self._rollback = None
            self._snapshots.clear()
        self._snapshots.append((est[0].get_state(), est[1].get_state(),
                                self.host._theta_now))

    # -- classification ---------------------------------------------------------
    def decide(self, t: float, eta: Sequence[list[float]], band_alarm: bool,
               block_done: bool) -> tuple[bool, int, NDArray[np.int64], DTGDiagnosis]:
        """Alarm of the band or the residual tests; the diagnosis is renewed at block
        ends and when the alarm changes."""
        mon = self.monitor
        residual_alarm = mon is not None and mon.alarm
        physical = self._physical_verdict()
        if physical is not None and physical.kind:
            self._held_physical = physical
        elif physical is None and not residual_alarm:
            self._held_physical = None
        if self._held_physical is not None and residual_alarm and self._one_axis():
            self._held_physical = None  # one axis's θ moved: a read-out's noise
        alarm = band_alarm or residual_alarm or physical is not None
        d = self.host.diagnosis
        if block_done or (alarm and d.fault_type == 0) or (not alarm and d.fault_type != 0):
            d = self._diagnose(band_alarm, physical)
        code = 0
        if alarm:
            code = (UNKNOWN_CODE if d.fault_type <= 0 else SEVERAL_CODE
                    if d.signal_mask and d.fault_signal == -1
                    else self._class_code(d.class_name))
        return alarm, code, NO_FEATURE, d

    def _one_axis(self) -> bool:
        """The physical test's fit over the residual alarm moved one axis's θ only."""
        test = self.host.physical_test
        return test is not None and attenuated_axis(test.axis_evidence()) is not None

    def holds_physical_test(self) -> bool:
        """The residual tests alarm, or the case rate moved in the last block (a
        manoeuvre shifts the fitted θ by more than a spin or torquer change would)."""
        if self.monitor is not None and self.monitor.alarm:
            return True
        dev = self.host._blocks.omega_dev
        return bool(dev) and dev[-1] > OMEGA_EXCITATION_Z

    def _physical_verdict(self) -> PhysicalResult | None:
        """The physical-parameter test's alarm, when it has one on a valid reference and
        the residual tests are quiet (they hold it)."""
        host = self.host
        test = host.physical_test
        if test is None or not test.result.alarm or host.reference is None:
            return None
        if host.reference.status != REFERENCE_STATUS["valid"]:
            return None
        return test.result

    def class_name(self, code: int) -> str:
        """Name of a ``fault_code`` in the pattern library (both names for a pair)."""
        if code == SEVERAL_CODE:
            return self.host.diagnosis.class_name
        patterns = self.host.config.patterns
        return names_class(patterns.names if patterns is not None else [], code)

    def _class_code(self, name: str) -> int:
        assert self.host.config.patterns is not None
        return self.host.config.patterns.names.index(name) + 1

    def _classify(self, band_alarm: bool, stats: ClassificationStatistics | None,
                  physical: PhysicalResult | None = None
                  ) -> tuple[PatternResult | None, ClassificationStatistics | None]:
        """Fit the library to a residual alarm's statistics; name the physical test's
        class, or fit a band alarm's statistics to the physical classes."""
        mon = self.monitor
        assert mon is not None
        result: PatternResult | None = None
        streak, self._pair_streak = self._pair_streak, 0
        if mon.alarm:
            if stats is not None and self._pattern is not None:
                result = self._pattern.classify_signal_fault(stats)
                pair = (self._pattern.classify_pair(stats, result)
                        if result.signal != 0 else None)  # a level class or unknown
                self._pair_streak = streak + 1 if pair is not None else 0
                if pair is not None and self._pair_streak >= PAIR_CONFIRM:
                    result = pair
                if self._pattern.has_physical:
                    # a large physical fault (e.g. torquer scale 0.6) also raises the
                    # residual variance: the family that explains more wins (a signal
                    # fault, or a pair, corrupts one axis' estimates, which no physical
                    # class explains)
                    physical = self._pattern.classify_physical(
                        mon.window_statistics(self.host._long_blocks))
                    # the ratio band out and only the slow residual power up: a θ change
                    # (physical fault) explains both, a read-out noise not the band
                    if physical.fault_type > 0 and not self._one_axis() and (
                            result.fault_type < 0 or physical.distance < result.distance
                            or (band_alarm and mon.power_only)
                            or (band_alarm and not stats.raw_signals
                                and result.distance > MASKED_SIGNAL_FIT)):
                        result = physical
            held = self._held_physical
            if held is not None and self._explained_by_change(result, stats):
                result = physical_class(self.host.config.patterns, held.kind, held.ratio)
        elif physical is not None:
            result = physical_class(self.host.config.patterns, physical.kind, physical.ratio)
        elif band_alarm:
            stats = self._raw_signals_checked(
                mon.window_statistics(self.host._long_blocks))
            if self._pattern is not None:
                result = self._pattern.classify_physical(stats)
        return result, stats

    def _explained_by_change(self, result: PatternResult | None,
                             stats: ClassificationStatistics | None) -> bool:
        """A residual alarm after the physical test named a spin or torquer change is
        that change's (the residuals still compare with θ0): slow residual power alone,
        no class, or a noise class whose own signal's variance has not risen."""
        mon = self.monitor
        assert mon is not None
        if mon.power_only or result is None or result.fault_type < 0:
            return True
        if result.fault_type != NOISE_TYPE or stats is None or self._pattern is None:
            return False
        noise = self._pattern.library.noise
        i = result.signal - 1
        std = noise.log_variance_std[i] * noise.scale(stats.window_blocks)
        return bool(stats.log_variance[i] < HELD_NOISE_Z * std)

    def _diagnose(self, band_alarm: bool, physical: PhysicalResult | None = None
                  ) -> DTGDiagnosis:
        """Classify the current state (at block ends, and when the alarm changes)."""
        mon = self.monitor
        ref = self.host.reference
        status = ref.status if ref is not None else REFERENCE_STATUS["learning"]
        block = self.host.diagnosis.block + 1
        if mon is None:
            return DTGDiagnosis(reference_status=status, block=block)
        stats = mon.classification_statistics() if mon.alarm else None
        if stats is not None:
            stats = self._raw_signals_checked(stats)
        result, stats = self._classify(band_alarm, stats, physical)
        result = self._held_drift(result, stats)
        test = self.host.physical_test
        if mon.alarm and test is not None:
            result = renamed_noise(self.host.config.patterns, result, test.axis_evidence())
        if stats is None:
            # pending classification: the blocks of the alarm so far (the test window
            # without alarm), so that the outputs never mix in data from before the alarm
            short = self.host._short_blocks
            k = mon.blocks_in_alarm if mon.alarm else short
            stats = mon.window_statistics(max(1, min(k, short)))
        alarm = mon.alarm or band_alarm or physical is not None
        if not alarm:
            kind = (0, 0, 0, "")
        elif result is None or result.fault_type < 0:
            kind = (-1, -1, -1, "unknown")
        else:
            kind = (result.fault_type, result.signal, result.axis, result.name)
        return DTGDiagnosis(
            reference_status=status, residual_alarm=mon.alarm, class_name=kind[3],
            fault_type=kind[0], fault_signal=kind[1], fault_axis=kind[2],
            distance=math.nan if result is None or not alarm else result.distance,
            size=math.nan if result is None or not alarm else result.size,
            rate=math.nan if result is None or not alarm else result.rate,
            ratio=math.nan if result is None or not alarm else result.ratio,
            signal_mask=0 if result is None or not alarm else result.signal_mask,
            level=stats.level, log_variance=stats.log_variance, growth=stats.growth,
            window_s=stats.window_s, tests=mon.statistics.copy(), block=block)

    def _held_drift(self, result: PatternResult | None,
                    stats: ClassificationStatistics | None) -> PatternResult | None:
        """A step whose level has grown steadily since the alarm is a drift, and a drift
        whose level still grows is not renamed a step."""
        if (result is None or stats is None or self._pattern is None
                or not stats.raw_signals  # in a manoeuvre the level's slope is not a drift's
                or result.fault_type != STEP_TYPE):
            return result
        prev = self.host.diagnosis
        held = (prev.fault_type == DRIFT_TYPE and result.signal == prev.fault_signal
                and (stats.growth_t >= DRIFT_HOLD_T
                     or stats.span_growth_t >= DRIFT_SPAN_HOLD_T))
        if held or stats.span_growth_t >= DRIFT_SPAN_T:
            return self._pattern.as_drift(result, stats) or result
        return result

    def _raw_signals_checked(self, stats: ClassificationStatistics
                             ) -> ClassificationStatistics:
        """The statistics with ``raw_signals`` False when the case rate moved in their
        window: the measured voltages then carry the manoeuvre (the torquer voltages
        rebalance H·ω), and their levels and variances, compared with a reference
        learned in other flight, would read as a fault of their own."""
        omega_dev = self.host._blocks.omega_dev
        if not self.host._case_rate or not omega_dev:
            return stats
        window = list(omega_dev)[-max(1, stats.window_blocks):]
        if max(window) > OMEGA_EXCITATION_Z:
            return replace(stats, raw_signals=False)
        return stats

    # -- state ------------------------------------------------------------------
    def get_state(self) -> dict[str, Any]:
        """Residual monitor and the estimators' rollback snapshots."""
        return {
            "monitor": None if self.monitor is None else self.monitor.get_state(),
            "rollback": None if self._rollback is None else list(self._rollback),
            "snapshots": [list(snap) for snap in self._snapshots],
            "pair_streak": self._pair_streak,
            "held_physical": (None if self._held_physical is None else
                              [self._held_physical.kind, self._held_physical.ratio,
                               self._held_physical.chi2]),
        }

    def set_state(self, state: dict[str, Any],
                  reference: NominalReference | None) -> None:
        """Restore :meth:`get_state` on the host's restored ``reference``."""
        def snapshot(raw: Any) -> tuple[Any, ...]:
            sx, sy, theta = raw
            return sx, sy, tuple(tuple(float(v) for v in row) for row in theta)

        host = self.host
        self._rollback = None if state["rollback"] is None else snapshot(state["rollback"])
        self._snapshots.clear()
        self._pair_streak = int(state["pair_streak"])
        held = state["held_physical"]
        self._held_physical = (None if held is None else PhysicalResult(
            alarm=True, kind=str(held[0]), ratio=float(held[1]), chi2=float(held[2])))
        for raw_snap in state["snapshots"]:
            self._snapshots.append(snapshot(raw_snap))
        if state["monitor"] is None:
            self.monitor = None
        else:
            assert reference is not None
            self.monitor = ResidualMonitor(reference, host._nb, host._nb * host.T,
                                           host._short_blocks, host._long_blocks,
                                           host.config.thresholds, host._clear_blocks,
                                           host._model)
            self.monitor.set_state(state["monitor"])
