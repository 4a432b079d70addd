"""Scenario files (gyrodiag_harness.cosim.scenario): validation messages with file and key
path, fault schedule → FaultInjector parameters, names checked against the FMUs'
modelDescriptions.

Only modelDescriptions are read here (fmpy.read_model_description on the built FMUs);
no FMU binary is loaded into the test process.
"""

from __future__ import annotations

import importlib.util
import math
import re
from pathlib import Path

import numpy as np
import pytest

from gyrodiag_harness.cosim.master import fault_windows, model_info, plan_coupling
from gyrodiag_harness.cosim.results import FaultWindow, RunResult
from gyrodiag_harness.cosim.scenario import (
    FAULT_TYPE_CODES,
    InjectorFault,
    ScenarioError,
    check_against_models,
    key_path,
    load_scenario,
    parse_scenario,
)

ROOT = Path(__file__).resolve().parents[1]
DATA = Path(__file__).resolve().parent / "data" / "scenarios"

BASE = """
duration_s = 1.0
step_s = 0.01

[fmus.aircraft]
fmu = "Aircraft"

[fmus.injector]
fmu = "FaultInjector"

[[connections]]
from = "aircraft.y_q"
to = "injector.in_3"
"""


def write(tmp_path: Path, text: str, name: str = "x.toml") -> Path:
    path = tmp_path / name
    path.write_text(text, encoding="utf-8")
    return path


def problems_of(path: Path) -> list[tuple[str, str]]:
    with pytest.raises(ScenarioError) as info:
        load_scenario(path)
    err = info.value
    # every line of the message starts with the file
    for line in str(err).splitlines():
        assert line.startswith(err.source + ": ")
    assert err.source.endswith(path.name)
    return err.problems


@pytest.fixture(scope="module")
def models(fmu_dir: Path):
    from fmpy import read_model_description

    return {name: model_info(read_model_description(str(fmu_dir / f"{name}.fmu")))
            for name in ("Aircraft", "FaultInjector", "PitchController", "HRG")}


def infos_for(scenario, models) -> dict:
    return {n: models[i.fmu] for n, i in scenario.fmus.items()}


# ---------------------------------------------------------------------------- loading
def test_valid_file_loads_with_defaults(tmp_path):
    s = load_scenario(write(tmp_path, BASE, "my_case.toml"))
    assert s.name == "my_case"                 # default: file stem
    assert s.coupling == "gauss-seidel"
    assert s.n_steps == 100
    assert s.fmus["aircraft"].step_ratio == 1
    assert s.record.variables is None and s.record.decimation == 1
    assert s.connections[0].from_ == "aircraft.y_q"
    assert s.path == (tmp_path / "my_case.toml").resolve()


def test_step_ratio_error_names_file_and_key(tmp_path):
    path = write(tmp_path, BASE.replace('fmu = "Aircraft"', 'fmu = "Aircraft"\nstep_ratio = 0'))
    with pytest.raises(ScenarioError) as info:
        load_scenario(path)
    assert str(info.value) == (f"{info.value.source}: fmus.aircraft.step_ratio: "
                               "Input should be greater than or equal to 1")


def test_unknown_keys_and_bad_values_all_reported(tmp_path):
    text = BASE.replace('to = "injector.in_3"', 'to = "injector.in_3"\nextra = 1')
    text = text.replace("step_s = 0.01", "step_s = -0.01\ncoupling = \"async\"")
    problems = dict(problems_of(write(tmp_path, text)))
    assert problems["connections[0].extra"] == "unknown key (not allowed here)"
    assert "greater than 0" in problems["step_s"]
    assert "gauss-seidel" in problems["coupling"]


def test_toml_syntax_error_names_file(tmp_path):
    problems = problems_of(write(tmp_path, BASE + "\n[fmus.aircraft\n"))
    assert problems[0][1].startswith("invalid TOML")


@pytest.mark.parametrize("fault, key, fragment", [
    ('type = "bais"\nmagnitude = 1.0', "faults[0].type", "did you mean 'bias'"),
    ('type = "bias"', "faults[0]", "fault type 'bias' needs magnitude"),
    ('type = "bias"\nmagnitude = 1.0\ngain = 2.0', "faults[0]", "does not use gain"),
    ('type = "step"\nmagnitude = 1.0\nend_s = 0.8', "faults[0]", "leave out end_s"),
    ('type = "bias"\nmagnitude = 1.0\nend_s = 0.2', "faults[0]", "must be > start_s"),
    ('type = "intermittent"\nmagnitude = 1.0\nperiod = 0.1\nduty = 1.5',
     "faults[0].duty", "less than or equal to 1"),
])
def test_fault_entries_validated(tmp_path, fault, key, fragment):
    text = BASE + ('\n[[faults]]\nname = "f"\ninjector = "injector"\nchannel = 3\n'
                   f'start_s = 0.5\n{fault}\n')
    problems = problems_of(write(tmp_path, text))
    assert any(k == key and fragment in msg for k, msg in problems), problems


def test_cross_references_checked_in_the_file(tmp_path):
    text = BASE.replace("duration_s = 1.0", "duration_s = 1.005") + """
[[connections]]
from = "aircrat.y_alpha"
to = "injector.in_3"

[[faults]]
name = "f"
injector = "injector"
channel = 3
type = "failure"
start_s = 0.5

[[faults]]
name = "f"
injector = "injector"
channel = 3
type = "failure"
start_s = 0.6

[[expect]]
kind = "detected_within"
signal = "injector.fault_active_3"
fault = "g"
max_delay_s = 0.1
"""
    problems = dict(problems_of(write(tmp_path, text)))
    assert "whole number of steps" in problems["duration_s"]
    assert "unknown instance 'aircrat'" in problems["connections[1].from"]
    assert "did you mean 'aircraft'" in problems["connections[1].from"]
    assert "already connected by connections[0]" in problems["connections[1].to"]
    assert "duplicate fault name 'f'" in problems["faults[1].name"]
    assert "one fault per channel" in problems["faults[1].channel"]
    assert problems["expect[0].fault"] == "unknown fault 'g' (known: 'f')"


def test_step_ratio_must_divide_the_number_of_steps(tmp_path):
    text = BASE.replace("duration_s = 1.0", "duration_s = 0.99").replace(
        'fmu = "Aircraft"', 'fmu = "Aircraft"\nstep_ratio = 2')
    problems = dict(problems_of(write(tmp_path, text)))
    assert "99 base steps, not a multiple of step_ratio 2" in problems["fmus.aircraft.step_ratio"]


def test_expectation_arguments_validated_by_the_expectations_module(tmp_path):
    text = BASE + """
[[expect]]
kind = "value_at_end"
signal = "injector.out_3"
equals = 1.0
tolerance = 0.1
"""
    problems = problems_of(write(tmp_path, text))
    assert ("expect[0].tolerance", "unknown key for kind 'value_at_end'") in problems


def test_key_path_conversion():
    assert key_path(("fmus", "aircraft", "step_ratio")) == "fmus.aircraft.step_ratio"
    assert key_path(("connections", 2, "from")) == "connections[2].from"
    # the fault discriminator tag is not a key of the file
    assert key_path(("faults", 0, "injector_fault", "channel")) == "faults[0].channel"
    assert key_path(("faults", 1, "physical_fault", "set")) == "faults[1].set"


# ------------------------------------------------------------------------ fault codes
def test_fault_type_table_matches_the_fault_injector_documentation(fmu_dir):
    """The copied table equals the codes documented in the built FMU and in its source."""
    from fmpy import read_model_description

    md = read_model_description(str(fmu_dir / "FaultInjector.fmu"))
    text = next(v.description for v in md.modelVariables if v.name == "fault_type_1")
    documented = {name.lower(): int(code) for code, name in re.findall(r"(\d+)=([A-Z_]+)", text)}
    assert documented == FAULT_TYPE_CODES
    spec = importlib.util.spec_from_file_location(
        "gd_fault_injector_core_for_test",
        ROOT / "models" / "fault_injector" / "gd_fault_injector_core.py")
    core = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(core)
    assert {f.name.lower(): int(f) for f in core.FaultType} == FAULT_TYPE_CODES


def test_injector_fault_becomes_channel_parameters(tmp_path):
    text = BASE + """
[[faults]]
name = "q_stuck"
injector = "injector"
channel = 3
type = "stuck"
stuck_value = 0.25
start_s = 0.5
end_s = 0.75
"""
    s = load_scenario(write(tmp_path, text))
    f = s.faults[0]
    assert isinstance(f, InjectorFault)
    assert f.injector_parameters() == {"fault_type_3": 3, "t_start_3": 0.5, "t_end_3": 0.75,
                                       "stuck_value_3": 0.25}
    assert fault_windows(s) == [FaultWindow("q_stuck", "injector.out_3", "stuck_value", 0.5,
                                            0.75)]


# ------------------------------------------------------------ names against the FMUs
def test_unknown_variables_suggest_close_names(tmp_path, models):
    text = BASE.replace("aircraft.y_q", "aircraft.y_qq").replace(
        'fmu = "Aircraft"', 'fmu = "Aircraft"\nparameters = { seed = 1.5, noise_std_Q = 0.1 }'
    ) + """
[[connections]]
from = "injector.out_3"
to = "aircraft.y_alpha"

[record]
variables = ["injector.fault_activ_3"]
"""
    s = load_scenario(write(tmp_path, text))
    with pytest.raises(ScenarioError) as info:
        check_against_models(s, infos_for(s, models))
    problems = dict(info.value.problems)
    assert problems["connections[0].from"].startswith(
        "instance 'aircraft' (FMU Aircraft) has no variable 'y_qq'; did you mean 'y_q'")
    assert "is an output, a destination must be input" in problems["connections[1].to"]
    assert "did you mean 'fault_active_3'" in problems["record.variables[0]"]
    assert "'noise_std_q'" in problems["fmus.aircraft.parameters.noise_std_Q"]
    assert problems["fmus.aircraft.parameters.seed"] == (
        "seed is Integer, got 1.5 (write an integer)")
    assert str(info.value).startswith(f"{info.value.source}: ")


def test_physical_fault_must_target_a_tunable_parameter(tmp_path, models):
    text = BASE + """
[[faults]]
name = "x0"
set = "aircraft.x0_q"
value = 0.1
start_s = 0.5
"""
    s = load_scenario(write(tmp_path, text))
    with pytest.raises(ScenarioError) as info:
        check_against_models(s, infos_for(s, models))
    assert "'aircraft.x0_q' is fixed, not tunable" in dict(info.value.problems)["faults[0].set"]
    ok = load_scenario(write(tmp_path, text.replace("x0_q", "noise_std_q"), "ok.toml"))
    check_against_models(ok, infos_for(ok, models))  # no exception


def test_seed_scenarios_match_the_fmus(models):
    for path in sorted(DATA.glob("*.toml")):
        s = load_scenario(path)
        check_against_models(s, infos_for(s, models))


# ------------------------------------------------------------------ coupling order
def test_coupling_plan_breaks_cycles_before_first_declared_instance():
    s = load_scenario(DATA / "closed_loop.toml")
    plan = plan_coupling(s)
    assert plan.order == ["aircraft", "injector", "controller"]
    assert [(c.from_, c.to) for c in plan.delayed] == [
        ("controller.elevator", "aircraft.elevator"), ("controller.throttle", "aircraft.throttle")]
    # declaring the controller first moves the break to its inputs
    data = s.model_dump(by_alias=True)
    data["fmus"] = {k: data["fmus"][k] for k in ("controller", "injector", "aircraft")}
    flipped = plan_coupling(parse_scenario(data))
    assert flipped.order == ["controller", "aircraft", "injector"]
    assert {c.to for c in flipped.delayed} == {"controller.q_meas", "controller.alpha_meas",
                                              "controller.theta_meas"}
    data["coupling"] = "jacobi"
    assert len(plan_coupling(parse_scenario(data)).delayed) == len(s.connections)


# ------------------------------------------------------------------------- results
def test_run_result_round_trip_and_missing_signal(tmp_path):
    r = RunResult(scenario="demo", time=np.array([0.0, 0.1, 0.2]),
                  signals={"a.x": np.array([1.0 / 3.0, np.nan, -np.inf]),
                           "a.flag": np.array([0.0, 1.0, 1.0])},
                  fault_windows=[FaultWindow("f", "inj.out_1", "bias", 0.1),
                                 FaultWindow("g", "dtg.spin", "physical", 0.1, 0.2)],
                  step_s=0.1, error="instance a: doStep at t=0.2 returned ERROR: boom\nline 2",
                  wall_time_s=1.5, stop_time_s=0.3)
    r.save(tmp_path / "run", precision="float64")
    back = RunResult.load(tmp_path / "run")
    assert back.scenario == "demo" and back.error == r.error and back.step_s == 0.1
    assert back.stop_time_s == 0.3 and back.wall_time_s == 1.5
    np.testing.assert_array_equal(back.time, r.time)
    assert list(back.signals) == ["a.x", "a.flag"]
    np.testing.assert_array_equal(back.signal("a.x"), r.signals["a.x"])  # exact, nan, -inf
    assert back.fault_windows == r.fault_windows
    assert math.isinf(back.fault("f").end_s)
    with pytest.raises(KeyError, match=r"'a\.flagg' was not recorded; closest: a\.flag"):
        back.signal("a.flagg")
