"""Every FMU in hosts other than the harness: fmpy's own simulate with its defaults, and
a plain C host (tests/host/gd_fmi2_host.c) without LD_PRELOAD or PYTHONPATH.

Issue 13 items 1 and 2, docs/methods.md §6.5, §6.12, §6.13. The C host is compiled here with the
system C compiler against fmpy's FMI headers (the same compiler build_fmu.py needs for
the status shim). Its outputs are compared with fmpy's run of the same inputs, bit for
bit; then it is run 20 times in a row, each time loading every FMU, running 1 s with
inputs, freeing and exiting: the exit must be clean (issue 13: SIGSEGV at exit in
Py_FinalizeEx before the shim started the interpreter itself).
"""

from __future__ import annotations

import csv
import json
import os
import subprocess
import sys
import sysconfig
import zipfile
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import fmpy
import numpy as np
import pytest
from _host_runner import FMUS, HOST_SETS, HOST_STEP, HOST_STOP, REFUSED_STEPS

HERE = Path(__file__).resolve().parent
HOST_SOURCE = HERE / "host" / "gd_fmi2_host.c"
RUNNER = HERE / "_host_runner.py"
EXIT_RUNS = 20


def _run_runner(fmu_dir: Path, out: Path, mode: str) -> dict:
    proc = subprocess.run([sys.executable, str(RUNNER), str(fmu_dir), str(out), mode],
                          capture_output=True, text=True, timeout=600)
    if proc.returncode != 0:
        pytest.fail(f"_host_runner {mode} failed:\n{proc.stdout[-3000:]}\n{proc.stderr[-6000:]}")
    return json.loads(out.read_text(encoding="utf-8"))


@pytest.fixture(scope="module")
def host(c_host) -> Path:
    return c_host


@pytest.fixture(scope="module")
def extracted(fmu_dir, tmp_path_factory) -> list[Path]:
    root = tmp_path_factory.mktemp("extracted")
    dirs = []
    for name in FMUS:
        target = root / name
        with zipfile.ZipFile(fmu_dir / f"{name}.fmu") as zf:
            zf.extractall(target)
        dirs.append(target)
    return dirs


def _host_env(**extra: str) -> dict[str, str]:
    """The test's environment without anything that would hand Python to the host."""
    env = {k: v for k, v in os.environ.items()
           if k not in ("PYTHONPATH", "PYTHONHOME", "LD_PRELOAD", "VIRTUAL_ENV",
                        "GYRODIAG_PYTHON")}
    env.update(extra)
    return env


def _host_args(host: Path, dirs: list[Path], *more: str) -> list[str]:
    sets = [a for k, v in HOST_SETS.items() for a in ("--set", f"{k}={v!r}")]
    return [str(host), "--stop", repr(HOST_STOP), "--step", repr(HOST_STEP), *sets, *more,
            *map(str, dirs)]


def _run_host(args: list[str], env: dict[str, str]) -> subprocess.CompletedProcess:
    return subprocess.run(args, env=env, capture_output=True, text=True, timeout=300)


# ---------------------------------------------------------------------------------------
# fmpy simulate with its defaults (item 1)
# ---------------------------------------------------------------------------------------

@pytest.mark.parametrize("name", FMUS)
def test_fmpy_simulate_with_defaults_runs(fmu_dir, tmp_path, name):
    """``fmpy simulate X.fmu``: fmpy picks its own output interval from the default
    experiment (for the Diagnoser 16 sample periods per step); it must run to the end."""
    out = tmp_path / f"{name}.csv"
    proc = subprocess.run([sys.executable, "-m", "fmpy.cli", "simulate",
                           str(fmu_dir / f"{name}.fmu"), "--output-file", str(out)],
                          capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr[-4000:]
    assert "[ERROR]" not in proc.stdout + proc.stderr
    with out.open() as f:
        rows = list(csv.reader(f))
    header = rows[0]
    data = np.array([[{"True": 1.0, "False": 0.0}.get(x, x) for x in r] for r in rows[1:]],
                    dtype=float)
    md = fmpy.read_model_description(str(fmu_dir / f"{name}.fmu"))
    stop = float(md.defaultExperiment.stopTime)
    assert header[0] == "time" and data[-1, 0] == pytest.approx(stop)
    assert len(data) > 100
    assert np.all(np.isfinite(data)), "non-finite output"


def test_plant_fmus_take_any_positive_step_and_refuse_the_others(fmu_dir, tmp_path):
    """The plants integrate exactly over any step (canHandleVariableCommunicationStepSize
    = true, as declared); zero, negative or non-finite steps are fmi2Error, not taken."""
    res = _run_runner(fmu_dir, tmp_path / "steps.json", "steps")
    assert set(res) == set(FMUS) - {"Diagnoser"}
    for name, r in res.items():
        assert r["accepted"] == [0] * len(r["accepted"]), name
        assert r["refused"] == [3] * len(REFUSED_STEPS), (name, r["refused_log"])
        for h, log in zip(REFUSED_STEPS, r["refused_log"], strict=True):
            assert f"communication step {h!r} s must be finite and > 0" in log, (name, log)
        assert r["after"] == 0, name
    with zipfile.ZipFile(fmu_dir / "Diagnoser.fmu") as zf:
        md = zf.read("modelDescription.xml").decode()
    assert 'canHandleVariableCommunicationStepSize="true"' in md


# ---------------------------------------------------------------------------------------
# a C host (item 2)
# ---------------------------------------------------------------------------------------

def test_c_host_equals_fmpy_bit_for_bit(host, extracted, tmp_path, fmu_dir):
    out = tmp_path / "c"
    out.mkdir()
    proc = _run_host(_host_args(host, extracted, "--out-dir", str(out)),
                     _host_env(GYRODIAG_PYTHON=sys.executable))
    assert proc.returncode == 0, proc.stderr[-4000:]
    ref = _run_runner(fmu_dir, tmp_path / "fmpy.json", "crosscheck")
    n_steps = round(HOST_STOP / HOST_STEP)
    for name in FMUS:
        with (out / f"{name}.csv").open() as f:
            rows = list(csv.reader(f))
        assert rows[0][1:] == ref[name]["columns"], name
        got = np.array(rows[1:], dtype=float)
        assert got.shape == (n_steps, len(ref[name]["columns"]) + 1), name
        np.testing.assert_allclose(got[:, 0], HOST_STEP * np.arange(1, n_steps + 1), rtol=1e-12)
        np.testing.assert_array_equal(got[:, 1:], np.array(ref[name]["rows"]), err_msg=name)
        # the inputs moved the outputs (a host that set nothing would fail here)
        assert np.nanmax(np.ptp(got[:, 1:], axis=0)) > 0, name
    assert "Diagnoser: 100 steps of 0.01 s OK" in proc.stdout


def test_c_host_exits_cleanly_20_times_in_a_row(host, extracted):
    """Each run loads every FMU, runs 1 s with inputs, frees it, dlcloses and exits."""
    env = _host_env(GYRODIAG_PYTHON=sys.executable)
    args = _host_args(host, extracted)
    with ThreadPoolExecutor(max_workers=2) as pool:
        results = list(pool.map(lambda _: _run_host(args, env), range(EXIT_RUNS)))
    codes = [r.returncode for r in results]
    assert codes == [0] * EXIT_RUNS, [r.stderr[-2000:] for r in results if r.returncode][:2]
    for r in results:
        assert r.stdout.count(" OK\n") == len(FMUS) and r.stderr == "", r.stderr


def test_c_host_finds_python_through_the_virtual_environment(host, extracted):
    """No GYRODIAG_PYTHON: the shim asks $VIRTUAL_ENV/bin/python (the usual activated
    environment) for its libpython and sys.path."""
    if sys.prefix == sys.base_prefix:
        pytest.skip("the tests do not run in a virtual environment")
    diag_and_hrg = [d for d in extracted if d.name in ("Diagnoser", "HRG")]
    proc = _run_host(_host_args(host, diag_and_hrg), _host_env(VIRTUAL_ENV=sys.prefix))
    assert proc.returncode == 0, proc.stderr[-3000:]


def test_c_host_with_the_old_ld_preload_recipe_exits_cleanly(host, extracted):
    """A host that preloads libpython (the recipe before the shim loaded it) but leaves
    the interpreter uninitialised: the shim initialises it; the exit is clean."""
    libdir = sysconfig.get_config_var("LIBDIR")
    names = [sysconfig.get_config_var(k) for k in ("INSTSONAME", "LDLIBRARY")]
    libs = [Path(libdir) / n for n in names if n and ".so" in n and (Path(libdir) / n).exists()]
    if not libs:
        pytest.skip("this Python has no shared libpython")
    env = _host_env(GYRODIAG_PYTHON=sys.executable, LD_PRELOAD=str(libs[0]))
    proc = _run_host(_host_args(host, extracted), env)
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert proc.stdout.count(" OK\n") == len(FMUS)


def test_c_host_without_a_usable_python_gets_an_error_not_a_crash(host, extracted):
    proc = _run_host(_host_args(host, extracted[:1]),
                     _host_env(GYRODIAG_PYTHON="/nonexistent/gyrodiag/python"))
    assert proc.returncode == 1
    assert "[ERROR]" in proc.stderr and "cannot run /nonexistent/gyrodiag/python" in proc.stderr
    assert "GYRODIAG_PYTHON" in proc.stderr and "fmi2Instantiate failed" in proc.stderr
