"""Scenarios run in parallel worker processes give exactly the results of a serial run:
the same samples to the last bit, the same verdicts, the same reports (times aside); run
processes forked from the pre-imported server give those of processes started with
``python -m`` (GYRODIAG_FORK_SERVER=0)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest

from gyrodiag_harness.cosim.batch import default_workers, run_all
from gyrodiag_harness.cosim.results import RunResult

ROOT = Path(__file__).resolve().parents[1]
DATA = Path(__file__).resolve().parent / "data" / "scenarios"
SCENARIOS = [DATA / "closed_loop.toml", DATA / "aircraft_pitch.toml",
             ROOT / "scenarios" / "aircraft_q_bias.toml",
             ROOT / "scenarios" / "hrg_seed001_grey.toml"]


def _verify(out: Path, fmu_dir: Path, workers: int,
            fork_server: bool = True) -> subprocess.CompletedProcess:
    env = dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    env["GYRODIAG_FORK_SERVER"] = "1" if fork_server else "0"
    return subprocess.run([sys.executable, "-m", "gyrodiag_harness", "verify", *map(str, SCENARIOS),
                           "--out", str(out), "--fmu-dir", str(fmu_dir), "--workers",
                           str(workers), "--no-progress"], cwd=ROOT, env=env,
                          capture_output=True, text=True, timeout=600)


def _junit(path: Path) -> list:
    root = ET.parse(path).getroot()
    for node in root.iter():
        node.attrib.pop("time", None)
    return [ET.tostring(s, encoding="unicode") for s in root]


@pytest.fixture(scope="module")
def runs(fmu_dir: Path, tmp_path_factory: pytest.TempPathFactory) -> dict:
    outs = {}
    # serial runs started with python -m, against 3 runs at a time (> cores: they finish
    # in another order than started) forked from the pre-imported server
    for workers in (1, 3):
        out = tmp_path_factory.mktemp(f"workers{workers}")
        proc = _verify(out, fmu_dir, workers, fork_server=workers > 1)
        assert proc.returncode == 0, proc.stdout + proc.stderr
        outs[workers] = (out, proc)
    return outs


def test_parallel_signals_are_bit_identical_to_serial(runs: dict) -> None:
    (serial, _), (parallel, _) = runs[1], runs[3]
    for path in SCENARIOS:
        name = path.stem
        a, b = RunResult.load(serial / name), RunResult.load(parallel / name)
        assert list(a.signals) == list(b.signals) and len(a.time) > 100
        assert np.array_equal(a.time.view(np.uint64), b.time.view(np.uint64))
        for signal in a.signals:
            assert np.array_equal(a.signals[signal].view(np.uint64),
                                  b.signals[signal].view(np.uint64)), (name, signal)
        meta_a = json.loads((serial / name / "run.json").read_text())
        meta_b = json.loads((parallel / name / "run.json").read_text())
        meta_a.pop("wall_time_s"), meta_b.pop("wall_time_s")
        assert meta_a == meta_b


def test_parallel_verdicts_and_reports_match_serial(runs: dict) -> None:
    (serial, proc_1), (parallel, proc_3) = runs[1], runs[3]
    verdicts = [sorted(line for line in p.stdout.splitlines()
                       if ": PASS" in line or ": FAIL" in line) for p in (proc_1, proc_3)]
    assert verdicts[0] == verdicts[1] and len(verdicts[0]) == len(SCENARIOS)
    assert _junit(serial / "junit.xml") == _junit(parallel / "junit.xml")


def test_run_all_api_rejects_bad_worker_counts(tmp_path: Path) -> None:
    for bad in (0, -1, 1.5, True):
        with pytest.raises(ValueError, match="workers must be an integer >= 1"):
            run_all([], tmp_path, workers=bad)
    assert default_workers() >= 1
    assert run_all([], tmp_path, workers=None) == []
