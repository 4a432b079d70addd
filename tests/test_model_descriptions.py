"""Every FMU's modelDescription keeps the project's rules (issue 13 item 4, team brief).

The rules hold for variables added later too: a new variable either follows them or is
listed below with the reason it is an exception.

* ``fmpy validate`` finds nothing;
* every variable has a description; every Real a unit declared in UnitDefinitions
  (dimensionless: "1");
* every Real/Integer parameter has min and/or max, unless listed in :data:`UNBOUNDED`
  (sign-free coefficients, values with "< 0 means off" conventions);
* outputs are ``discrete`` (they change only at communication points) unless listed in
  :data:`CONTINUOUS_OUTPUTS` (true continuous-time states of a plant);
* the parameters of :data:`MUST_BE_TUNABLE` are tunable;
* declared bounds are what the FMU accepts: a value just outside gives fmi2Error naming
  the parameter and its range, the bound itself initialises (checked in a fresh
  process, tests/_md_runner.py);
* no output is NaN or Inf, with default inputs, with the C host's input signal, and (for
  the Diagnoser) with non-finite inputs.
"""

from __future__ import annotations

import json
import re
import subprocess
import sys
import xml.etree.ElementTree as ET
import zipfile
from pathlib import Path

import pytest
from _host_runner import FMUS
from fmpy.validation import validate_fmu

RUNNER = Path(__file__).resolve().parent / "_md_runner.py"

#: Parameters without declared bounds, per FMU: (name pattern, why none).
UNBOUNDED: dict[str, list[tuple[str, str]]] = {
    "Diagnoser": [
        (r"df\.[ABC]\[\d+,\d+\]", "plant model coefficients, any sign"),
        (r"df\.x0\[\d+\]", "initial state estimate, any sign"),
        (r"dtg\.theta0\[\d+\]", "nominal parameters, any sign (nonzero)"),
        (r"dtg\.signature\[\d+,\d+\]", "signature features are signed decades"),
        (r"dtg\.max_distance", "< 0 means no limit"),
        (r"grey\.clear_after_s", "<= 0 means never"),
        (r"df\.noise_std\[\d+\]", "< 0 means threshold / k_sigma"),
    ],
    "Aircraft": [(r"x0_\w+", "initial state, any sign")],
    "FaultInjector": [
        (r"(t_start|t_end)_\d", "fault window times, any"),
        (r"(magnitude|stuck_value|sat_min|sat_max|gain)_\d", "fault values, any sign"),
    ],
    "HRG": [(r"(scale_factor|bias|rate_const)", "model values, any sign"),
            (r"bandwidth_hz", "<= 0 means no filter")],
    "PitchController": [(r"(cmd_amplitude|throttle_trim)", "command values, any sign"),
                        (r"cmd_start_s", "manoeuvre start time, any")],
    "DTG": [(r"k_offset", "detuning, any sign")],
}
#: Outputs that are continuous-time signals of a plant (all others are sampled).
CONTINUOUS_OUTPUTS: dict[str, set[str]] = {
    "Aircraft": {"x_v", "x_alpha", "x_q", "x_theta", "x_h", "gust_alpha", "gust_q"},
    "HRG": {"rate_true"},
}
#: Bounds that other parameters move: the declared bound is the widest the FMU accepts,
#: the bound itself is not always reachable.
COUPLED_BOUNDS: dict[str, dict[str, str]] = {
    "Diagnoser": {"dtg.learn_end_s": "must exceed dtg.learn_start_s by a sample period",
                  "dtg.n_signatures": "> 0 only with dtg.classifier = paper",
                  "dtg.long_window_s": "must be >= dtg.window_s",
                  "df.calibrate_s": "0 only with df.noise_std given (sequential rule)",
                  "grey.reference_window_s": "must hold grey.reference_order + 3 samples "
                                             "at sample_period_s",
                  "grey.learn_end_s": "must hold the warm-up window and 10 errors at "
                                      "sample_period_s"},
}
#: Safe-to-change parameters that must be tunable.
MUST_BE_TUNABLE: dict[str, set[str]] = {
    "Diagnoser": {"dtg.low", "dtg.high", "dtg.persistence_k", "dtg.latch", "dtg.max_distance",
                  "dtg.level_threshold", "dtg.var_threshold", "dtg.long_var_threshold",
                  "dtg.power_threshold", "dtg.allowance_sigma",
                  "grey.threshold", "grey.threshold_floor", "grey.clear_after_s"}
    | {f"dtg.monitored[{i}]" for i in range(1, 6)},
    "FaultInjector": {f"fault_type_{i}" for i in range(1, 9)},
    "DTG": {"spin_fraction", "torquer_scale", "pickoff_scale", "damping_scale", "k_offset"},
}


def _variables(fmu: Path) -> tuple[ET.Element, list[ET.Element]]:
    with zipfile.ZipFile(fmu) as zf:
        root = ET.fromstring(zf.read("modelDescription.xml"))
    return root, list(root.find("ModelVariables"))


def _unbounded_reason(fmu_name: str, name: str) -> str | None:
    for pattern, reason in UNBOUNDED.get(fmu_name, []):
        if re.fullmatch(pattern, name):
            return reason
    return None


@pytest.fixture(scope="module")
def runtime(fmu_dir, tmp_path_factory) -> dict:
    out = tmp_path_factory.mktemp("md") / "md.json"
    proc = subprocess.run([sys.executable, str(RUNNER), str(fmu_dir), str(out)],
                          capture_output=True, text=True, timeout=600)
    if proc.returncode != 0:
        pytest.fail(f"_md_runner failed:\n{proc.stdout[-3000:]}\n{proc.stderr[-6000:]}")
    return json.loads(out.read_text(encoding="utf-8"))


def test_every_project_fmu_is_walked(fmu_dir):
    assert sorted(p.stem for p in fmu_dir.glob("*.fmu")) == sorted(FMUS)


@pytest.mark.parametrize("name", FMUS)
def test_fmpy_validate_finds_nothing(fmu_dir, name):
    assert validate_fmu(str(fmu_dir / f"{name}.fmu")) == []


@pytest.mark.parametrize("name", FMUS)
def test_descriptions_and_units(fmu_dir, name):
    root, svs = _variables(fmu_dir / f"{name}.fmu")
    declared = {u.get("name") for u in root.iter("Unit")}
    problems = []
    for sv in svs:
        vname, type_el = sv.get("name"), sv[0]
        if len(sv.get("description", "")) < 6:
            problems.append(f"{vname}: no description")
        if type_el.tag == "Real":
            unit = type_el.get("unit")
            if unit is None:
                problems.append(f"{vname}: Real without unit")
            elif unit not in declared:
                problems.append(f"{vname}: unit {unit!r} not in UnitDefinitions")
    assert problems == []


@pytest.mark.parametrize("name", FMUS)
def test_bounded_parameters_declare_min_or_max(fmu_dir, name):
    _, svs = _variables(fmu_dir / f"{name}.fmu")
    problems = []
    for sv in svs:
        vname, type_el = sv.get("name"), sv[0]
        if sv.get("causality") != "parameter" or type_el.tag not in ("Real", "Integer"):
            continue
        bounded = type_el.get("min") is not None or type_el.get("max") is not None
        reason = _unbounded_reason(name, vname)
        if not bounded and reason is None:
            problems.append(f"{vname}: no min/max (bounded? declare them; else list it in "
                            "UNBOUNDED with the reason)")
        if bounded and reason is not None:
            problems.append(f"{vname}: listed as unbounded ({reason}) but declares bounds")
    assert problems == []


@pytest.mark.parametrize("name", FMUS)
def test_outputs_are_discrete_unless_continuous_states(fmu_dir, name):
    _, svs = _variables(fmu_dir / f"{name}.fmu")
    wrong = []
    continuous = CONTINUOUS_OUTPUTS.get(name, set())
    outputs = {sv.get("name"): sv.get("variability") for sv in svs
               if sv.get("causality") == "output"}
    assert continuous <= set(outputs)
    for vname, variability in outputs.items():
        want = "continuous" if vname in continuous else "discrete"
        if variability != want:
            wrong.append(f"{vname}: {variability}, expected {want}")
    assert wrong == []


@pytest.mark.parametrize("name", FMUS)
def test_safe_to_change_parameters_are_tunable(fmu_dir, name):
    _, svs = _variables(fmu_dir / f"{name}.fmu")
    variability = {sv.get("name"): sv.get("variability") for sv in svs}
    for vname in MUST_BE_TUNABLE.get(name, set()):
        assert variability[vname] == "tunable", vname


@pytest.mark.parametrize("name", FMUS)
def test_declared_bounds_are_honoured(runtime, name):
    checks = runtime[name]["bounds"]
    assert checks, f"{name}: no bounded parameter checked"
    problems = []
    for entry in checks:
        label = f"{entry['name']} = {entry['value']!r} ({entry['side']})"
        if entry["outside"]:
            if entry["status"] != 3:
                problems.append(f"{label}: accepted (status {entry['status']})")
            elif entry["name"] not in entry["log"] or "range" not in entry["log"]:
                problems.append(f"{label}: message does not name it and its range: "
                                f"{entry['log'][:300]}")
        elif entry["status"] != 0 and entry["name"] not in COUPLED_BOUNDS.get(name, {}):
            problems.append(f"{label}: the bound itself is refused (declare the bound that "
                            f"is accepted): {entry['log'][:300]}")
    assert problems == [], "\n".join(problems)


@pytest.mark.parametrize("name", FMUS)
def test_no_output_is_ever_non_finite(runtime, name):
    res = runtime[name]
    assert res["n_rows"] > 10
    assert res["non_finite"] == [], res["non_finite"][:10]
