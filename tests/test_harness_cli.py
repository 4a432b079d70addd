"""``python -m gyrodiag_harness`` in subprocesses: run, list, verify, and its error exits."""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from gyrodiag_harness.cosim.results import RunResult

ROOT = Path(__file__).resolve().parents[1]
DATA = Path(__file__).resolve().parent / "data" / "scenarios"


def harness(*args: str, cwd: Path = ROOT) -> subprocess.CompletedProcess:
    env = dict(os.environ)
    env["PYTHONPATH"] = str(ROOT) + os.pathsep + env.get("PYTHONPATH", "")
    return subprocess.run([sys.executable, "-m", "gyrodiag_harness", *args], cwd=cwd, env=env,
                          capture_output=True, text=True, timeout=120)


def test_run_writes_signals_and_meta_per_scenario(tmp_path, fmu_dir):
    out = tmp_path / "results"
    proc = harness("run", str(DATA / "closed_loop.toml"), str(DATA / "aircraft_pitch.toml"),
                   "--out", str(out), "--fmu-dir", str(fmu_dir), "--no-progress")
    assert proc.returncode == 0, proc.stdout + proc.stderr
    # one line per scenario, in the order the runs end (they run in parallel)
    lines = sorted(proc.stdout.strip().splitlines())
    assert len(lines) == 2
    assert lines[1].startswith("closed_loop: ok, 201 samples of 5 signals, 2 s simulated")
    assert lines[1].endswith(str(out / "closed_loop"))
    r = RunResult.load(out / "closed_loop")
    assert (out / "closed_loop" / "signals.npz").is_file()
    assert r.error is None and r.stop_time_s == 2.0 and r.step_s == 0.01
    np.testing.assert_allclose(r.time[[0, -1]], [0.0, 2.0])
    assert [w.name for w in r.fault_windows] == ["q_bias"]
    # saved by default "compact": the one signal the expectation reads is an Integer
    # (exact), the Real signals, there for plots, are rounded to 13 significant bits
    meta = json.loads((out / "closed_loop" / "run.json").read_text())
    assert meta["signals_precision"] == "compact"
    assert r.rounded_signals == dict.fromkeys(["aircraft.y_q", "aircraft.x_theta",
                                               "injector.out_3", "controller.elevator"],
                                              2.0**-13)
    assert meta["signal_storage"]["injector.fault_active_3"] == "int8"
    np.testing.assert_array_equal(r.signal("injector.fault_active_3"), r.time > 1.005)
    # the q bias reaches the injector output from t = 1.01 s on; before, both are the
    # same float64 and so round alike; after, each is within 2**-13 of its value
    out3, y_q = r.signal("injector.out_3"), r.signal("aircraft.y_q")
    diff = out3 - y_q
    assert np.all(diff[r.time < 1.005] == 0.0)
    after = r.time > 1.005
    bound = 2.0**-13 * (np.abs(out3) + np.abs(y_q))[after] + 1e-15
    assert np.all(np.abs(diff[after] - 0.1) <= bound)
    assert np.abs(diff[after] - 0.1).max() > 2.0**-24  # rounded indeed, not float32


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


def test_default_output_folders_never_clobber_and_latest_follows(tmp_path, fmu_dir):
    # no --out: each command gets results/<command>-<time>/ in the working folder, and
    # results/latest points to the newest; two verifies of different scenarios keep both
    # reports (the README examples in a row)
    scenario = DATA / "closed_loop.toml"
    first = harness("verify", str(scenario), "--fmu-dir", str(fmu_dir), "--no-progress",
                    cwd=tmp_path)
    second = harness("run", str(DATA / "aircraft_pitch.toml"), "--fmu-dir", str(fmu_dir),
                     "--no-progress", cwd=tmp_path)
    third = harness("verify", str(scenario), "--fmu-dir", str(fmu_dir), "--no-progress",
                    cwd=tmp_path)
    for proc in (first, second, third):
        assert proc.returncode == 0, proc.stdout + proc.stderr
    folders = sorted(p.name for p in (tmp_path / "results").iterdir() if p.name != "latest")
    assert [f.split("-")[0] for f in folders] == ["run", "verify", "verify"], folders
    assert len(set(folders)) == 3
    verifies = [tmp_path / "results" / f for f in folders if f.startswith("verify")]
    assert all((v / "report.html").is_file() and (v / "closed_loop" / "run.json").is_file()
               for v in verifies)
    latest = (tmp_path / "results" / "latest").resolve()
    assert latest.name in third.stdout and latest.parent == (tmp_path / "results").resolve()
    assert (latest / "junit.xml").is_file()
    # report without --out reads and writes results/latest
    again = harness("report", str(scenario), cwd=tmp_path)
    assert again.returncode == 0 and f"HTML: {latest / 'report.html'}" in again.stdout.replace(
        str(tmp_path / "results" / "latest"), str(latest))


def test_export_csv_writes_the_saved_signals_exactly(tmp_path, fmu_dir):
    out = tmp_path / "r"
    proc = harness("run", str(DATA / "closed_loop.toml"), "--out", str(out), "--fmu-dir",
                   str(fmu_dir), "--no-progress", "-q")
    assert proc.returncode == 0 and proc.stdout == "", proc.stdout + proc.stderr  # -q
    exported = harness("export-csv", str(out))
    assert exported.returncode == 0, exported.stderr
    csv_file = out / "closed_loop" / "signals.csv"
    assert exported.stdout.strip() == str(csv_file)
    saved = RunResult.load(out / "closed_loop")
    lines = csv_file.read_text().splitlines()
    header = lines[0].split(",")
    table = np.loadtxt(csv_file, delimiter=",", skiprows=1)
    assert header == ["time", *saved.signals]
    # up to 17 significant digits: the CSV holds every bit of the exact signals; the
    # ones rounded to 13 bits with 5 digits, which round back to the stored value
    assert np.array_equal(table[:, 0], saved.time)
    assert set(saved.rounded_signals.values()) == {2.0**-13}
    for j, name in enumerate(saved.signals, start=1):
        if name in saved.rounded_signals:
            back = table[:, j].copy()
            mantissa, exponent = np.frexp(back)  # back to 13 significant bits
            back = np.ldexp(np.round(mantissa * 2.0**13) / 2.0**13, exponent)
            assert np.array_equal(back, saved.signals[name]), name
            digits = [len(row.split(",")[j].lstrip("-").split("e")[0].replace(".", "")
                          .lstrip("0")) for row in lines[1:]]
            assert max(digits) <= 5, name
        else:
            assert np.array_equal(table[:, j], saved.signals[name]), name
    # --exact-signals: every bit in the store and in the CSV
    exact = harness("run", str(DATA / "closed_loop.toml"), "--out", str(tmp_path / "x"),
                    "--fmu-dir", str(fmu_dir), "--no-progress", "-q", "--exact-signals")
    assert exact.returncode == 0, exact.stderr
    full = RunResult.load(tmp_path / "x" / "closed_loop")
    assert not full.rounded_signals
    assert harness("export-csv", str(tmp_path / "x")).returncode == 0
    table = np.loadtxt(tmp_path / "x" / "closed_loop" / "signals.csv", delimiter=",",
                       skiprows=1)
    for j, name in enumerate(full.signals, start=1):
        assert np.array_equal(table[:, j], full.signals[name]), name
        rel = np.abs(saved.signals[name] - full.signals[name]) \
            / np.maximum(np.abs(full.signals[name]), 1e-300)
        assert rel.max() <= saved.rounded_signals.get(name, 0.0), name
    single = harness("export-csv", str(out / "closed_loop"), "--out", str(tmp_path / "x.csv"))
    assert single.returncode == 0 and (tmp_path / "x.csv").read_text() == csv_file.read_text()
    bad = harness("export-csv", str(tmp_path / "nothing"))
    assert bad.returncode == 2 and "not a run folder" in bad.stderr


def test_a_run_error_is_said_once(tmp_path, fmu_dir):
    bad = tmp_path / "failing.toml"
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
""" + "".join(f"""
[[expect]]
kind = "value_at_end"
signal = "ctl.elevator"
name = "e{i}"
min = -1
""" for i in range(5)))
    proc = harness("verify", str(bad), "--out", str(tmp_path / "r"), "--fmu-dir", str(fmu_dir))
    assert proc.returncode == 1
    text = proc.stdout + proc.stderr
    assert text.count("ValueError: command_source must be") == 1, text
    assert "failing: ERROR (instance ctl: doStep at t=0.1" in proc.stdout
    assert "5 expectations not evaluated" in proc.stdout
    html = (tmp_path / "r" / "report.html").read_text()
    assert html.count("ValueError: command_source must be") == 1


def test_all_keeps_only_run_json_of_its_training_runs(tmp_path, fmu_dir):
    # two DTG training runs (codes 1, 2) and one scenario: the main job in small
    scenarios = tmp_path / "scenarios"
    (scenarios / "training").mkdir(parents=True)
    for name, code in (("dtg_train_utx_step_t1", 1), ("dtg_train_ux_drift_t1", 2)):
        text = (ROOT / "scenarios" / "training" / f"{name}.toml").read_text()
        text = re.sub(r"(?m)^code = \d+$", f"code = {code}", text)
        (scenarios / "training" / f"{name}.toml").write_text(text)
    (scenarios / "closed_loop.toml").write_text((DATA / "closed_loop.toml").read_text())

    def main_job(out: Path, *extra: str) -> subprocess.CompletedProcess[str]:
        proc = harness("all", "--no-build", "--scenarios", str(scenarios), "--fmu-dir",
                       str(fmu_dir), "--out", str(out), "--no-progress", *extra)
        assert proc.returncode == 0, proc.stdout + proc.stderr
        return proc

    proc = main_job(tmp_path / "out")
    assert "training runs: signals not kept" in proc.stdout
    training = tmp_path / "out" / "training"
    for name in ("dtg_train_utx_step_t1", "dtg_train_ux_drift_t1"):
        assert sorted(p.name for p in (training / name).iterdir()) == ["run.json"]
        meta = json.loads((training / name / "run.json").read_text())
        assert meta["error"] is None and "diag.dtg.eta_x[3]" in meta["signals"]
        with pytest.raises(FileNotFoundError, match="the signals of this run were not kept"):
            RunResult.load(training / name)
    library = json.loads((tmp_path / "out" / "dtg_signatures.json").read_text())
    assert [r["scenario"] for r in library["runs"]] == ["dtg_train_utx_step_t1",
                                                        "dtg_train_ux_drift_t1"]
    assert (tmp_path / "out" / "closed_loop" / "signals.npz").is_file()
    # export-csv of the whole folder passes over them; learn-signatures --saved says why
    exported = harness("export-csv", str(tmp_path / "out"))
    assert exported.returncode == 0, exported.stderr
    assert "2 run(s) without signals passed over" in exported.stdout
    saved = harness("learn-signatures", str(scenarios / "training"), "--saved", "--runs-out",
                    str(training), "--out", str(tmp_path / "again.json"))
    assert saved.returncode == 2 and "the signals of this run were not kept" in saved.stderr
    # --keep-training-signals: the same library, learned again from the saved runs
    main_job(tmp_path / "kept", "--keep-training-signals")
    kept = tmp_path / "kept" / "training"
    assert (kept / "dtg_train_utx_step_t1" / "signals.npz").is_file()
    again = harness("learn-signatures", str(scenarios / "training"), "--saved", "--runs-out",
                    str(kept), "--out", str(tmp_path / "again.json"))
    assert again.returncode == 0, again.stderr
    learned = json.loads((tmp_path / "again.json").read_text())
    assert learned["signatures"] == library["signatures"]
