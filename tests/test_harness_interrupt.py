"""Ctrl-C and SIGTERM on real runs: ``python -m gyrodiag_harness`` stops between two steps, keeps
the partial signals of the runs in flight (marked interrupted in run.json and the report),
starts nothing new and exits 130; the FMUs never see the interrupt as an exception.

The commands run in subprocesses with SIGINT at its default disposition: CI may start
the suite with SIGINT ignored (a background job of a non-interactive shell), which a
child would inherit and, rightly, keep ignoring.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np

from gyrodiag_harness.cosim.results import RunResult

ROOT = Path(__file__).resolve().parents[1]
DATA = Path(__file__).resolve().parent / "data" / "scenarios"
LONG_S = 600.0   # 60 000 steps of the closed loop: minutes, far longer than the test waits


def _long_scenario(tmp: Path, name: str, seed: int) -> Path:
    text = (DATA / "closed_loop.toml").read_text()
    text = text.replace("duration_s = 2.0", f"duration_s = {LONG_S}")
    text = text.replace("seed = 3", f"seed = {seed}")
    path = tmp / f"{name}.toml"
    path.write_text(f'name = "{name}"\n' + text)
    return path


def _start(args: list[str], tmp: Path) -> tuple[subprocess.Popen, Path, Path]:
    stdout, stderr = tmp / "stdout.txt", tmp / "stderr.txt"
    env = dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    with open(stdout, "w") as out, open(stderr, "w") as err:  # the child keeps its copies
        proc = subprocess.Popen(
            [sys.executable, "-m", "gyrodiag_harness", *args, "-v", "--no-progress"], cwd=ROOT,
            env=env, stdout=out, stderr=err,
            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    return proc, stdout, stderr


def _wait_for(path: Path, text: str, count: int, proc: subprocess.Popen,
              timeout_s: float = 120.0) -> None:
    t0 = time.monotonic()
    while time.monotonic() - t0 < timeout_s:
        if path.read_text().count(text) >= count:
            return
        assert proc.poll() is None, f"the command ended early:\n{path.read_text()}"
        time.sleep(0.1)
    raise AssertionError(f"{text!r} x{count} not seen in {timeout_s} s:\n{path.read_text()}")


def _check_partial(run_dir: Path, reason: str) -> RunResult:
    meta = json.loads((run_dir / "run.json").read_text())
    assert meta["interrupted"] is True
    assert meta["error"].startswith(f"interrupted by {reason} after ")
    r = RunResult.load(run_dir)
    assert r.interrupted and not r.completed
    # stepping had begun: some samples, far from the end, on the 0.01 s grid, all finite
    assert 10 < len(r.time) < LONG_S / 0.01
    np.testing.assert_allclose(np.diff(r.time), 0.01, rtol=1e-9)
    assert all(np.all(np.isfinite(v)) for v in r.signals.values())
    assert meta["n_samples"] == len(r.time)
    return r


def test_sigint_stops_verify_keeps_partial_run_and_starts_nothing_new(tmp_path, fmu_dir):
    first = _long_scenario(tmp_path, "a_long", seed=3)
    second = _long_scenario(tmp_path, "b_long", seed=4)
    out = tmp_path / "results"
    proc, stdout, stderr = _start(["verify", str(first), str(second), "--out", str(out),
                                   "--fmu-dir", str(fmu_dir), "--workers", "1"], tmp_path)
    _wait_for(stderr, "initialised, stepping", 1, proc)
    time.sleep(1.0)
    sent = time.monotonic()
    proc.send_signal(signal.SIGINT)
    code = proc.wait(timeout=60)
    stop_s = time.monotonic() - sent
    err, text = stderr.read_text(), stdout.read_text()
    assert code == 130, text + err
    print(f"SIGINT to exit: {stop_s:.2f} s")
    # the FMUs never saw it: no traceback, no fatal status, no FMU error
    for bad in ("Traceback", "KeyboardInterrupt", "FATAL", "fmi2Fatal", "ERROR]"):
        assert bad not in err, err
    # one run was in flight (the longest first: equal here, so file order), the other
    # never started
    started = [n for n in ("a_long", "b_long") if (out / n).exists()]
    assert len(started) == 1, started
    _check_partial(out / started[0], "SIGINT")
    not_started = "b_long" if started == ["a_long"] else "a_long"
    assert f"{started[0]}: INTERRUPTED" in text
    assert f"{not_started}: NOT RUN (not started: the command was stopped by SIGINT)" in text
    # the report and the JUnit file say so too
    html = (out / "report.html").read_text()
    assert "INTERRUPTED" in html and "NOT RUN" in html and "Run interrupted" in html
    suites = {s.get("name"): s for s in ET.parse(out / "junit.xml").getroot()}
    run_error = suites[started[0]].find("testcase[@name='run']/error")
    assert run_error is not None and run_error.get("message").startswith(
        "interrupted by SIGINT")
    # its expectation is not evaluated (the error is said once, in the run case)
    assert suites[started[0]].get("skipped") == "1"
    assert suites[not_started].find("testcase[@name='run']/error").get("message").startswith(
        "not started")


def test_sigterm_stops_parallel_runs_in_flight(tmp_path, fmu_dir):
    scenarios = [_long_scenario(tmp_path, f"s{i}", seed=10 + i) for i in range(3)]
    out = tmp_path / "results"
    proc, stdout, stderr = _start(["run", *map(str, scenarios), "--out", str(out),
                                   "--fmu-dir", str(fmu_dir), "--workers", "2"], tmp_path)
    _wait_for(stderr, "initialised, stepping", 2, proc)
    time.sleep(1.0)
    proc.send_signal(signal.SIGTERM)
    code = proc.wait(timeout=60)
    err, text = stderr.read_text(), stdout.read_text()
    assert code == 130, text + err
    assert "Traceback" not in err and "FATAL" not in err, err
    started = sorted(p.name for p in out.iterdir() if p.is_dir())
    assert len(started) == 2, started
    for name in started:
        _check_partial(out / name, "SIGTERM")
    assert "stopped by SIGTERM: 0 run(s) finished, 2 interrupted" in err
    assert "1 not started" in err


def test_run_scenario_api_raises_run_interrupted_with_the_partial_result(tmp_path, fmu_dir):
    # in a fresh process (FMUs are never loaded into the test process): a SIGINT while
    # stepping becomes RunInterrupted carrying the saved partial result
    scenario = _long_scenario(tmp_path, "api_long", seed=5)
    script = tmp_path / "api.py"
    script.write_text(f"""
import logging, os, signal, sys, threading
import gyrodiag_harness
from gyrodiag_harness.cosim.interrupt import RunInterrupted, stop_requested

class SignalWhenStepping(logging.Handler):
    def emit(self, record):
        if "initialised, stepping" in record.getMessage():
            threading.Timer(0.5, lambda: os.kill(os.getpid(), signal.SIGINT)).start()

logging.getLogger("gyrodiag_harness").addHandler(SignalWhenStepping())
logging.getLogger("gyrodiag_harness").setLevel(logging.DEBUG)
try:
    gyrodiag_harness.run_scenario({str(scenario)!r}, fmu_dir={str(fmu_dir)!r}, progress=False,
                                  out_dir={str(tmp_path / "api_out")!r})
except RunInterrupted as exc:
    r = exc.result
    print("interrupted", exc.reason, r.interrupted, len(r.time), stop_requested())
    sys.stdout.flush()
    os._exit(0)
print("not interrupted")
sys.stdout.flush()
os._exit(1)
""")
    proc = subprocess.run([sys.executable, str(script)], cwd=ROOT, capture_output=True,
                          text=True, timeout=300,
                          preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    assert proc.returncode == 0, proc.stdout + proc.stderr
    word, reason, flag, n, still = proc.stdout.split()
    assert (word, reason, flag, still) == ("interrupted", "SIGINT", "True", "SIGINT")
    saved = _check_partial(tmp_path / "api_out", "SIGINT")
    assert len(saved.time) == int(n)


def _marked_processes(marker: str) -> list[int]:
    """PIDs of processes whose environment holds ``marker`` (Linux /proc)."""
    found = []
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit() or int(entry.name) == os.getpid():
            continue
        try:
            if marker.encode() in (entry / "environ").read_bytes():
                found.append(int(entry.name))
        except OSError:
            continue
    return found


def test_a_killed_batch_leaves_no_run_process_and_no_fork_server(tmp_path, fmu_dir):
    """SIGKILL of the batch cannot be forwarded: its fork server sees the request pipe
    close and exits, the runs forked from it see their parent change and stop, saving
    their partial signals (as runs of a killed batch always did)."""
    if not Path("/proc/self/environ").exists():
        import pytest

        pytest.skip("needs /proc")
    marker = f"GYRODIAG_TEST_MARKER=killed-batch-{os.getpid()}-{time.time_ns()}"
    scenarios = [_long_scenario(tmp_path, f"k{i}", seed=20 + i) for i in range(3)]
    out = tmp_path / "results"
    key, value = marker.split("=", 1)
    os.environ[key] = value
    try:
        proc, _, stderr = _start(["run", *map(str, scenarios), "--out", str(out),
                                  "--fmu-dir", str(fmu_dir), "--workers", "2"], tmp_path)
    finally:
        del os.environ[key]
    _wait_for(stderr, "initialised, stepping", 2, proc)
    assert len(_marked_processes(marker)) >= 3  # batch, two runs (and the fork server)
    proc.send_signal(signal.SIGKILL)
    proc.wait(timeout=30)
    t0 = time.monotonic()
    while _marked_processes(marker) and time.monotonic() - t0 < 30.0:
        time.sleep(0.2)
    assert _marked_processes(marker) == [], "run processes or the server outlived the batch"
    for run_dir in (p for p in out.iterdir() if p.is_dir()):
        _check_partial(run_dir, "the batch that started this run exited")
