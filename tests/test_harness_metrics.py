"""Metrics of harness runs on synthetic signals with known answers."""

from __future__ import annotations

import dataclasses
import inspect
import math

import numpy as np
import pytest

from gyrodiag_harness.cosim.results import FaultWindow, RunResult
from gyrodiag_harness.verification import metrics

STEP_S = 0.01


def _time(duration_s: float, step_s: float = STEP_S) -> np.ndarray:
    # k·step as the master records it, not an accumulated sum
    return np.arange(round(duration_s / step_s) + 1) * step_s


def _alarm_from(t: np.ndarray, k0: int) -> np.ndarray:
    x = np.zeros(t.size)
    x[k0:] = 1.0
    return x


# ------------------------------------------------------------------ timing
def test_rising_edges_count_a_signal_already_on_at_start() -> None:
    t = np.arange(8.0)
    x = np.array([1, 1, 0, 0, 1, 0, 1, 1], dtype=float)
    assert metrics.rising_edge_times_s(t, x).tolist() == [0.0, 4.0, 6.0]


def test_detection_delay_is_exactly_the_sample_offset() -> None:
    t = _time(20.0)
    alarm = _alarm_from(t, 1037)  # t = 10.37 s
    assert metrics.detection_time_s(t, alarm, 10.0) == pytest.approx(10.37, abs=1e-12)
    assert metrics.detection_delay_s(t, alarm, 10.0) == pytest.approx(0.37, abs=1e-12)


def test_detection_ignores_alarms_before_the_start_time() -> None:
    t = _time(20.0)
    alarm = np.zeros(t.size)
    alarm[200:210] = 1.0  # 2.00..2.09 s pulse, before the fault
    alarm[1250:] = 1.0
    assert metrics.detection_delay_s(t, alarm, 10.0) == pytest.approx(2.5, abs=1e-12)
    assert metrics.detection_time_s(t, alarm) == pytest.approx(2.0, abs=1e-12)


def test_detection_counts_an_alarm_already_on_at_the_start_time() -> None:
    t = _time(20.0)
    assert metrics.detection_delay_s(t, _alarm_from(t, 500), 10.0) == pytest.approx(0.0)


def test_sample_at_start_within_time_tolerance_counts() -> None:
    # 10.0 recorded as 9.999999999999998: still "at" the fault start
    t = np.array([9.98, 9.99, 10.0 - 2e-15, 10.01])
    x = np.array([0.0, 0.0, 1.0, 1.0])
    assert metrics.detection_delay_s(t, x, 10.0) == pytest.approx(0.0, abs=1e-12)


def test_no_alarm_gives_nan_delay_and_missed_detection() -> None:
    t = _time(5.0)
    alarm = np.zeros(t.size)
    assert math.isnan(metrics.detection_delay_s(t, alarm, 1.0))
    assert metrics.missed_detection(t, alarm, 1.0)


def test_missed_detection_against_deadline() -> None:
    t = _time(20.0)
    alarm = _alarm_from(t, 1037)
    assert metrics.missed_detection(t, alarm, 10.0, max_delay_s=0.3)
    assert not metrics.missed_detection(t, alarm, 10.0, max_delay_s=0.37)
    assert not metrics.missed_detection(t, alarm, 10.0)


def test_level_and_nan_alarm_samples() -> None:
    t = np.arange(5.0)
    x = np.array([np.nan, 0.4, 0.6, np.nan, 2.0])
    assert metrics.detection_time_s(t, x) == 2.0
    assert metrics.detection_time_s(t, x, level=1.0) == 4.0
    assert metrics.rising_edge_times_s(t, x).tolist() == [2.0, 4.0]


# ------------------------------------------------------------- false alarms
def test_two_false_alarms_over_half_an_hour_is_four_per_hour() -> None:
    t = _time(1800.0, 1.0)
    alarm = np.zeros(t.size)
    alarm[100:103] = 1.0
    alarm[1500] = 1.0
    fa = metrics.false_alarms(t, alarm)
    assert fa.count == 2
    assert fa.fault_free_time_s == pytest.approx(1800.0)
    assert fa.rate_per_h == pytest.approx(4.0)
    assert fa.times_s == (100.0, 1500.0)


def test_false_alarms_exclude_fault_windows_and_margin() -> None:
    t = _time(1800.0, 1.0)
    alarm = np.zeros(t.size)
    for k in (100, 650, 905, 1500):
        alarm[k] = 1.0
    # 650 inside [600, 900]; 905 inside the 10 s margin after the window
    fa = metrics.false_alarms(t, alarm, [(600.0, 900.0)], margin_s=10.0)
    assert fa.count == 2
    assert fa.fault_free_time_s == pytest.approx(1800.0 - 310.0)
    assert fa.rate_per_h == pytest.approx(2 / (1490.0 / 3600.0))
    assert metrics.false_alarms(t, alarm, [(600.0, 900.0)]).count == 3


def test_false_alarm_rate_with_open_window_and_overlaps() -> None:
    t = _time(100.0, 1.0)
    windows = [(10.0, 30.0), (20.0, 40.0), (90.0, math.inf)]
    # union [10, 40] and [90, 100]: 40 s of the 100 s record are faulty
    assert metrics.fault_free_time_s(t, windows) == pytest.approx(60.0)
    alarm = np.zeros(t.size)
    alarm[95] = 1.0
    assert metrics.false_alarms(t, alarm, windows).count == 0


def test_no_fault_free_time_gives_nan_rate() -> None:
    t = _time(10.0, 1.0)
    fa = metrics.false_alarms(t, np.zeros(t.size), [(0.0, math.inf)])
    assert fa.count == 0 and math.isnan(fa.rate_per_h)


# --------------------------------------------------------------- isolation
def test_isolation_end_and_mode_after_detection() -> None:
    t = _time(10.0, 1.0)
    iso = np.array([0, 0, 0, 0, 2, 3, 3, 3, 2, 0, 0], dtype=float)
    assert metrics.isolation_result(t, iso) == 0.0
    assert metrics.isolation_result(t, iso, how="mode") == 0.0
    assert metrics.isolation_result(t, iso, how="mode", after_s=4.0) == 3.0
    assert metrics.isolation_result(t, iso, how="mode", ignore=[0.0]) == 3.0
    # a tie goes to the smaller value, whatever the order of appearance
    assert metrics.isolation_result(np.arange(4.0), [3.0, 3.0, 2.0, 2.0], how="mode") == 2.0
    with pytest.raises(ValueError, match="how"):
        metrics.isolation_result(t, iso, how="median")  # type: ignore[arg-type]


# -------------------------------------------------------------- statistics
def test_signal_statistics_window_and_nan() -> None:
    t = np.arange(6.0)
    x = np.array([100.0, 1.0, 2.0, np.nan, 3.0, 4.0])
    s = metrics.signal_statistics(t, x, 1.0, 5.0)
    assert (s.mean, s.min, s.max, s.n) == (2.5, 1.0, 4.0, 4)
    assert s.std == pytest.approx(math.sqrt(1.25))
    empty = metrics.signal_statistics(t, x, 10.0, 20.0)
    assert empty.n == 0 and math.isnan(empty.mean)


def test_theta_statistics_per_signal() -> None:
    t = np.arange(4.0)
    stats = metrics.theta_statistics(t, {"a": [1, 1, 3, 3], "b": [0, 0, 0, 8]}, 2.0, None)
    assert stats["a"].mean == 3.0 and stats["a"].std == 0.0
    assert stats["b"].mean == 4.0 and stats["b"].max == 8.0


def test_prediction_errors_percent_known_answer() -> None:
    t = np.arange(6.0)
    y = np.array([2.0, 4.0, np.nan, 0.0, 5.0, 10.0])
    p = np.array([2.2, 4.0, 1.0, 1.0, np.nan, 0.0])
    e = metrics.prediction_errors_percent(t, y, p, None, 4.0)
    # used: 10 %, 0 %; y = NaN and y = 0 excluded; NaN prediction ignored; t = 5 outside
    assert e.mean_percent == pytest.approx(5.0)
    assert e.max_percent == pytest.approx(10.0)
    assert (e.n_used, e.n_excluded) == (2, 2)
    assert metrics.prediction_errors_percent(t, y, p).max_percent == pytest.approx(100.0)
    # a validity signal drops rows whose prediction is a sentinel: row 5 (ŷ = 0, 100 %)
    valid = [1, 1, 1, 1, 1, 0]
    e = metrics.prediction_errors_percent(t, y, p, valid=valid)
    assert (e.n_used, e.max_percent) == (2, pytest.approx(10.0))


def test_absolute_errors_known_answer() -> None:
    t = np.arange(4.0)
    e = metrics.absolute_errors(t, [1.0, 2.0, 3.0, np.nan], [1.0, 1.0, 6.0, 0.0])
    assert (e.mean, e.max, e.n) == (pytest.approx(4.0 / 3.0), 3.0, 3)
    assert e.rms == pytest.approx(math.sqrt(10.0 / 3.0))


def test_bad_inputs_name_the_argument() -> None:
    with pytest.raises(ValueError, match="time_s must be non-decreasing"):
        metrics.detection_time_s([0.0, 2.0, 1.0], [0, 0, 1])
    with pytest.raises(ValueError, match="alarm must have the shape"):
        metrics.detection_time_s([0.0, 1.0], [0, 0, 1])
    with pytest.raises(ValueError, match="margin_s must be >= 0"):
        metrics.false_alarms([0.0, 1.0], [0, 1], [(0.0, 1.0)], margin_s=-1.0)
    with pytest.raises(ValueError, match="t1_s"):
        metrics.signal_statistics([0.0, 1.0], [0, 1], 1.0, 0.0)
    with pytest.raises(TypeError, match="fault_start_s must be a number"):
        metrics.detection_delay_s([0.0, 1.0], [0, 1], "1")  # type: ignore[arg-type]


# ---------------------------------------------------------------- registry
@pytest.fixture
def run() -> RunResult:
    t = _time(1800.0, 0.5)
    alarm = np.zeros(t.size)
    alarm[(t >= 100.37) & (t < 200.0)] = 1.0  # inside the fault window
    alarm[(t >= 600.0) & (t < 601.0)] = 1.0   # false alarms
    alarm[(t >= 1700.0) & (t < 1701.0)] = 1.0
    iso = np.where(t >= 100.5, 4.0, 0.0)
    return RunResult(
        scenario="reg", time=t,
        signals={"d.alarm": alarm, "d.iso": iso, "d.y": np.full(t.size, 2.0),
                 "d.p": np.full(t.size, 2.1)},
        fault_windows=[FaultWindow("bias", "inj.out_1", "bias", 100.0, 200.0)],
        step_s=0.5,
    )


def test_registry_metrics_on_a_run(run: RunResult) -> None:
    # 100.37 is not on the 0.5 s grid: the first alarm row is 100.5 s
    assert metrics.compute_metric("detection_delay_s", run, {"signal": "d.alarm"}) == \
        pytest.approx(0.5)
    assert metrics.compute_metric("detection_time_s", run, {"signal": "d.alarm",
                                                            "fault": "bias"}) == 100.5
    assert metrics.compute_metric("missed_detection", run,
                                  {"signal": "d.alarm", "max_delay_s": 0.4}) == 1.0
    fa_args = {"signal": "d.alarm"}
    assert metrics.compute_metric("false_alarms", run, fa_args, "count") == 2.0
    assert metrics.compute_metric("false_alarms", run, fa_args, "rate_per_h") == \
        pytest.approx(2.0 / (1700.0 / 3600.0))
    assert metrics.compute_metric("isolation_result", run,
                                  {"signal": "d.iso", "how": "mode", "alarm": "d.alarm",
                                   "fault": "bias"}) == 4.0
    assert metrics.compute_metric("prediction_errors_percent", run,
                                  {"measured": "d.y", "predicted": "d.p"},
                                  "mean_percent") == pytest.approx(5.0)
    assert metrics.compute_metric("theta_statistics", run,
                                  {"signal": "d.iso", "t0_s": 150.0, "t1_s": 160.0},
                                  "mean") == 4.0


def test_isolation_mode_counts_from_a_delay_after_the_fault(run: RunResult) -> None:
    iso = np.where(run.time >= 1000.0, 4.0, np.where(run.time >= 100.5, 2.0, 0.0))
    run = dataclasses.replace(run, signals={**run.signals, "d.iso": iso})
    args = {"signal": "d.iso", "how": "mode", "fault": "bias"}
    assert metrics.compute_metric("isolation_result", run, args) == 2.0
    assert metrics.compute_metric("isolation_result", run, {**args, "delay_s": 950.0}) == 4.0
    # from the alarm's first rise (100.5 s) + 900 s = 1000.5 s
    assert metrics.compute_metric("isolation_result", run,
                                  {**args, "alarm": "d.alarm", "delay_s": 900.0}) == 4.0
    with pytest.raises(ValueError, match="delay_s"):
        metrics.compute_metric("isolation_result", run,
                               {"signal": "d.iso", "how": "mode", "delay_s": 1.0})
    with pytest.raises(ValueError, match="delay_s"):
        metrics.compute_metric("isolation_result", run, {**args, "delay_s": -1.0})
    with pytest.raises(ValueError, match="delay_s"):
        metrics.compute_metric("isolation_result", run, {**args, "how": "end", "delay_s": 1.0})


def test_registry_errors_name_metric_and_argument(run: RunResult) -> None:
    with pytest.raises(ValueError, match="unknown metric 'delay'"):
        metrics.check_metric_args("delay", {})
    with pytest.raises(ValueError, match=r"metric 'detection_delay_s': unknown argument "
                                         r"'max_delay'"):
        metrics.check_metric_args("detection_delay_s", {"signal": "a", "max_delay": 1})
    with pytest.raises(ValueError, match="missing required argument 'signal'"):
        metrics.check_metric_args("detection_delay_s", {})
    with pytest.raises(TypeError, match="argument 'level' must be a number"):
        metrics.check_metric_args("detection_delay_s", {"signal": "a", "level": "high"})
    with pytest.raises(ValueError, match="argument 'how' must be one of"):
        metrics.check_metric_args("isolation_result", {"signal": "a", "how": "median"})
    with pytest.raises(ValueError, match="choose field"):
        metrics.check_metric_args("false_alarms", {"signal": "a"})
    with pytest.raises(ValueError, match="unknown field 'mean'"):
        metrics.check_metric_args("detection_delay_s", {"signal": "a"}, "mean")
    with pytest.raises(KeyError, match="nope"):
        metrics.compute_metric("detection_delay_s", run, {"signal": "nope"})
    with pytest.raises(KeyError, match="no fault named 'gain'"):
        metrics.compute_metric("detection_delay_s", run, {"signal": "d.alarm",
                                                          "fault": "gain"})


@pytest.mark.parametrize("name", sorted(metrics.METRICS))
def test_registry_parameters_match_the_functions(name: str) -> None:
    spec = metrics.METRICS[name]
    signature = inspect.signature(spec.function)
    params = list(signature.parameters)[1:]  # after the result
    assert params == [p.name for p in spec.params]
    for p in spec.params:
        has_default = signature.parameters[p.name].default is not inspect.Parameter.empty
        assert has_default != p.required, p.name
    assert all(p.name in spec.describe() for p in spec.params)
