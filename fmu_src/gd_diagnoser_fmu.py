"""Diagnoser.fmu: the gyrodiag algorithm library as an FMI 2.0 co-simulation FMU.

A thin facade: it declares the variables, builds the library's channel objects from
the parameters when initialisation ends, feeds them one sample per communication step
and copies their outputs. All the diagnosis lives in the ``gyrodiag`` package, shipped
in the FMU's resources.

Channels (each can be switched off):

* DTG: parameter identification of a dynamically tuned gyro (``gyrodiag.dtg.channel``).
* Grey: grey-prediction fault detection of one signal, e.g. an HRG output
  (``gyrodiag.grey``).
* Detection filter: sensor-fault detection and isolation on a linear plant, by default
  the seed aircraft (``gyrodiag.df.channel``).

Sampled-data contract: a ``doStep`` of n sample periods (h = n·``sample_period_s``,
n ≥ 1, relative tolerance 1e−6) makes every enabled channel process n samples, at the
times t, t + T, …, t + (n−1)·T, all from the inputs set before the step (held over the
step); the outputs after the step describe the last of them (``dtg.first_alarm_time``
and the latched ``df.detected`` keep what happened inside the step). Any other step is
refused with fmi2Error and consumes no sample. Run several instances for channels at
different rates.

Errors: an invalid parameter, a wrong step or an unexpected exception is logged through
the FMU logger with the parameter name and allowed range, and the call returns
fmi2Error (never fmi2Fatal): the status shim in the FMU binary maps the logged error.
NaN/Inf on a channel's input clears that channel's ``valid`` output, leaves its state
untouched, and the channel resumes on the next valid sample: its outputs are then those
of a run without that sample (the channels' own clocks count valid samples, e.g. for the
learning and calibration windows). One exception: the DTG channel remembers the gap and
leaves the regression rows that span it, and the prefilter's ringing after it, out of
its reference statistics (a one-sample jump in the signals would look like a noise
burst). Reported times (``dtg.first_alarm_time``) are simulation times.
"""

from __future__ import annotations

import contextlib
import json
import math
import operator
import re
from collections.abc import Iterator
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from gd_fmu_base import FacadeBase, sample_instants, samples_in_step
from pythonfmu import DefaultExperiment
from pythonfmu.enums import Fmi2Status

from gyrodiag.df.plant import seed_aircraft
from gyrodiag.dtg.case_rate import CASE_RATE_SCHEMES
from gyrodiag.dtg.channel import (
    BAND_SIGMA,
    CLASSIFIERS,
    ESTIMATOR_KINDS,
    DTGChannel,
    DTGChannelConfig,
    DTGChannelOutput,
)
from gyrodiag.dtg.model import N_THETA
from gyrodiag.dtg.patterns import PatternLibrary, default_library
from gyrodiag.dtg.reference import ALLOWANCE_SIGMA, CHANNELS, N_CHANNELS, POWER_THRESHOLD
from gyrodiag.grey import ClassicGreyPredictor, GreyFaultDetector, ImprovedGreyPredictor
from gyrodiag.grey.decision import (
    DEFAULT_LEARN_END_S,
    CalibratedKSigma,
    CalibratedSequential,
    GreyDecision,
    PaperThreshold,
)

if TYPE_CHECKING:  # imported when the channel is built: it needs SciPy (design time)
    from gyrodiag.df.channel import DFChannel, DFChannelConfig, DFChannelOutput

#: The shipped pattern library in the FMU's resources.
DEFAULT_LIBRARY_RESOURCE = "gyrodiag/dtg/default_patterns.json"
#: Signatures that fit in the parameter table (more: use ``dtg.signature_file``).
MAX_SIGNATURES = 8
#: Fault codes of the summary output ``fault_code``.
SUMMARY_CODE_BASE = {"dtg": 100, "grey": 200, "df": 300}
#: Summary code offsets of the detection filter beyond a sensor number.
DF_NOT_ISOLATED, DF_MULTIPLE = -1, -2

SEED = seed_aircraft()
#: Detection-filter dimensions: states, inputs, sensors (those of the seed aircraft).
DF_N, DF_P, DF_M = SEED.A.shape[0], SEED.B.shape[1], SEED.C.shape[0]
#: df.decision code of the automatic choice (the default; gyrodiag.df.channel's).
DF_DECISION_AUTO = 2

PHYSICAL_NAMES = ("c_over_J", "k_over_J", "L_over_J", "lambda_over_J", "Ku_over_KT_J")
#: Units of the DTG statistics channels (Utx, Uty, Ux, Uy, ex, ey).
CHANNEL_TEXT = "Utx, Uty, Ux, Uy, residual x, residual y"
PHYSICAL_UNITS = ("1/s", "1/s2", "rad/s", "1/s2", "1/s2")
#: Declared unit of the grey channel's signal (the HRG output voltage it was made for).
GREY_UNIT = "V"
#: grey.decision codes -> the rule (gyrodiag.grey.decision); 1, the sequential rule, is
#: the default, 0 the paper's fixed threshold.
GREY_DECISIONS = {0: PaperThreshold, 1: CalibratedSequential, 2: CalibratedKSigma}
GREY_DECISION_DEFAULT = 1

#: Packages the host's Python needs (written to resources/requirements.txt).
# SciPy only for the detection filter and the grey channel's learned rules (a clear
# fmi2Error names them without it): DTG and the paper's grey rule run on numpy alone
REQUIREMENTS = ["numpy>=1.24", "scipy>=1.10  # optional at start-up"]

VARIABLE_META: dict[str, dict[str, Any]] = {}
#: Lower bound declared for parameters that must be > 0 (FMI bounds are inclusive).
POSITIVE = 1e-9
#: Default df.gust_sigma_w: MIL-F-8785C's severe low-altitude turbulence, m/s.
DF_GUST_SIGMA_W = 2.3
#: Value of a Real (AUTO) or Integer (AUTO_INT) parameter that takes its automatic value.
AUTO = -1.0
AUTO_INT = -1
#: Parameters that may change between steps; a change applies from the next sample
#: (the channel is rebuilt with the new value and takes over the old one's state).
TUNABLE = {
    "dtg": ("dtg.low", "dtg.high", "dtg.persistence_k", "dtg.latch", "dtg.max_distance",
            "dtg.band_sigma",
            *(f"dtg.monitored[{i}]" for i in range(1, N_THETA + 1)),
            # the pattern classifier's residual tests (the monitor is rebuilt with them)
            "dtg.level_threshold", "dtg.var_threshold", "dtg.long_var_threshold",
            "dtg.power_threshold", "dtg.allowance_sigma"),
    "grey": ("grey.threshold", "grey.threshold_floor", "grey.clear_after_s"),
}
_TUNABLE_NAMES = frozenset(n for names in TUNABLE.values() for n in names)

# Variable names used at every step, formatted once (an f-string per variable per step
# cost ~10 % of a step).
_DTG_INPUT_KEYS = ("dtg.Utx", "dtg.Uty", "dtg.Ux", "dtg.Uy", "dtg.case_rate_x",
                   "dtg.case_rate_y")
_dtg_inputs = operator.itemgetter(*_DTG_INPUT_KEYS)
_DTG_THETA_KEYS = tuple(tuple(f"dtg.theta_{axis}[{i + 1}]" for i in range(N_THETA))
                        for axis in ("x", "y"))
_DTG_ETA_KEYS = tuple(tuple(f"dtg.eta_{axis}[{i + 1}]" for i in range(N_THETA))
                      for axis in ("x", "y"))
_DTG_THETA_FLAT_KEYS = tuple(k for row in _DTG_THETA_KEYS for k in row)
_DTG_ETA_FLAT_KEYS = tuple(k for row in _DTG_ETA_KEYS for k in row)
_DTG_THETA_ETA_KEYS = _DTG_THETA_FLAT_KEYS + _DTG_ETA_FLAT_KEYS
_DTG_THETA0_KEYS = tuple(f"dtg.theta0_used[{i + 1}]" for i in range(N_THETA))
_DTG_THETA0_Y_KEYS = tuple(f"dtg.theta0_used_y[{i + 1}]" for i in range(N_THETA))
#: dtg.case_rate codes (0: the paper's regression, the case at rest).
DTG_CASE_RATE_CODES = (None, *CASE_RATE_SCHEMES)
_DTG_PHYSICAL_KEYS = tuple(f"dtg.{name}" for name in PHYSICAL_NAMES)
_ZEROS_5 = (0.0,) * N_THETA
_DF_U_KEYS = tuple(f"df.u[{j + 1}]" for j in range(DF_P))
_DF_Y_KEYS = tuple(f"df.y[{i + 1}]" for i in range(DF_M))
_df_u = operator.itemgetter(*_DF_U_KEYS)
_df_y = operator.itemgetter(*_DF_Y_KEYS)
_DF_RESIDUAL_KEYS = tuple(f"df.residual[{i + 1}]" for i in range(DF_M))
_DF_ALARM_KEYS = tuple(f"df.alarm[{i + 1}]" for i in range(DF_M))
_DF_THRESHOLD_KEYS = tuple(f"df.threshold_in_use[{i + 1}]" for i in range(DF_M))
_DF_STATISTIC_KEYS = tuple(f"df.statistic[{i + 1}]" for i in range(DF_M))
_DF_SENSOR_TYPE_KEYS = tuple(f"df.sensor_fault_type[{i + 1}]" for i in range(DF_M))
_DF_OFFSET_KEYS = tuple(f"df.fault_offset[{i + 1}]" for i in range(DF_M))
_DF_GAIN_KEYS = tuple(f"df.fault_gain[{i + 1}]" for i in range(DF_M))
_DF_RATE_KEYS = tuple(f"df.fault_rate[{i + 1}]" for i in range(DF_M))
_DF_NOISE_RATIO_KEYS = tuple(f"df.noise_ratio[{i + 1}]" for i in range(DF_M))
_DF_NOISE_STD_KEYS = tuple(f"df.noise_std_in_use[{i + 1}]" for i in range(DF_M))
#: outputs of the detection filter written at every sample, in _copy_df's order
_DF_SAMPLE_KEYS = (*_DF_RESIDUAL_KEYS, *_DF_ALARM_KEYS, *_DF_STATISTIC_KEYS,
                   "df.calibrating", "df.detected", "df.episodes", "df.isolated_sensor",
                   "df.isolated_mask", "df.fault_type", "df.fault_magnitude",
                   "df.fault_magnitude_valid", "df.input_delay_in_use", "df.valid")
#: df.sensor_fault_type codes whose size goes to each per-sensor output.
_OFFSET_TYPES, _GAIN_TYPES, _RATE_TYPES, _NOISE_TYPES = {1, 3, 4, 7}, {2}, {6}, {5}

#: SI exponents of the seed aircraft's signal units (for the units of A, B, C entries).
_UNIT_EXPONENTS: dict[str, dict[str, int]] = {
    "1": {}, "m": {"m": 1}, "m/s": {"m": 1, "s": -1}, "rad": {"rad": 1},
    "rad/s": {"rad": 1, "s": -1},
}


def _unit_ratio(num: str, den: str, per_second: bool = False) -> str:
    """Unit of num/den (/s), e.g. ("m/s", "rad", True) → "m/(rad.s2)"."""
    exps = dict(_UNIT_EXPONENTS[num])
    for base, e in _UNIT_EXPONENTS[den].items():
        exps[base] = exps.get(base, 0) - e
    if per_second:
        exps["s"] = exps.get("s", 0) - 1

    def part(base: str, e: int) -> str:
        return base if abs(e) == 1 else f"{base}{abs(e)}"

    order = ("m", "rad", "s")
    top = ".".join(part(b, exps[b]) for b in order if exps.get(b, 0) > 0) or "1"
    bottom = [part(b, exps[b]) for b in order if exps.get(b, 0) < 0]
    if not bottom:
        return top
    return f"{top}/{bottom[0]}" if len(bottom) == 1 else f"{top}/({'.'.join(bottom)})"


def _meta(name: str, unit: str | None = None, lo: float | None = None,
          hi: float | None = None) -> None:
    entry: dict[str, Any] = {}
    if unit is not None:
        entry["unit"] = unit
    if lo is not None:
        entry["min"] = lo
    if hi is not None:
        entry["max"] = hi
    if entry:
        VARIABLE_META[name] = entry


class Diagnoser(FacadeBase):
    """Sensor-fault diagnoser for gyros and flight-control sensors (gyrodiag)."""

    author = "gyrodiag developers"
    description = (
        "Gyro and flight-control sensor fault diagnosis: DTG parameter identification, "
        "grey-prediction detection, Beard-Jones detection filter with isolation"
    )
    default_experiment = DefaultExperiment(start_time=0.0, stop_time=10.0, step_size=1e-3)
    # building the channels costs up to a second, and the initial outputs (learning,
    # calibrating flags) depend on no input: computed once, at the end of initialisation
    provisional_outputs = False

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(**kwargs)
        self._declare()
        # only a set of a tunable (or a state restore) can change one: no per-step scan
        vr_of = {name: vr for names in self._vr_names.values() for vr, name in names.items()}
        self.watched_vrs = frozenset(vr_of[n] for n in _TUNABLE_NAMES)
        self._dtg: DTGChannel | None = None
        self._grey: GreyFaultDetector | None = None
        self._df: DFChannel | None = None
        self._df_copied: tuple[bool, Any, Any] | None = None
        self._period = math.nan
        self._last_step, self._last_samples = math.nan, 0
        # last outputs of each channel not yet copied into the variables (_sync_outputs)
        self._pending_dtg: Any = None
        self._pending_grey: Any = None
        self._pending_df: Any = None
        self._outputs_pending = False
        # a copy wrote an output it did not check for finiteness (see _sync_outputs)
        self._outputs_unchecked = False
        self._ready = False
        self._start_time = 0.0
        # Host time of the first DTG alarm: the channel's own clock counts valid samples
        # only, so after a skipped NaN sample it would lag the simulation time.
        self._dtg_first_alarm_time = math.nan
        self._dtg_block_copied = -1
        self._dtg_named_code: int | None = None
        self._unclassified_note = ""  # why DTG alarms go unclassified (set at build)
        self._theta0_copied: Any = False  # never a channel's theta0: copy at first
        self._dtg_reference_warned = False
        # tunable values the running channels were built with
        self._applied: dict[str, Any] = {}
        self._real_outputs = [n for n, kind in self.kinds.items()
                              if kind == "Real" and self.causalities[n] == "output"]
        self._guard_outputs_of(("dtg", "grey", "df"))
        self._nonfinite_reported: set[str] = set()

    # ------------------------------------------------------------------ variables
    def add_variable(self, name: str, kind: str, causality: str, start: Any,
                     description: str, variability: str | None = None) -> None:
        if name in _TUNABLE_NAMES:
            variability = "tunable"
            description += " (tunable: a change applies from the next sample)"
        super().add_variable(name, kind, causality, start, description, variability)

    def _declare(self) -> None:
        p = self.add_variable
        p("sample_period_s", "Real", "parameter", 1e-3,
          "Sample period of every channel; a communication step must be a whole number "
          "of sample periods")
        _meta("sample_period_s", "s", POSITIVE)
        # DTG channel
        p("dtg.enabled", "Boolean", "parameter", True, "Run the DTG identification channel")
        p("dtg.prefilter_enabled", "Boolean", "parameter", True,
          "Butterworth low-pass on all four DTG signals")
        p("dtg.prefilter_order", "Integer", "parameter", 6, "Butterworth order")
        _meta("dtg.prefilter_order", None, 1, 20)
        p("dtg.prefilter_cutoff_hz", "Real", "parameter", 0.0,
          "Butterworth cut-off; 0: auto, 1/(20*sample_period_s) (the paper's 50 Hz at "
          "1 kHz), so that it follows the sample period")
        _meta("dtg.prefilter_cutoff_hz", "Hz", 0.0)
        p("dtg.prefilter_highpass_hz", "Real", "parameter", 0.0,
          "High-pass corner cascaded with the low-pass (band-pass); 0: off (paper). "
          "Removes the slow torquer response to case rates, not in the regression")
        _meta("dtg.prefilter_highpass_hz", "Hz", 0.0)
        p("dtg.estimator", "Integer", "parameter", 2,
          "Estimator: 0 sliding-window batch LS, 1 RLS, 2 RLS with forgetting factor")
        _meta("dtg.estimator", None, 0, 2)
        p("dtg.window", "Integer", "parameter", 500, "Batch LS window, samples")
        _meta("dtg.window", None, N_THETA)
        p("dtg.forgetting", "Real", "parameter", AUTO,
          "RLS forgetting factor (paper 0.99); -1: auto, 0.999, with dtg.case_rate 0.9998")
        _meta("dtg.forgetting", "1", AUTO, 1.0)
        p("dtg.p0", "Real", "parameter", 1e6, "Initial RLS covariance scale")
        _meta("dtg.p0", "1", POSITIVE)
        p("dtg.learn_theta0", "Boolean", "parameter", True,
          "Learn nominal theta0 from the learning window (else use dtg.theta0[i])")
        for i in range(1, N_THETA + 1):
            p(f"dtg.theta0[{i}]", "Real", "parameter", 1.0, f"Nominal theta{i}")
            _meta(f"dtg.theta0[{i}]", "1")
        p("dtg.learn_start_s", "Real", "parameter", AUTO,
          "Start of the theta0 learning window after the first sample; -1: auto, 1 s, "
          "with dtg.case_rate 2 s")
        _meta("dtg.learn_start_s", "s", AUTO)
        p("dtg.learn_end_s", "Real", "parameter", AUTO,
          "End of the theta0 learning window; -1: auto, 5 s, with dtg.case_rate 10 s")
        _meta("dtg.learn_end_s", "s", AUTO)
        p("dtg.low", "Real", "parameter", AUTO,
          "Lower ratio threshold on eta; -1: auto, 0.5 (paper), with dtg.case_rate 0.93")
        _meta("dtg.low", "1", AUTO, 1.0 - POSITIVE)
        p("dtg.high", "Real", "parameter", AUTO,
          "Upper ratio threshold on eta; -1: auto, 1.5 (paper), with dtg.case_rate 1.07")
        _meta("dtg.high", "1", AUTO)
        p("dtg.persistence_k", "Integer", "parameter", AUTO_INT,
          "Alarm when k of the last n violate; -1: auto, 1, with dtg.case_rate 0.1 s")
        _meta("dtg.persistence_k", None, AUTO_INT)
        p("dtg.persistence_n", "Integer", "parameter", AUTO_INT,
          "Persistence window n, samples; -1: auto, 1, with dtg.case_rate 0.2 s")
        _meta("dtg.persistence_n", None, AUTO_INT)
        p("dtg.band_sigma", "Real", "parameter", BAND_SIGMA,
          "Case rate, pattern classifier: a ratio outside the band counts only where "
          "theta is also this many standard errors from theta0 (0: the band alone)")
        _meta("dtg.band_sigma", "1", 0.0)
        p("dtg.latch", "Boolean", "parameter", False, "Keep the alarm once raised")
        for i in range(1, N_THETA + 1):
            p(f"dtg.monitored[{i}]", "Boolean", "parameter", True,
              f"theta{i} takes part in the decision")
        p("dtg.n_signatures", "Integer", "parameter", 0,
          "Number of signatures given as parameters dtg.signature[j,i]")
        _meta("dtg.n_signatures", None, 0, MAX_SIGNATURES)
        for j in range(1, MAX_SIGNATURES + 1):
            for i in range(1, N_THETA + 1):
                p(f"dtg.signature[{j},{i}]", "Integer", "parameter", 0,
                  f"Feature C{i} of fault signature {j} (fault code {j})")
        p("dtg.signature_file", "String", "parameter", "",
          "JSON signature library {\"signatures\": {name: [C1..C5]}}; relative paths "
          "are resolved in the FMU resources; overrides the parameter table")
        p("dtg.max_distance", "Real", "parameter", -1.0,
          "Eq. 7 distance beyond which a fault is unknown (code -1); < 0: no limit")
        _meta("dtg.max_distance", "1")
        p("dtg.classify_window_s", "Real", "parameter", 0.5,
          "Paper classifier: an alarm is classified by the median feature of its samples "
          "in this last window (the signature-learning rule); 0: each sample alone (paper)")
        _meta("dtg.classify_window_s", "s", 0.0)
        p("dtg.classifier", "String", "parameter", "pattern",
          "'pattern': frozen checked reference, residual tests with alarm memory and "
          "classification by learned response patterns (type, signal, axis, size); "
          "'paper': the paper's ratio band and decade signatures")
        p("dtg.window_s", "Real", "parameter", 0.5,
          "Pattern classifier: window of the residual level and variance tests, and the "
          "shortest classification window")
        _meta("dtg.window_s", "s", POSITIVE)
        p("dtg.long_window_s", "Real", "parameter", 2.0,
          "Pattern classifier: window of the long variance test and the longest "
          "classification window (>= dtg.window_s)")
        _meta("dtg.long_window_s", "s", POSITIVE)
        p("dtg.level_threshold", "Real", "parameter", 6.0,
          "Pattern classifier: alarm when a residual's window mean exceeds this many "
          "block-mean spreads / sqrt(blocks) (held down to 2/3 of it)")
        _meta("dtg.level_threshold", "1", POSITIVE)
        p("dtg.var_threshold", "Real", "parameter", 4.0,
          "Pattern classifier: alarm when a residual's window variance exceeds this "
          "multiple of its nominal (held down to its 2/3 power)")
        _meta("dtg.var_threshold", "1", 1.0 + 1e-9)
        p("dtg.long_var_threshold", "Real", "parameter", 2.0,
          "Pattern classifier: the same over the long window")
        _meta("dtg.long_var_threshold", "1", 1.0 + 1e-9)
        p("dtg.power_threshold", "Real", "parameter", POWER_THRESHOLD,
          "Pattern classifier: threshold of the CUSUM of the residuals' low-frequency "
          "power (squared 25 ms block means in nominal spreads, tuned to a tripling; the "
          "witness of torquer read-out noise); held down to half of it; 0: off")
        _meta("dtg.power_threshold", "1", 0.0)
        p("dtg.allowance_sigma", "Real", "parameter", ALLOWANCE_SIGMA,
          "Pattern classifier with the case rate: the reference's error the variance "
          "tests and the power CUSUM allow for, in standard deviations of its covariance "
          "(a manoeuvre edge raises their ratios to that error squared); 1: the channel's "
          "earlier, tighter allowance")
        _meta("dtg.allowance_sigma", "1", 0.0)
        p("dtg.theta_spread_threshold", "Real", "parameter", 30.0,
          "Learning guard: largest spread of a learning segment's theta against the "
          "segments before it, in units of its least-squares covariance")
        _meta("dtg.theta_spread_threshold", "1", POSITIVE)
        p("dtg.case_rate", "Integer", "parameter", 0,
          "Case rate in the DTG regression: 0 none (paper, case at rest), 1 central scheme, "
          "2 paper scheme; the rates are the inputs dtg.case_rate_x/_y, an estimate not from "
          "this gyro (e.g. a second gyro); theta0 and the reference are then per axis")
        _meta("dtg.case_rate", None, 0, len(CASE_RATE_SCHEMES))
        p("dtg.pickoff_scale", "Real", "parameter", 1e-3,
          "Nominal pick-off scale KT of the gyro (datasheet); the case rate enters the "
          "regressors as rate*T/KT (used when dtg.case_rate > 0)")
        _meta("dtg.pickoff_scale", "rad/V", POSITIVE)
        p("dtg.case_rate_delay_samples", "Integer", "parameter", 0,
          "Case rate: the voltages of sample k are paired with the case rate of sample "
          "k - d (d = 1: Jacobi coupling with the DTG plant between the aircraft and this "
          "FMU; d < 0: the case rate arrives later, the outputs describe the sample |d| "
          "earlier); the harness sets it from its coupling plan")
        _meta("dtg.case_rate_delay_samples", None, -50, 50)
        p("dtg.case_rate_align_max", "Integer", "parameter", 0,
          "Case rate: choose the delay in -this..this from the data (0: keep "
          "dtg.case_rate_delay_samples); for hosts whose timing is unknown "
          "(docs/dtg_case_rate.md section 9)")
        _meta("dtg.case_rate_align_max", None, 0, 50)
        p("dtg.case_rate_lookahead_s", "Real", "parameter", 0.032,
          "Case-rate alignment: how far the aligner runs ahead of the estimators (used "
          "when dtg.case_rate_align_max > 0; the outputs describe the sample this much "
          "earlier)")
        _meta("dtg.case_rate_lookahead_s", "s", POSITIVE, 1.0)
        p("dtg.clear_after_s", "Real", "parameter", 0.5,
          "Pattern classifier: a residual alarm clears this long after the last block "
          "with a test above its hold threshold")
        _meta("dtg.clear_after_s", "s", 0.0)
        for name in ("Utx", "Uty", "Ux", "Uy"):
            p(f"dtg.{name}", "Real", "input", 0.0, f"DTG signal {name}")
            _meta(f"dtg.{name}", "V")
        for axis in ("x", "y"):
            p(f"dtg.case_rate_{axis}", "Real", "input", 0.0,
              f"Case rate about the gyro's {axis} axis held over the sample, from an "
              "estimate independent of this gyro (used when dtg.case_rate > 0)")
            _meta(f"dtg.case_rate_{axis}", "rad/s")
        for axis in ("x", "y"):
            for i in range(1, N_THETA + 1):
                p(f"dtg.theta_{axis}[{i}]", "Real", "output", 0.0,
                  f"Identified theta{i}, {axis} axis")
                _meta(f"dtg.theta_{axis}[{i}]", "1")
                p(f"dtg.eta_{axis}[{i}]", "Real", "output", 1.0,
                  f"Ratio |theta{i}|/|theta0_{i}|, {axis} axis")
                _meta(f"dtg.eta_{axis}[{i}]", "1")
        for i in range(1, N_THETA + 1):
            p(f"dtg.theta0_used[{i}]", "Real", "output", 0.0,
              f"Nominal theta{i} in use, x axis (both axes when dtg.case_rate = 0; 0 while "
              "learning)")
            _meta(f"dtg.theta0_used[{i}]", "1")
            p(f"dtg.theta0_used_y[{i}]", "Real", "output", 0.0,
              f"Nominal theta{i} in use, y axis (= dtg.theta0_used[{i}] when "
              "dtg.case_rate = 0; 0 while learning)")
            _meta(f"dtg.theta0_used_y[{i}]", "1")
        for name, unit in zip(PHYSICAL_NAMES, PHYSICAL_UNITS, strict=True):
            p(f"dtg.{name}", "Real", "output", 0.0,
              f"Identified {name}; 0 while dtg.physical_valid is false")
            _meta(f"dtg.{name}", unit)
        p("dtg.physical_valid", "Boolean", "output", False,
          "The identified theta gives finite physical parameters")
        p("dtg.learning", "Boolean", "output", False, "Nominal theta0 still being learned")
        p("dtg.alarm", "Boolean", "output", False, "DTG parameter-ratio alarm")
        p("dtg.fault_code", "Integer", "output", 0,
          "0 none, j = nearest signature j, -1 unknown/unclassified")
        p("dtg.fault_name", "String", "output", "",
          "Name of dtg.fault_code's class (e.g. uty_step, spin): empty none, unknown")
        p("dtg.first_alarm_time", "Real", "output", -1.0,
          "Simulation time of the first DTG alarm (its sample's time), -1 if none")
        _meta("dtg.first_alarm_time", "s")
        p("dtg.case_rate_delay_in_use", "Integer", "output", 0,
          "Delay d of the case rate in use (dtg.case_rate_delay_samples, or the aligner's "
          "choice with dtg.case_rate_align_max > 0)")
        p("dtg.valid", "Boolean", "output", True, "Last DTG sample was finite")
        self._declare_dtg_diagnosis()
        # Grey channel
        p("grey.enabled", "Boolean", "parameter", True, "Run the grey-prediction channel")
        p("grey.model", "Integer", "parameter", 1,
          "0 classic GM(1,1) (C = first sample), 1 improved (optimised C, residual fit)")
        _meta("grey.model", None, 0, 1)
        p("grey.window", "Integer", "parameter", 10,
          "Moving window length m >= 4, samples; 0 (classic model only): the whole "
          "record since the start or the last alarm clearing (the paper's ordinary GM)")
        _meta("grey.window", None, 0)
        p("grey.classic_evaluation", "Integer", "parameter", 0,
          "Classic model's time response: 0 careful (exact as a -> 0), 1 textbook "
          "(1 - e^a)(C - b/a)e^(-am), which collapses on a constant window as in the paper")
        _meta("grey.classic_evaluation", None, 0, 1)
        p("grey.decision", "Integer", "parameter", GREY_DECISION_DEFAULT,
          "Decision rule: 0 paper (alarm when |y - prediction| > grey.threshold), "
          "1 sequential (threshold from the prediction errors of the fault-free start "
          "grey.learn_end_s, lagged step test and CUSUM for grey.false_alarm_rate), "
          "2 k-sigma (the same learned sigma_e, alarm at grey.k_sigma * sigma_e per sample)")
        _meta("grey.decision", None, 0, max(GREY_DECISIONS))
        p("grey.threshold", "Real", "parameter", 0.05,
          "Paper rule (grey.decision = 0): alarm threshold on |y - prediction|, in the "
          "monitored signal's unit")
        _meta("grey.threshold", GREY_UNIT, POSITIVE)
        p("grey.clear_after_s", "Real", "parameter", 20.0,
          "Clear an alarm this long after onset; <= 0: never")
        _meta("grey.clear_after_s", "s")
        p("grey.a_min", "Real", "parameter", 1e-6,
          "|a| below which the improved model predicts by the polynomial")
        _meta("grey.a_min", "1", 0.0)
        p("grey.residual_order", "Integer", "parameter", 2,
          "Improved model: degree of the residual polynomial (paper: 2)")
        _meta("grey.residual_order", None, 0, 4)
        p("grey.learn_end_s", "Real", "parameter", DEFAULT_LEARN_END_S,
          "Learned rules (grey.decision = 1, 2): the signal is fault-free from the start "
          "until this time: the predictor's warm-up window, then the one-step prediction "
          "errors that give their standard deviation sigma_e (at least 10 of them)")
        _meta("grey.learn_end_s", "s", POSITIVE)
        p("grey.threshold_floor", "Real", "parameter", 0.01,
          "Learned rules: smallest threshold allowed on |y - prediction| (sigma_e >= "
          "floor / grey.k_sigma; floor / grey.k_sigma is also the lagged test's allowance "
          "for its reference's model error), in the monitored signal's unit")
        _meta("grey.threshold_floor", GREY_UNIT, POSITIVE)
        p("grey.k_sigma", "Real", "parameter", 5.0,
          "Learned rules: k-sigma alarm at |y - prediction| > k_sigma * sigma_e "
          "(grey.decision = 2); sigma floor grey.threshold_floor / k_sigma")
        _meta("grey.k_sigma", "1", POSITIVE)
        p("grey.false_alarm_rate", "Real", "parameter", 1e-3,
          "Sequential rule: design false-alarm rate (per hour)")
        _meta("grey.false_alarm_rate", "1/h", 1e-9, 3600.0)
        p("grey.cusum_k", "Real", "parameter", 1.5,
          "Sequential rule: CUSUM reference in sigma_e")
        _meta("grey.cusum_k", "1", 0.05, 5.0)
        p("grey.suspicion_sigma", "Real", "parameter", 4.0,
          "Learned rules: a sample off its prediction by more than this many sigma_e is "
          "not fed to the predictor until the test decides")
        _meta("grey.suspicion_sigma", "1", POSITIVE)
        p("grey.lag_max", "Integer", "parameter", 3,
          "Sequential rule: lagged step test on the last 1..lag_max samples "
          "against a polynomial reference window that ends before them (a generalised "
          "likelihood ratio per lag, threshold for grey.false_alarm_rate); while it is "
          "ready the CUSUM only holds alarms; 0: CUSUM alone")
        _meta("grey.lag_max", None, 0, 4)
        p("grey.reference_window_s", "Real", "parameter", 30.0,
          "Sequential rule, lagged test: longest reference window, s (at most 400 "
          "samples, at least grey.reference_order + 3; it starts at min(20 samples, this) "
          "after the start or an alarm and grows)")
        _meta("grey.reference_window_s", "s", POSITIVE)
        p("grey.reference_order", "Integer", "parameter", 3,
          "Sequential rule, lagged test: degree of the reference polynomial "
          "(grey.reference_window_s must hold order + 3 samples)")
        _meta("grey.reference_order", None, 0, 3)
        p("grey.auto_order", "Boolean", "parameter", True,
          "Learned rules, improved model: also run residual orders 1 and 0 during the "
          "calibration and keep the one with the least error (noise favours low orders); "
          "not used by the paper rule or the classic model")
        p("grey.y", "Real", "input", 0.0,
          f"Monitored signal (declared in {GREY_UNIT}, the HRG output the channel was made "
          "for; any signal works, its unit is then that of grey.threshold, "
          "grey.threshold_floor and the outputs)")
        _meta("grey.y", GREY_UNIT)
        p("grey.prediction", "Real", "output", 0.0,
          "One-step prediction of this sample; 0 while grey.prediction_valid is false")
        _meta("grey.prediction", GREY_UNIT)
        p("grey.error", "Real", "output", 0.0,
          "y - prediction; 0 while grey.prediction_valid or grey.valid is false")
        _meta("grey.error", GREY_UNIT)
        p("grey.prediction_valid", "Boolean", "output", False,
          "A prediction exists for this sample (window filled)")
        p("grey.alarm", "Boolean", "output", False, "Grey prediction alarm")
        p("grey.calibrating", "Boolean", "output", False,
          "Learned rules: warm-up or calibration window in progress (no alarm)")
        p("grey.sigma", "Real", "output", 0.0,
          "Learned rules: standard deviation of the fault-free prediction error in use "
          "(signal units); 0 before it is learned and with the paper rule")
        _meta("grey.sigma", GREY_UNIT, 0.0)
        p("grey.noise_sigma", "Real", "output", 0.0,
          "Sequential rule, lagged test: standard deviation of the signal's white noise in "
          "use (95 % upper bound from third differences, grey.threshold_floor / "
          "grey.k_sigma added in quadrature); 0 before it is known or without the lagged "
          "test")
        _meta("grey.noise_sigma", GREY_UNIT, 0.0)
        p("grey.statistic", "Real", "output", 0.0,
          "Alarm statistic in units of its threshold (alarm at 1)")
        _meta("grey.statistic", "1", 0.0)
        p("grey.valid", "Boolean", "output", True, "Last grey sample was finite")
        # Detection-filter channel
        self._declare_df()
        # Summary
        p("any_alarm", "Boolean", "output", False, "Any enabled channel in alarm")
        p("fault_code", "Integer", "output", 0,
          "0 none; 100+j DTG signature j (99 unknown); 200 grey alarm; "
          "300+i sensor i isolated by the detection filter (299 not isolated, "
          "298 several sensors)")
        p("inputs_valid", "Boolean", "output", True, "All enabled channels' inputs finite")

    def _declare_dtg_diagnosis(self) -> None:
        """Outputs of the reference, residual tests and pattern classification."""

        def out(name: str, kind: str, start: Any, text: str, unit: str | None = None) -> None:
            self.add_variable(name, kind, "output", start, text, variability="discrete")
            if unit is not None:
                _meta(name, unit)

        out("dtg.reference_valid", "Boolean", False,
            "The learned nominal reference passed its checks (false while learning)")
        out("dtg.reference_status", "Integer", 0,
            "0 learning, 1 valid, 2 change inside the learning window (reference from the "
            "segments before it), 3 mismatch with the nominal prior (prior in use), "
            "4 not checked (paper classifier, too little data), 5 no reference (no usable "
            "data in the learning window: no alarm)")
        out("dtg.residual_alarm", "Boolean", False,
            "Pattern classifier: residual tests against the frozen reference in alarm")
        out("dtg.fault_type", "Integer", 0,
            "0 none, 1 step, 2 noise, 3 loss, 4 drift, 5 spin slow-down, 6 torquer scale, "
            "-1 unknown")
        out("dtg.fault_signal", "Integer", 0,
            "0 none or physical, 1 Utx, 2 Uty, 3 Ux, 4 Uy, -1 unknown")
        out("dtg.fault_axis", "Integer", 0, "0 none, 1 x, 2 y, 3 both, -1 unknown")
        out("dtg.class_distance", "Real", -1.0,
            "Chi-square per channel of the class fitted to the statistics; -1 if none",
            "1")
        out("dtg.fault_size", "Real", 0.0,
            "Estimated fault size: step offset, noise std, noise left by a loss, current "
            "drift offset (V); 0 if undefined (dtg.fault_size_valid)", "V")
        out("dtg.fault_size_valid", "Boolean", False, "dtg.fault_size is defined")
        out("dtg.fault_rate", "Real", 0.0, "Estimated drift rate; 0 unless a drift", "V/s")
        out("dtg.fault_ratio", "Real", 1.0,
            "Physical classes: estimated parameter ratio (spin Omega/Omega_nom, torquer "
            "Ku/Ku_nom); 1 otherwise", "1")
        for i, ch in enumerate(CHANNELS, start=1):
            out(f"dtg.level[{i}]", "Real", 0.0,
                f"{ch}: window mean minus nominal, in nominal block-mean spreads (test "
                "window; classification window in alarm)", "1")
            out(f"dtg.log_var_ratio[{i}]", "Real", 0.0,
                f"{ch}: log10 of window variance / nominal (detrended)", "1")
        out("dtg.level_growth", "Real", 0.0,
            "Growth of the residual level across the window (drift witness)", "1")
        out("dtg.stat_window_s", "Real", 0.0,
            "Length of the window of dtg.level / dtg.log_var_ratio", "s")
        for i, axis in enumerate("xy", start=1):
            out(f"dtg.residual_level_z[{i}]", "Real", 0.0,
                f"Level test statistic of the {axis} residual", "1")
            out(f"dtg.residual_var_ratio[{i}]", "Real", 0.0,
                f"Short-window variance ratio of the {axis} residual", "1")
            out(f"dtg.residual_long_var_ratio[{i}]", "Real", 0.0,
                f"Long-window variance ratio of the {axis} residual", "1")
            out(f"dtg.residual_power_cusum[{i}]", "Real", 0.0,
                f"Low-frequency power CUSUM of the {axis} residual over "
                "dtg.power_threshold (alarm at 1)", "1")
        for i in range(1, N_THETA + 1):
            out(f"dtg.ref_theta0[{i}]", "Real", 0.0,
                f"Reference theta{i} of the residuals, x axis (both axes when "
                "dtg.case_rate = 0; 0 before the reference)", "1")
            out(f"dtg.ref_theta0_y[{i}]", "Real", 0.0,
                f"Reference theta{i} of the residuals, y axis (0 before the reference)",
                "1")
        for key, unit, text in (("ref_mean", "V", "nominal mean"),
                                ("ref_block_std", "V", "nominal spread of block means"),
                                ("ref_var_short", "V2", "nominal variance, short window"),
                                ("ref_var_long", "V2", "nominal variance, long window")):
            for i, ch in enumerate(CHANNELS, start=1):
                out(f"dtg.{key}[{i}]", "Real", 0.0,
                    f"{ch}: {text} (0 before the reference)", unit)

    def _declare_df(self) -> None:
        p = self.add_variable
        A, B, C = SEED.A, SEED.B, SEED.C
        p("df.enabled", "Boolean", "parameter", True, "Run the detection-filter channel")
        for i in range(DF_N):
            for j in range(DF_N):
                p(f"df.A[{i + 1},{j + 1}]", "Real", "parameter", float(A[i, j]),
                  f"Plant matrix A, row {i + 1} ({SEED.state_names[i]})")
                _meta(f"df.A[{i + 1},{j + 1}]",
                      _unit_ratio(SEED.state_units[i], SEED.state_units[j], True))
            for j in range(DF_P):
                p(f"df.B[{i + 1},{j + 1}]", "Real", "parameter", float(B[i, j]),
                  f"Input matrix B, row {i + 1}, input {SEED.input_names[j]}")
                _meta(f"df.B[{i + 1},{j + 1}]",
                      _unit_ratio(SEED.state_units[i], SEED.input_units[j], True))
        for i in range(DF_M):
            for j in range(DF_N):
                p(f"df.C[{i + 1},{j + 1}]", "Real", "parameter", float(C[i, j]),
                  f"Output matrix C, sensor {SEED.output_names[i]}")
                _meta(f"df.C[{i + 1},{j + 1}]",
                      _unit_ratio(SEED.output_units[i], SEED.state_units[j]))
        for i in range(DF_N):
            p(f"df.eigenvalue[{i + 1}]", "Real", "parameter", -float(i + 1),
              f"Eigenvalue {i + 1} of A - KC (real, negative, distinct)")
            _meta(f"df.eigenvalue[{i + 1}]", "1/s", None, -POSITIVE)
            p(f"df.x0[{i + 1}]", "Real", "parameter", 0.0,
              f"Initial estimate of state {SEED.state_names[i]}")
            _meta(f"df.x0[{i + 1}]", SEED.state_units[i])
        p("df.decision", "Integer", "parameter", DF_DECISION_AUTO,
          "Decision rule: 0 paper (k-sigma per sample, k-of-n, latched, observer-bank "
          "isolation), 1 sequential (whitened residual, CUSUM for df.false_alarm_rate, "
          "isolation of one or two sensors, fault typing, episodes), 2 auto: sequential, "
          "or paper when df.sensor_dynamics_file gives a read-out model (the sequential "
          "rule does not isolate there)")
        _meta("df.decision", None, 0, 2)
        p("df.false_alarm_rate", "Real", "parameter", 1e-3,
          "Sequential: design false-alarm rate of the detection (per hour)")
        _meta("df.false_alarm_rate", "1/h", 1e-9, 3600.0)
        p("df.cusum_k", "Real", "parameter", 0.5,
          "Sequential: CUSUM reference in sigma of the whitened residual (optimal for "
          "mean shifts of 2k)")
        _meta("df.cusum_k", "1", 0.05, 5.0)
        p("df.variance_ratio", "Real", "parameter", 4.0,
          "Sequential: variance increase the variance CUSUMs are designed for (> 1)")
        _meta("df.variance_ratio", "1", 1.0 + 1e-9, 1e6)
        p("df.max_faults", "Integer", "parameter", 2,
          "Sequential: simultaneously faulty sensors to isolate (1 or 2)")
        _meta("df.max_faults", None, 1, 2)
        p("df.history_s", "Real", "parameter", 4.0,
          "Sequential: samples kept to start the isolation before a change")
        _meta("df.history_s", "s", POSITIVE, 600.0)
        p("df.memory_s", "Real", "parameter", 10.0,
          "Sequential: the isolation keeps running this long after a fault episode")
        _meta("df.memory_s", "s", 0.0)
        p("df.input_delay_samples", "Integer", "parameter", 0,
          "Alignment: y(k) is paired with u(k - d) (d < 0: with a later u, outputs then "
          "describe the sample |d| steps back); the chosen one if df.align_auto")
        _meta("df.input_delay_samples", None, -50, 50)
        p("df.align_auto", "Boolean", "parameter", True,
          "Choose the alignment on the calibration window (least residual variance over "
          "d in [-df.align_max, df.align_max]); the master's coupling order needs no setting. "
          "Not with df.sensor_dynamics_file, whose read-out model sets the timing")
        p("df.align_max", "Integer", "parameter", 2, "Largest |d| tried by df.align_auto")
        _meta("df.align_max", None, 0, 50)
        for i in range(DF_M):
            p(f"df.sensor_delay[{i + 1}]", "Integer", "parameter", 0,
              f"Sensor {i + 1} (df.y[{i + 1}]) arrives this many samples after the others "
              "of the same instant (routed through one FMU more under Jacobi coupling, "
              "e.g. the DTG read-out: 1); the other channels are held back to match; the "
              "harness sets it from its coupling plan")
            _meta(f"df.sensor_delay[{i + 1}]", None, 0, 50)
        p("df.sensor_dynamics_file", "String", "parameter", "",
          "JSON file of one sensor's read-out dynamics G (e.g. the DTG's rebalance loop on "
          "q, models/dtg/gd_dtg_readout.py; relative paths are in the FMU's resources): "
          "every input and every other sensor go through the same G (matched filtering); "
          "empty: every sensor is y = Cx")
        p("df.gust_sigma_w", "Real", "parameter", DF_GUST_SIGMA_W,
          "Sequential: Dryden vertical gust intensity sigma_w the residual model allows "
          "for (turbulence up to it is not a fault; MIL-F-8785C light 0.77, moderate "
          "1.5, severe 2.3); the gust enters through the alpha and q columns of df.A in "
          "the alpha-dot and q-dot rows; 0: no turbulence model")
        _meta("df.gust_sigma_w", "m/s", 0.0, 100.0)
        p("df.gust_scale_length", "Real", "parameter", 50.0,
          "Sequential: Dryden scale length L_w of the gust model (below 1000 ft: the "
          "altitude)")
        _meta("df.gust_scale_length", "m", POSITIVE)
        p("df.gust_airspeed", "Real", "parameter", 272.24,
          "Sequential: true airspeed V of the gust model")
        _meta("df.gust_airspeed", "m/s", POSITIVE)
        p("df.gust_wingspan", "Real", "parameter", 10.0,
          "Sequential: wing span b of the gust model's pitch-rate filter 4b/(pi V)")
        _meta("df.gust_wingspan", "m", POSITIVE)
        p("df.calibrate_s", "Real", "parameter", 10.0,
          "Fault-free calibration window for the alignment, noise and thresholds; 0: "
          "none (paper rule: df.threshold[i]; sequential rule: df.noise_std[i])")
        _meta("df.calibrate_s", "s", 0.0)
        p("df.burn_in_s", "Real", "parameter", 2.0,
          "Start of the calibration window ignored (observer convergence)")
        _meta("df.burn_in_s", "s", 0.0)
        p("df.k_sigma", "Real", "parameter", 6.0,
          "Paper rule: thresholds at k standard deviations")
        _meta("df.k_sigma", "1", POSITIVE)
        for i in range(DF_M):
            unit = SEED.output_units[i]
            p(f"df.threshold[{i + 1}]", "Real", "parameter", 1.0,
              f"Main residual threshold of sensor {SEED.output_names[i]} "
              "(used when df.calibrate_s = 0)")
            _meta(f"df.threshold[{i + 1}]", unit, POSITIVE)
            p(f"df.noise_std[{i + 1}]", "Real", "parameter", -1.0,
              f"Noise std of sensor {SEED.output_names[i]}; < 0 on any sensor: learned "
              "from the calibration window (paper rule without one: threshold / k_sigma)")
            _meta(f"df.noise_std[{i + 1}]", unit)
            used = [k for k in range(DF_M) if k != i]
            for j in range(DF_M - 1):
                p(f"df.bank_threshold[{i + 1},{j + 1}]", "Real", "parameter", 1.0,
                  f"Threshold of observer {i + 1} (without sensor {i + 1}) on its "
                  f"residual {j + 1}, sensor {SEED.output_names[used[j]]} "
                  "(used when df.calibrate_s = 0)")
                _meta(f"df.bank_threshold[{i + 1},{j + 1}]", SEED.output_units[used[j]],
                      POSITIVE)
        p("df.persistence_k", "Integer", "parameter", 3, "Residual alarm: k of the last n")
        _meta("df.persistence_k", None, 1)
        p("df.persistence_n", "Integer", "parameter", 5, "Residual alarm persistence n")
        _meta("df.persistence_n", None, 1)
        p("df.confirm_samples", "Integer", "parameter", 5,
          "Samples of one isolation pattern before it is latched")
        _meta("df.confirm_samples", None, 1)
        p("df.isolation_window_s", "Real", "parameter", 4.0,
          "Paper rule: when the alarm pattern does not isolate, isolate by the observer "
          "bank's residual energy within this time after detection (0: the pattern "
          "alone, as the paper's filter; a shorter window than 10 sample periods is "
          "lengthened to 10; small faults in turbulence need it)")
        _meta("df.isolation_window_s", "s", 0.0, 3600.0)
        p("df.isolation_baseline_s", "Real", "parameter", 10.0,
          "Paper rule: time constant of the bank's fault-free energy baseline before "
          "detection; the energy isolation measures against the larger of it and the "
          "calibration, so turbulence stronger than during calibration is not taken for "
          "a faultless observer (0: the calibration alone)")
        _meta("df.isolation_baseline_s", "s", 0.0, 3600.0)
        for j in range(DF_P):
            p(f"df.u[{j + 1}]", "Real", "input", 0.0, f"Plant input {SEED.input_names[j]}")
            _meta(f"df.u[{j + 1}]", SEED.input_units[j])
        for i in range(DF_M):
            p(f"df.y[{i + 1}]", "Real", "input", 0.0, f"Sensor {SEED.output_names[i]}")
            _meta(f"df.y[{i + 1}]", SEED.output_units[i])
            p(f"df.residual[{i + 1}]", "Real", "output", 0.0,
              f"Detection-filter residual of sensor {SEED.output_names[i]}")
            _meta(f"df.residual[{i + 1}]", SEED.output_units[i])
            p(f"df.alarm[{i + 1}]", "Boolean", "output", False,
              f"Residual alarm of sensor {SEED.output_names[i]}")
            p(f"df.threshold_in_use[{i + 1}]", "Real", "output", 0.0,
              f"Paper rule: residual threshold in use for sensor {SEED.output_names[i]} "
              "(learned or given); 0 while calibrating and with the sequential rule")
            _meta(f"df.threshold_in_use[{i + 1}]", SEED.output_units[i])
            p(f"df.statistic[{i + 1}]", "Real", "output", 0.0,
              f"Alarm statistic of sensor {SEED.output_names[i]} in units of its "
              "threshold (alarm at 1): largest CUSUM / threshold (sequential), "
              "|residual| / threshold (paper)")
            _meta(f"df.statistic[{i + 1}]", "1", 0.0)
            p(f"df.noise_std_in_use[{i + 1}]", "Real", "output", 0.0,
              f"Noise std of sensor {SEED.output_names[i]} in use (given or learned); 0 "
              "while calibrating")
            _meta(f"df.noise_std_in_use[{i + 1}]", SEED.output_units[i], 0.0)
            p(f"df.sensor_fault_type[{i + 1}]", "Integer", "output", 0,
              f"Fault type of sensor {SEED.output_names[i]} (codes of df.fault_type; 0 "
              "when not isolated)")
            unit = SEED.output_units[i]
            p(f"df.fault_offset[{i + 1}]", "Real", "output", 0.0,
              f"Sensor {SEED.output_names[i]}: bias, intermittent amplitude or stuck value "
              "(0 for a failure or another type)")
            _meta(f"df.fault_offset[{i + 1}]", unit)
            p(f"df.fault_gain[{i + 1}]", "Real", "output", 1.0,
              f"Sensor {SEED.output_names[i]}: gain factor of a gain fault (1 otherwise)")
            _meta(f"df.fault_gain[{i + 1}]", "1")
            p(f"df.fault_rate[{i + 1}]", "Real", "output", 0.0,
              f"Sensor {SEED.output_names[i]}: drift rate of a ramp fault (0 otherwise)")
            _meta(f"df.fault_rate[{i + 1}]", f"{unit}/s" if unit != "m/s" else "m/s2")
            p(f"df.noise_ratio[{i + 1}]", "Real", "output", 1.0,
              f"Sensor {SEED.output_names[i]}: noise std over nominal of a noise-increase "
              "fault (1 otherwise)")
            _meta(f"df.noise_ratio[{i + 1}]", "1")
        p("df.calibrating", "Boolean", "output", False,
          "Calibration window still being recorded")
        p("df.detected", "Boolean", "output", False,
          "Sensor fault detected: latched (paper rule); a fault episode in progress, "
          "cleared when the fault clears (sequential rule)")
        p("df.episodes", "Integer", "output", 0, "Fault episodes since the start")
        p("df.isolated_sensor", "Integer", "output", 0,
          "1-based index of the isolated sensor (the current or, between episodes, the "
          "last diagnosis); 0 none; -1 detected, not isolated; -2 several sensors "
          "(df.isolated_mask says which, 0 if they cannot be told apart)")
        p("df.isolated_mask", "Integer", "output", 0,
          "Bit i-1 set for each isolated sensor i (e.g. 6: sensors 2 and 3)")
        p("df.fault_type", "Integer", "output", 0,
          "-1 unknown, 0 none, 1 bias, 2 gain, 3 stuck, 4 complete failure, 5 noise "
          "increase, 6 ramp, 7 intermittent (of the isolated sensor; two sensors: their "
          "common type, else -1)")
        p("df.fault_magnitude", "Real", "output", 0.0,
          "Size of the isolated sensor's fault in the unit of its type: bias / stuck "
          "value / intermittent amplitude (sensor units), gain factor, ramp rate (per s), "
          "noise std ratio; declared dimensionless because its unit follows the isolated "
          "sensor and type; 0 for a failure or when df.fault_magnitude_valid is false. The "
          "per-sensor outputs df.fault_offset/gain/rate, df.noise_ratio carry units")
        _meta("df.fault_magnitude", "1")
        p("df.fault_magnitude_valid", "Boolean", "output", False,
          "df.fault_magnitude holds an estimate (a fault of known type is isolated)")
        p("df.input_delay_in_use", "Integer", "output", 0,
          "Alignment d in use (chosen on the calibration window with df.align_auto)")
        p("df.valid", "Boolean", "output", True, "Last u, y sample was finite")

    def _df_sensor_dynamics(self, period: float) -> Any:
        """The :class:`~gyrodiag.df.sensor_dynamics.SensorDynamics` of
        df.sensor_dynamics_file, or None when it is empty."""
        from gyrodiag.df.sensor_dynamics import SensorDynamics

        text = str(self.values["df.sensor_dynamics_file"]).strip()
        if not text:
            return None
        path = Path(text)
        if not path.is_absolute() and self.resources:
            path = Path(self.resources) / path
        try:
            return SensorDynamics.from_json(path, period)
        except ValueError as exc:
            raise ValueError(f"df.sensor_dynamics_file: {exc}") from None

    def _df_config(self, period: float) -> DFChannelConfig:
        from gyrodiag.df.channel import DFChannelConfig

        v = self.values

        def matrix(name: str, rows: int, cols: int) -> np.ndarray:
            return np.array([[float(v[f"df.{name}[{i + 1},{j + 1}]"]) for j in range(cols)]
                             for i in range(rows)])

        def vector(name: str, size: int) -> np.ndarray:
            return np.array([float(v[f"df.{name}[{i + 1}]"]) for i in range(size)])

        noise = vector("noise_std", DF_M)
        from gyrodiag.df.channel import decision_rule

        decision = _named_int(v, "df.decision")
        if decision not in (0, 1, DF_DECISION_AUTO):
            raise ValueError("df.decision must be 0 (paper), 1 (sequential) or 2 (auto), "
                             f"got {decision}")
        sensor_dynamics = self._df_sensor_dynamics(period)
        rule = decision_rule(decision, sensor_dynamics is not None)
        return DFChannelConfig(
            A=matrix("A", DF_N, DF_N), B=matrix("B", DF_N, DF_P), C=matrix("C", DF_M, DF_N),
            eigenvalues=vector("eigenvalue", DF_N), sample_period_s=period,
            decision=rule,
            calibrate_s=float(v["df.calibrate_s"]), burn_in_s=float(v["df.burn_in_s"]),
            k_sigma=float(v["df.k_sigma"]), main_thresholds=vector("threshold", DF_M),
            bank_thresholds=matrix("bank_threshold", DF_M, DF_M - 1),
            noise_std=None if np.any(noise < 0) else noise,
            persistence_k=_named_int(v, "df.persistence_k"),
            persistence_n=_named_int(v, "df.persistence_n"),
            confirm_samples=_named_int(v, "df.confirm_samples"),
            isolation_window_s=float(v["df.isolation_window_s"]),
            isolation_baseline_s=float(v["df.isolation_baseline_s"]),
            false_alarms_per_h=float(v["df.false_alarm_rate"]),
            cusum_k=float(v["df.cusum_k"]), variance_ratio=float(v["df.variance_ratio"]),
            max_faults=_named_int(v, "df.max_faults"),
            history_s=float(v["df.history_s"]), memory_s=float(v["df.memory_s"]),
            input_delay_samples=_named_int(v, "df.input_delay_samples"),
            align_auto=bool(v["df.align_auto"]), align_max=_named_int(v, "df.align_max"),
            sensor_delay_samples=[_named_int(v, f"df.sensor_delay[{i + 1}]")
                                  for i in range(DF_M)],
            x0=vector("x0", DF_N),
            sensor_dynamics=sensor_dynamics,
            gust=self._df_gust(),
        )

    def _df_gust(self) -> Any:
        """The gust model of df.gust_*, or None when df.gust_sigma_w is 0."""
        from gyrodiag.df.gust import GustModel

        v = self.values
        sigma = float(v["df.gust_sigma_w"])
        if sigma == 0.0:
            return None
        return GustModel(sigma_w=sigma, scale_length=float(v["df.gust_scale_length"]),
                         airspeed=float(v["df.gust_airspeed"]),
                         wingspan=float(v["df.gust_wingspan"]))

    def _copy_df(self, out: DFChannelOutput) -> None:
        v = self.values
        magnitude_valid = bool(out.magnitude_valid) and math.isfinite(out.magnitude)
        residual, statistic = _as_list(out.residual), _as_list(out.statistic)
        checked = sum(residual) + sum(statistic)
        if checked - checked != 0.0:
            self._outputs_unchecked = True
        # one dict update of the per-sample outputs (keys in _DF_SAMPLE_KEYS order)
        v.update(zip(_DF_SAMPLE_KEYS, (
            *map(float, residual), *map(bool, _as_list(out.alarms)),
            *map(float, statistic),
            bool(out.calibrating), bool(out.detected), int(out.episodes),
            int(out.isolated_sensor), int(out.isolated_mask), int(out.fault_type),
            float(out.magnitude) if magnitude_valid else 0.0, magnitude_valid,
            int(out.input_delay), bool(out.valid)), strict=True))
        # the diagnosis and the calibration results change rarely: copy them on change
        # (the channel hands over the same arrays while they do not change)
        prev = self._df_copied
        if (prev is not None and prev[0] == out.calibrating
                and prev[1] is out.sensor_fault_type and prev[2] is out.sensor_magnitude):
            return
        self._df_copied = (out.calibrating, out.sensor_fault_type, out.sensor_magnitude)
        self._outputs_unchecked = True  # thresholds, noise and sizes: the full guard
        assert self._df is not None
        if prev is not None and prev[0] and not out.calibrating and self._df.gust_note:
            # information, not a warning status: the step itself succeeded
            self.log(f"df: {self._df.gust_note}", Fmi2Status.ok)
        thresholds = self._df.thresholds
        for k, value in zip(_DF_THRESHOLD_KEYS, [0.0] * DF_M if thresholds is None
                            else _as_list(thresholds[0]), strict=True):
            v[k] = float(value)
        noise = self._df.noise_std
        for k, value in zip(_DF_NOISE_STD_KEYS, [0.0] * DF_M if noise is None
                            else _as_list(noise), strict=True):
            v[k] = float(value)
        types = _as_list(out.sensor_fault_type)
        sizes = _as_list(out.sensor_magnitude)
        for i in range(DF_M):
            kind, size = int(types[i]), float(sizes[i])
            v[_DF_SENSOR_TYPE_KEYS[i]] = kind
            v[_DF_OFFSET_KEYS[i]] = size if kind in _OFFSET_TYPES else 0.0
            v[_DF_GAIN_KEYS[i]] = size if kind in _GAIN_TYPES and size != 0.0 else 1.0
            v[_DF_RATE_KEYS[i]] = size if kind in _RATE_TYPES else 0.0
            v[_DF_NOISE_RATIO_KEYS[i]] = size if kind in _NOISE_TYPES and size else 1.0

    # ------------------------------------------------------------------ lifecycle
    def setup_experiment(self, start_time: float, stop_time: float | None = None,
                         tolerance: float | None = None) -> None:
        self._start_time = float(start_time)

    def exit_initialization_mode(self) -> None:
        try:
            self._build_channels()
            self._dtg_first_alarm_time = math.nan
            # Outputs at the start time (before the first step) describe the channels'
            # initial state, e.g. df.calibrating and dtg.learning are already true.
            self._dtg_block_copied = -1
            self._dtg_named_code = None
            if self._dtg is not None:
                self._copy_dtg(self._dtg.last_output)
            if self._df is not None:
                self._copy_df(self._df.last_output)
            self._guard_finite_outputs()
            self._ready = True
        except MissingPackageError as exc:
            self._ready = False
            self.report_error(f"{self.instance_name}: {exc}")
        except (ValueError, TypeError, OSError, KeyError) as exc:
            self._ready = False
            self.report_error(f"{self.instance_name}: invalid parameter: {exc}")
        except Exception as exc:
            self._ready = False
            self.report_exception("fmi2ExitInitializationMode", exc)

    def _build_channels(self) -> None:
        v = self.values
        errors = self.range_errors(VARIABLE_META)
        if errors:
            raise ValueError("; ".join(errors))
        period = float(v["sample_period_s"])
        self._unclassified_note = ""
        # sample_period_s is fixed after initialisation (not tunable)
        self._period = period
        self._last_step, self._last_samples = math.nan, 0
        self._dtg = self._grey = self._df = None
        self._df_copied = None
        self._theta0_copied = False
        self._pending_dtg = self._pending_grey = self._pending_df = None
        self._outputs_pending = False
        with _channel_context("dtg"):
            self._dtg = DTGChannel(self._dtg_config(period)) if v["dtg.enabled"] else None
        with _channel_context("grey"):
            self._grey = self._grey_detector(period) if v["grey.enabled"] else None
        self._guard_outputs_of(tuple(c for c in ("dtg", "grey", "df") if v[f"{c}.enabled"]))
        if v["df.enabled"]:
            df_channel = _import_or_explain("gyrodiag.df.channel", "df.enabled")
            with _channel_context("df"):
                config = self._df_config(period)
                self._df = df_channel.DFChannel(config)
            if config.sensor_dynamics is not None and config.decision == "sequential":
                # only when asked for explicitly (df.decision = 1): auto picks the paper rule
                # measured (docs/notes.md, System): detection holds, isolation does not
                self.report_warning(
                    f"{self.instance_name}: df: with df.sensor_dynamics_file the sequential "
                    "rule (df.decision = 1) detects but does not isolate or type faults "
                    "reliably (its whitening assumes white sensor noise; the matched "
                    "filter colours it): set df.decision = 0 (paper rule) to isolate")
        self._applied = {n: v[n] for n in _TUNABLE_NAMES}

    def _apply_tunables(self) -> bool:
        """Rebuild the channels whose tunable parameters changed, keeping their state.

        Returns False (with an error logged, the previous values restored) if a new
        value is refused.
        """
        if not self.watched_changed:
            return True
        self.watched_changed = False
        v = self.values
        changed = [n for n in _TUNABLE_NAMES if v[n] != self._applied[n]]
        if not changed:
            return True
        period = float(v["sample_period_s"])
        rebuilt: dict[str, Any] = {}
        try:
            errors = self.range_errors(VARIABLE_META, changed)
            if errors:
                raise ValueError("; ".join(errors))
            for channel, names in TUNABLE.items():
                running = getattr(self, f"_{channel}")
                if running is None or not any(n in changed for n in names):
                    continue
                with _channel_context(channel):
                    fresh = (DTGChannel(self._dtg_config(period)) if channel == "dtg"
                             else self._grey_detector(period))
                fresh.set_state(running.get_state())
                rebuilt[channel] = fresh
        except (ValueError, TypeError) as exc:
            kept = ", ".join(f"{n} = {self._applied[n]!r}" for n in sorted(changed))
            for n in changed:
                v[n] = self._applied[n]
            self.report_error(f"{self.instance_name}: tunable parameter change refused: {exc}."
                              f" Kept {kept}; the step was not taken")
            return False
        for channel, fresh in rebuilt.items():
            setattr(self, f"_{channel}", fresh)
        self._applied.update({n: v[n] for n in changed})
        return True

    def _guard_outputs_of(self, channels: tuple[str, ...]) -> None:
        """Guard the Real outputs of these channels and those of no channel (the
        outputs of a disabled channel keep their finite start values)."""
        self._guarded = [n for n in self._real_outputs
                         if n.split(".", 1)[0] in channels or "." not in n]
        gather = operator.itemgetter(*self._guarded) if self._guarded else None
        self._guarded_values = (
            (lambda v: ()) if gather is None
            else gather if len(self._guarded) > 1 else (lambda v: (gather(v),)))

    def _guard_finite_outputs(self) -> None:
        """Publish 0 for any non-finite Real output (outputs are always finite; the known
        cases have validity outputs), with a warning once per variable."""
        v = self.values
        # one C-level gather and sum; inf/NaN anywhere makes total - total NaN (an
        # overflowing sum of finite values only sends us down the exact loop)
        total = sum(self._guarded_values(v))
        if total - total == 0.0:
            return
        for name in self._guarded:
            x = v[name]
            if not math.isfinite(x):
                v[name] = 0.0
                if name not in self._nonfinite_reported:
                    self._nonfinite_reported.add(name)
                    self.report_warning(f"{self.instance_name}: output {name} was {x!r}; "
                                        "published as 0 (outputs are always finite)")

    def _dtg_config(self, period: float) -> DTGChannelConfig:
        v = self.values
        kind = int(v["dtg.estimator"])
        if kind not in range(len(ESTIMATOR_KINDS)):
            raise ValueError(f"dtg.estimator must be 0, 1 or 2, got {kind}")
        max_distance = float(v["dtg.max_distance"])
        classifier = str(v["dtg.classifier"]).strip()
        if classifier not in CLASSIFIERS:
            raise ValueError(f"dtg.classifier must be one of {', '.join(CLASSIFIERS)}, got "
                             f"{classifier!r}")
        case_rate = int(v["dtg.case_rate"])
        if case_rate not in range(len(DTG_CASE_RATE_CODES)):
            raise ValueError(f"dtg.case_rate must be 0 (none), 1 (central) or 2 (paper), got "
                             f"{case_rate}")
        signatures, patterns = self._dtg_library(classifier, period)
        return DTGChannelConfig(
            sample_period_s=period,
            prefilter_enabled=bool(v["dtg.prefilter_enabled"]),
            prefilter_order=_named_int(v, "dtg.prefilter_order"),
            prefilter_cutoff_hz=float(v["dtg.prefilter_cutoff_hz"]) or None,
            prefilter_highpass_hz=(
                None if float(v["dtg.prefilter_highpass_hz"]) == 0.0
                else float(v["dtg.prefilter_highpass_hz"])
            ),
            estimator=ESTIMATOR_KINDS[kind],
            window=_named_int(v, "dtg.window"),
            forgetting=_auto(float(v["dtg.forgetting"])),
            p0=float(v["dtg.p0"]),
            theta0=None if v["dtg.learn_theta0"] else [
                float(v[f"dtg.theta0[{i}]"]) for i in range(1, N_THETA + 1)],
            learn_start_s=_auto(float(v["dtg.learn_start_s"])),
            learn_end_s=_auto(float(v["dtg.learn_end_s"])),
            low=_auto(float(v["dtg.low"])),
            high=_auto(float(v["dtg.high"])),
            persistence_k=_auto(_named_int(v, "dtg.persistence_k")),
            persistence_n=_auto(_named_int(v, "dtg.persistence_n")),
            band_sigma=float(v["dtg.band_sigma"]),
            latch=bool(v["dtg.latch"]),
            monitored=[bool(v[f"dtg.monitored[{i}]"]) for i in range(1, N_THETA + 1)],
            signatures=signatures,
            max_distance=None if max_distance < 0 else max_distance,
            classify_window_s=float(v["dtg.classify_window_s"]),
            classifier=classifier,  # type: ignore[arg-type]
            patterns=patterns,
            window_s=float(v["dtg.window_s"]),
            long_window_s=float(v["dtg.long_window_s"]),
            level_threshold=float(v["dtg.level_threshold"]),
            var_threshold=float(v["dtg.var_threshold"]),
            long_var_threshold=float(v["dtg.long_var_threshold"]),
            theta_spread_threshold=float(v["dtg.theta_spread_threshold"]),
            power_threshold=float(v["dtg.power_threshold"]),
            allowance_sigma=float(v["dtg.allowance_sigma"]),
            clear_after_s=float(v["dtg.clear_after_s"]),
            case_rate=DTG_CASE_RATE_CODES[case_rate],
            pickoff_scale=float(v["dtg.pickoff_scale"]),
            case_rate_delay_samples=_named_int(v, "dtg.case_rate_delay_samples"),
            case_rate_align_max=_named_int(v, "dtg.case_rate_align_max"),
            case_rate_lookahead_s=float(v["dtg.case_rate_lookahead_s"]),
        )

    def _dtg_library(self, classifier: str, period: float
                     ) -> tuple[dict[str, list[float]], PatternLibrary | None]:
        """(decade signatures, pattern library) from dtg.signature_file or the table."""
        v = self.values
        path_text = str(v["dtg.signature_file"]).strip()
        n = int(v["dtg.n_signatures"])
        if not 0 <= n <= MAX_SIGNATURES:
            raise ValueError(f"dtg.n_signatures must be in [0, {MAX_SIGNATURES}], got {n}")
        if classifier == "pattern" and n > 0 and not path_text:
            raise ValueError(
                f"dtg.n_signatures = {n}: the signature table holds decade signatures of "
                "dtg.classifier = paper; the pattern classifier reads a pattern library "
                "from dtg.signature_file")
        if not path_text:
            table = {
                f"signature_{j}": [float(v[f"dtg.signature[{j},{i}]"])
                                   for i in range(1, N_THETA + 1)]
                for j in range(1, n + 1)
            }
            if classifier == "paper":
                return table, None
            return {}, self._shipped_patterns(period)
        path = Path(path_text)
        if not path.is_absolute() and self.resources:
            path = Path(self.resources) / path
        try:
            data = json.loads(path.read_text(encoding="utf-8"))
        except (OSError, json.JSONDecodeError) as exc:
            raise ValueError(f"dtg.signature_file {str(path)!r} cannot be read: {exc}") from None
        if not isinstance(data, dict):
            raise ValueError(f"dtg.signature_file {str(path)!r} must hold a JSON object")
        if classifier == "pattern":
            if "patterns" not in data:
                raise ValueError(
                    f"dtg.signature_file {str(path)!r} holds no 'patterns' library (decade "
                    "signatures are for dtg.classifier = paper; learn patterns with "
                    "python -m harness learn-signatures on pattern training scenarios)")
            try:
                return {}, PatternLibrary.from_dict(data["patterns"])
            except (ValueError, TypeError) as exc:
                raise ValueError(f"dtg.signature_file {str(path)!r}: {exc}") from None
        sigs = data.get("signatures")
        if not isinstance(sigs, dict) or not sigs:
            raise ValueError(
                f"dtg.signature_file {str(path)!r} must hold a non-empty object "
                "'signatures': {name: [C1, ..., C5]} for dtg.classifier = paper"
                + (" (it holds a pattern library: set dtg.classifier = pattern)"
                   if "patterns" in data else "")
            )
        return {str(k): list(s) for k, s in sigs.items()}, None

    def _shipped_patterns(self, period: float) -> PatternLibrary | None:
        """The shipped pattern library, or None at a sample period it was not learned
        for: the channel then detects and reports class unknown (a warning at the first
        alarm says why)."""
        # this instance's copy: another instance's extracted module may be gone by now
        own = Path(self.resources) / DEFAULT_LIBRARY_RESOURCE if self.resources else None
        lib = default_library(own if own is not None and own.exists() else None)
        if abs(period - lib.sample_period_s) <= 1e-6 * lib.sample_period_s:
            return lib
        self._unclassified_note = (  # reported at the first DTG alarm, if any
            f"{self.instance_name}: dtg: the shipped pattern library was learned at "
            f"sample_period_s = {lib.sample_period_s:g} s; at {period:g} s DTG faults are "
            "detected but not classified (learn a library at this period: dtg.signature_file)")
        return None

    def _grey_detector(self, period: float) -> GreyFaultDetector:
        v = self.values
        predictor, candidates = self._grey_predictors()
        clear = float(v["grey.clear_after_s"])
        rule = self._grey_decision()
        for package in rule.requires:
            _import_or_explain(package, f"grey.decision = {int(v['grey.decision'])} (a "
                               "learned rule; the paper rule, grey.decision = 0, does "
                               "without it)")
        return rule.build(predictor, period, None if clear <= 0 else clear, candidates)

    def _grey_predictors(self) -> tuple[Any, list[Any]]:
        """The grey predictor, and the improved model's other residual orders that
        compete on the calibration window (``grey.auto_order``; a learned rule uses
        them, the paper rule does not)."""
        v = self.values
        model = int(v["grey.model"])
        window = _named_int(v, "grey.window")
        if model == 0:
            evaluation = _named_int(v, "grey.classic_evaluation")
            if evaluation not in (0, 1):
                raise ValueError("grey.classic_evaluation must be 0 (careful) or 1 (textbook), "
                                 f"got {evaluation}")
            # window 0 stands for None: FMI has no "absent" Integer
            return ClassicGreyPredictor(
                None if window == 0 else window,
                evaluation="textbook" if evaluation == 1 else "careful",
            ), []
        if model != 1:
            raise ValueError(f"grey.model must be 0 (classic) or 1 (improved), got {model}")
        if window == 0:
            raise ValueError("grey.window = 0 (whole record) is only available for the "
                             "classic model (grey.model = 0); the improved model needs "
                             "a moving window >= 4")
        order = _named_int(v, "grey.residual_order")
        a_min = float(v["grey.a_min"])
        predictor = ImprovedGreyPredictor(window, a_min=a_min, residual_order=order)
        candidates = ([ImprovedGreyPredictor(window, a_min=a_min, residual_order=o)
                       for o in (1, 0) if o != order] if bool(v["grey.auto_order"]) else [])
        return predictor, candidates

    def _grey_decision(self) -> GreyDecision:
        """The rule of ``grey.decision`` with its parameters."""
        v = self.values
        code = _named_int(v, "grey.decision")
        rule = GREY_DECISIONS.get(code)
        if rule is None:
            raise ValueError(f"grey.decision must be 0 (paper), 1 (sequential) or 2 "
                             f"(k-sigma), got {code}")
        if rule is PaperThreshold:
            return PaperThreshold(float(v["grey.threshold"]))
        learned: dict[str, Any] = {
            "learn_end_s": float(v["grey.learn_end_s"]),
            "threshold_floor": float(v["grey.threshold_floor"]),
            "k_sigma": float(v["grey.k_sigma"]),
            "suspicion_sigma": float(v["grey.suspicion_sigma"]),
        }
        if rule is CalibratedSequential:
            learned.update(
                false_alarms_per_h=float(v["grey.false_alarm_rate"]),
                cusum_k=float(v["grey.cusum_k"]), lag_max=_named_int(v, "grey.lag_max"),
                reference_window_s=float(v["grey.reference_window_s"]),
                reference_order=_named_int(v, "grey.reference_order"))
        return rule(**learned)

    def reset(self) -> None:  # pythonfmu re-creates the instance on fmi2Reset
        pass

    # ------------------------------------------------------------------ stepping
    def do_step(self, current_time: float, step_size: float) -> bool:
        # Returning False would mean fmi2Discard (docs/methods.md §6.7): always True, and report
        # problems through the logger (→ fmi2Error).
        try:
            self._step(current_time, step_size)
        except Exception as exc:
            self.report_exception("fmi2DoStep", exc)
        return True

    def _step(self, t: float, h: float) -> None:
        if not self._ready:
            self.report_error(
                f"{self.instance_name}: doStep called but initialisation did not succeed "
                "(see the earlier error); fix the parameters and re-instantiate or reset"
            )
            return
        period = self._period
        if h == self._last_step:  # the usual case: the same step as before
            n = self._last_samples
        else:
            if not self.check_step(h):
                return
            n = samples_in_step(h, period)
            if n is not None:
                self._last_step, self._last_samples = h, n
        if self.watched_changed and not self._apply_tunables():
            return
        if n == 1:
            self._sample(t)
        elif n is not None:
            for i in range(n):
                self._sample(t + i * period)
        else:  # not a whole number of periods: the sample instants that fall in the step
            for t_k in sample_instants(self._start_time, period, t, h):
                self._sample(t_k)

    def _sample(self, t: float) -> None:
        """Process one sample of every enabled channel, taken at time ``t``."""
        v = self.values
        valid = True
        codes: list[int] = []
        if self._dtg is not None:
            out = self._dtg.update(*_dtg_inputs(v))
            if not self._dtg_reference_warned and self._dtg.reference_failed:
                self._dtg_reference_warned = True
                self.report_warning(
                    f"{self.instance_name}: dtg: no reference theta0 was learned between "
                    "dtg.learn_start_s and dtg.learn_end_s (a zero entry: no excitation on "
                    "the DTG inputs); the DTG channel will not alarm")
            if math.isnan(self._dtg_first_alarm_time) and not math.isnan(
                out.first_alarm_time_s
            ):
                self._dtg_first_alarm_time = t
            self._pending_dtg = out
            valid &= out.valid
            if out.alarm:
                code = out.fault_code
                codes.append(SUMMARY_CODE_BASE["dtg"] + (code if code > 0 else -1))
        if self._grey is not None:
            g = self._grey.update(float(v["grey.y"]), time_s=t)
            self._pending_grey = g
            valid &= g.valid
            if g.alarm:
                codes.append(SUMMARY_CODE_BASE["grey"])
        if self._df is not None:
            df_out = self._df.update_floats(_df_u(v), _df_y(v))
            self._pending_df = df_out
            valid &= df_out.valid
            if df_out.alarm:
                iso = df_out.isolated_sensor
                codes.append(SUMMARY_CODE_BASE["df"] + (iso if iso > 0 else (
                    DF_MULTIPLE if iso == DF_MULTIPLE else DF_NOT_ISOLATED)))
        v["any_alarm"] = bool(codes)
        v["fault_code"] = codes[0] if codes else 0
        v["inputs_valid"] = bool(valid)
        self._outputs_pending = True

    def _sync_outputs(self) -> None:
        """Copy the channels' last outputs into the output variables.

        Deferred from the samples to the first read or state save after them: a step of
        n samples copies once, and a host that reads a few outputs does not pay for the
        ~150 it does not read. The published values are the last sample's either way
        (block-rate and on-change copies compare with what was copied last).
        """
        if not self._outputs_pending:
            return
        self._outputs_pending = False
        # the copies check the Real outputs they write at every sample (one sum) and
        # flag the rest: the full guard runs only when something may be non-finite
        self._outputs_unchecked = False
        if self._pending_dtg is not None:
            self._copy_dtg(self._pending_dtg)
        if self._pending_grey is not None:
            self._copy_grey(self._pending_grey)
        if self._pending_df is not None:
            self._copy_df(self._pending_df)
        if self._outputs_unchecked:
            self._guard_finite_outputs()

    def _copy_grey(self, g: Any) -> None:
        v = self.values
        prediction_valid = math.isfinite(g.prediction)
        v["grey.prediction"] = g.prediction if prediction_valid else 0.0
        v["grey.error"] = g.error if math.isfinite(g.error) else 0.0
        v["grey.prediction_valid"] = prediction_valid
        v["grey.alarm"] = g.alarm
        v["grey.valid"] = g.valid
        v["grey.calibrating"] = g.calibrating
        v["grey.statistic"] = g.statistic
        assert self._grey is not None
        sigma = self._grey.sigma
        sigma = sigma if sigma == sigma else 0.0
        v["grey.sigma"] = sigma
        noise = self._grey.noise_sigma
        noise = noise if noise == noise else 0.0
        v["grey.noise_sigma"] = noise
        checked = g.statistic + sigma + noise
        if checked - checked != 0.0:
            self._outputs_unchecked = True

    def _copy_dtg(self, out: Any) -> None:
        v = self.values
        # the channel's arrays have fixed shapes (2×5, 2×5, 5): plain zips
        theta_eta = out.theta.ravel().tolist() + out.eta.ravel().tolist()
        v.update(zip(_DTG_THETA_ETA_KEYS, theta_eta, strict=True))
        assert self._dtg is not None
        theta0 = self._dtg.theta0
        if theta0 is not self._theta0_copied:  # set once, when learning ends
            self._theta0_copied = theta0
            self._outputs_unchecked = True
            rows = (_ZEROS_5, _ZEROS_5) if theta0 is None else theta0.reshape(-1, N_THETA)
            v.update(zip(_DTG_THETA0_KEYS, _flat_floats(rows[0]), strict=True))
            v.update(zip(_DTG_THETA0_Y_KEYS, _flat_floats(rows[-1]), strict=True))
        physical = out.physical.tolist()
        # the sum of finite values is finite unless it overflows (then: the exact test)
        total = sum(physical)
        physical_valid = total - total == 0.0 or all(math.isfinite(x) for x in physical)
        v.update(zip(_DTG_PHYSICAL_KEYS, physical if physical_valid else _ZEROS_5, strict=True))
        v["dtg.physical_valid"] = physical_valid
        v["dtg.learning"] = bool(out.learning)
        v["dtg.alarm"] = bool(out.alarm)
        code = int(out.fault_code) if out.alarm else 0
        v["dtg.fault_code"] = code
        if code != self._dtg_named_code:  # the name follows the code
            self._dtg_named_code = code
            v["dtg.fault_name"] = self._dtg.class_name(code)
            if code != 0 and self._unclassified_note:
                self.report_warning(self._unclassified_note)
                self._unclassified_note = ""
        first = self._dtg_first_alarm_time
        first = -1.0 if math.isnan(first) else first
        v["dtg.first_alarm_time"] = first
        checked = sum(theta_eta) + first  # physical: checked above
        if checked - checked != 0.0:
            self._outputs_unchecked = True
        v["dtg.valid"] = bool(out.valid)
        v["dtg.case_rate_delay_in_use"] = self._dtg.case_rate_delay
        d = out.diagnosis
        if d.block != self._dtg_block_copied:  # block-rate outputs change at block ends
            self._copy_dtg_diagnosis(out)
            self._dtg_block_copied = d.block
        if not out.alarm and v["dtg.fault_type"] != 0:
            self._copy_dtg_diagnosis(out)

    def _copy_dtg_diagnosis(self, out: DTGChannelOutput) -> None:
        """Reference, residual tests and class (sentinels instead of NaN)."""
        self._outputs_unchecked = True  # a block's outputs: the full guard checks them
        v = self.values
        d = out.diagnosis
        v["dtg.reference_status"] = int(d.reference_status)
        v["dtg.reference_valid"] = d.reference_status == 1
        v["dtg.residual_alarm"] = bool(d.residual_alarm)
        alarm = bool(out.alarm)
        v["dtg.fault_type"] = int(d.fault_type) if alarm else 0
        v["dtg.fault_signal"] = int(d.fault_signal) if alarm else 0
        v["dtg.fault_axis"] = int(d.fault_axis) if alarm else 0
        v["dtg.class_distance"] = _finite_or(d.distance, -1.0) if alarm else -1.0
        size_ok = alarm and math.isfinite(d.size)
        v["dtg.fault_size"] = float(d.size) if size_ok else 0.0
        v["dtg.fault_size_valid"] = size_ok
        v["dtg.fault_rate"] = _finite_or(d.rate, 0.0) if alarm else 0.0
        v["dtg.fault_ratio"] = _finite_or(d.ratio, 1.0) if alarm else 1.0
        for i in range(N_CHANNELS):
            v[f"dtg.level[{i + 1}]"] = _finite_or(float(d.level[i]), 0.0)
            v[f"dtg.log_var_ratio[{i + 1}]"] = _finite_or(float(d.log_variance[i]), 0.0)
        v["dtg.level_growth"] = _finite_or(d.growth, 0.0)
        v["dtg.stat_window_s"] = float(d.window_s)
        for a in range(2):
            v[f"dtg.residual_level_z[{a + 1}]"] = _finite_or(float(d.tests[a]), 0.0)
            v[f"dtg.residual_var_ratio[{a + 1}]"] = _finite_or(float(d.tests[2 + a]), 0.0)
            v[f"dtg.residual_long_var_ratio[{a + 1}]"] = _finite_or(float(d.tests[4 + a]),
                                                                    0.0)
            v[f"dtg.residual_power_cusum[{a + 1}]"] = _finite_or(float(d.tests[6 + a]), 0.0)
        assert self._dtg is not None
        ref = self._dtg.reference
        per_axis = None if ref is None else ref.theta0.reshape(-1, N_THETA)
        for i in range(N_THETA):
            v[f"dtg.ref_theta0[{i + 1}]"] = 0.0 if per_axis is None else float(per_axis[0, i])
            v[f"dtg.ref_theta0_y[{i + 1}]"] = (0.0 if per_axis is None
                                               else float(per_axis[-1, i]))
        for key, attr in (("ref_mean", "mean"), ("ref_block_std", "block_std"),
                          ("ref_var_short", "var_short"), ("ref_var_long", "var_long")):
            for i in range(N_CHANNELS):
                v[f"dtg.{key}[{i + 1}]"] = 0.0 if ref is None else float(getattr(ref, attr)[i])

    # ------------------------------------------------------------------ state
    def _capture_state(self) -> dict[str, Any]:
        return {
            "ready": self._ready,
            "start_time": self._start_time,
            "dtg_first_alarm_time": self._dtg_first_alarm_time,
            "dtg": None if self._dtg is None else self._dtg.get_state(),
            "grey": None if self._grey is None else self._grey.get_state(),
            "df": None if self._df is None else self._df.get_state(),
        }

    def _restore_state(self, state: dict[str, Any]) -> None:
        # Channels are rebuilt from the (restored) parameters, then their state is set.
        # the restored variables hold the outputs (saved after _sync_outputs)
        self._pending_dtg = self._pending_grey = self._pending_df = None
        self._outputs_pending = False
        self._theta0_copied = False
        if state["ready"]:
            self._build_channels()
        self._ready = bool(state["ready"])
        self._start_time = float(state["start_time"])
        self._dtg_first_alarm_time = float(state["dtg_first_alarm_time"])
        self._dtg_block_copied = -1  # the restored values are complete; recopy at the next block
        self._dtg_named_code = None
        for name, channel in (("dtg", self._dtg), ("grey", self._grey), ("df", self._df)):
            sub = state[name]
            if (sub is None) != (channel is None):
                raise ValueError(f"FMU state of channel {name!r} does not match its 'enabled'")
            if channel is not None:
                channel.set_state(sub)


#: Library argument names → FMU parameter names, per channel, so that a validation
#: message names the parameter the user has to change.
_PARAMETER_NAMES: dict[str, dict[str, str]] = {
    "dtg": {
        "order": "dtg.prefilter_order", "cutoff_hz": "dtg.prefilter_cutoff_hz",
        "highpass_hz": "dtg.prefilter_highpass_hz",
        "sample_rate_hz": "1/sample_period_s", "estimator": "dtg.estimator",
        "window": "dtg.window", "forgetting": "dtg.forgetting", "p0": "dtg.p0",
        "theta0": "dtg.theta0[1..5]", "learn_start_s": "dtg.learn_start_s",
        "learn_end_s": "dtg.learn_end_s", "low": "dtg.low", "high": "dtg.high",
        "persistence_k": "dtg.persistence_k", "persistence_n": "dtg.persistence_n",
        "monitored": "dtg.monitored[1..5]", "classify_window_s": "dtg.classify_window_s",
        "signatures": "signatures (dtg.signature[j,i] or dtg.signature_file)",
        "max_distance": "dtg.max_distance", "classifier": "dtg.classifier",
        "window_s": "dtg.window_s", "long_window_s": "dtg.long_window_s",
        "level_threshold": "dtg.level_threshold", "var_threshold": "dtg.var_threshold",
        "long_var_threshold": "dtg.long_var_threshold",
        "theta_spread_threshold": "dtg.theta_spread_threshold",
        "power_threshold": "dtg.power_threshold",
        "allowance_sigma": "dtg.allowance_sigma",
        "clear_after_s": "dtg.clear_after_s", "patterns": "dtg.signature_file",
        "case_rate": "dtg.case_rate", "pickoff_scale": "dtg.pickoff_scale",
        "case_rate_delay_samples": "dtg.case_rate_delay_samples",
        "case_rate_align_max": "dtg.case_rate_align_max",
        "case_rate_lookahead_s": "dtg.case_rate_lookahead_s",
    },
    "grey": {
        "window": "grey.window", "threshold": "grey.threshold", "a_min": "grey.a_min",
        "clear_after_s": "grey.clear_after_s", "residual_order": "grey.residual_order",
        "k_sigma": "grey.k_sigma", "false_alarms_per_h": "grey.false_alarm_rate",
        "cusum_k": "grey.cusum_k", "suspicion_sigma": "grey.suspicion_sigma",
        "learn_end_s": "grey.learn_end_s", "threshold_floor": "grey.threshold_floor",
        "lag_max": "grey.lag_max",
        "reference_window_s": "grey.reference_window_s",
        "reference_order": "grey.reference_order",
    },
    "df": {
        "eigenvalues": "df.eigenvalue[1..5]", "calibrate_s": "df.calibrate_s",
        "burn_in_s": "df.burn_in_s", "k_sigma": "df.k_sigma",
        "main_thresholds": "df.threshold[1..6]", "bank_thresholds": "df.bank_threshold[i,j]",
        "noise_std": "df.noise_std[1..6]", "persistence_k": "df.persistence_k",
        "persistence_n": "df.persistence_n", "confirm_samples": "df.confirm_samples",
        "isolation_window_s": "df.isolation_window_s",
        "isolation_baseline_s": "df.isolation_baseline_s",
        "x0": "df.x0[1..5]", "decision": "df.decision",
        "sensor_dynamics": "df.sensor_dynamics_file",
        "false_alarms_per_h": "df.false_alarm_rate", "cusum_k": "df.cusum_k",
        "variance_ratio": "df.variance_ratio", "max_faults": "df.max_faults",
        "history_s": "df.history_s", "memory_s": "df.memory_s",
        "input_delay_samples": "df.input_delay_samples", "align_auto": "df.align_auto",
        "align_max": "df.align_max", "sensor_delay_samples": "df.sensor_delay[1..6]",
    },
}


def _fill_variable_meta() -> None:
    """Fill VARIABLE_META at import time.

    build_fmu.py reads VARIABLE_META from its own import of this module, in which no
    Diagnoser has been instantiated (the pythonfmu builder instantiates the class in a
    separate module object), so declaring the variables once here is what puts the
    units and ranges into the modelDescription.
    """
    Diagnoser(instance_name="variable-table")


@contextlib.contextmanager
def _channel_context(prefix: str) -> Iterator[None]:
    """Rewrite a channel's validation message in terms of its FMU parameter names."""
    try:
        yield
    except (ValueError, TypeError) as exc:
        text = str(exc)
        if text.startswith(f"{prefix}."):
            raise
        names = _PARAMETER_NAMES[prefix]
        # whole identifiers only, and not ones already qualified ("dtg.window")
        pattern = r"(?<![\w.])(" + "|".join(map(re.escape, names)) + r")(?![\w\[])"
        renamed, count = re.subn(pattern, lambda m: names[m.group(1)], text)
        if count:
            raise ValueError(renamed) from None
        raise ValueError(
            f"channel {prefix!r} (parameters {prefix}.*): {text}"
        ) from None


def _finite_or(value: float, fallback: float) -> float:
    """``value`` if finite, else the documented sentinel (outputs never carry NaN)."""
    return float(value) if math.isfinite(value) else fallback


def _flat_floats(values: Any) -> list[float]:
    """Row-major Python floats of an array or a (nested) sequence of numbers."""
    return np.asarray(values, dtype=float).ravel().tolist()


def _as_list(values: Any) -> list:
    """Plain Python values of an array or sequence (one call for a numpy array)."""
    return values.tolist() if isinstance(values, np.ndarray) else list(values)


class MissingPackageError(ImportError):
    """A package a channel needs is not installed in the host's Python."""


def _import_or_explain(module: str, needed_by: str) -> Any:
    """Import a module needed only by some channels; a missing package is explained.

    Raises
    ------
    MissingPackageError
        Naming the missing package, who needs it and how to install it (the facade
        turns it into fmi2Error with this message in the log).
    """
    import importlib

    try:
        return importlib.import_module(module)
    except ModuleNotFoundError as exc:
        missing = (exc.name or str(exc)).split(".")[0]
        requirement = next((r.split("#")[0].strip() for r in REQUIREMENTS
                            if r.lower().startswith(missing.lower())), missing)
        raise MissingPackageError(
            f"{needed_by} needs the Python package {missing!r}, which is not installed in "
            f"the host's Python: pip install '{requirement}' (or pip install -r "
            "resources/requirements.txt of this FMU), or switch the channel off"
        ) from None


def _auto(value: Any) -> Any:
    """None (the library's automatic value) for the AUTO sentinel, else the value."""
    return None if value == AUTO else value


def _named_int(values: dict[str, Any], name: str) -> int:
    value = values[name]
    if isinstance(value, bool) or int(value) != value:
        raise ValueError(f"{name} must be an integer, got {value!r}")
    return int(value)


_fill_variable_meta()
