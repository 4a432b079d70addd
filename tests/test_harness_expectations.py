"""Scenario expectations: parsing, pass/fail with informative messages, verdicts."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest
from pydantic import ValidationError

from gyrodiag_harness.cosim.results import FaultWindow, RunResult
from gyrodiag_harness.verification import expectations as ex

STEP_S = 0.01


@pytest.fixture
def run() -> RunResult:
    """20 s at 10 ms; bias fault 10..15 s detected at 10.37 s; sensor 3 isolated."""
    t = np.arange(2001) * STEP_S
    detected = ((t >= 10.37) & (t < 15.2)).astype(float)
    early = detected.copy()
    early[300:305] = 1.0  # false alarm 3.00..3.04 s
    late = detected.copy()
    late[(t >= 16.0) & (t < 16.5)] = 1.0  # 0.5 s alarm 1 s after the window's end
    return RunResult(
        scenario="q_bias",
        time=t,
        signals={
            "diag.df.detected": detected,
            "diag.early": early,
            "diag.late": late,
            "diag.df.isolated_sensor": np.where(t >= 10.5, 3.0, 0.0),
            "diag.residual": np.where(t >= 10.0, 0.2, 0.01 * np.sin(t)),
        },
        fault_windows=[FaultWindow("q_bias", "inj.out_3", "bias", 10.0, 15.0)],
        step_s=STEP_S,
        wall_time_s=1.5,
        stop_time_s=20.0,
    )


def _eval(raw: dict, result: RunResult) -> ex.ExpectationResult:
    return ex.evaluate(raw, result)


# ------------------------------------------------------------ known limitations
def test_known_limitation_is_a_strict_expected_failure(run: RunResult) -> None:
    why = "the early false alarm at 3 s (issue 99)"
    still = _eval({"kind": "no_alarm_before", "signal": "diag.early", "t_s": 10.0,
                   "known_limitation": why}, run)
    assert still.passed and still.is_known_limitation
    assert still.known_limitation == why and "known limitation: " + why in still.message
    assert still.value == pytest.approx(3.0)  # the measurement is kept
    fixed = _eval({"kind": "no_alarm_before", "signal": "diag.df.detected", "t_s": 10.0,
                   "known_limitation": why}, run)
    assert not fixed.passed and not fixed.is_known_limitation
    assert "promote it" in fixed.message
    plain = _eval({"kind": "no_alarm_before", "signal": "diag.early", "t_s": 10.0}, run)
    assert not plain.passed and not plain.is_known_limitation
    (verdict,) = ex.verify_results([run], [{"name": "q_bias", "expect": [
        {"kind": "no_alarm_before", "signal": "diag.early", "t_s": 10.0,
         "known_limitation": why}]}])
    assert verdict.passed
    with pytest.raises(ValidationError, match="known_limitation"):
        ex.parse_expectation({"kind": "no_alarm_before", "signal": "s",
                              "known_limitation": ""})


# ------------------------------------------------------------ detected_within
def test_detected_within_passes_and_reports_the_delay(run: RunResult) -> None:
    r = _eval({"kind": "detected_within", "signal": "diag.df.detected", "fault": "q_bias",
               "max_delay_s": 0.5}, run)
    assert r.passed
    assert r.value == pytest.approx(0.37, abs=1e-9)
    assert "within 0.5 s" in r.message and "measured delay 0.37 s" in r.message
    assert r.kind == "detected_within"


def test_detected_within_fails_when_too_slow(run: RunResult) -> None:
    r = _eval({"kind": "detected_within", "signal": "diag.df.detected", "fault": "q_bias",
               "max_delay_s": 0.3, "name": "fast detection"}, run)
    assert not r.passed
    assert r.name == "fast detection"
    assert "within 0.3 s" in r.message and "0.37 s" in r.message


def test_detected_within_fails_when_never_detected(run: RunResult) -> None:
    run.signals["diag.never"] = np.zeros(run.time.size)
    r = _eval({"kind": "detected_within", "signal": "diag.never", "fault": "q_bias",
               "max_delay_s": 1.0}, run)
    assert not r.passed and r.value is None
    assert "no alarm up to the end of the run (20 s)" in r.message


def test_detected_within_notes_an_alarm_already_on(run: RunResult) -> None:
    run.signals["diag.on"] = np.ones(run.time.size)
    r = _eval({"kind": "detected_within", "signal": "diag.on", "fault": "q_bias",
               "max_delay_s": 1.0}, run)
    assert r.passed and r.value == pytest.approx(0.0, abs=1e-9)
    assert "already on before the fault" in r.message


# ------------------------------------------------------------ alarm absence
def test_no_alarm_before_defaults_to_the_first_fault(run: RunResult) -> None:
    assert _eval({"kind": "no_alarm_before", "signal": "diag.df.detected"}, run).passed
    r = _eval({"kind": "no_alarm_before", "signal": "diag.early"}, run)
    assert not r.passed
    assert r.value == pytest.approx(3.0)
    assert "before 10 s (start of fault 'q_bias')" in r.message
    assert "first alarm at 3 s" in r.message and "1 rising edge" in r.message
    assert _eval({"kind": "no_alarm_before", "signal": "diag.early", "t_s": 2.5}, run).passed


def test_no_alarm_outside_faults_with_and_without_margin(run: RunResult) -> None:
    # detected stays on until 15.19 s: 0.2 s after the window's end
    r = _eval({"kind": "no_alarm_outside_faults", "signal": "diag.df.detected"}, run)
    assert not r.passed
    assert r.value == pytest.approx(0.19, abs=1e-9)
    assert "first at 15.01 s" in r.message and "0 false-alarm rising edge(s)" in r.message
    ok = _eval({"kind": "no_alarm_outside_faults", "signal": "diag.df.detected",
                "margin_s": 0.5}, run)
    assert ok.passed and ok.value == 0.0
    late = _eval({"kind": "no_alarm_outside_faults", "signal": "diag.late",
                  "margin_s": 0.5}, run)
    assert not late.passed
    assert late.value == pytest.approx(0.5, abs=1e-9)
    assert "1 false-alarm rising edge(s)" in late.message


# ------------------------------------------------------------------ values
def test_value_at_end_equals_and_bounds(run: RunResult) -> None:
    r = _eval({"kind": "value_at_end", "signal": "diag.df.isolated_sensor", "equals": 3}, run)
    assert r.passed and r.value == 3.0
    bad = _eval({"kind": "value_at_end", "signal": "diag.df.isolated_sensor", "equals": 2},
                run)
    assert not bad.passed
    assert "at the end (20 s) == 2" in bad.message and "measured 3" in bad.message
    assert _eval({"kind": "value_at_end", "signal": "diag.residual", "min": 0.19,
                  "max": 0.21}, run).passed


def test_value_at_holds_the_last_sample_before(run: RunResult) -> None:
    r = _eval({"kind": "value_at", "signal": "diag.df.isolated_sensor", "t_s": 10.495,
               "equals": 0}, run)
    assert r.passed and "sample at 10.49 s" in r.message
    assert _eval({"kind": "value_at", "signal": "diag.df.isolated_sensor", "t_s": 10.5,
                  "equals": 3}, run).passed
    before = _eval({"kind": "value_at", "signal": "diag.residual", "t_s": -1.0, "max": 1},
                   run)
    assert not before.passed and "no sample at or before -1 s" in before.message


def test_value_in_window_reports_the_deciding_sample(run: RunResult) -> None:
    ok = _eval({"kind": "value_in_window", "signal": "diag.residual", "t0_s": 0.0,
                "t1_s": 9.99, "min": -0.05, "max": 0.05}, run)
    assert ok.passed
    assert ok.value == pytest.approx(0.01, abs=1e-4)  # |0.01 sin t| closest to a bound
    bad = _eval({"kind": "value_in_window", "signal": "diag.residual", "t0_s": 5.0,
                 "t1_s": 12.0, "max": 0.05}, run)
    assert not bad.passed and bad.value == pytest.approx(0.2)
    assert "201 outside, first at 10 s (0.2)" in bad.message
    assert "<= 0.05 for all t in [5, 12] s" in bad.message
    empty = _eval({"kind": "value_in_window", "signal": "diag.residual", "t0_s": 30.0,
                   "t1_s": 40.0, "max": 1}, run)
    assert not empty.passed and "no samples in the window" in empty.message


# ------------------------------------------------------------------ metric
def test_metric_expectation_pass_and_fail(run: RunResult) -> None:
    raw = {"kind": "metric", "metric": "detection_delay_s",
           "args": {"signal": "diag.df.detected", "fault": "q_bias"}, "max": 0.4}
    r = _eval(raw, run)
    assert r.passed and r.value == pytest.approx(0.37, abs=1e-9)
    assert "<= 0.4 [s]" in r.message and "measured 0.37" in r.message
    fail = _eval({**raw, "max": 0.3}, run)
    assert not fail.passed
    fa = _eval({"kind": "metric", "metric": "false_alarms", "field": "count",
                "args": {"signal": "diag.early"}, "max": 0}, run)
    assert not fa.passed and fa.value == 1.0
    assert "false_alarms(signal='diag.early').count <= 0" in fa.message


def test_metric_with_undefined_value_fails(run: RunResult) -> None:
    run.signals["diag.never"] = np.zeros(run.time.size)
    r = _eval({"kind": "metric", "metric": "detection_delay_s",
               "args": {"signal": "diag.never"}, "max": 1.0}, run)
    assert not r.passed and r.value is None and "measured n/a" in r.message


# ----------------------------------------------------------------- parsing
@pytest.mark.parametrize(
    ("raw", "needle"),
    [
        ({"kind": "detected_within", "signal": "a", "fault": "f", "max_delay_s": 0.5,
          "delay": 1}, "delay"),
        ({"kind": "detected_within", "signal": "a", "fault": "f", "max_delay_s": -1},
         "max_delay_s"),
        ({"kind": "value_at_end", "signal": "a", "equals": 1, "max": 2}, "not both"),
        ({"kind": "value_at_end", "signal": "a"}, "min and/or max"),
        ({"kind": "value_in_window", "signal": "a", "t0_s": 2, "t1_s": 1, "max": 1}, "t1_s"),
        ({"kind": "value_at", "signal": "a", "min": 2, "max": 1, "t_s": 0}, "min (2.0)"),
        ({"kind": "metric", "metric": "false_alarms", "args": {"signal": "a",
                                                               "margin": 1},
          "field": "count", "max": 0}, "metric 'false_alarms': unknown argument 'margin'"),
        ({"kind": "metric", "metric": "detection_delay_s", "args": {"signal": "a",
                                                                    "level": "x"},
          "max": 0}, "argument 'level' must be a number"),
        ({"kind": "nonsense"}, "does not match any of the expected tags"),
    ],
)
def test_invalid_expectations_are_rejected_with_the_key(raw: dict, needle: str) -> None:
    with pytest.raises(ValidationError, match=needle.replace("(", r"\(").replace(")", r"\)")):
        ex.parse_expectation(raw)


def test_parse_expectations_reports_the_index() -> None:
    with pytest.raises(ValidationError) as info:
        ex.parse_expectations([{"kind": "value_at_end", "signal": "a", "equals": 1},
                               {"kind": "value_at", "signal": "a", "equals": 1}])
    assert info.value.errors()[0]["loc"][:3] == (1, "value_at", "t_s")


def test_referenced_signals_include_metric_arguments() -> None:
    assert ex.referenced_signals({"kind": "metric", "metric": "prediction_errors_percent",
                                  "args": {"measured": "h.v", "predicted": "d.p"},
                                  "field": "max_percent", "max": 1}) == ["h.v", "d.p"]
    assert ex.referenced_signals({"kind": "no_alarm_before", "signal": "d.a"}) == ["d.a"]


# --------------------------------------------------------------- robustness
def test_missing_signal_and_fault_fail_without_raising(run: RunResult) -> None:
    r = _eval({"kind": "value_at_end", "signal": "diag.df.detectd", "equals": 0}, run)
    assert not r.passed
    assert "not recorded" in r.message and "diag.df.detected" in r.message  # suggestion
    f = _eval({"kind": "detected_within", "signal": "diag.df.detected", "fault": "gain",
               "max_delay_s": 1}, run)
    assert not f.passed and "no fault named 'gain'" in f.message and "q_bias" in f.message


def test_run_error_leaves_every_expectation_unevaluated_and_says_the_error_once(
        run: RunResult) -> None:
    run.error = "instance diag: doStep at t=12.3: division by zero"
    scenario = {"name": "q_bias", "expect": [
        {"kind": "value_at_end", "signal": "diag.df.isolated_sensor", "equals": 3},
        {"kind": "no_alarm_before", "signal": "diag.df.detected"},
    ]}
    (verdict,) = ex.verify_results([run], [scenario])
    assert not verdict.passed and verdict.error == run.error
    assert [(e.passed, e.evaluated) for e in verdict.expectations] == [(False, False)] * 2
    assert [e.message for e in verdict.expectations] == [
        "not evaluated: the run did not complete"] * 2
    run.interrupted = True
    (verdict,) = ex.verify_results([run], [scenario])
    assert verdict.expectations[0].message == "not evaluated: the run was interrupted"


# ---------------------------------------------------------------- verdicts
def test_verify_results_pairs_by_name_and_reports_orphans(run: RunResult) -> None:
    good = ex.parse_expectation({"kind": "value_at_end", "signal": "diag.df.isolated_sensor",
                                 "equals": 3})
    scenarios = [
        SimpleNamespace(name="other", expect=[{"kind": "no_alarm_before", "signal": "x.y"}]),
        SimpleNamespace(name="q_bias", expect=[good, {"kind": "detected_within",
                                                      "signal": "diag.df.detected",
                                                      "fault": "q_bias",
                                                      "max_delay_s": 0.3}]),
    ]
    stray = RunResult("stray", np.arange(3.0), {}, [], 1.0)
    verdicts = ex.verify_results([stray, run], scenarios)
    assert [v.scenario for v in verdicts] == ["other", "q_bias", "stray"]
    other, q_bias, orphan = verdicts
    assert not other.passed and "no run result for scenario 'other'" in other.error
    assert other.expectations[0].message == "not evaluated: no run result"
    assert not other.expectations[0].evaluated
    assert [e.passed for e in q_bias.expectations] == [True, False]
    assert q_bias.n_failed == 1 and not q_bias.passed and q_bias.error is None
    assert orphan.passed and orphan.expectations == []


def test_verify_results_accepts_scenarios_from_the_loader(run: RunResult, tmp_path) -> None:
    from gyrodiag_harness.cosim import scenario as scenario_mod
    toml = tmp_path / "q_bias.toml"
    toml.write_text(
        'duration_s = 20.0\nstep_s = 0.01\n'
        '[fmus.diag]\nfmu = "Diagnoser"\n'
        '[[faults]]\nname = "q_bias"\nset = "diag.grey.threshold"\nvalue = 0.1\n'
        'start_s = 10.0\n'
        '[[expect]]\nkind = "detected_within"\nsignal = "diag.df.detected"\n'
        'fault = "q_bias"\nmax_delay_s = 0.5\n'
        '[[expect]]\nkind = "metric"\nmetric = "isolation_result"\n'
        'args = { signal = "diag.df.isolated_sensor", how = "mode", ignore = [0] }\n'
        'min = 3\nmax = 3\n',
        encoding="utf-8",
    )
    scenario = scenario_mod.load_scenario(toml)
    (verdict,) = ex.verify_results([run], [scenario])
    assert [e.passed for e in verdict.expectations] == [True, True], verdict.expectations
