"""Copies of the Diagnoser channels' output records into the FMU output variables.

The facade (``gd_diagnoser_fmu``) runs the channels; this writer turns their records
into variable values: sentinels instead of NaN, per-sample outputs in one dict update,
and the rarely changing ones (theta0, the DTG diagnosis, the DF calibration) copied only
when they change. It flags what it wrote unchecked so that the facade runs its full
finiteness guard only then.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

import numpy as np

from gyrodiag.dtg.model import N_THETA
from gyrodiag.dtg.patterns import SEVERAL_CODE
from gyrodiag.dtg.reference import N_CHANNELS

from .df import DF_M
from .dtg import PHYSICAL_NAMES

if TYPE_CHECKING:
    from gyrodiag.df.channel import DFChannel, DFChannelOutput
    from gyrodiag.dtg.channel import DTGChannel, DTGChannelOutput
    from gyrodiag.grey import GreyFaultDetector

# Variable names used at every step, formatted once, not per step (docs/notes.md, Speed).
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
#: outputs of the detection filter written at every sample, in copy_df's order
_DF_SAMPLE_KEYS = (*_DF_RESIDUAL_KEYS, *_DF_ALARM_KEYS, *_DF_STATISTIC_KEYS,
                   "df.calibrating", "df.detected", "df.episodes", "df.isolated_sensor",
                   "df.isolated_mask", "df.fault_type", "df.fault_magnitude",
                   "df.fault_magnitude_valid", "df.input_delay_in_use", "df.valid")
#: df.sensor_fault_type codes whose size goes to each per-sensor output.
_OFFSET_TYPES, _GAIN_TYPES, _RATE_TYPES, _NOISE_TYPES = {1, 3, 4, 7}, {2}, {6}, {5}

class OutputWriter:
    """Writes the channels' outputs into the FMU variable values, remembering what it
    copied last (the on-change copies compare with it)."""

    def __init__(self, values: dict[str, Any], inform: Callable[[str], None],
                 warn: Callable[[str], None]) -> None:
        self.values = values
        self._inform = inform  # information for the log (not a warning status)
        self._warn = warn
        # something written since the flag was cleared may be non-finite (full guard)
        self.unchecked = False
        self.df_copied: tuple[bool, Any, Any] | None = None
        self.theta0_copied: Any = False  # never a channel's theta0: copy at first
        self.dtg_block_copied = -1
        self.dtg_named_code: int | str | None = None
        self.unclassified_note = ""  # why DTG alarms go unclassified (set at build)

    def copy_df(self, out: DFChannelOutput, channel: DFChannel) -> None:
        """Per-sample outputs of the detection filter; its diagnosis and calibration
        results on change."""
        v = self.values
        magnitude_valid = bool(out.magnitude_valid) and math.isfinite(out.magnitude)
        residual, statistic = _as_list(out.residual), _as_list(out.statistic)
        checked = sum(residual) + sum(statistic)
        if checked - checked != 0.0:
            self.unchecked = True
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
        prev = self.df_copied
        if (prev is not None and prev[0] == out.calibrating
                and prev[1] is out.sensor_fault_type and prev[2] is out.sensor_magnitude):
            return
        self.df_copied = (out.calibrating, out.sensor_fault_type, out.sensor_magnitude)
        self.unchecked = True  # thresholds, noise and sizes: the full guard
        if prev is not None and prev[0] and not out.calibrating and channel.gust_note:
            # information, not a warning status: the step itself succeeded
            self._inform(f"df: {channel.gust_note}")
        thresholds = channel.thresholds
        for k, value in zip(_DF_THRESHOLD_KEYS, [0.0] * DF_M if thresholds is None
                            else _as_list(thresholds[0]), strict=True):
            v[k] = float(value)
        noise = channel.noise_std
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

    def copy_grey(self, g: Any, channel: GreyFaultDetector) -> None:
        """Outputs of the grey channel (0 for a prediction or error not defined)."""
        v = self.values
        prediction_valid = math.isfinite(g.prediction)
        v["grey.prediction"] = g.prediction if prediction_valid else 0.0
        v["grey.error"] = g.error if math.isfinite(g.error) else 0.0
        v["grey.prediction_valid"] = prediction_valid
        v["grey.alarm"] = g.alarm
        v["grey.valid"] = g.valid
        v["grey.calibrating"] = g.calibrating
        v["grey.statistic"] = g.statistic
        sigma = channel.sigma
        sigma = sigma if sigma == sigma else 0.0
        v["grey.sigma"] = sigma
        noise = channel.noise_sigma
        noise = noise if noise == noise else 0.0
        v["grey.noise_sigma"] = noise
        checked = g.statistic + sigma + noise
        if checked - checked != 0.0:
            self.unchecked = True


    def copy_dtg(self, out: Any, channel: DTGChannel, first_alarm_time: float) -> None:
        """Per-sample outputs of the DTG channel; theta0, name and diagnosis on change."""
        v = self.values
        # the channel's arrays have fixed shapes (2×5, 2×5, 5): plain zips
        theta_eta = out.theta.ravel().tolist() + out.eta.ravel().tolist()
        v.update(zip(_DTG_THETA_ETA_KEYS, theta_eta, strict=True))
        theta0 = channel.theta0
        if theta0 is not self.theta0_copied:  # set once, when learning ends
            self.theta0_copied = theta0
            self.unchecked = True
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
        if named != self.dtg_named_code:  # the name follows the code (a pair: names)
            self.dtg_named_code = named
            v["dtg.fault_name"] = channel.class_name(code)
            if code != 0 and self.unclassified_note:
                self._warn(self.unclassified_note)
                self.unclassified_note = ""
        first = first_alarm_time
        first = -1.0 if math.isnan(first) else first
        v["dtg.first_alarm_time"] = first
        checked = sum(theta_eta) + first  # physical: checked above
        if checked - checked != 0.0:
            self.unchecked = True
        v["dtg.valid"] = bool(out.valid)
        v["dtg.case_rate_delay_in_use"] = channel.case_rate_delay
        d = out.diagnosis
        if d.block != self.dtg_block_copied:  # block-rate outputs change at block ends
            self.copy_dtg_diagnosis(out, channel)
            self.dtg_block_copied = d.block
        if not out.alarm and v["dtg.fault_type"] != 0:
            self.copy_dtg_diagnosis(out, channel)


    def copy_dtg_diagnosis(self, out: DTGChannelOutput, channel: DTGChannel) -> None:
        """Reference, residual tests and class (sentinels instead of NaN)."""
        self.unchecked = True  # a block's outputs: the full guard checks them
        v = self.values
        d = out.diagnosis
        v["dtg.reference_status"] = int(d.reference_status)
        v["dtg.reference_valid"] = d.reference_status == 1
        v["dtg.residual_alarm"] = bool(d.residual_alarm)
        test = channel.physical_test
        v["dtg.physical_alarm"] = test is not None and test.result.alarm
        v["dtg.physical_statistic"] = 0.0 if test is None else _finite_or(test.result.chi2,
                                                                            0.0)
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
        ref = channel.reference
        per_axis = None if ref is None else ref.theta0.reshape(-1, N_THETA)
        for i in range(N_THETA):
            v[f"dtg.ref_theta0[{i + 1}]"] = 0.0 if per_axis is None else float(per_axis[0, i])
            v[f"dtg.ref_theta0_y[{i + 1}]"] = (0.0 if per_axis is None
                                               else float(per_axis[-1, i]))
        for key, attr in (("ref_mean", "mean"), ("ref_block_std", "block_std"),
                          ("ref_var_short", "var_short"), ("ref_var_long", "var_long")):
            for i in range(N_CHANNELS):
                v[f"dtg.{key}[{i + 1}]"] = 0.0 if ref is None else float(getattr(ref, attr)[i])



def _finite_or(value: float, fallback: float) -> float:
    """``value`` if finite, else the documented sentinel (outputs never carry NaN)."""
    return float(value) if math.isfinite(value) else fallback


def _flat_floats(values: Any) -> list[float]:
    """Row-major Python floats of an array or a (nested) sequence of numbers."""
    return np.asarray(values, dtype=float).ravel().tolist()


def _as_list(values: Any) -> list:
    """Plain Python values of an array or sequence (one call for a numpy array)."""
    return values.tolist() if isinstance(values, np.ndarray) else list(values)

