"""``python -m gyrodiag_harness compare-results A B`` (harness/cli/compare.py) and the ``gyrodiag``
console script.

The results folders are written by the harness's own writers (RunResult.save,
drop_signals, write_report, run_campaign with the fake runner of
tests/_campaign_fake_runner.py, summarize, the campaign write_report), twice, with wall
times that differ, so that "identical" also checks the ignore list; then one thing is
changed at a time.
"""

from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
import sys
from importlib.metadata import entry_points
from pathlib import Path

import numpy as np
import pytest

from gyrodiag_harness.campaigns.campaign import CampaignSpec, load_records, run_campaign
from gyrodiag_harness.campaigns.campaign_report import summarize
from gyrodiag_harness.campaigns.campaign_report import write_report as write_campaign_report
from gyrodiag_harness.cli import main
from gyrodiag_harness.cli.compare import IGNORED, ResultsFolderError, compare_results
from gyrodiag_harness.cosim.results import FaultWindow, RunResult, drop_signals
from gyrodiag_harness.reporting.report import write_report
from gyrodiag_harness.verification.expectations import ExpectationResult, ScenarioVerdict

ROOT = Path(__file__).resolve().parents[1]


# ---------------------------------------------------------------------------- helpers
def _runs(wall: float) -> list[RunResult]:
    t = np.round(np.arange(201) * 0.01, 10)
    q = 0.1 * np.sin(2 * np.pi * t) + 0.013 * t
    residual = np.where(t < 0.5, np.nan, np.cos(3 * t) / 7)  # NaN before calibration
    alarm = (t >= 1.2).astype(float)
    fault = FaultWindow("q_bias", "injector.out_3", "bias", 1.0)
    alpha = RunResult("alpha", t, {"aircraft.q": q, "diag.residual": residual,
                                   "diag.alarm": alarm, "aircraft.gain": np.full(201, 2.5)},
                      fault_windows=[fault], step_s=0.01, stop_time_s=2.0, wall_time_s=wall)
    beta = RunResult("beta", t, {"aircraft.q": -q}, step_s=0.01, stop_time_s=2.0,
                     wall_time_s=2 * wall)
    return [alpha, beta]


def _verdicts(q_passes: bool = True, delay: float = 0.2) -> list[ScenarioVerdict]:
    return [
        ScenarioVerdict("alpha", [
            ExpectationResult("detects the bias", True,
                              f"expected diag.alarm > 0.5 within 1 s of fault 'q_bias' "
                              f"(start 1 s); measured delay {delay:.6g} s", delay,
                              "detected_within"),
            ExpectationResult("q stays small", q_passes,
                              "expected value_at(aircraft.q, 2 s) in [-1, 1]; measured "
                              + ("0.126 rad/s" if q_passes else "1.5 rad/s"),
                              0.126 if q_passes else 1.5, "value_at"),
        ]),
        ScenarioVerdict("beta", [ExpectationResult("no alarm", True,
                                                   "expected no alarm; measured: no alarm",
                                                   None, "no_false_alarm")]),
    ]


def write_runs_folder(out: Path, wall: float, runs: list[RunResult] | None = None,
                      verdicts: list[ScenarioVerdict] | None = None) -> Path:
    """A results folder as ``harness all`` writes one: a folder per run, a training run
    whose signals were dropped, a learned library, junit.xml and report.html."""
    runs = runs if runs is not None else _runs(wall)
    for run in runs:
        run.save(out / run.scenario, precision="float64" if run.scenario == "alpha"
                 else "compact", judged={"aircraft.q"})
    training = RunResult("train_1", runs[0].time, {"dtg.x": runs[0].time ** 2},
                         step_s=0.01, stop_time_s=2.0, wall_time_s=wall)
    training.save(out / "training" / "train_1")
    drop_signals(out / "training" / "train_1", "learned from in memory")
    (out / "dtg_signatures.json").write_text(json.dumps(
        {"codes": {"ux_drift": 3}, "signatures": {"ux_drift": [0.25, -1.0, float("nan")]}},
        indent=1), encoding="utf-8")
    write_report(verdicts if verdicts is not None else _verdicts(), runs, out, workers=1)
    return out


@pytest.fixture(scope="module")
def runs_pair(tmp_path_factory) -> tuple[Path, Path]:
    root = tmp_path_factory.mktemp("runs")
    return (write_runs_folder(root / "a", wall=1.25), write_runs_folder(root / "b", wall=3.5))


def copy(folder: Path, tmp_path: Path) -> Path:
    return Path(shutil.copytree(folder, tmp_path / "copy"))


def cli(capsys, *args: str | Path) -> tuple[int, str, str]:
    code = main(["compare-results", *map(str, args)])
    captured = capsys.readouterr()
    return code, captured.out, captured.err


# ------------------------------------------------------------------------ runs folders
def test_two_writes_of_the_same_runs_are_identical_and_the_ignore_list_is_printed(
        runs_pair, capsys):
    a, b = runs_pair
    # the two folders do differ: wall times in run.json, junit.xml and report.html
    assert (a / "alpha" / "run.json").read_bytes() != (b / "alpha" / "run.json").read_bytes()
    assert (a / "junit.xml").read_bytes() != (b / "junit.xml").read_bytes()
    cmp = compare_results(a, b)
    assert cmp.identical, cmp.render()
    assert cmp.kind == "runs"
    assert cmp.counts["runs"] == 3  # alpha, beta, training/train_1
    assert cmp.counts["signals"] == 5 + 2  # time + 4, time + 1
    assert cmp.counts["expectations"] == 3
    assert cmp.counts["files"] == 1  # dtg_signatures.json (report.html is ignored)
    code, out, _ = cli(capsys, a, b)
    assert code == 0
    assert out.rstrip().endswith("IDENTICAL")
    for item in IGNORED:
        assert item.describe() in out
    assert "wall_time_s" in out and "report.html" not in out.split("IDENTICAL")[0] \
        .split("compared:")[1]


def test_one_changed_sample_of_one_signal_is_named_with_its_time(runs_pair, tmp_path,
                                                                 capsys):
    a, b = runs_pair
    b = copy(b, tmp_path)
    runs = _runs(3.5)
    runs[0].signals["aircraft.q"][137] += 1e-12  # below any rounding: bit for bit
    runs[0].save(b / "alpha", precision="float64", judged={"aircraft.q"})
    code, out, _ = cli(capsys, a, b)
    assert code == 1
    diffs = [line for line in out.splitlines() if line.startswith("  alpha:")]
    assert len(diffs) == 1, out
    assert "alpha: signal aircraft.q: 1 of 201 samples differ, first at t = 1.37 s " \
           "(sample 137)" in diffs[0]
    assert re.search(r"max \|A - B\| = 1\.0\d*e-12", diffs[0])
    assert "DIFFERENT: 1 difference" in out
    # a tolerance accepts it; a tighter one does not
    assert main(["-q", "compare-results", str(a), str(b), "--atol", "1e-11"]) == 0
    assert main(["-q", "compare-results", str(a), str(b), "--atol", "1e-13"]) == 1
    capsys.readouterr()


def test_nan_equals_nan_but_not_a_number(runs_pair, tmp_path):
    a, b = runs_pair
    b = copy(b, tmp_path)
    runs = _runs(3.5)
    runs[0].signals["diag.residual"][10] = 0.0  # was NaN
    runs[0].save(b / "alpha", precision="float64")
    cmp = compare_results(a, b)
    assert [d for d in cmp.differences if "signal diag.residual" in d] == [
        "alpha: signal diag.residual: 1 of 201 samples differ, first at t = 0.1 s "
        "(sample 10): nan in A, 0.0 in B; max |A - B| = inf"]


def test_missing_renamed_or_shortened_signals_and_runs_are_differences(runs_pair, tmp_path):
    a, b = runs_pair
    b = copy(b, tmp_path)
    runs = _runs(3.5)
    runs[0].signals["aircraft.pitch"] = runs[0].signals.pop("aircraft.gain")
    runs[0].save(b / "alpha", precision="float64")
    short = RunResult("beta", runs[1].time[:150], {"aircraft.q": runs[1].signals[
        "aircraft.q"][:150]}, step_s=0.01, stop_time_s=2.0)
    short.save(b / "beta")
    shutil.copytree(b / "beta", b / "gamma")
    text = "\n".join(compare_results(a, b).differences)
    assert "alpha: signal aircraft.gain only in A" in text
    assert "alpha: signal aircraft.pitch only in B" in text
    assert "beta: signal time: 201 samples in A, 150 in B" in text
    assert "beta/run.json: n_samples: 201 in A, 150 in B" in text
    assert "gamma: run only in B" in text


def test_a_changed_verdict_is_a_difference(runs_pair, tmp_path, capsys):
    a, b = runs_pair
    b = copy(b, tmp_path)
    write_report(_verdicts(q_passes=False), _runs(3.5), b, workers=1)
    code, out, _ = cli(capsys, a, b)
    assert code == 1
    assert ("alpha: expectation 'q stays small': PASS in A, FAIL in B; A: measured "
            "0.126 rad/s | B: measured 1.5 rad/s") in out
    # the same verdict with another measured value is a difference too
    write_report(_verdicts(delay=0.21), _runs(3.5), b, workers=1)
    cmp = compare_results(a, b)
    assert cmp.differences == [
        "alpha: expectation 'detects the bias': pass in both; A: measured delay 0.2 s | "
        "B: measured delay 0.21 s"]
    # an expectation less
    verdicts = _verdicts()
    del verdicts[0].expectations[1]
    write_report(verdicts, _runs(3.5), b, workers=1)
    assert compare_results(a, b).differences == [
        "alpha: 'q stays small': testcase in junit.xml only in A"]


def test_a_changed_library_or_fault_window_is_a_difference(runs_pair, tmp_path):
    a, b = runs_pair
    b = copy(b, tmp_path)
    lib = json.loads((b / "dtg_signatures.json").read_text())
    lib["signatures"]["ux_drift"][0] = 0.25000000000000006
    (b / "dtg_signatures.json").write_text(json.dumps(lib), encoding="utf-8")
    runs = _runs(3.5)
    runs[0].fault_windows[0].start_s = 1.01
    runs[0].save(b / "alpha", precision="float64")
    assert compare_results(a, b).differences == [
        "alpha/run.json: fault_windows.0.start_s: 1.0 in A, 1.01 in B",
        "dtg_signatures.json: signatures.ux_drift.0: 0.25 in A, 0.25000000000000006 in B"]


def test_bad_input_exits_2_naming_the_culprit(runs_pair, tmp_path, capsys):
    a, _ = runs_pair
    missing = tmp_path / "nowhere"
    code, out, err = cli(capsys, a, missing)
    assert code == 2 and f"{missing}: no such folder" in err and out == ""
    empty = tmp_path / "empty"
    empty.mkdir()
    code, _, err = cli(capsys, empty, a)
    assert code == 2 and f"{empty}: not a results folder" in err
    (tmp_path / "file").write_text("x")
    code, _, err = cli(capsys, tmp_path / "file", a)
    assert code == 2 and f"{tmp_path / 'file'}: not a folder" in err
    campaign = tmp_path / "campaign"
    campaign.mkdir()
    (campaign / "campaign.json").write_text("{}")
    code, _, err = cli(capsys, a, campaign)
    assert code == 2 and f"{campaign}: a campaign folder, but {a} is a runs folder" in err
    with pytest.raises(ResultsFolderError, match="no such folder"):
        compare_results(missing, a)


# --------------------------------------------------------------------- campaign folders
FAKE_SPEC = {
    "name": "fake", "timeout_s": 60.0, "runner": "_campaign_fake_runner:fake",
    "classes": {"air": {"scenario": "unused.toml", "channel": "df"}},
    "sweeps": [{"class": "air", "type": "bias", "magnitudes": [0.3, 0.6, 0.9],
                "onsets_s": [1.0], "channels": [3], "duration_s": 2.0}],
    "nominal": [{"class": "air", "duration_s": 60.0, "runs": 2}],
}


def write_campaign_folder(base: Path, out: Path) -> Path:
    spec = CampaignSpec.model_validate(FAKE_SPEC)
    outcome = run_campaign(spec, base, out, workers=2, progress=False, fraction=0.5)
    summary = summarize(outcome.records, n_planned=outcome.n_total)
    write_campaign_report(summary, outcome.records, out, title=spec.name)
    return out


@pytest.fixture(scope="module")
def campaign_pair(tmp_path_factory) -> tuple[Path, Path]:
    # two runs of a fixed fraction in different folders (so results_dir differs too)
    root = tmp_path_factory.mktemp("campaigns")
    return (write_campaign_folder(root, root / "a"), write_campaign_folder(root, root / "b"))


def test_two_runs_of_a_campaign_fraction_are_identical(campaign_pair, capsys):
    a, b = campaign_pair
    walls = [r["wall_s"] for r in load_records(a / "runs").values()]
    assert walls and all(w > 0 for w in walls)
    cmp = compare_results(a, b)
    assert cmp.identical, cmp.render()
    assert cmp.kind == "campaign"
    assert cmp.counts["run records"] == len(walls) == 3  # half of each stratum, rounded up
    code, out, _ = cli(capsys, a, b)
    assert code == 0 and "runs/*.json: wall_s" in out and out.rstrip().endswith("IDENTICAL")


def test_the_wall_times_of_real_run_records_are_ignored(campaign_pair, tmp_path):
    """A real run's record also holds sim_wall_s (the fake runner's does not)."""
    a, b = campaign_pair
    b = copy(b, tmp_path)
    for path in (b / "runs").glob("*.json"):
        record = json.loads(path.read_text())
        record.update(sim_wall_s=12.5, wall_s=13.0)
        path.write_text(json.dumps(record, indent=1), encoding="utf-8")
    assert compare_results(a, b).identical
    record["seed"] = 3
    path.write_text(json.dumps(record, indent=1), encoding="utf-8")
    assert compare_results(a, b).differences == [f"runs/{path.name}: seed: only in B"]


def test_a_changed_run_record_or_summary_is_a_difference(campaign_pair, tmp_path, capsys):
    a, b = campaign_pair
    b = copy(b, tmp_path)
    path = next(p for p in sorted((b / "runs").glob("*.json"))
                if json.loads(p.read_text())["run"]["kind"] == "fault")
    record = json.loads(path.read_text())
    record["delay_s"] = (record["delay_s"] or 0.0) + 1e-9
    path.write_text(json.dumps(record, indent=1), encoding="utf-8")
    summary = json.loads((b / "summary.json").read_text())
    summary["n_finished"] -= 1
    (b / "summary.json").write_text(json.dumps(summary, indent=1), encoding="utf-8")
    code, out, _ = cli(capsys, a, b)
    assert code == 1
    assert f"runs/{path.name}: delay_s: " in out
    assert "summary.json: n_finished: 3 in A, 2 in B" in out
    (b / "runs" / path.name).unlink()
    assert f"{path.stem}: run record only in A" in "\n".join(
        compare_results(a, b).differences)


def test_a_campaign_summary_folder_compares_its_summary(campaign_pair, tmp_path):
    a, b = campaign_pair
    for name, src in (("sa", a), ("sb", b)):
        assert main(["-q", "campaign-summary", str(src), "--out", str(tmp_path / name)]) == 0
    cmp = compare_results(tmp_path / "sa", tmp_path / "sb")
    assert cmp.kind == "campaign-summary"
    # run_hours (wall times) differ and are ignored; every other figure is the same
    assert cmp.identical, cmp.render()


# ------------------------------------------------------------------- the console script
def test_console_script_is_the_harness_main():
    (ep,) = [e for e in entry_points(group="console_scripts") if e.name == "gyrodiag"]
    assert ep.value == "gyrodiag_harness.cli:console"
    from gyrodiag_harness.cli import console

    assert ep.load() is console


def _commands(help_text: str) -> list[str]:
    block = help_text.split("positional arguments:")[1].split("options:")[0]
    return re.findall(r"^    (\S[\w-]*)", block, flags=re.MULTILINE)


def test_gyrodiag_help_lists_the_same_commands_as_python_m_harness():
    script = Path(sys.executable).with_name("gyrodiag")
    if not script.is_file():
        script = Path(shutil.which("gyrodiag") or "gyrodiag")
    env = {**os.environ, "COLUMNS": "100"}
    mine = subprocess.run([str(script), "--help"], capture_output=True, text=True, env=env,
                          timeout=60, check=True).stdout
    theirs = subprocess.run([sys.executable, "-m", "gyrodiag_harness", "--help"],
                            capture_output=True, text=True, env=env, cwd=ROOT, timeout=60,
                            check=True).stdout
    assert mine.startswith("usage: gyrodiag ")
    assert theirs.startswith("usage: python -m gyrodiag_harness ")
    commands = _commands(theirs)
    assert "all" in commands and "compare-results" in commands and len(commands) >= 12
    assert _commands(mine) == commands
