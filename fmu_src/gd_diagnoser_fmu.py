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

from gd_diagnoser_vars import MESSAGE_NAMES, TUNABLE, VARIABLE_META, VARIABLES, adapters
from gd_diagnoser_vars.df import DF_M, DF_P
from gd_diagnoser_vars.outputs import OutputWriter
from gd_fmu_base import FacadeBase, sample_instants, samples_in_step
from pythonfmu import DefaultExperiment
from pythonfmu.enums import Fmi2Status

from gyrodiag.dtg.channel import (
    DTGChannel,
    DTGChannelConfig,
)
from gyrodiag.grey import GreyFaultDetector

if TYPE_CHECKING:  # imported when the channel is built: it needs SciPy (design time)
    from gyrodiag.df.channel import DFChannel, DFChannelConfig

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
_DF_U_KEYS = tuple(f"df.u[{j + 1}]" for j in range(DF_P))
_DF_Y_KEYS = tuple(f"df.y[{i + 1}]" for i in range(DF_M))
_df_u = operator.itemgetter(*_DF_U_KEYS)
_df_y = operator.itemgetter(*_DF_Y_KEYS)

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
        self._period = math.nan
        self._last_step, self._last_samples = math.nan, 0
        # last outputs of each channel not yet copied into the variables (_sync_outputs)
        self._pending_dtg: Any = None
        self._pending_grey: Any = None
        self._pending_df: Any = None
        self._outputs_pending = False
        # copies the channels' outputs into the variables (and flags unchecked ones)
        self._out = OutputWriter(self.values, lambda text: self.log(text, Fmi2Status.ok),
                                 self.report_warning)
        self._ready = False
        self._start_time = 0.0
        # Host time of the first DTG alarm: the channel's own clock counts valid samples
        # only, so after a skipped NaN sample it would lag the simulation time.
        self._dtg_first_alarm_time = math.nan
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
            self._out.dtg_block_copied = -1
            self._out.dtg_named_code = None
            if self._dtg is not None:
                self._out.copy_dtg(self._dtg.last_output, self._dtg, self._dtg_first_alarm_time)
            if self._df is not None:
                self._out.copy_df(self._df.last_output, self._df)
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
        self._out.unclassified_note = ""
        # sample_period_s is fixed after initialisation (not tunable)
        self._period = period
        self._last_step, self._last_samples = math.nan, 0
        self._dtg = self._grey = self._df = None
        self._out.df_copied = None
        self._out.theta0_copied = False
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
        self._out.unclassified_note = f"{self.instance_name}: {text}"

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
        out = self._out
        out.unchecked = False
        if self._pending_dtg is not None:
            assert self._dtg is not None
            out.copy_dtg(self._pending_dtg, self._dtg, self._dtg_first_alarm_time)
        if self._pending_grey is not None:
            assert self._grey is not None
            out.copy_grey(self._pending_grey, self._grey)
        if self._pending_df is not None:
            assert self._df is not None
            out.copy_df(self._pending_df, self._df)
        if out.unchecked:
            self._guard_finite_outputs()

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
        self._out.theta0_copied = False
        if state["ready"]:
            self._build_channels()
        self._ready = bool(state["ready"])
        self._start_time = float(state["start_time"])
        self._dtg_first_alarm_time = float(state["dtg_first_alarm_time"])
        # the restored values are complete; recopy at the next block
        self._out.dtg_block_copied = -1
        self._out.dtg_named_code = None
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


