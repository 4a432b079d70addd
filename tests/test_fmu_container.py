"""fmu-manipulation-toolbox as a host: its checker on every FMU, and the aircraft chain as
one container FMU (issue 32 item 6, docs/fmu.md "Third-party hosts").

* ``fmutool -check`` reports nothing but its two passes (generic conformity, semantic
  checks) on each FMU that build_fmu.py builds, and on the container.
* ``fmucontainer`` packs the aircraft seed scenario's four FMUs (aircraft, injector,
  controller, Diagnoser) as the scenario wires them, with the harness's parameters as
  start values, in sequential mode in the harness's stepping order; fmpy simulates the
  container (tests/_container_runner.py, a fresh process). Stated tolerance: none: the
  container runs the same binaries in the same Gauss-Seidel order as the harness, so
  every recorded signal (224, row 0 included) must be equal bit for bit.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from _host_runner import FMUS

from gyrodiag_harness import RunResult
from gyrodiag_harness.cosim.scenario import load_scenario
from gyrodiag_harness.verification.expectations import evaluate

HERE = Path(__file__).resolve().parent
RUNNER = HERE / "_container_runner.py"
SCENARIO = HERE.parent / "scenarios" / "aircraft_q_bias.toml"
#: The checker's lines on a clean FMU, after its banner and the READING line.
CHECK_PASSES = ("This FMU seems to be compliant with FMI-2.0.",
                "No semantic error against the FMI-2 standard.")


def _tool(name: str) -> str:
    """A console script of the test environment (installed next to its Python)."""
    exe = Path(sys.executable).with_name(name)
    assert exe.is_file(), f"{exe} not found: pip install -e \".[test]\" installs {name}"
    return str(exe)


def _check(fmu: Path) -> list[str]:
    """``fmutool -check`` on ``fmu``: the lines that are not its passes or its banner."""
    proc = subprocess.run([_tool("fmutool"), "-input", str(fmu), "-check"],
                          capture_output=True, text=True, timeout=300)
    lines = [ln.strip() for ln in (proc.stdout + proc.stderr).splitlines() if ln.strip()]
    assert proc.returncode == 0, lines
    for passed in CHECK_PASSES:
        assert any(ln.endswith(passed) for ln in lines), (fmu.name, lines)
    quiet = ("FMU Manipulation Toolbox version", "READING Input=", "=> FMU Generic",
             "=> FMU Semantic", "Modified FMU is not saved", *CHECK_PASSES)
    return [ln for ln in lines if not (ln.startswith("INFO") and any(q in ln for q in quiet))]


@pytest.mark.parametrize("name", FMUS)
def test_fmutool_check_reports_nothing(fmu_dir, name):
    assert _check(fmu_dir / f"{name}.fmu") == []


@pytest.fixture(scope="module")
def runs(fmu_dir, tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("container")
    proc = subprocess.run([sys.executable, str(RUNNER), str(fmu_dir), str(out)],
                          capture_output=True, text=True, timeout=900)
    if proc.returncode != 0:
        pytest.fail(f"container runner failed:\n{proc.stdout[-3000:]}\n{proc.stderr[-6000:]}")
    return out


def test_container_fmu_passes_the_checker(runs):
    assert _check(runs / "container" / "aircraft_chain.fmu") == []


def test_fmucontainer_complains_only_of_the_inputs_the_scenario_leaves_open(runs, fmu_dir):
    """Its build log's errors name the unconnected inputs (they keep their start values,
    as in the harness); any other error or warning would be a defect of the description."""
    import re

    from fmpy import read_model_description

    scenario = load_scenario(SCENARIO)
    connected = {c.to for c in scenario.connections}
    open_inputs = {f"{i.fmu}.fmu/{v.name}" for n, i in scenario.fmus.items()
                   for v in read_model_description(str(fmu_dir / f"{i.fmu}.fmu")).modelVariables
                   if v.causality == "input" and f"{n}.{v.name}" not in connected}
    log = (runs / "container.log").read_text().splitlines()
    errors = [ln for ln in log if ln.startswith("ERROR")]
    named = {m.group(1) for ln in errors
             if (m := re.search(r"Input 'Port (.+)' is not connected", ln))}
    assert len(named) == len(errors) and named == open_inputs, errors
    # String outputs (dtg.fault_name) are not recorded: fmucontainer says so
    strings = {f"{i.fmu}.fmu/{v.name}" for i in scenario.fmus.values()
               for v in read_model_description(str(fmu_dir / f"{i.fmu}.fmu")).modelVariables
               if v.causality == "output" and v.type == "String"}
    unrecorded = {m.group(1) for ln in log
                  if (m := re.search(r"Output 'Port (.+)' is not connected", ln))}
    assert unrecorded == strings and strings, (unrecorded, strings)
    warnings = [ln for ln in log if ln.startswith("WARNING")
                and not re.search(r"Output 'Port .+' is not connected", ln)]
    # the controller-aircraft loop: the harness initialises it the same way (equal rows)
    assert all("Loop of links through the embedded FMU 'Aircraft.fmu'" in ln
               for ln in warnings), warnings


def test_container_equals_the_harness_run_bit_for_bit(runs):
    ref = RunResult.load(runs / "aircraft-harness")
    got = RunResult.load(runs / "aircraft-container")
    types = json.loads((runs / "aircraft.types.json").read_text())
    assert len(types) == len(ref.signals) > 200
    np.testing.assert_allclose(got.time, ref.time, rtol=0, atol=1e-12)
    problems = []
    for name, kind in types.items():
        a, b = got.signal(name), ref.signal(name)
        bad = ~((a == b) | (np.isnan(a) & np.isnan(b)))
        if bad.any():
            k = int(np.argmax(bad))
            problems.append(f"{name} ({kind}) row {k}: container {a[k]!r}, harness {b[k]!r}")
    assert problems == []


def test_container_run_meets_the_scenario_expectations(runs):
    """Detected within 0.5 s, isolated to q, typed a bias of about 0.1 rad/s."""
    ref = RunResult.load(runs / "aircraft-harness")
    got = RunResult.load(runs / "aircraft-container")
    got.fault_windows = ref.fault_windows  # the container knows no scenario faults
    verdicts = [(e.name, evaluate(e, got).passed) for e in load_scenario(SCENARIO).expect]
    assert len(verdicts) == 6 and all(ok for _, ok in verdicts), verdicts
    t = got.time
    assert got.signal("diag.df.isolated_sensor")[-1] == 3
    added = got.signal("injector.out_3")[t > 10.0 + 1e-9] - got.signal("aircraft.y_q")[
        t > 10.0 + 1e-9]
    np.testing.assert_allclose(added, 0.1, atol=1e-12)  # the injector's start values took
