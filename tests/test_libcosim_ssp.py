"""A second master and SSP: libcosim runs the seed scenarios and the exported SSPs with
the same results as the harness's Jacobi run (issue 13 items 6 and 7, docs/methods.md §6.15-16).

The three masters run in one fresh process (tests/_libcosim_runner.py): the aircraft
seed scenario as shipped, the DTG seed scenario dtg_fault_utx_step_s1 shortened (θ0
learned 0.3-1.2 s, Utx step at 1.6 s, classified with a signature library packed into the
SSP), and an HRG/grey case with a physical fault, which only the scenario master carries.

Stated tolerance: Integer and Boolean outputs (alarms, codes, isolated sensor, fault
type) are equal; Real outputs within 1e-10 · max(1, |x|) (measured: 9e-13 on the aircraft,
5e-12 on the DTG identification, 0 on the HRG case). Row 0 of a libcosim run is NaN:
libcosimpy cannot stop between initialisation and the first step.
"""

from __future__ import annotations

import json
import subprocess
import sys
import zipfile
from pathlib import Path

import numpy as np
import pytest
from _libcosim_runner import CASES, ROOT, _hrg_physical

from gyrodiag_harness import RunResult
from gyrodiag_harness.cosim.scenario import parse_scenario
from gyrodiag_harness.cosim.ssp import PARAMETER_SET, check_ssp, export_ssp
from gyrodiag_harness.verification.expectations import evaluate

RUNNER = Path(__file__).resolve().parent / "_libcosim_runner.py"
REAL_TOL = 1e-10
SSP_CASES = ("aircraft", "dtg")


@pytest.fixture(scope="module")
def runs(fmu_dir, tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("libcosim")
    proc = subprocess.run([sys.executable, str(RUNNER), str(fmu_dir), str(out)],
                          capture_output=True, text=True, timeout=1200)
    if proc.returncode != 0:
        pytest.fail(f"libcosim runner failed:\n{proc.stdout[-3000:]}\n{proc.stderr[-6000:]}")
    return out


def _load(runs: Path, case: str, master: str) -> RunResult:
    return RunResult.load(runs / f"{case}-{master}")


def _compare(runs: Path, case: str, master: str) -> None:
    ref, got = _load(runs, case, "harness"), _load(runs, case, master)
    types = json.loads((runs / f"{case}.types.json").read_text())
    assert got.error is None and ref.error is None, got.error
    np.testing.assert_allclose(got.time, ref.time, rtol=0, atol=1e-12)
    assert np.all(np.isnan(np.array([got.signal(n)[0] for n in types])))
    problems = []
    for name, kind in types.items():
        a, b = got.signal(name)[1:], ref.signal(name)[1:]
        if kind == "Real":
            bad = np.abs(a - b) > REAL_TOL * np.maximum(1.0, np.abs(b))
        else:
            bad = a != b
        if bad.any():
            k = int(np.argmax(bad)) + 1
            problems.append(f"{name} ({kind}) row {k}: {master} {a[k - 1]!r}, harness "
                            f"{b[k - 1]!r}")
    assert problems == []


@pytest.mark.parametrize("case", list(CASES))
def test_libcosim_runs_the_scenario_like_the_harness_jacobi_run(runs, case):
    _compare(runs, case, "libcosim")


@pytest.mark.parametrize("case", SSP_CASES)
def test_libcosim_runs_the_exported_ssp_like_the_harness_jacobi_run(runs, case):
    _compare(runs, case, "ssp")


def test_the_compared_runs_diagnose_something(runs):
    """Equal outputs would prove little if nothing happened in the runs."""
    air = _load(runs, "aircraft", "libcosim")
    t = air.time
    assert not air.signal("diag.df.detected")[1:][t[1:] < 10.0].any()
    assert air.signal("diag.df.detected")[-1] == 1
    dtg = _load(runs, "dtg", "ssp")
    alarm = dtg.signal("diag.dtg.alarm")
    assert alarm[1:][dtg.time[1:] < 1.6].sum() == 0 and alarm[-1] == 1
    assert dtg.signal("diag.dtg.fault_code")[-1] > 0  # classified with the packed library
    hrg = _load(runs, "hrg_physical", "libcosim")
    grey = hrg.signal("diag.grey.alarm")
    on = hrg.time[grey == 1]
    assert on.size and on.min() >= 5.0  # the physical fault (5-12 s) was applied in libcosim


@pytest.mark.parametrize("case", ["aircraft", "dtg"])
def test_expectation_verdicts_agree(runs, case):
    data = CASES[case]()
    data["coupling"] = "jacobi"
    scenario = parse_scenario(data, source=case, default_name=case)
    for master in ("libcosim", "ssp"):
        ref, got = _load(runs, case, "harness"), _load(runs, case, master)
        got.fault_windows = ref.fault_windows  # an SSP run knows no scenario faults
        verdicts = [(evaluate(e, ref).passed, evaluate(e, got).passed) for e in scenario.expect]
        assert verdicts and all(a == b for a, b in verdicts), (master, verdicts)


def test_ssp_package_holds_structure_fmus_and_parameters(runs):
    path = runs / "aircraft.ssp"
    check_ssp(path)  # SystemStructure.ssd and every .ssv against the SSP 1.0 XSDs
    with zipfile.ZipFile(path) as zf:
        names = set(zf.namelist())
        assert {"SystemStructure.ssd", "resources/Aircraft.fmu", "resources/Diagnoser.fmu",
                "resources/injector.ssv", "resources/diag.ssv"} <= names
        injector = zf.read("resources/injector.ssv").decode()
        ssd = zf.read("SystemStructure.ssd").decode()
    # the injector fault is carried as the FaultInjector's parameters
    assert 'name="fault_type_3"' in injector and '<ssv:Integer value="1"/>' in injector
    assert 'name="t_start_3"' in injector and 'value="10.0"' in injector
    assert 'baseStepSize="0.01"' in ssd and 'stopTime="20.0"' in ssd
    assert 'startElement="injector" startConnector="out_3" endElement="diag"' in ssd
    report = json.loads((runs / "aircraft.export.json").read_text())
    assert report["components"] == ["aircraft", "injector", "controller", "diag"]
    assert any("[record]" in n for n in report["not_carried"])


def test_files_parameters_are_packed_into_the_fmu_copy(runs):
    with zipfile.ZipFile(runs / "dtg.ssp") as zf:
        diag_ssv = zf.read("resources/diag.ssv").decode()
        with zf.open("resources/Diagnoser.fmu") as f, zipfile.ZipFile(f) as fmu:
            packed = fmu.read("resources/gyrodiag-files/diag/dtg.signature_file.json")
    assert 'value="gyrodiag-files/diag/dtg.signature_file.json"' in diag_ssv
    assert json.loads(packed) == json.loads((runs / "results" / "dtg_signatures.json")
                                            .read_text())


def test_physical_faults_are_reported_as_not_carried(fmu_dir, tmp_path):
    scenario = parse_scenario(_hrg_physical(), source="hrg_physical")
    done = export_ssp(scenario, tmp_path / "hrg.ssp", fmu_dir=fmu_dir)
    assert any("physical fault 'scale': hrg.scale_factor = 10.2 from 5 s to 12 s" in n
               and "no time events" in n for n in done.not_carried)
    assert any("coupling 'gauss-seidel'" in n for n in done.not_carried)
    with zipfile.ZipFile(done.path) as zf:
        assert "org.gyrodiag.not-carried" in zf.read("SystemStructure.ssd").decode()


def test_export_ssp_command_line(fmu_dir, tmp_path):
    out = tmp_path / "q_bias.ssp"
    proc = subprocess.run([sys.executable, "-m", "gyrodiag_harness", "export-ssp",
                           str(ROOT / "scenarios" / "aircraft_q_bias.toml"), "--out", str(out),
                           "--fmu-dir", str(fmu_dir)], capture_output=True, text=True,
                          cwd=ROOT, timeout=300)
    assert proc.returncode == 0, proc.stderr
    assert "4 components (aircraft, injector, controller, diag)" in proc.stdout
    assert "not carried: coupling 'gauss-seidel'" in proc.stdout
    assert f"Ecos only when named (--parameterSet {PARAMETER_SET})" in proc.stdout
    check_ssp(out)
    bad = subprocess.run([sys.executable, "-m", "gyrodiag_harness", "export-ssp",
                          str(ROOT / "scenarios" / "aircraft_q_bias.toml"), "--out",
                          str(tmp_path / "x.zip"), "--fmu-dir", str(fmu_dir)],
                         capture_output=True, text=True, cwd=ROOT, timeout=300)
    assert bad.returncode == 2 and "ends in .ssp" in bad.stderr
