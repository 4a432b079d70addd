"""Diagnoser.fmu needs only what it imports: DTG and the paper's grey rule run without
SciPy or control.

A host whose Python lacks SciPy and python-control (both blocked in the runner's
process) runs the DTG channel and the grey channel's paper rule (``grey.decision = 0``)
with the compiled kernels and with the plain-Python fallback; the outputs equal the
library's (full install, this process) to 1e−12. Switching on the detection filter or
the grey channel's learned rules (its default) there gives fmi2Error naming the missing
package and how to install it.
"""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest

from gyrodiag.demo import NOMINAL, simulate
from gyrodiag.dtg.channel import DTGChannel, DTGChannelConfig
from gyrodiag.grey import GreyFaultDetector, ImprovedGreyPredictor

RUNNER = Path(__file__).resolve().parent / "_lean_host_runner.py"
N = 1500


def _record() -> np.ndarray:
    rec = np.zeros((N, 13))
    rec[:, 0:4] = simulate(NOMINAL, N, 4, noise_v=1e-4)
    t = np.arange(N) * 1e-3
    rec[:, 4] = 2.0 + 0.3 * np.sin(2 * np.pi * 0.5 * t) + 1e-3 * np.random.default_rng(
        4).standard_normal(N)
    rec[1000:1100, 4] += 0.2  # a bias fault: the grey alarm and substitution path
    return rec


def _library(rec: np.ndarray) -> dict[str, np.ndarray]:
    dtg = DTGChannel(DTGChannelConfig(sample_period_s=1e-3, p0=1e8, learn_start_s=0.2,
                                      learn_end_s=0.8))
    grey = GreyFaultDetector(ImprovedGreyPredictor(10, a_min=1e-6), 0.05, 1e-3, 20.0)
    cols: dict[str, list] = {}
    for k, row in enumerate(rec):
        out = dtg.update(*row[:4])
        g = grey.update(float(row[4]), time_s=k * 1e-3)
        for a, axis in enumerate("xy"):
            for i in range(5):
                cols.setdefault(f"dtg.theta_{axis}[{i + 1}]", []).append(out.theta[a, i])
                cols.setdefault(f"dtg.eta_{axis}[{i + 1}]", []).append(out.eta[a, i])
        cols.setdefault("dtg.alarm", []).append(out.alarm)
        cols.setdefault("grey.prediction", []).append(g.prediction)
        cols.setdefault("grey.error", []).append(g.error)
        cols.setdefault("grey.alarm", []).append(g.alarm)
    return {k: np.array(v, dtype=float) for k, v in cols.items()}


@pytest.fixture(scope="module")
def library() -> tuple[np.ndarray, dict[str, np.ndarray]]:
    rec = _record()
    return rec, _library(rec)


@pytest.mark.parametrize("kernels", ["default", "python"])
def test_dtg_and_grey_run_without_scipy_or_control(run_fmu_script, tmp_path, library,
                                                   kernels):
    rec, lib = library
    np.savez(tmp_path / "in.npz", record=rec)
    res = run_fmu_script(RUNNER, str(tmp_path / "in.npz"), kernels)
    assert res["loaded"].tolist() == []  # neither package was imported
    if kernels == "python":
        assert not bool(res["accelerated"])
    elif shutil.which("cc") or shutil.which("gcc"):
        # build_fmu.py compiled the kernels into the FMU, and the FMU loaded them from
        # its own resources
        assert bool(res["accelerated"])
        assert str(res["kernel_file"]).startswith(str(res["resources"]))
    names = res["names"].tolist()
    rows = res["rows"]
    assert lib["grey.alarm"].any() and lib["grey.alarm"][:1000].sum() == 0
    for name, want in lib.items():
        got = rows[:, names.index(name)]
        ok = np.isfinite(want)
        scale = max(1.0, float(np.max(np.abs(want[ok]))))
        np.testing.assert_allclose(got[ok], want[ok], rtol=0, atol=1e-12 * scale,
                                   err_msg=name)


def test_missing_package_is_fmi2error_saying_how_to_install(run_fmu_script, tmp_path,
                                                           library):
    rec, _ = library
    np.savez(tmp_path / "in.npz", record=rec[:50])
    res = run_fmu_script(RUNNER, str(tmp_path / "in.npz"))
    assert int(res["init_status"]) == 3  # fmi2Error, not fmi2Fatal
    log = str(res["init_log"])
    assert "df.enabled needs the Python package 'scipy'" in log, log
    assert "pip install 'scipy>=1.10'" in log and "requirements.txt" in log, log
    assert "Traceback" not in log
    assert int(res["step_status"]) == 3  # not initialised: steps refused, host alive
    # the grey channel's default, learned rule needs SciPy too; the paper rule does not
    assert int(res["learned_status"]) == 3
    log = str(res["learned_log"])
    assert "grey.decision = 1 (a learned rule; the paper rule, grey.decision = 0, does " \
           "without it) needs the Python package 'scipy'" in log, log
    assert "Traceback" not in log


_NO_CONTROL = r"""
import sys, zipfile
sys.modules["control"] = None  # python-control absent from the host
import numpy as np
from fmpy import extract, read_model_description
from fmpy.fmi2 import FMU2Slave

fmu = sys.argv[1]
print(zipfile.ZipFile(fmu).read("resources/requirements.txt").decode().split())
unzipdir = extract(fmu)
md = read_model_description(unzipdir)
refs = {v.name: v.valueReference for v in md.modelVariables}
s = FMU2Slave(guid=md.guid, unzipDirectory=unzipdir,
              modelIdentifier=md.coSimulation.modelIdentifier, instanceName="no_control")
s.instantiate()
s.setReal([refs["sample_period_s"]], [0.01])
s.setBoolean([refs["dtg.enabled"]], [False])  # its 50 Hz prefilter needs 1 kHz
s.setupExperiment(startTime=0.0)
s.enterInitializationMode()
s.exitInitializationMode()
rng = np.random.default_rng(1)
for k in range(1200):  # past the calibration window (10 s): observers designed
    s.setReal([refs[f"df.y[{i}]"] for i in range(1, 7)], list(1e-3 * rng.standard_normal(6)))
    s.doStep(k * 0.01, 0.01)
print(s.getBoolean([refs["df.calibrating"]])[0], s.getReal([refs["df.noise_std_in_use[3]"]])[0])
s.terminate()
s.freeInstance()
print(sorted(m for m in sys.modules if m.split(".")[0] == "control" and sys.modules[m]))
"""


def test_requirements_list_only_what_the_fmu_imports_and_no_control_is_needed(fmu_dir):
    """resources/requirements.txt says numpy and scipy; a host without python-control
    designs the detection filter's observers (pole placement by scipy.signal) and runs."""
    import subprocess
    import sys

    proc = subprocess.run([sys.executable, "-c", _NO_CONTROL, str(fmu_dir / "Diagnoser.fmu")],
                          capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr[-3000:]
    req, status, loaded = proc.stdout.strip().splitlines()[-3:]
    assert req == "['numpy>=1.24', 'scipy>=1.10', '#', 'optional', 'at', 'start-up']"
    calibrating, noise = status.split()
    assert calibrating in ("0", "False") and 5e-4 < float(noise) < 2e-3, status
    assert loaded == "[]"
