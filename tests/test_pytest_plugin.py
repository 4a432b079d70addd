"""The gyrodiag pytest plugin (``pytest --gyrodiag``), tested with pytest's own pytester:
scenario files become items with docs and markers, expectations fail them with the
report's sentences, a scenario that cannot run is an error, it works with -n (xdist) and
--junitxml, and the fixtures give users' tests the runs."""

from __future__ import annotations

import xml.etree.ElementTree as ET
from pathlib import Path

import pytest

DATA = Path(__file__).resolve().parent / "data" / "scenarios"
BASE = (DATA / "closed_loop.toml").read_text()
PASSING = BASE.replace('description = "closed loop with a q-sensor bias through the injector"',
                       'description = "bias on q, the injector flags it"')
FAILING = BASE.replace("equals = 1", "equals = 0").replace(
    'description = "closed loop with a q-sensor bias through the injector"',
    'description = "an expectation that cannot hold"')
NOMINAL = """
description = "aircraft alone, no fault"
duration_s = 0.5
step_s = 0.01
[fmus.aircraft]
fmu = "Aircraft"
[record]
variables = ["aircraft.y_q"]
[[expect]]
kind = "value_in_window"
signal = "aircraft.y_q"
t0_s = 0.0
t1_s = 0.5
min = -1.0
max = 1.0
"""
CANNOT_RUN = BASE.replace('fmu = "FaultInjector"', 'fmu = "NoSuchInjector"')
INVALID = BASE.replace("step_s = 0.01", "step_s = -0.01")


@pytest.fixture
def project(pytester: pytest.Pytester) -> pytest.Pytester:
    pytester.makefile(".toml", **{"scenarios/passing": PASSING, "scenarios/failing": FAILING,
                                  "scenarios/nominal": NOMINAL})
    return pytester


def _run(pytester: pytest.Pytester, fmu_dir: Path, *args: str) -> pytest.RunResult:
    # option=value: a separate path argument would take part in finding the rootdir
    return pytester.runpytest_subprocess(f"--gyrodiag-fmu-dir={fmu_dir}", "-p",
                                         "no:cacheprovider", *args, timeout=600)


def test_off_unless_asked(project: pytest.Pytester, fmu_dir: Path) -> None:
    off = _run(project, fmu_dir, "scenarios")
    assert off.ret == pytest.ExitCode.NO_TESTS_COLLECTED
    project.makeini("[pytest]\ngyrodiag = true\n")
    on = _run(project, fmu_dir, "scenarios", "--collect-only", "-q")
    assert on.ret == 0
    assert sorted(line for line in on.outlines if "::" in line) == [
        "scenarios/failing.toml::failing", "scenarios/nominal.toml::nominal",
        "scenarios/passing.toml::passing"]


def test_items_have_the_description_as_doc_and_markers(project: pytest.Pytester,
                                                       fmu_dir: Path) -> None:
    (project.path / "pyproject.toml").write_text("[project]\nname = 'x'\n")  # not collected
    project.mkdir("scenarios/training")
    (project.path / "scenarios" / "training" / "t.toml").write_text(
        BASE + '\n[training]\nsignature = "x"\ncode = 1\n')  # an input, not a test
    shown = _run(project, fmu_dir, "--gyrodiag", "--collect-only", "-v", "scenarios")
    text = shown.stdout.str()
    assert "<ScenarioItem passing>" in text and "bias on q, the injector flags it" in text
    assert "training" not in text and "3 tests collected" in text
    # markers: the plant (aircraft) and the kind (fault / nominal)
    faults = _run(project, fmu_dir, "--gyrodiag", "-m", "aircraft and fault",
                  "--collect-only", "-q", "scenarios")
    assert sorted(line for line in faults.outlines if "::" in line) == [
        "scenarios/failing.toml::failing", "scenarios/passing.toml::passing"]
    nominal = _run(project, fmu_dir, "--gyrodiag", "-m", "nominal", "--strict-markers",
                   "--collect-only", "-q", "scenarios")
    assert [line for line in nominal.outlines if "::" in line] == [
        "scenarios/nominal.toml::nominal"]
    assert _run(project, fmu_dir, "--gyrodiag", "-m", "dtg or hrg or system", "-q",
                "scenarios").ret == pytest.ExitCode.NO_TESTS_COLLECTED


def test_verdicts_errors_junit_and_report(project: pytest.Pytester, fmu_dir: Path) -> None:
    project.makefile(".toml", **{"scenarios/cannot_run": CANNOT_RUN})
    results = project.path / "out"
    result = _run(project, fmu_dir, "--gyrodiag", "scenarios", "--junitxml=junit.xml",
                  f"--gyrodiag-results={results}", "-rA")
    result.assert_outcomes(passed=2, failed=1, errors=1)
    text = result.stdout.str()
    # the failure: the report's sentence of the failing expectation, no traceback
    assert "1 of 1 expectations of failing failed:" in text
    assert ("value_at_end(injector.fault_active_3): expected injector.fault_active_3 at the "
            "end (2 s) == 0 ± 1e-09; measured 1") in text
    # said once in the error section, not chained (the -rA short summary repeats it when
    # the terminal is wide enough, so count before that summary)
    errors = text.split("short test summary info")[0]
    assert errors.count("NoSuchInjector.fmu not found") == 1
    assert "Traceback" not in text and "def runtest" not in text
    # cannot run: an error at setup, naming the file, the key and the missing FMU
    assert "cannot run: " in text and "fmus.injector.fmu: FMU file" in text
    assert "NoSuchInjector.fmu not found" in text
    # JUnit: one testcase per scenario, the description as a property
    cases = {c.get("name"): c for c in ET.parse(project.path / "junit.xml").iter("testcase")}
    assert set(cases) == {"passing", "failing", "nominal", "cannot_run"}
    assert cases["failing"].find("failure") is not None
    assert cases["cannot_run"].find("error") is not None
    props = {p.get("name"): p.get("value") for p in cases["passing"].iter("property")}
    assert props["description"] == "bias on q, the injector flags it"
    # runs and the harness's report in the results folder
    assert (results / "passing" / "run.json").is_file()
    assert (results / "report.html").is_file() and "gyrodiag report:" in text
    assert "failing" in (results / "report.html").read_text()


def test_invalid_file_is_a_collection_error_naming_the_key(project: pytest.Pytester,
                                                           fmu_dir: Path) -> None:
    project.makefile(".toml", **{"scenarios/invalid": INVALID})
    result = _run(project, fmu_dir, "--gyrodiag", "scenarios", "--collect-only")
    assert result.ret == pytest.ExitCode.INTERRUPTED  # collection errors stop the session
    assert "scenarios/invalid.toml: step_s: Input should be greater than 0" in \
        result.stdout.str()


def test_xdist_and_fixtures_share_one_run_per_scenario(project: pytest.Pytester,
                                                       fmu_dir: Path) -> None:
    project.makepyfile(test_users_own="""
        import numpy as np

        def test_bias_reaches_the_controller(gyrodiag_run):
            r = gyrodiag_run("scenarios/passing.toml")
            assert r is gyrodiag_run("scenarios/passing.toml")   # cached in the process
            diff = r.signal("injector.out_3") - r.signal("aircraft.y_q")
            np.testing.assert_allclose(diff[r.time > 1.005], 0.1, atol=1e-12)

        def test_the_same_run_again(gyrodiag_run, gyrodiag_scenario, gyrodiag_results):
            s = gyrodiag_scenario("scenarios/passing.toml")
            r = gyrodiag_run(s)
            assert (gyrodiag_results / s.name / "run.json").is_file()
            print("WALL", repr(r.wall_time_s))

        def test_fmu_dir(gyrodiag_fmu_dir):
            assert (gyrodiag_fmu_dir / "Aircraft.fmu").is_file()

        def test_many_at_once(gyrodiag_run):
            paths = ["scenarios/nominal.toml", "scenarios/passing.toml"]
            nominal, passing = gyrodiag_run.many(paths)
            assert nominal.scenario == "nominal" and passing.scenario == "passing"
            assert gyrodiag_run(paths[0]) is nominal
            print("WALL", repr(passing.wall_time_s))
    """)
    results = project.path / "out"
    result = _run(project, fmu_dir, "--gyrodiag", "scenarios", "test_users_own.py", "-n",
                  "2", f"--gyrodiag-results={results}", "--junitxml=j.xml", "-rA")
    result.assert_outcomes(passed=6, failed=1)
    # one run of 'passing' for the scenario item and both user tests, whichever worker
    # got there first: the saved run's wall time is the one every test saw
    from gyrodiag_harness.cosim.results import RunResult

    saved = RunResult.load(results / "passing")
    assert result.stdout.str().count(f"WALL {saved.wall_time_s!r}") == 2
    assert len(list(results.glob("*/run.json"))) == 3
    assert ET.parse(project.path / "j.xml").getroot().find(".//testcase") is not None
