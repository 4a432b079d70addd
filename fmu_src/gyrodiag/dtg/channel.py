"""The DTG diagnosis channel: prefilter → regressors → estimators → decision → class.

One object per monitored gyro, fed one sample of (Utx, Uty, Ux, Uy) per sample period.
It identifies θ on both axes with its own estimator each, learns the nominal reference
from an initial fault-free window (or takes θ0 as given) and runs the ratio band on
η = |θ|/|θ0|. Alarms and their classes come from one classifier object
(:mod:`gyrodiag.dtg.classifier`):

* ``"paper"`` (:class:`~gyrodiag.dtg.paper_rule.PaperRule`, the paper's rule, kept so
  that the seed scenarios reproduce it): the ratio band, classified by the nearest decade
  signature C = round(log10 η).
* ``"pattern"`` (default, :class:`~gyrodiag.dtg.pattern_rule.PatternRule`): residual
  tests against the frozen reference, classified by the learned pattern library; the
  ratio band still alarms too.

Settings are in :mod:`gyrodiag.dtg.config`, outputs in :mod:`gyrodiag.dtg.outputs`
(both importable from here too). The Diagnoser FMU only maps its variables onto this
class.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ..common.estimators import RLS, ForgettingRLS, SlidingWindowLS
from ..common.prefilter import ButterworthPrefilter, ringing_samples
from ..common.state import migrate, stamp
from .blocks import OMEGA_SPREAD_FLOOR, ReferenceBlocks  # noqa: F401  (re-exported)
from .case_rate import CaseRateDTGRegressor, physical_from_theta_central
from .classifier import ChannelClassifier
from .config import (  # noqa: F401  (re-exported: importable from here as before)
    AUTO_CUTOFF_FRACTION,
    AUTO_SETTINGS,
    BAND_SIGMA,
    BLOCK_S,
    CLASSIFIERS,
    ESTIMATOR_KINDS,
    ClassifierKind,
    DTGChannelConfig,
    EstimatorKind,
)
from .decision import ThresholdDecision
from .growth import LevelGrowth
from .model import N_THETA, DTGRegressor
from .outputs import (  # noqa: F401  (re-exported)
    STATUS_FAILED,
    STATUS_NOT_CHECKED,
    DTGChannelOutput,
    DTGDiagnosis,
    diagnosis_from_dict,
    diagnosis_to_dict,
    output_from_dict,
    output_to_dict,
    replace_output,
)
from .pairing import CaseRatePairing
from .paper_rule import PaperRule
from .pattern_rule import (  # noqa: F401  (re-exported)
    MASKED_SIGNAL_FIT,
    OMEGA_EXCITATION_Z,
    PatternRule,
)
from .physical_test import PhysicalTest
from .reference import NominalPrior, NominalReference, ReferenceLearner, ResidualMonitor

__all__ = ["DTGChannel"]

#: The classifier classes by ``DTGChannelConfig.classifier``.
_RULES: dict[str, type[ChannelClassifier]] = {"paper": PaperRule, "pattern": PatternRule}


class DTGChannel:
    """Streaming DTG parameter-identification diagnoser.

    Parameters
    ----------
    config : DTGChannelConfig
        Settings; validated here (ValueError naming the setting).
    """

    def __init__(self, config: DTGChannelConfig) -> None:
        config.validate()
        self.config = config
        self.T = float(config.sample_period_s)
        self._nb = config.block_samples
        self._short_blocks = config.blocks(config.window_s)
        self._long_blocks = max(config.blocks(config.long_window_s), self._short_blocks)
        self._clear_blocks = max(1, round(config.clear_after_s / (self._nb * self.T)))
        # sample indices of the learning window [n_start, n_end)
        self._n_start = math.ceil(config.learn_start_s / self.T - 1e-9)
        self._n_end = max(math.ceil(config.learn_end_s / self.T - 1e-9), self._n_start + 1)
        # rows left out after a skipped sample: the two regression rows that span it and
        # the prefilter's memory (impulse response above 1e-3 of its peak)
        self._gap_samples = 2 + (_ringing_samples(config, self.T)
                                 if config.prefilter_enabled else 0)
        self._model = config.regression
        self._case_rate = self._model.case_rate
        self._band_on = bool(config.ratio_band)
        self._central = config.case_rate == "central"
        self._width = self._model.width
        self._given_theta0: NDArray[np.float64] | None = (
            None if config.theta0 is None
            else np.broadcast_to(np.asarray(config.theta0, dtype=float),
                                 self.theta0_shape).copy())
        # the prior is the paper regression's θ0 (one for both axes); with the case rate
        # the reference is per axis and differs (θ5 in particular)
        self._prior: NominalPrior | None = (
            config.patterns.prior
            if config.patterns is not None and config.case_rate is None else None)
        self._pairing = CaseRatePairing(config, self._gap_samples)
        self._blocks = ReferenceBlocks(self._nb, self._width, self._long_blocks)
        self._rule: ChannelClassifier = _RULES[config.classifier](self)
        self.physical_test: PhysicalTest | None = (
            PhysicalTest(self.T, config.cutoff_hz, config.learn_start_s, config.learn_end_s,
                         config.physical_sigma, config.case_rate, config.pickoff_scale)
            if config.physical_test_on else None)
        self.reset()

    # -- construction helpers -------------------------------------------------
    def _make_decisions(self, theta0: NDArray[np.float64]) -> list[ThresholdDecision]:
        return _ratio_decisions(self.config, theta0)

    def adopt_theta0(self, theta0: NDArray[np.float64]) -> None:
        """Take ``theta0`` (shape :attr:`theta0_shape`) as θ0 with fresh ratio
        decisions."""
        self.theta0 = theta0
        self._decisions = self._make_decisions(theta0)

    @property
    def theta0_shape(self) -> tuple[int, ...]:
        """Shape of θ0: (5,) for both axes, (2, 5) per axis with the case rate."""
        return (2, N_THETA) if self._case_rate else (N_THETA,)

    def reset(self) -> None:
        """Return to the state right after construction."""
        c = self.config
        self._prefilter = (
            ButterworthPrefilter(
                c.prefilter_order, c.cutoff_hz, 1.0 / self.T, self._width,
                highpass_hz=c.prefilter_highpass_hz,
            )
            if c.prefilter_enabled
            else None
        )
        self._regressor: DTGRegressor | CaseRateDTGRegressor = (
            CaseRateDTGRegressor(self.T, c.pickoff_scale, scheme=c.case_rate)  # type: ignore[arg-type]
            if c.case_rate is not None else DTGRegressor())
        self._estimators = [_estimator(c), _estimator(c)]
        self._theta_now = tuple(tuple(e.theta.tolist()) for e in self._estimators)
        self._n_samples = 0
        # (5,) for both axes; (2, 5) per axis with the case rate
        self.theta0: NDArray[np.float64] | None = (
            None if self._given_theta0 is None else self._given_theta0.copy())
        self._decisions = None if self.theta0 is None else self._make_decisions(self.theta0)
        self._first_alarm_time = float("nan")
        self._blocks.reset()
        self._learner: ReferenceLearner | None = ReferenceLearner(
            self._nb, self._short_blocks, self._long_blocks, c.thresholds, self._nb * self.T,
            self._model)
        self.reference: NominalReference | None = None
        self._diagnosis = DTGDiagnosis()
        self._rule.reset()
        self._pairing.reset()
        if self.physical_test is not None:
            self.physical_test.reset()
        self._last = self._initial_output()

    case_rate_delay = property(lambda self: self._pairing.delay,
                               doc="Delay of the case rate against the voltages, samples.")
    case_rate_switches = property(lambda self: self._pairing.switches,
                                  doc="How often the aligner has changed the delay.")

    def _initial_output(self) -> DTGChannelOutput:
        return DTGChannelOutput(
            valid=True, learning=self.theta0 is None, theta=np.zeros((2, N_THETA)),
            eta=np.ones((2, N_THETA)), physical=np.full(N_THETA, np.nan), alarm=False,
            fault_code=0, feature=np.zeros(N_THETA, dtype=np.int64),
            first_alarm_time_s=float("nan"), diagnosis=self._diagnosis,
        )

    def _physical(self, th_x: tuple[float, ...], th_y: tuple[float, ...]
                  ) -> NDArray[np.float64]:
        if not self._central:
            return _physical(th_x, th_y, self.T)
        mean = 0.5 * (np.array(th_x) + np.array(th_y))
        try:
            return physical_from_theta_central(mean, self.T).as_array()
        except ValueError:
            return np.full(N_THETA, np.nan)

    @property
    def pattern_mode(self) -> bool:
        """The pattern classifier is configured."""
        return self._rule.kind == "pattern"

    @property
    def classifier(self) -> ChannelClassifier:
        """The classifier object (:class:`~gyrodiag.dtg.paper_rule.PaperRule` or
        :class:`~gyrodiag.dtg.pattern_rule.PatternRule`)."""
        return self._rule

    @property
    def monitor(self) -> ResidualMonitor | None:
        """The pattern classifier's residual monitor (None before the reference, and
        with the paper classifier)."""
        return getattr(self._rule, "monitor", None)

    @property
    def diagnosis(self) -> DTGDiagnosis:
        """The current block-rate diagnosis."""
        return self._diagnosis

    @property
    def samples(self) -> int:
        """Samples that have reached the estimators."""
        return self._n_samples

    # -- streaming ------------------------------------------------------------
    def update(self, Utx: float, Uty: float, Ux: float, Uy: float,
               omega_x: float = 0.0, omega_y: float = 0.0) -> DTGChannelOutput:
        """Process one sample and return the channel outputs.

        Parameters
        ----------
        Utx, Uty, Ux, Uy : float
            Pick-off and torquer voltages, V.
        omega_x, omega_y : float
            Case rates about the gyro's x and y axes held over the sample, rad/s (an
            independent estimate); used only when ``config.case_rate`` is set.

        A sample with any NaN/Inf (case rates included when they are used) is skipped:
        the state is untouched and the previous outputs are returned with
        ``valid=False``.
        """
        raw = (float(Utx), float(Uty), float(Ux), float(Uy))
        if self._case_rate:
            w = (float(omega_x), float(omega_y))
            ok = math.isfinite(w[0]) and math.isfinite(w[1])
        else:
            ok = True
        if not (ok and math.isfinite(raw[0]) and math.isfinite(raw[1])
                and math.isfinite(raw[2]) and math.isfinite(raw[3])):
            # the regression rows spanning the gap, and the prefilter's ringing after it,
            # are left out of the reference statistics (a one-sample jump would look
            # like a burst of noise)
            if self._pairing.shifting:
                self._pairing.mark_gap()
            else:
                self._mark_gap()
            self._last = replace_output(self._last, valid=False)
            return self._last
        # raw was checked finite above; the stages downstream need not check again
        signals = raw + w if self._case_rate else raw
        sample = (tuple(self._prefilter.step(signals)) if self._prefilter is not None
                  else signals)
        if self._pairing.shifting:
            pair = self._pairing.pair(raw, sample)
            if pair is None:
                return self._last
            raw, sample, gap = pair
            if gap:
                self._mark_gap()
        if self.physical_test is not None:
            self.physical_test.update(sample, self._rule.holds_physical_test())
        return self._identify(raw, sample)

    def _mark_gap(self) -> None:
        """Leave the rows and blocks spanning a skipped sample out."""
        self._blocks.gap = self._gap_samples
        if self.physical_test is not None:
            self.physical_test.gap()

    def _identify(self, raw: tuple[float, ...], sample: tuple[float, ...]
                  ) -> DTGChannelOutput:
        """Estimate θ from a (paired) filtered sample, collect the reference blocks and
        decide."""
        n = self._n_samples
        t = n * self.T
        self._n_samples += 1
        if self._case_rate:
            rows = self._regressor.update(*sample, validate=False)  # type: ignore[call-arg]
        else:
            rows = self._regressor.step(*sample)  # type: ignore[union-attr]
        if rows is not None and self._case_rate and n < self._gap_samples:
            # a case-rate channel may start in a manoeuvre (off trim: ω ≠ 0, torquer
            # voltages at L·ω/Ku): the prefilter, from zero state, shows every signal
            # jumping at t = 0, a ½s·Δω impulse on the y line that the rotor never had;
            # its rows are left out until the filter's start has rung down, as after a gap
            rows = None
        if rows is not None:
            self._theta_now = (self._estimators[0].step(rows[0], rows[1]),
                               self._estimators[1].step(rows[2], rows[3]))
        th_x, th_y = self._theta_now
        block_done = self._collect(n, raw, sample, th_x + th_y)
        th_x, th_y = self._theta_now  # rolled back if the residual alarm just cleared
        theta = np.array((th_x, th_y))

        if self.theta0 is None:
            theta0 = self._rule.learn(t, theta)
            if theta0 is not None:
                self.adopt_theta0(theta0)
        if self.theta0 is None or self._decisions is None:
            self._last = DTGChannelOutput(
                True, not self.reference_failed, theta, np.ones((2, N_THETA)),
                self._physical(th_x, th_y), False, 0, np.zeros(N_THETA, dtype=np.int64),
                self._first_alarm_time, self._diagnosis,
            )
            return self._last

        confirm_x, confirm_y = self._rule.confirm_hooks()
        eta_x, alarm_x = self._decisions[0].step(th_x, confirm_x)
        eta_y, alarm_y = self._decisions[1].step(th_y, confirm_y)
        eta = np.array((eta_x, eta_y))
        physical = self._physical(th_x, th_y)
        alarm, code, feature, self._diagnosis = self._rule.decide(
            t, (eta_x, eta_y), (alarm_x or alarm_y) and self._band_on, block_done)
        if alarm and math.isnan(self._first_alarm_time):
            self._first_alarm_time = t
        self._last = DTGChannelOutput(
            True, False, theta, eta, physical, alarm, code, feature,
            self._first_alarm_time, self._diagnosis,
        )
        return self._last

    def class_name(self, code: int) -> str:
        """Name of a ``fault_code``: its class (pattern library or signature table),
        "" for 0 (no fault), "unknown" otherwise."""
        return self._rule.class_name(code)

    # -- reference blocks -----------------------------------------------------
    def _collect(self, n: int, raw: tuple[float, ...], sample: tuple[float, ...],
                 theta: tuple[float, ...]) -> bool:
        """Buffer one sample into the reference blocks; True when a runtime block ended.

        Blocks start at the learning window's first sample and again at its end (the
        partial block before the end is dropped); the learner gets the learning blocks,
        the classifier the blocks after.
        """
        blocks = self._blocks
        if n == self._n_start or n == self._n_end:
            # restart the block grid; the two samples before become the history
            blocks.next_block()
            if n == self._n_start and self._learner is not None:
                self._learner.set_history(np.array(blocks.history))
            if n == self._n_end:
                self._finish_learning()
        if not blocks.append(raw, sample, theta):
            return False
        done = False
        learning = self._n_start <= n < self._n_end
        if self._case_rate:
            blocks.omega_block(learning)
        if learning:
            if self._learner is not None:
                self._learner.push_block(*blocks.arrays())
        elif n >= self._n_end:
            done = self._rule.end_block(theta)
        # the two samples before the next block (a block may hold a single sample)
        blocks.next_block()
        return done

    def _finish_learning(self) -> None:
        """Build the checked reference at the end of the learning window."""
        learner = self._learner
        if learner is None:
            return
        try:
            ref = learner.finish(None if self._given_theta0 is None
                                 else self._given_theta0.ravel(), self._prior)
        except ValueError:
            self._learner = None
            self._diagnosis = DTGDiagnosis(reference_status=self._rule.failed_status,
                                           block=self._diagnosis.block + 1)
            return
        self.reference = ref
        self._rule.on_reference(ref, learner)
        self._learner = None  # its data are no longer needed
        self._diagnosis = DTGDiagnosis(reference_status=ref.status,
                                       block=self._diagnosis.block + 1)

    @property
    def reference_failed(self) -> bool:
        """True once the learning window has ended without a usable θ0 (a zero entry:
        no excitation); the channel then never alarms."""
        return self._rule.reference_failed()

    # -- state ----------------------------------------------------------------
    def get_state(self) -> dict[str, Any]:
        """Full internal state (filters, estimators, decisions, reference blocks,
        reference, classifier, outputs, case-rate pairing), tagged with
        :data:`STATE_VERSION`."""
        buffers, omega = self._blocks.get_state()
        return stamp({
            "prefilter": None if self._prefilter is None else self._prefilter.get_state(),
            "regressor": self._regressor.get_state(),
            "estimators": [e.get_state() for e in self._estimators],
            "n_samples": self._n_samples,
            "theta0": None if self.theta0 is None else self.theta0.copy(),
            "decisions": None
            if self._decisions is None
            else [d.get_state() for d in self._decisions],
            "first_alarm_time": self._first_alarm_time,
            "buffers": buffers,
            "omega": omega,
            "learner": None if self._learner is None else self._learner.get_state(),
            "reference": None if self.reference is None else self.reference.get_state(),
            "classifier": self._rule.get_state(),
            "diagnosis": diagnosis_to_dict(self._diagnosis),
            "last": output_to_dict(self._last),
            "alignment": self._pairing.get_state(),
            "physical_test": (None if self.physical_test is None
                              else self.physical_test.get_state()),
        }, STATE_VERSION)

    def set_state(self, state: dict[str, Any]) -> None:
        """Restore a state produced by :meth:`get_state` of an identically configured
        channel (an older state version is migrated first)."""
        state = migrate(state, STATE_VERSION, _MIGRATIONS, "DTG channel")
        ref = state["reference"]
        reference = None if ref is None else NominalReference.from_state(ref)
        # first: a state of another classify_window_s leaves this channel untouched
        self._rule.set_state(state["classifier"], reference)
        buffers = state["buffers"]
        raw = np.asarray(buffers["raw"], dtype=float).reshape(-1, 4)
        if raw.shape[0] >= self._nb:
            raise ValueError(f"state['buffers'] hold {raw.shape[0]} samples of a block, this "
                             f"channel's blocks have {self._nb} (another sample period?)")
        if (state["prefilter"] is None) != (self._prefilter is None):
            raise ValueError("state['prefilter'] does not match prefilter_enabled")
        if self._prefilter is not None:
            self._prefilter.set_state(state["prefilter"])
        self._regressor.set_state(state["regressor"])
        for e, s in zip(self._estimators, state["estimators"], strict=True):
            e.set_state(s)
        self._n_samples = int(state["n_samples"])
        t0 = state["theta0"]
        self.theta0 = None if t0 is None else np.asarray(t0, dtype=float).copy()
        if state["decisions"] is None:
            self._decisions = None
        else:
            assert self.theta0 is not None
            self._decisions = self._make_decisions(self.theta0)
            for d, s in zip(self._decisions, state["decisions"], strict=True):
                d.set_state(s)
        self._first_alarm_time = float(state["first_alarm_time"])
        self._blocks.set_state(buffers, state["omega"])
        self._theta_now = tuple(tuple(e.theta.tolist()) for e in self._estimators)
        if state["learner"] is None:
            self._learner = None
        else:
            c = self.config
            self._learner = ReferenceLearner(self._nb, self._short_blocks, self._long_blocks,
                                             c.thresholds, self._nb * self.T, self._model)
            self._learner.set_state(state["learner"])
        self.reference = reference
        self._diagnosis = diagnosis_from_dict(state["diagnosis"])
        self._last = output_from_dict(state["last"], self._diagnosis)
        self._pairing.set_state(state["alignment"])
        _restore_test(self.physical_test, state["physical_test"], self._n_samples)

    @property
    def last_output(self) -> DTGChannelOutput:
        """Outputs of the most recent update (initial outputs before any)."""
        return self._last


def _estimator(c: DTGChannelConfig) -> RLS | SlidingWindowLS:
    """A fresh θ estimator of the configured kind."""
    if c.estimator == "batch":
        return SlidingWindowLS(N_THETA, window=c.window)
    if c.estimator == "rls":
        return RLS(N_THETA, p0=c.p0)
    return ForgettingRLS(N_THETA, forgetting=c.forgetting, p0=c.p0)


def _ratio_decisions(c: DTGChannelConfig, theta0: NDArray[np.float64]
                     ) -> list[ThresholdDecision]:
    """One ratio decision per axis; θ0 (5,) for both or (2, 5) per axis."""
    per_axis = theta0.reshape(-1, N_THETA)
    return [ThresholdDecision(per_axis[min(i, per_axis.shape[0] - 1)], c.low, c.high,
                              c.persistence_k, c.persistence_n, c.latch, c.monitored)
            for i in range(2)]


def _restore_test(test: PhysicalTest | None, saved: dict[str, Any] | None,
                  samples: int) -> None:
    """Restore the physical-parameter test; one saved without it (an older state) starts
    afresh with its learning window past, i.e. quiet."""
    if test is None:
        return
    if saved is None:
        test.reset(samples)
    else:
        test.set_state(saved)


def _ringing_samples(config: DTGChannelConfig, T: float) -> int:
    """Samples after which the prefilter's impulse response stays below 1e-3 of its
    peak."""
    return ringing_samples(ButterworthPrefilter(
        config.prefilter_order, config.cutoff_hz, 1.0 / T,
        highpass_hz=config.prefilter_highpass_hz), 4096)


def _physical(th_x: tuple[float, ...], th_y: tuple[float, ...],
              T: float) -> NDArray[np.float64]:
    """:func:`~gyrodiag.dtg.model.physical_from_theta` of the mean θ of both axes, on plain
    floats (same operations, same values); NaN where the inversion is undefined."""
    t1 = (th_x[0] + th_y[0]) / 2.0
    t2 = (th_x[1] + th_y[1]) / 2.0
    if t2 == 0.0:
        return np.full(N_THETA, np.nan)
    t3 = (th_x[2] + th_y[2]) / 2.0
    t4 = (th_x[3] + th_y[3]) / 2.0
    t5 = (th_x[4] + th_y[4]) / 2.0
    T2 = T**2
    return np.array([(t1 - 2.0 * t2) / (t2 * T), (1.0 - t1 + t2) / (t2 * T2),
                     t4 / (t2 * T), (t3 - t4) / (t2 * T2), t5 / (t2 * T2)])


#: Version of :meth:`DTGChannel.get_state`'s format (1: tagged; case rate and alignment
#: always present; 2: the classifier's part under "classifier"; 3: the diagnosis's
#: signal mask and the pattern classifier's pair count; 4: the physical-parameter test;
#: 5: the residual level's growth since the alarm, the held physical verdict; 6: the
#: physical test's fit over a hold).
STATE_VERSION = 6
#: Keys of a version-1 state that belong to a classifier (paper: the first three;
#: pattern: the last three; a version-1 state holds all six).
_CLASSIFIER_KEYS = ("features", "learn_sum", "learn_count", "monitor", "rollback",
                    "snapshots")


def _from_version_0(state: dict[str, Any]) -> dict[str, Any]:
    """Unversioned states may lack the case-rate part and the alignment queue."""
    out = dict(state)
    out.setdefault("omega", {"learn": np.zeros((0, 2)), "ref": None,
                             "deviation": np.zeros(0)})
    out.setdefault("alignment", None)
    return out


def _from_version_1(state: dict[str, Any]) -> dict[str, Any]:
    """The classifier's keys move under "classifier" (each classifier reads its own)."""
    out = dict(state)
    out["classifier"] = {key: out.pop(key) for key in _CLASSIFIER_KEYS}
    return out


def _from_version_2(state: dict[str, Any]) -> dict[str, Any]:
    """The diagnosis gains its signal mask (the one signal it names, if any), the
    pattern classifier its count of pair wins."""
    diagnosis = dict(state["diagnosis"])
    signal = int(diagnosis["fault_signal"])
    diagnosis["signal_mask"] = 1 << (signal - 1) if signal > 0 else 0
    classifier = dict(state["classifier"])
    if "monitor" in classifier:
        classifier["pair_streak"] = 0
    return {**state, "diagnosis": diagnosis, "classifier": classifier}


def _from_version_3(state: dict[str, Any]) -> dict[str, Any]:
    """No physical-parameter test was saved: it starts afresh (and stays quiet, its
    learning window being past)."""
    return {**state, "physical_test": None}


def _from_version_4(state: dict[str, Any]) -> dict[str, Any]:
    """No growth record was saved: the level's span since the alarm starts afresh; no
    physical verdict is held."""
    classifier = dict(state["classifier"])
    if isinstance(classifier.get("monitor"), dict):
        classifier["monitor"] = {**classifier["monitor"],
                                 "growth": LevelGrowth().get_state()}
    if "pair_streak" in classifier:
        classifier["held_physical"] = None
    return {**state, "classifier": classifier}


def _from_version_5(state: dict[str, Any]) -> dict[str, Any]:
    """No fit over a hold was saved: it starts with the next hold."""
    test = state["physical_test"]
    return {**state, "physical_test": None if test is None else {**test, "held": None}}


_MIGRATIONS = {0: _from_version_0, 1: _from_version_1, 2: _from_version_2,
               3: _from_version_3, 4: _from_version_4, 5: _from_version_5}
