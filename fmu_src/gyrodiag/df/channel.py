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

Each rule is a strategy behind :class:`~gyrodiag.df.decision.DFDecision`
(:mod:`gyrodiag.df.paper_rule`, :mod:`gyrodiag.df.sequential_rule`); the channel streams,
aligns, equalises and keeps the calibration window, the rule decides. The settings are
in :mod:`gyrodiag.df.channel_config`, the output record in :mod:`gyrodiag.df.channel_output`,
the window's fits in :mod:`gyrodiag.df.calibration`.

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
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..common.state import migrate, stamp
from .calibration import CalibrationWindow, DFDesign, alignment_score, window_pairs
from .channel_config import CAL_MIN_SAMPLES
from .channel_config import DECISION_AUTO as DECISION_AUTO
from .channel_config import DECISIONS as DECISIONS
from .channel_config import DFChannelConfig as DFChannelConfig
from .channel_config import decision_rule as decision_rule
from .channel_output import NONE_DETECTED, invalid_output, output_from_state, output_state
from .channel_output import DFChannelOutput as DFChannelOutput
from .decision import RULE_STATE_KEYS, DFDecision
from .filter import DetectionFilter, design_detection_filter
from .isolation import FaultType, SensorFaultIsolator
from .paper_rule import PaperRule
from .sensor_dynamics import SensorDynamicsEqualiser
from .sequential_diagnosis import SequentialDiagnoser
from .sequential_rule import SequentialRule

# DECISIONS, DECISION_AUTO, DFChannelConfig, DFChannelOutput and decision_rule are
# re-exported from their modules (imported from here before the split)
__all__ = ["DFChannel"]

#: The decision rules by name (:data:`DECISIONS`).
_RULES: dict[str, type[DFDecision]] = {"paper": PaperRule, "sequential": SequentialRule}


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
        self._design = DFDesign(A, B, C, self.K, self.T, x0, self._monitor)
        self._rule: DFDecision = _RULES[config.decision](self._design, config)
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
        # the sensors before the equaliser (the white noise of those it filters)
        self._cal_raw = np.zeros(self._raw_shape())
        self._skew_line: deque[tuple[NDArray[np.float64], NDArray[np.float64]]] = deque(
            maxlen=self._skew_max + 1)
        self._rule.reset()
        self._monitor.reset(self._x0)
        if self._equaliser is not None:
            self._equaliser.reset()
        self._calibrated = False
        self._last = self._initial_output()
        if self._n_cal == 0:
            self._install(None)

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
        thresholds = self._rule.thresholds
        if thresholds is None:
            return None
        return [t.copy() for t in thresholds]

    @property
    def cusum_thresholds(self) -> tuple[float, float] | None:
        """Sequential rule: (mean-CUSUM threshold σ, variance-CUSUM threshold)."""
        return self._rule.cusum_thresholds

    @property
    def noise_std(self) -> NDArray[np.float64] | None:
        """Sensor noise standard deviations in use (sensor units), once calibrated."""
        noise = self._rule.noise_std
        return None if noise is None else noise.copy()

    @property
    def gust_note(self) -> str:
        """Why the gust model is not in use after calibration ("" when it is, or when
        none is configured)."""
        return self._rule.gust_note

    @property
    def gust_in_use(self) -> bool:
        """The sequential engine models the turbulence."""
        return self._rule.gust_in_use

    @property
    def engine(self) -> SensorFaultIsolator | SequentialDiagnoser | None:
        """The decision object (None while calibrating)."""
        return self._rule.engine

    @property
    def _engine(self) -> SensorFaultIsolator | SequentialDiagnoser | None:
        """:attr:`engine` (the name tests and benchmarks read)."""
        return self._rule.engine

    @property
    def rule(self) -> DFDecision:
        """The decision rule (strategy) the channel composes."""
        return self._rule

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
                self._last = invalid_output(self._last)
                return self._last
        if self._skew_max:
            line = self._skew_line
            line.append((uu, yy))
            if len(line) <= self._skew_max:
                return self._last
            # u and the on-time sensors from max(e) samples back, sensor j from e_j
            uu = line[0][0]
            yy = np.array([line[e][1][i] for i, e in enumerate(self._skew)])
        raw = yy
        if self._equaliser is not None:
            uu, yy = self._equaliser.update(uu, yy, validate=False)
        k = self._n_samples
        self._n_samples = k + 1
        if not self._calibrated:
            self._cal_u[k], self._cal_y[k] = uu, yy
            if self._cal_raw.shape[0]:
                self._cal_raw[k] = raw
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
        self._last = self._rule.decide(*pair, self._delay)
        return self._last

    def update_floats(self, u: Sequence[float], y: Sequence[float]) -> DFChannelOutput:
        """:meth:`update` for a host that holds the sample as plain floats (``p`` and
        ``m`` of them; the lengths are the caller's to get right): the same outputs and
        state change, without the array conversions on the per-sample path of the
        calibrated sequential decision."""
        total = sum(u) + sum(y)
        rule = self._rule
        if not (total - total == 0.0 and self._calibrated and self._delay == 0
                and self._equaliser is None and not self._skew_max and rule.stacked):
            return self.update(u, y)  # NaN/inf, calibration, a delay line, the paper rule
        self._n_samples += 1
        self._last = rule.decide_stacked(np.array((*u, *y)), 0)
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

    # ------------------------------------------------------------------ calibration

    def _raw_shape(self) -> tuple[int, int]:
        """Shape of the raw window: kept only in front of an equaliser."""
        return (self._n_cal if self._equaliser is not None else 0, self.m)

    def _pairs(self, d: int) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Aligned (u, y) rows of the stored window for alignment d."""
        return window_pairs(self._cal_u, self._cal_y, d)

    def _window(self, d: int) -> CalibrationWindow:
        """The stored window at alignment d, its burn-in shortened for a short one."""
        u, y = self._pairs(d)
        burn = min(self._n_burn, max(u.shape[0] - 10, 0))
        raw = self._cal_raw
        usable = raw.shape[0] > 0 and bool(np.all(np.isfinite(raw)))
        return CalibrationWindow(u, y, burn, self._n_burn, raw if usable else None)

    def _choose_alignment(self) -> int:
        """The alignment d whose window residuals are the whitest (module notes)."""
        c = self.config
        if not c.aligns:
            return int(c.input_delay_samples)
        # every pairing scored alike: by the gust model's innovations when each window
        # is long enough to fit a noise model to, else by the residual variance
        by_model = (c.gust is not None and
                    self._n_cal - self._n_burn - int(c.align_max) >= 4 * CAL_MIN_SAMPLES)
        scores = {}
        for d in range(-int(c.align_max), int(c.align_max) + 1):
            w = self._window(d)
            res = self._design.residuals(w.u, w.y)[w.burn:]
            scores[d] = alignment_score(self._design, res, c.gust if by_model else None)
        best = min(scores.values())
        configured = int(c.input_delay_samples)
        # equal within rounding: the inputs did not move; keep the configured pairing
        if configured in scores and scores[configured] - best <= 1e-9 * max(1.0, abs(best)):
            return configured
        return min(scores, key=scores.__getitem__)

    def _finish_calibration(self) -> None:
        self._delay = self._choose_alignment()
        self._install(self._window(self._delay))
        # the delay line continues from the end of the window
        d = self._delay
        self._u_line = [row for row in self._cal_u[self._n_cal - d:]] if d > 0 else []
        self._y_line = [row for row in self._cal_y[self._n_cal + d:]] if d < 0 else []
        self._cal_u = np.zeros((0, self.p))
        self._cal_y = np.zeros((0, self.m))
        self._cal_raw = np.zeros((0, self.m))
        self._calibrated = True

    def _install(self, window: CalibrationWindow | None) -> None:
        """Install the decision rule from the aligned window (or from the given
        thresholds / noise when there is no window)."""
        self._rule.install(window)
        self._calibrated = True

    # ------------------------------------------------------------------ state

    def get_state(self) -> dict[str, Any]:
        """Full internal state (engine, alignment, window, outputs)."""
        rule = self._rule
        if rule.engine is None:  # calibrating: nothing installed
            parts = dict.fromkeys(RULE_STATE_KEYS)
            parts["gust_note"] = rule.gust_note
        else:
            parts = rule.get_state()
        return stamp({
            "n_samples": self._n_samples,
            "calibrated": self._calibrated,
            "delay": self._delay,
            "u_line": np.array(self._u_line).reshape(-1, self.p),
            "y_line": np.array(self._y_line).reshape(-1, self.m),
            "cal_u": self._cal_u.copy(), "cal_y": self._cal_y.copy(),
            "cal_raw": self._cal_raw.copy(),
            "monitor": self._monitor.get_state(),
            # the rule's part: noise, gust note, noise variances, engine, thresholds
            **{key: parts[key] for key in RULE_STATE_KEYS},
            "last": output_state(self._last),
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
        eq = state["equaliser"]
        if (eq is None) != (self._equaliser is None):
            raise ValueError("state['equaliser'] does not match sensor_dynamics (a state of "
                             "a channel with other read-out dynamics)")
        if self._equaliser is not None:
            self._equaliser.set_state(eq)
        calibrated = bool(state["calibrated"])
        delay = int(state["delay"])
        if "noise_std" not in state:  # refused, calibrated or not
            raise KeyError("noise_std")
        if calibrated:
            self._delay = delay
            self._rule.set_state(state, has_window=self._n_cal > 0)
        else:
            self._rule.uninstall()
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
        raw = (np.full(self._raw_shape(), np.nan) if state["cal_raw"] is None
               else np.asarray(state["cal_raw"], dtype=float))
        if calibrated:
            raw = np.zeros((0, self.m))
        elif raw.shape != self._raw_shape():
            raise ValueError("state['cal_raw'] does not fit the calibration window of "
                             "this channel")
        self._cal_raw = raw.copy()
        self._monitor.set_state(state["monitor"])
        self._last = output_from_state(state["last"])
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


#: Version of :meth:`DFChannel.get_state`'s format (1: tagged; equaliser,
#: sensor skew and threshold statistics always present; 2: the raw window; 3: the
#: presence test's growth record).
STATE_VERSION = 3


def _from_version_0(state: dict[str, Any]) -> dict[str, Any]:
    """Unversioned states may lack the equaliser, the sensor skew line and the
    threshold statistics."""
    out = dict(state)
    out.setdefault("equaliser", None)
    out.setdefault("skew_u", [])
    out.setdefault("skew_y", [])
    out.setdefault("threshold_stats", None)
    return out


def _from_version_1(state: dict[str, Any]) -> dict[str, Any]:
    """Version 1 kept no raw window (the noise is then fitted to the residual alone)."""
    return {**state, "cal_raw": None}


def _from_version_2(state: dict[str, Any]) -> dict[str, Any]:
    """Version 2's sequential engine kept no record of the presence misfit's sign."""
    engine = state.get("engine")
    if not isinstance(engine, dict) or "hist_c" not in engine:
        return state
    n_hist = np.asarray(engine["hist_c"]).shape[0]
    return {**state, "engine": {**engine, "hist_p": np.zeros(n_hist), "presence_grew": 0}}


_MIGRATIONS = {0: _from_version_0, 1: _from_version_1, 2: _from_version_2}
