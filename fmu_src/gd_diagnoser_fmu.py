"""Diagnoser.fmu: the gyrodiag algorithm library as an FMI 2.0 co-simulation FMU.

A thin facade: it declares the variables, builds the library's channel objects from
the parameters when initialisation ends, feeds them one sample per communication step
and copies their outputs. All the diagnosis lives in the ``gyrodiag`` package, shipped
in the FMU's resources.

Channels (each can be switched off):

* DTG: parameter identification of a dynamically tuned gyro (``gyrodiag.dtg_channel``).
* Grey: grey-prediction fault detection of one signal, e.g. an HRG output
  (``gyrodiag.grey``).
* Detection filter: sensor-fault detection and isolation on a linear plant, by default
  the seed aircraft (``gyrodiag.df_channel``).

Sampled-data contract: every enabled channel processes exactly one sample per
``doStep``, taken from the inputs set before the step (at the step's start time), and
the outputs after the step describe that sample. The communication step must equal
``sample_period_s`` (relative tolerance 1e−6); any other step is refused with fmi2Error.
Run several instances for channels at different rates.

Errors: an invalid parameter, a wrong step or an unexpected exception is logged through
the FMU logger with the parameter name and allowed range, and the call returns
fmi2Error (never fmi2Fatal): the status shim in the FMU binary maps the logged error.
NaN/Inf on a channel's input clears that channel's ``valid`` output, leaves its state
untouched, and the channel resumes on the next valid sample: its outputs are then those
of a run without that sample (the channels' own clocks count valid samples, e.g. for the
learning and calibration windows). Reported times (``dtg.first_alarm_time``) are
simulation times.
"""

from __future__ import annotations

import contextlib
import json
import math
import re
from collections.abc import Iterator
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from gd_fmu_base import FacadeBase
from pythonfmu import DefaultExperiment

from gyrodiag.aircraft import seed_aircraft
from gyrodiag.decision import UNKNOWN_CODE
from gyrodiag.dtg import N_THETA
from gyrodiag.dtg_channel import ESTIMATOR_KINDS, DTGChannel, DTGChannelConfig
from gyrodiag.grey import ClassicGreyPredictor, GreyFaultDetector, ImprovedGreyPredictor

if TYPE_CHECKING:  # imported when the channel is built: it needs SciPy (design time)
    from gyrodiag.df_channel import DFChannel, DFChannelConfig, DFChannelOutput

#: Signatures that fit in the parameter table (more: use ``dtg.signature_file``).
MAX_SIGNATURES = 8
#: Fault codes of the summary output ``fault_code``.
SUMMARY_CODE_BASE = {"dtg": 100, "grey": 200, "df": 300}

SEED = seed_aircraft()
#: Detection-filter dimensions: states, inputs, sensors (those of the seed aircraft).
DF_N, DF_P, DF_M = SEED.A.shape[0], SEED.B.shape[1], SEED.C.shape[0]

PHYSICAL_NAMES = ("c_over_J", "k_over_J", "L_over_J", "lambda_over_J", "Ku_over_KT_J")
PHYSICAL_UNITS = ("1/s", "1/s2", "rad/s", "1/s2", "1/s2")

#: Packages the host's Python needs (written to resources/requirements.txt).
REQUIREMENTS = ["numpy>=1.24", "scipy>=1.10"]

VARIABLE_META: dict[str, dict[str, Any]] = {}

# Variable names used at every step, formatted once (an f-string per variable per step
# cost ~10 % of a step).
_DTG_INPUT_KEYS = ("dtg.Utx", "dtg.Uty", "dtg.Ux", "dtg.Uy")
_DTG_THETA_KEYS = tuple(tuple(f"dtg.theta_{axis}[{i + 1}]" for i in range(N_THETA))
                        for axis in ("x", "y"))
_DTG_ETA_KEYS = tuple(tuple(f"dtg.eta_{axis}[{i + 1}]" for i in range(N_THETA))
                      for axis in ("x", "y"))
_DTG_THETA0_KEYS = tuple(f"dtg.theta0_used[{i + 1}]" for i in range(N_THETA))
_DTG_PHYSICAL_KEYS = tuple(f"dtg.{name}" for name in PHYSICAL_NAMES)
_DF_U_KEYS = tuple(f"df.u[{j + 1}]" for j in range(DF_P))
_DF_Y_KEYS = tuple(f"df.y[{i + 1}]" for i in range(DF_M))
_DF_RESIDUAL_KEYS = tuple(f"df.residual[{i + 1}]" for i in range(DF_M))
_DF_ALARM_KEYS = tuple(f"df.alarm[{i + 1}]" for i in range(DF_M))
_DF_THRESHOLD_KEYS = tuple(f"df.threshold_in_use[{i + 1}]" for i in range(DF_M))

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

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(**kwargs)
        self._declare()
        self._dtg: DTGChannel | None = None
        self._grey: GreyFaultDetector | None = None
        self._df: DFChannel | None = None
        self._ready = False
        self._start_time = 0.0
        # Host time of the first DTG alarm: the channel's own clock counts valid samples
        # only, so after a skipped NaN sample it would lag the simulation time.
        self._dtg_first_alarm_time = math.nan

    # ------------------------------------------------------------------ variables
    def _declare(self) -> None:
        p = self.add_variable
        p("sample_period_s", "Real", "parameter", 1e-3,
          "Sample period of every channel = required communication step")
        _meta("sample_period_s", "s", 0.0)
        # DTG channel
        p("dtg.enabled", "Boolean", "parameter", True, "Run the DTG identification channel")
        p("dtg.prefilter_enabled", "Boolean", "parameter", True,
          "Butterworth low-pass on all four DTG signals")
        p("dtg.prefilter_order", "Integer", "parameter", 6, "Butterworth order")
        _meta("dtg.prefilter_order", None, 1, 20)
        p("dtg.prefilter_cutoff_hz", "Real", "parameter", 50.0, "Butterworth cut-off")
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
        p("dtg.forgetting", "Real", "parameter", 0.99, "RLS forgetting factor")
        _meta("dtg.forgetting", "1", 0.0, 1.0)
        p("dtg.p0", "Real", "parameter", 1e6, "Initial RLS covariance scale")
        _meta("dtg.p0", "1", 0.0)
        p("dtg.learn_theta0", "Boolean", "parameter", True,
          "Learn nominal theta0 from the learning window (else use dtg.theta0[i])")
        for i in range(1, N_THETA + 1):
            p(f"dtg.theta0[{i}]", "Real", "parameter", 1.0, f"Nominal theta{i}")
            _meta(f"dtg.theta0[{i}]", "1")
        p("dtg.learn_start_s", "Real", "parameter", 1.0,
          "Start of the theta0 learning window after the first sample")
        _meta("dtg.learn_start_s", "s", 0.0)
        p("dtg.learn_end_s", "Real", "parameter", 5.0, "End of the theta0 learning window")
        _meta("dtg.learn_end_s", "s", 0.0)
        p("dtg.low", "Real", "parameter", 0.5, "Lower ratio threshold on eta")
        _meta("dtg.low", "1", 0.0, 1.0)
        p("dtg.high", "Real", "parameter", 1.5, "Upper ratio threshold on eta")
        _meta("dtg.high", "1", 1.0)
        p("dtg.persistence_k", "Integer", "parameter", 1, "Alarm when k of the last n violate")
        _meta("dtg.persistence_k", None, 1)
        p("dtg.persistence_n", "Integer", "parameter", 1, "Persistence window n, samples")
        _meta("dtg.persistence_n", None, 1)
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
          "An alarm is classified by the median feature of its samples in this last "
          "window (the signature-learning rule); 0: each sample alone (paper)")
        _meta("dtg.classify_window_s", "s", 0.0)
        for name in ("Utx", "Uty", "Ux", "Uy"):
            p(f"dtg.{name}", "Real", "input", 0.0, f"DTG signal {name}")
            _meta(f"dtg.{name}", "V")
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
              f"Nominal theta{i} in use (0 while learning)")
            _meta(f"dtg.theta0_used[{i}]", "1")
        for name, unit in zip(PHYSICAL_NAMES, PHYSICAL_UNITS, strict=True):
            p(f"dtg.{name}", "Real", "output", 0.0, f"Identified {name}")
            _meta(f"dtg.{name}", unit)
        p("dtg.learning", "Boolean", "output", False, "Nominal theta0 still being learned")
        p("dtg.alarm", "Boolean", "output", False, "DTG parameter-ratio alarm")
        p("dtg.fault_code", "Integer", "output", 0,
          "0 none, j = nearest signature j, -1 unknown/unclassified")
        p("dtg.first_alarm_time", "Real", "output", -1.0,
          "Simulation time of the first DTG alarm (its sample's time), -1 if none")
        _meta("dtg.first_alarm_time", "s")
        p("dtg.valid", "Boolean", "output", True, "Last DTG sample was finite")
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
        p("grey.threshold", "Real", "parameter", 0.05,
          "Alarm threshold on |y - prediction|, signal units")
        _meta("grey.threshold", None, 0.0)
        p("grey.clear_after_s", "Real", "parameter", 20.0,
          "Clear an alarm this long after onset; <= 0: never")
        _meta("grey.clear_after_s", "s")
        p("grey.a_min", "Real", "parameter", 1e-6,
          "|a| below which the improved model predicts by the polynomial")
        _meta("grey.a_min", "1", 0.0)
        p("grey.y", "Real", "input", 0.0, "Monitored signal")
        p("grey.prediction", "Real", "output", 0.0, "One-step prediction of this sample")
        p("grey.error", "Real", "output", 0.0, "y - prediction")
        p("grey.alarm", "Boolean", "output", False, "Grey prediction alarm")
        p("grey.valid", "Boolean", "output", True, "Last grey sample was finite")
        # Detection-filter channel
        self._declare_df()
        # Summary
        p("any_alarm", "Boolean", "output", False, "Any enabled channel in alarm")
        p("fault_code", "Integer", "output", 0,
          "0 none; 100+j DTG signature j (99 unknown); 200 grey alarm; "
          "300+i sensor i isolated by the detection filter (299 not isolated)")
        p("inputs_valid", "Boolean", "output", True, "All enabled channels' inputs finite")

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
            _meta(f"df.eigenvalue[{i + 1}]", "1/s")
            p(f"df.x0[{i + 1}]", "Real", "parameter", 0.0,
              f"Initial estimate of state {SEED.state_names[i]}")
            _meta(f"df.x0[{i + 1}]", SEED.state_units[i])
        p("df.calibrate_s", "Real", "parameter", 10.0,
          "Fault-free calibration window for the thresholds; 0: use df.threshold[i]")
        _meta("df.calibrate_s", "s", 0.0)
        p("df.burn_in_s", "Real", "parameter", 2.0,
          "Start of the calibration window ignored (observer convergence)")
        _meta("df.burn_in_s", "s", 0.0)
        p("df.k_sigma", "Real", "parameter", 6.0, "Thresholds at k standard deviations")
        _meta("df.k_sigma", "1", 0.0)
        for i in range(DF_M):
            unit = SEED.output_units[i]
            p(f"df.threshold[{i + 1}]", "Real", "parameter", 1.0,
              f"Main residual threshold of sensor {SEED.output_names[i]} "
              "(used when df.calibrate_s = 0)")
            _meta(f"df.threshold[{i + 1}]", unit)
            p(f"df.noise_std[{i + 1}]", "Real", "parameter", -1.0,
              f"Noise std of sensor {SEED.output_names[i]}; < 0: threshold / k_sigma")
            _meta(f"df.noise_std[{i + 1}]", unit)
            used = [k for k in range(DF_M) if k != i]
            for j in range(DF_M - 1):
                p(f"df.bank_threshold[{i + 1},{j + 1}]", "Real", "parameter", 1.0,
                  f"Threshold of observer {i + 1} (without sensor {i + 1}) on its "
                  f"residual {j + 1}, sensor {SEED.output_names[used[j]]} "
                  "(used when df.calibrate_s = 0)")
                _meta(f"df.bank_threshold[{i + 1},{j + 1}]", SEED.output_units[used[j]])
        p("df.persistence_k", "Integer", "parameter", 3, "Residual alarm: k of the last n")
        _meta("df.persistence_k", None, 1)
        p("df.persistence_n", "Integer", "parameter", 5, "Residual alarm persistence n")
        _meta("df.persistence_n", None, 1)
        p("df.confirm_samples", "Integer", "parameter", 5,
          "Samples of one isolation pattern before it is latched")
        _meta("df.confirm_samples", None, 1)
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
              f"Residual threshold in use for sensor {SEED.output_names[i]} "
              "(learned or given; 0 while calibrating)")
            _meta(f"df.threshold_in_use[{i + 1}]", SEED.output_units[i])
        p("df.calibrating", "Boolean", "output", False, "Thresholds still being learned")
        p("df.detected", "Boolean", "output", False, "Sensor fault detected (latched)")
        p("df.isolated_sensor", "Integer", "output", 0,
          "1-based index of the isolated sensor; 0 none; -1 detected, not isolated")
        p("df.fault_type", "Integer", "output", 0,
          "-1 unknown, 0 none, 1 bias, 2 gain, 3 stuck, 4 complete failure")
        p("df.fault_magnitude", "Real", "output", 0.0,
          "Bias (sensor units), gain factor, stuck value or 0; NaN if unknown")
        p("df.valid", "Boolean", "output", True, "Last u, y sample was finite")

    def _df_config(self, period: float) -> DFChannelConfig:
        from gyrodiag.df_channel import DFChannelConfig

        v = self.values

        def matrix(name: str, rows: int, cols: int) -> np.ndarray:
            return np.array([[float(v[f"df.{name}[{i + 1},{j + 1}]"]) for j in range(cols)]
                             for i in range(rows)])

        def vector(name: str, size: int) -> np.ndarray:
            return np.array([float(v[f"df.{name}[{i + 1}]"]) for i in range(size)])

        noise = vector("noise_std", DF_M)
        return DFChannelConfig(
            A=matrix("A", DF_N, DF_N), B=matrix("B", DF_N, DF_P), C=matrix("C", DF_M, DF_N),
            eigenvalues=vector("eigenvalue", DF_N), sample_period_s=period,
            calibrate_s=float(v["df.calibrate_s"]), burn_in_s=float(v["df.burn_in_s"]),
            k_sigma=float(v["df.k_sigma"]), main_thresholds=vector("threshold", DF_M),
            bank_thresholds=matrix("bank_threshold", DF_M, DF_M - 1),
            noise_std=None if np.any(noise < 0) else noise,
            persistence_k=_named_int(v, "df.persistence_k"),
            persistence_n=_named_int(v, "df.persistence_n"),
            confirm_samples=_named_int(v, "df.confirm_samples"),
            x0=vector("x0", DF_N),
        )

    def _copy_df(self, out: DFChannelOutput) -> None:
        v = self.values
        for key, value in zip(_DF_RESIDUAL_KEYS, _as_list(out.residual), strict=True):
            v[key] = float(value)
        for key, value in zip(_DF_ALARM_KEYS, _as_list(out.alarms), strict=True):
            v[key] = bool(value)
        assert self._df is not None
        thresholds = self._df.thresholds
        if thresholds is None:
            for key in _DF_THRESHOLD_KEYS:
                v[key] = 0.0
        else:
            for key, value in zip(_DF_THRESHOLD_KEYS, _as_list(thresholds[0]), strict=True):
                v[key] = float(value)
        v["df.calibrating"] = bool(out.calibrating)
        v["df.detected"] = bool(out.detected)
        v["df.isolated_sensor"] = int(out.isolated_sensor)
        v["df.fault_type"] = int(out.fault_type)
        v["df.fault_magnitude"] = float(out.magnitude)
        v["df.valid"] = bool(out.valid)

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
            if self._dtg is not None:
                self._copy_dtg(self._dtg.last_output)
            if self._df is not None:
                self._copy_df(self._df.last_output)
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
        period = float(v["sample_period_s"])
        if not (math.isfinite(period) and period > 0.0):
            raise ValueError(f"sample_period_s must be > 0 s, got {period!r}")
        self._dtg = self._grey = self._df = None
        with _channel_context("dtg"):
            self._dtg = DTGChannel(self._dtg_config(period)) if v["dtg.enabled"] else None
        with _channel_context("grey"):
            self._grey = self._grey_detector(period) if v["grey.enabled"] else None
        if v["df.enabled"]:
            df_channel = _import_or_explain("gyrodiag.df_channel", "df.enabled")
            with _channel_context("df"):
                self._df = df_channel.DFChannel(self._df_config(period))

    def _dtg_config(self, period: float) -> DTGChannelConfig:
        v = self.values
        kind = int(v["dtg.estimator"])
        if kind not in range(len(ESTIMATOR_KINDS)):
            raise ValueError(f"dtg.estimator must be 0, 1 or 2, got {kind}")
        max_distance = float(v["dtg.max_distance"])
        return DTGChannelConfig(
            sample_period_s=period,
            prefilter_enabled=bool(v["dtg.prefilter_enabled"]),
            prefilter_order=_named_int(v, "dtg.prefilter_order"),
            prefilter_cutoff_hz=float(v["dtg.prefilter_cutoff_hz"]),
            prefilter_highpass_hz=(
                None if float(v["dtg.prefilter_highpass_hz"]) == 0.0
                else float(v["dtg.prefilter_highpass_hz"])
            ),
            estimator=ESTIMATOR_KINDS[kind],
            window=_named_int(v, "dtg.window"),
            forgetting=float(v["dtg.forgetting"]),
            p0=float(v["dtg.p0"]),
            theta0=None if v["dtg.learn_theta0"] else [
                float(v[f"dtg.theta0[{i}]"]) for i in range(1, N_THETA + 1)],
            learn_start_s=float(v["dtg.learn_start_s"]),
            learn_end_s=float(v["dtg.learn_end_s"]),
            low=float(v["dtg.low"]),
            high=float(v["dtg.high"]),
            persistence_k=_named_int(v, "dtg.persistence_k"),
            persistence_n=_named_int(v, "dtg.persistence_n"),
            latch=bool(v["dtg.latch"]),
            monitored=[bool(v[f"dtg.monitored[{i}]"]) for i in range(1, N_THETA + 1)],
            signatures=self._signatures(),
            max_distance=None if max_distance < 0 else max_distance,
            classify_window_s=float(v["dtg.classify_window_s"]),
        )

    def _signatures(self) -> dict[str, list[float]]:
        v = self.values
        path_text = str(v["dtg.signature_file"]).strip()
        if path_text:
            path = Path(path_text)
            if not path.is_absolute() and self.resources:
                path = Path(self.resources) / path
            try:
                data = json.loads(path.read_text(encoding="utf-8"))
            except (OSError, json.JSONDecodeError) as exc:
                raise ValueError(
                    f"dtg.signature_file {str(path)!r} cannot be read: {exc}"
                ) from None
            sigs = data.get("signatures") if isinstance(data, dict) else None
            if not isinstance(sigs, dict) or not sigs:
                raise ValueError(
                    f"dtg.signature_file {str(path)!r} must hold a non-empty object "
                    "'signatures': {name: [C1, ..., C5]}"
                )
            return {str(k): list(s) for k, s in sigs.items()}
        n = int(v["dtg.n_signatures"])
        if not 0 <= n <= MAX_SIGNATURES:
            raise ValueError(f"dtg.n_signatures must be in [0, {MAX_SIGNATURES}], got {n}")
        return {
            f"signature_{j}": [float(v[f"dtg.signature[{j},{i}]"]) for i in range(1, N_THETA + 1)]
            for j in range(1, n + 1)
        }

    def _grey_detector(self, period: float) -> GreyFaultDetector:
        v = self.values
        model = int(v["grey.model"])
        window = _named_int(v, "grey.window")
        if model == 0:
            evaluation = _named_int(v, "grey.classic_evaluation")
            if evaluation not in (0, 1):
                raise ValueError("grey.classic_evaluation must be 0 (careful) or 1 (textbook), "
                                 f"got {evaluation}")
            # window 0 stands for None: FMI has no "absent" Integer
            predictor = ClassicGreyPredictor(
                None if window == 0 else window,
                evaluation="textbook" if evaluation == 1 else "careful",
            )
        elif model == 1:
            if window == 0:
                raise ValueError("grey.window = 0 (whole record) is only available for the "
                                 "classic model (grey.model = 0); the improved model needs "
                                 "a moving window >= 4")
            predictor = ImprovedGreyPredictor(window, a_min=float(v["grey.a_min"]))
        else:
            raise ValueError(f"grey.model must be 0 (classic) or 1 (improved), got {model}")
        clear = float(v["grey.clear_after_s"])
        return GreyFaultDetector(
            predictor, float(v["grey.threshold"]), period, None if clear <= 0 else clear
        )

    def reset(self) -> None:  # pythonfmu re-creates the instance on fmi2Reset
        pass

    # ------------------------------------------------------------------ stepping
    def do_step(self, current_time: float, step_size: float) -> bool:
        # Returning False would mean fmi2Discard (DESIGN §6.7): always True, and report
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
        period = float(self.values["sample_period_s"])
        if abs(h - period) > 1e-6 * period:
            self.report_error(
                f"{self.instance_name}: communication step {h!r} s differs from "
                f"sample_period_s = {period!r} s; the Diagnoser is sampled-data and "
                "processes one sample per step (set sample_period_s to the step)"
            )
            return
        v = self.values
        valid = True
        codes: list[int] = []
        if self._dtg is not None:
            out = self._dtg.update(*[v[key] for key in _DTG_INPUT_KEYS])
            if math.isnan(self._dtg_first_alarm_time) and not math.isnan(
                out.first_alarm_time_s
            ):
                self._dtg_first_alarm_time = t
            self._copy_dtg(out)
            valid &= out.valid
            if out.alarm:
                code = out.fault_code
                codes.append(SUMMARY_CODE_BASE["dtg"] + (code if code > 0 else -1))
        if self._grey is not None:
            g = self._grey.update(float(v["grey.y"]), time_s=t)
            v["grey.prediction"] = g.prediction
            v["grey.error"] = g.error
            v["grey.alarm"] = g.alarm
            v["grey.valid"] = g.valid
            valid &= g.valid
            if g.alarm:
                codes.append(SUMMARY_CODE_BASE["grey"])
        if self._df is not None:
            df_out = self._df.update(
                [v[key] for key in _DF_U_KEYS],
                [v[key] for key in _DF_Y_KEYS],
            )
            self._copy_df(df_out)
            valid &= df_out.valid
            if df_out.alarm:
                iso = df_out.isolated_sensor
                codes.append(SUMMARY_CODE_BASE["df"] + (iso if iso > 0 else -1))
        v["any_alarm"] = bool(codes)
        v["fault_code"] = codes[0] if codes else 0
        v["inputs_valid"] = bool(valid)

    def _copy_dtg(self, out: Any) -> None:
        v = self.values
        for keys, row in zip(_DTG_THETA_KEYS, _as_list(out.theta), strict=True):
            for key, value in zip(keys, row, strict=True):
                v[key] = float(value)
        for keys, row in zip(_DTG_ETA_KEYS, _as_list(out.eta), strict=True):
            for key, value in zip(keys, row, strict=True):
                v[key] = float(value)
        assert self._dtg is not None
        theta0 = self._dtg.theta0
        theta0_values = [0.0] * N_THETA if theta0 is None else _as_list(theta0)
        for key, value in zip(_DTG_THETA0_KEYS, theta0_values, strict=True):
            v[key] = float(value)
        for key, value in zip(_DTG_PHYSICAL_KEYS, _as_list(out.physical), strict=True):
            v[key] = float(value)
        v["dtg.learning"] = bool(out.learning)
        v["dtg.alarm"] = bool(out.alarm)
        v["dtg.fault_code"] = int(out.fault_code) if out.alarm else 0
        if out.alarm and out.fault_code == UNKNOWN_CODE:
            v["dtg.fault_code"] = UNKNOWN_CODE
        first = self._dtg_first_alarm_time
        v["dtg.first_alarm_time"] = -1.0 if math.isnan(first) else first
        v["dtg.valid"] = bool(out.valid)

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
        if state["ready"]:
            self._build_channels()
        self._ready = bool(state["ready"])
        self._start_time = float(state["start_time"])
        self._dtg_first_alarm_time = float(state["dtg_first_alarm_time"])
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
        "max_distance": "dtg.max_distance",
    },
    "grey": {
        "window": "grey.window", "threshold": "grey.threshold", "a_min": "grey.a_min",
        "clear_after_s": "grey.clear_after_s",
    },
    "df": {
        "eigenvalues": "df.eigenvalue[1..5]", "calibrate_s": "df.calibrate_s",
        "burn_in_s": "df.burn_in_s", "k_sigma": "df.k_sigma",
        "main_thresholds": "df.threshold[1..6]", "bank_thresholds": "df.bank_threshold[i,j]",
        "noise_std": "df.noise_std[1..6]", "persistence_k": "df.persistence_k",
        "persistence_n": "df.persistence_n", "confirm_samples": "df.confirm_samples",
        "x0": "df.x0[1..5]",
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
        requirement = next((r for r in REQUIREMENTS if r.lower().startswith(missing.lower())),
                           missing)
        raise MissingPackageError(
            f"{needed_by} needs the Python package {missing!r}, which is not installed in "
            f"the host's Python: pip install '{requirement}' (or pip install -r "
            "resources/requirements.txt of this FMU), or switch the channel off"
        ) from None


def _named_int(values: dict[str, Any], name: str) -> int:
    value = values[name]
    if isinstance(value, bool) or int(value) != value:
        raise ValueError(f"{name} must be an integer, got {value!r}")
    return int(value)


_fill_variable_meta()
