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
import math
import operator
import re
from collections.abc import Iterator
from typing import TYPE_CHECKING, Any

import numpy as np
from gd_diagnoser_vars import MESSAGE_NAMES, TUNABLE, VARIABLE_META, VARIABLES, adapters
from gd_diagnoser_vars.df import DF_M, DF_P
from gd_diagnoser_vars.dtg import PHYSICAL_NAMES
from gd_fmu_base import FacadeBase, sample_instants, samples_in_step
from pythonfmu import DefaultExperiment
from pythonfmu.enums import Fmi2Status

from gyrodiag.dtg.channel import (
    DTGChannel,
    DTGChannelConfig,
    DTGChannelOutput,
)
from gyrodiag.dtg.model import N_THETA
from gyrodiag.dtg.patterns import SEVERAL_CODE
from gyrodiag.dtg.reference import N_CHANNELS
from gyrodiag.grey import GreyFaultDetector

if TYPE_CHECKING:  # imported when the channel is built: it needs SciPy (design time)
    from gyrodiag.df.channel import DFChannel, DFChannelConfig, DFChannelOutput

#: Fault codes of the summary output ``fault_code``.
SUMMARY_CODE_BASE = {"dtg": 100, "grey": 200, "df": 300}
#: Summary code offsets of the detection filter beyond a sensor number.
DF_NOT_ISOLATED, DF_MULTIPLE = -1, -2

#: Packages the host's Python needs (written to resources/requirements.txt).
# SciPy only for the detection filter and the grey channel's learned rules (a clear
# fmi2Error names them without it): DTG and the paper's grey rule run on numpy alone
REQUIREMENTS = ["numpy>=1.24", "scipy>=1.10  # optional at start-up"]

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
        self._dtg_named_code: int | str | None = None
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
    def _declare(self) -> None:
        """Declare every variable of gd_diagnoser_vars, in its order (value references)."""
        for var in VARIABLES:
            text, variability = var.description, None
            if var.tunable:
                variability = "tunable"
                text += " (tunable: a change applies from the next sample)"
            self.add_variable(var.name, var.kind, var.causality, var.start, text, variability)

    def _df_config(self, period: float) -> DFChannelConfig:
        return adapters.df_config(self.values, period, self.resources)

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
        return adapters.dtg_config(self.values, period, self.resources,
                                   self._note_unclassified)

    def _note_unclassified(self, text: str) -> None:
        """Keep why DTG alarms go unclassified: reported at the first one, if any."""
        self._unclassified_note = f"{self.instance_name}: {text}"

    def _grey_detector(self, period: float) -> GreyFaultDetector:
        v = self.values
        predictor, candidates = adapters.grey_predictors(v)
        clear = float(v["grey.clear_after_s"])
        rule = adapters.grey_decision(v)
        for package in rule.requires:
            _import_or_explain(package, f"grey.decision = {int(v['grey.decision'])} (a "
                               "learned rule; the paper rule, grey.decision = 0, does "
                               "without it)")
        return rule.build(predictor, period, None if clear <= 0 else clear, candidates)

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
        named = code if code != SEVERAL_CODE else out.diagnosis.class_name
        if named != self._dtg_named_code:  # the name follows the code (a pair: names)
            self._dtg_named_code = named
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
        v["dtg.fault_signals"] = int(d.signal_mask) if alarm else 0
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


@contextlib.contextmanager
def _channel_context(prefix: str) -> Iterator[None]:
    """Rewrite a channel's validation message in terms of its FMU parameter names."""
    try:
        yield
    except (ValueError, TypeError) as exc:
        text = str(exc)
        if text.startswith(f"{prefix}."):
            raise
        names = MESSAGE_NAMES[prefix]
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


