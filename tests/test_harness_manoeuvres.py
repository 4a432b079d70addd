"""Manoeuvres in scenarios (``[[manoeuvres]]``): validation, mapping to the command
generator's and the aircraft's start values, windows in results, and the expectations
that judge alarms during manoeuvres as false alarms.

A manoeuvre used to be listed under ``[[faults]]`` (a tunable set at a time), which made
``no_alarm_outside_faults`` ignore every alarm while the pilot manoeuvred.
"""

from __future__ import annotations

import importlib.util
import math
import sys
from pathlib import Path

import numpy as np
import pytest

from gyrodiag_harness.cosim.master import manoeuvre_windows, model_info
from gyrodiag_harness.cosim.results import FaultWindow, RunResult
from gyrodiag_harness.cosim.scenario import (
    MANOEUVRE_COMMAND_CODES,
    ScenarioError,
    check_against_models,
    load_scenario,
)
from gyrodiag_harness.verification import expectations as ex

ROOT = Path(__file__).resolve().parents[1]

BASE = """
duration_s = 20.0
step_s = 0.01

[fmus.aircraft]
fmu = "Aircraft"

[fmus.controller]
fmu = "PitchController"

[fmus.injector]
fmu = "FaultInjector"

[[connections]]
from = "aircraft.y_q"
to = "injector.in_3"
"""


def write(tmp_path: Path, text: str) -> Path:
    path = tmp_path / "m.toml"
    path.write_text(text, encoding="utf-8")
    return path


def problems_of(path: Path) -> list[tuple[str, str]]:
    with pytest.raises(ScenarioError) as info:
        load_scenario(path)
    return info.value.problems


def test_command_codes_match_the_pitch_controller(fmu_dir: Path) -> None:
    """The copied table equals the model's shape codes and the built FMU's description."""
    from fmpy import read_model_description

    spec = importlib.util.spec_from_file_location(
        "gd_pitch_commands_for_test", ROOT / "models" / "pitch_controller" / "gd_pitch_commands.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # dataclasses look their module up
    spec.loader.exec_module(module)
    names = {v: k for k, v in module.KIND_NAMES.items() if k != module.COMMAND_INPUT}
    assert names == MANOEUVRE_COMMAND_CODES
    md = read_model_description(str(fmu_dir / "PitchController.fmu"))
    text = next(v.description for v in md.modelVariables if v.name == "command_source")
    for name, code in MANOEUVRE_COMMAND_CODES.items():
        assert f"{code} {name.replace('_', ' ')}" in text.replace("exponential ", "")


def test_every_kind_maps_to_start_values(tmp_path: Path) -> None:
    text = BASE + """
[[manoeuvres]]
name = "sweep"
kind = "sine_sweep"
instance = "controller"
start_s = 2.0
duration_s = 10.0
amplitude_rad = 0.02
f0_hz = 0.1
f1_hz = 2.0

[[manoeuvres]]
name = "start"
kind = "off_trim"
instance = "aircraft"
duration_s = 8.0
theta0_rad = 0.05
q0_rad_s = -0.02
"""
    s = load_scenario(write(tmp_path, text))
    sweep, start = s.manoeuvres
    assert sweep.instance_parameters() == {
        "command_source": 4, "cmd_start_s": 2.0, "cmd_duration_s": 10.0,
        "cmd_amplitude": 0.02, "cmd_f0_hz": 0.1, "cmd_f1_hz": 2.0}
    assert start.instance_parameters() == {"x0_theta": 0.05, "x0_q": -0.02}
    assert manoeuvre_windows(s) == [FaultWindow("sweep", "controller", "sine_sweep", 2.0, 12.0),
                                    FaultWindow("start", "aircraft", "off_trim", 0.0, 8.0)]
    for kind, extra, params in [
        ("square_wave", "period_s = 8.0", {"cmd_period": 8.0}),
        ("step", "", {}),
        ("doublet", "pulse_s = 0.5", {"cmd_pulse_s": 0.5, "cmd_period": 0.0}),
        ("doublet", "pulse_s = 0.5\nperiod_s = 4.0", {"cmd_pulse_s": 0.5, "cmd_period": 4.0}),
    ]:
        text = BASE + f"""
[[manoeuvres]]
name = "m"
kind = "{kind}"
instance = "controller"
start_s = 1.0
amplitude_rad = -0.1
{extra}
"""
        m = load_scenario(write(tmp_path, text)).manoeuvres[0]
        assert m.instance_parameters() == {"command_source": MANOEUVRE_COMMAND_CODES[kind],
                                           "cmd_start_s": 1.0, "cmd_duration_s": 0.0,
                                           "cmd_amplitude": -0.1, **params}
        assert math.isinf(m.end_s)


@pytest.mark.parametrize("body,key,fragment", [
    ('kind = "dublet"\ninstance = "controller"\namplitude_rad = 0.1\npulse_s = 1.0',
     "manoeuvres[0].kind", "did you mean 'doublet'"),
    ('kind = "doublet"\ninstance = "controller"\namplitude_rad = 0.1',
     "manoeuvres[0]", "needs pulse_s"),
    ('kind = "step"\ninstance = "controller"\namplitude_rad = 0.1\nf0_hz = 1.0',
     "manoeuvres[0]", "does not use f0_hz"),
    ('kind = "sine_sweep"\ninstance = "controller"\namplitude_rad = 0.1\nf0_hz = 0.1\n'
     'f1_hz = 2.0\nduration_s = 0.0', "manoeuvres[0]", "duration_s > 0"),
    ('kind = "off_trim"\ninstance = "aircraft"\nstart_s = 1.0\nduration_s = 5.0\n'
     'theta0_rad = 0.1', "manoeuvres[0]", "begins at t = 0"),
    ('kind = "off_trim"\ninstance = "aircraft"\nduration_s = 5.0', "manoeuvres[0]",
     "at least one of"),
    ('kind = "doublet"\ninstance = "controller"\namplitude_rad = 0.1\npulse_s = 1.0\n'
     'period_s = 1.5', "manoeuvres[0]", "must be >= 2 * pulse_s"),
    ('kind = "square_wave"\ninstance = "controler"\namplitude_rad = 0.1\nperiod_s = 2.0',
     "manoeuvres[0].instance", "did you mean 'controller'"),
    ('kind = "step"\ninstance = "controller"\namplitude_rad = 0.1\nstart_s = 30.0',
     "manoeuvres[0].start_s", "after the end of the run"),
])
def test_manoeuvre_entries_validated(tmp_path: Path, body: str, key: str, fragment: str) -> None:
    text = BASE + f'\n[[manoeuvres]]\nname = "m"\n{body}\n'
    problems = problems_of(write(tmp_path, text))
    assert any(k == key and fragment in msg for k, msg in problems), problems


def test_cross_checks_one_command_per_generator_names_and_clashes(tmp_path: Path) -> None:
    text = BASE.replace('fmu = "PitchController"',
                        'fmu = "PitchController"\nparameters = { cmd_amplitude = 0.3 }') + """
[[faults]]
name = "q_bias"
injector = "injector"
channel = 3
type = "bias"
magnitude = 0.01
start_s = 5.0

[[manoeuvres]]
name = "q_bias"
kind = "step"
instance = "controller"
amplitude_rad = 0.1

[[manoeuvres]]
name = "second"
kind = "square_wave"
instance = "controller"
amplitude_rad = 0.1
period_s = 4.0

[[expect]]
kind = "no_alarm_during_manoeuvres"
signal = "injector.out_3"
manoeuvre = "thrid"
"""
    problems = problems_of(write(tmp_path, text))

    def has(key: str, fragment: str) -> bool:
        return any(k == key and fragment in msg for k, msg in problems)

    assert has("manoeuvres[0].name", "duplicate name 'q_bias' (also faults[0])")
    assert has("manoeuvres[1].instance", "one command manoeuvre per command generator")
    assert has("fmus.controller.parameters.cmd_amplitude", "also set by manoeuvre 'q_bias'")
    assert has("expect[0].manoeuvre", "unknown manoeuvre 'thrid'")


def test_manoeuvre_instance_must_fly_it(tmp_path: Path, fmu_dir: Path) -> None:
    from fmpy import read_model_description

    models = {n: model_info(read_model_description(str(fmu_dir / f"{n}.fmu")))
              for n in ("Aircraft", "PitchController", "FaultInjector")}
    text = BASE + """
[[manoeuvres]]
name = "wrong"
kind = "step"
instance = "aircraft"
amplitude_rad = 0.1

[[manoeuvres]]
name = "also_wrong"
kind = "off_trim"
instance = "controller"
duration_s = 4.0
theta0_rad = 0.1
"""
    s = load_scenario(write(tmp_path, text))
    with pytest.raises(ScenarioError) as info:
        check_against_models(s, {n: models[i.fmu] for n, i in s.fmus.items()})
    problems = dict(info.value.problems)
    assert "has no parameter 'command_source': not a PitchController" in \
        problems["manoeuvres[0].instance"]
    assert "not an Aircraft" in problems["manoeuvres[1].instance"]


# ----------------------------------------------------------------------- expectations
@pytest.fixture
def run() -> RunResult:
    """20 s; a fault 14..16 s; a manoeuvre 5..9 s with an alarm 6..6.5 s in it."""
    t = np.arange(2001) * 0.01
    alarm = (((t >= 6.0) & (t < 6.5)) | ((t >= 14.2) & (t < 16.0))).astype(float)
    quiet_in_manoeuvre = ((t >= 14.2) & (t < 16.0)).astype(float)
    return RunResult(
        scenario="m", time=t,
        signals={"diag.alarm": alarm, "diag.quiet": quiet_in_manoeuvre},
        fault_windows=[FaultWindow("bias", "inj.out_3", "bias", 14.0, 16.0)],
        manoeuvre_windows=[FaultWindow("sq", "controller", "square_wave", 5.0, 9.0),
                           FaultWindow("start", "aircraft", "off_trim", 0.0, 3.0)],
        step_s=0.01, stop_time_s=20.0)


def test_an_alarm_during_a_manoeuvre_is_a_false_alarm(run: RunResult) -> None:
    r = ex.evaluate({"kind": "no_alarm_outside_faults", "signal": "diag.alarm"}, run)
    assert not r.passed and r.value == pytest.approx(0.5)
    assert "first at 6 s" in r.message
    assert ex.evaluate({"kind": "no_alarm_outside_faults", "signal": "diag.quiet"}, run).passed


def test_no_alarm_during_manoeuvres(run: RunResult) -> None:
    r = ex.evaluate({"kind": "no_alarm_during_manoeuvres", "signal": "diag.alarm"}, run)
    assert not r.passed and r.value == pytest.approx(0.5)
    assert "'sq', 'start'" in r.message
    only_start = ex.evaluate({"kind": "no_alarm_during_manoeuvres", "signal": "diag.alarm",
                              "manoeuvre": "start"}, run)
    assert only_start.passed
    unknown = ex.evaluate({"kind": "no_alarm_during_manoeuvres", "signal": "diag.alarm",
                           "manoeuvre": "nope"}, run)
    assert not unknown.passed and "no manoeuvre 'nope'" in unknown.message
    none = RunResult(scenario="x", time=run.time, signals=run.signals, step_s=0.01)
    r = ex.evaluate({"kind": "no_alarm_during_manoeuvres", "signal": "diag.alarm"}, none)
    assert not r.passed and "no manoeuvre window" in r.message


def test_manoeuvre_windows_round_trip_through_files(run: RunResult, tmp_path: Path) -> None:
    run.save(tmp_path / "r")
    back = RunResult.load(tmp_path / "r")
    assert back.manoeuvre_windows == run.manoeuvre_windows
    assert back.fault_windows == run.fault_windows


# -------------------------------------------------------------------------- witnesses
@pytest.fixture
def two_witnesses() -> RunResult:
    """A fault at 20 s; witness A at 20.7 s, B only once the manoeuvre starts at 28 s."""
    t = np.arange(3201) * 0.01
    a = (t >= 20.7).astype(float)
    b = (t >= 28.1).astype(float)
    return RunResult(
        scenario="w", time=t,
        signals={"fine.dtg.alarm": a, "df.df.detected": b, "quiet.alarm": np.zeros_like(t),
                 "df.df.fault_magnitude": np.where(t >= 28.1, 0.9, 0.0)},
        fault_windows=[FaultWindow("spin", "dtg.spin_fraction", "physical", 20.0)],
        manoeuvre_windows=[FaultWindow("sq", "controller", "square_wave", 28.0, math.inf)],
        step_s=0.01, stop_time_s=32.0)


def test_witnesses_agree_on_one_root_cause(two_witnesses: RunResult) -> None:
    r = ex.evaluate({"kind": "witnesses_agree", "witnesses": ["fine.dtg.alarm",
                                                              "df.df.detected"],
                     "fault": "spin", "max_delay_s": 9.0,
                     "details": ["df.df.fault_magnitude"]}, two_witnesses)
    assert r.passed and r.value == pytest.approx(7.4)
    assert "the witnesses agree" in r.message
    assert "fine.dtg.alarm: detected after 0.7 s" in r.message
    assert "df.df.fault_magnitude = 0.9 at the end" in r.message
    late = ex.evaluate({"kind": "witnesses_agree", "witnesses": ["fine.dtg.alarm",
                                                                 "df.df.detected"],
                        "fault": "spin", "max_delay_s": 5.0}, two_witnesses)
    assert not late.passed and "disagree" in late.message
    missed = ex.evaluate({"kind": "witnesses_agree", "witnesses": ["quiet.alarm",
                                                                   "fine.dtg.alarm"],
                          "fault": "spin"}, two_witnesses)
    assert not missed.passed and "quiet.alarm: missed" in missed.message
    # a false alarm that is still on at the onset does not witness the fault
    early = RunResult(scenario="e", time=two_witnesses.time,
                      signals={"x.alarm": (two_witnesses.time >= 15.0).astype(float),
                               "fine.dtg.alarm": two_witnesses.signals["fine.dtg.alarm"]},
                      fault_windows=two_witnesses.fault_windows, step_s=0.01)
    r = ex.evaluate({"kind": "witnesses_agree", "witnesses": ["x.alarm", "fine.dtg.alarm"],
                     "fault": "spin", "max_delay_s": 5.0}, early)
    assert not r.passed and "x.alarm: alarm at 15 s, before the fault" in r.message
    assert "the witnesses disagree" in r.message
    clean = RunResult(scenario="c", time=two_witnesses.time,
                      signals={"x.alarm": np.zeros(3201), "y.alarm": np.zeros(3201)},
                      step_s=0.01)
    ok = ex.evaluate({"kind": "witnesses_agree", "witnesses": ["x.alarm", "y.alarm"]}, clean)
    assert ok.passed and "all quiet" in ok.message
    bad = ex.evaluate({"kind": "witnesses_agree", "witnesses": ["x.alarm", "fine.dtg.alarm"]},
                      RunResult(scenario="d", time=two_witnesses.time,
                                signals={"x.alarm": np.zeros(3201),
                                         "fine.dtg.alarm": two_witnesses.signals[
                                             "fine.dtg.alarm"]}, step_s=0.01))
    assert not bad.passed and "alarm at 20.7 s" in bad.message
    with pytest.raises(Exception, match="witnesses"):
        ex.parse_expectation({"kind": "witnesses_agree", "witnesses": ["only.one"]})


def test_witness_timeline_is_drawn_for_the_expectation(two_witnesses: RunResult) -> None:
    from gyrodiag_harness.reporting import plots

    scenario = {"expect": [{"kind": "witnesses_agree",
                            "witnesses": ["fine.dtg.alarm", "df.df.detected"],
                            "details": ["df.df.fault_magnitude"], "fault": "spin"}]}
    figures = dict(plots.figures_for_result(two_witnesses, scenario))
    title = next(k for k in figures if k.startswith("witnesses_agree"))
    fig = figures[title]
    assert len(fig.axes) == 3
    texts = [t.get_text() for ax in fig.axes for t in ax.texts]
    assert "20.70 s" in texts and "28.10 s" in texts
    labels = fig.axes[0].get_legend_handles_labels()[1]
    assert "fault: spin" in labels and "manoeuvre: sq (square_wave)" in labels
    assert plots.figure_to_png(fig).startswith(b"\x89PNG")
