"""``python -m harness`` in subprocesses: run, list, verify, and its error exits."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from harness.cosim.results import RunResult

ROOT = Path(__file__).resolve().parents[1]
DATA = Path(__file__).resolve().parent / "data" / "scenarios"


def harness(*args: str, cwd: Path = ROOT) -> subprocess.CompletedProcess:
    env = dict(os.environ)
    env["PYTHONPATH"] = str(ROOT) + os.pathsep + env.get("PYTHONPATH", "")
    return subprocess.run([sys.executable, "-m", "harness", *args], cwd=cwd, env=env,
                          capture_output=True, text=True, timeout=120)


def test_run_writes_signals_and_meta_per_scenario(tmp_path, fmu_dir):
    out = tmp_path / "results"
    proc = harness("run", str(DATA / "closed_loop.toml"), str(DATA / "aircraft_pitch.toml"),
                   "--out", str(out), "--fmu-dir", str(fmu_dir), "--no-progress")
    assert proc.returncode == 0, proc.stdout + proc.stderr
    lines = proc.stdout.strip().splitlines()
    assert len(lines) == 2
    assert lines[0].startswith("closed_loop: ok, 201 samples of 5 signals, 2 s simulated")
    assert lines[0].endswith(str(out / "closed_loop"))
    r = RunResult.load(out / "closed_loop")
    assert (out / "closed_loop" / "signals.csv").is_file()
    assert r.error is None and r.stop_time_s == 2.0 and r.step_s == 0.01
    np.testing.assert_allclose(r.time[[0, -1]], [0.0, 2.0])
    assert [w.name for w in r.fault_windows] == ["q_bias"]
    # the q bias reaches the injector output from t = 1.01 s on
    diff = r.signal("injector.out_3") - r.signal("aircraft.y_q")
    assert np.all(diff[r.time < 1.005] == 0.0)
    np.testing.assert_allclose(diff[r.time > 1.005], 0.1, atol=1e-12)


def test_list_shows_name_duration_fmus_and_expectations():
    proc = harness("list", str(DATA))
    assert proc.returncode == 0, proc.stderr
    rows = {line.split()[0]: line for line in proc.stdout.splitlines()}
    assert "closed_loop" in rows and "aircraft_pitch" in rows
    closed = rows["closed_loop"].split()
    assert closed[1:3] == ["2", "s"]
    assert "injector=FaultInjector," in closed
    assert closed[-2:] == ["1", str(DATA / "closed_loop.toml")]  # 1 expectation, file
    assert proc.stdout.strip().splitlines()[-1] == f"2 scenario(s) in {DATA}"


def test_invalid_scenario_exits_2_naming_file_and_key(tmp_path):
    bad = tmp_path / "bad.toml"
    bad.write_text((DATA / "closed_loop.toml").read_text().replace(
        'fmu = "Aircraft"', 'fmu = "Aircraft"\nstep_ratio = 0'))
    proc = harness("run", str(bad), "--out", str(tmp_path / "r"), cwd=tmp_path)
    assert proc.returncode == 2
    assert proc.stderr.strip() == ("error: bad.toml: fmus.aircraft.step_ratio: Input should "
                                   "be greater than or equal to 1")
    assert not (tmp_path / "r").exists()


def test_run_error_exits_1_and_keeps_partial_results(tmp_path, fmu_dir):
    bad = tmp_path / "unstable.toml"
    bad.write_text("""
duration_s = 0.2
step_s = 0.01
[fmus.ctl]
fmu = "PitchController"
[[faults]]
name = "bad_source"
set = "ctl.command_source"
value = 7
start_s = 0.1
""")
    proc = harness("run", str(bad), "--out", str(tmp_path / "r"), "--fmu-dir", str(fmu_dir))
    assert proc.returncode == 1
    assert "unstable: ERROR (0.1 s recorded of 0.2 s): instance ctl: doStep at t=0.1" in \
        proc.stdout
    assert "command_source must be 0..4" in proc.stderr
    r = RunResult.load(tmp_path / "r" / "unstable")
    assert len(r.time) == 11 and "got 7" in r.error


def test_verify_runs_checks_expectations_and_writes_reports(tmp_path, fmu_dir):
    pytest.importorskip("harness.reporting.report")
    scenario = tmp_path / "verify_me.toml"
    scenario.write_text((DATA / "closed_loop.toml").read_text() + """
[[expect]]
kind = "value_at"
signal = "injector.fault_active_3"
t_s = 0.5
equals = 1
""")
    proc = harness("verify", str(scenario), "--out", str(tmp_path / "r"), "--fmu-dir",
                   str(fmu_dir), "--junit", str(tmp_path / "j.xml"))
    assert proc.returncode == 1, proc.stdout + proc.stderr   # the second one must fail
    assert "verify_me: FAIL (1 of 2 expectations failed)" in proc.stdout
    assert (tmp_path / "j.xml").is_file() and (tmp_path / "r" / "report.html").is_file()
    # report: the same verdict from the saved run, nothing re-run
    again = harness("report", str(scenario), "--out", str(tmp_path / "r"))
    assert again.returncode == 1 and "verify_me: FAIL (1 of 2" in again.stdout
