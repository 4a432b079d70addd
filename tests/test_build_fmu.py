"""build_fmu.py: every built FMU validates with fmpy and carries the post-processed metadata."""

from __future__ import annotations

import subprocess
import sys
import xml.etree.ElementTree as ET
import zipfile
from pathlib import Path

import pytest
from conftest import ROOT, load_builder
from fmpy.validation import validate_fmu

builder = load_builder()
AVAILABLE = [e[0] for e in builder.REGISTRY if builder.available(e)]
MINE = ["FaultInjector", "HRG", "Aircraft", "PitchController"]


def _md(fmu: Path) -> ET.Element:
    with zipfile.ZipFile(fmu) as zf:
        return ET.fromstring(zf.read("modelDescription.xml"))


def test_registry_lists_the_project_fmus():
    names = [e[0] for e in builder.REGISTRY]
    assert {*MINE, "DTG"} <= set(names)
    for name in MINE:
        assert name in AVAILABLE


@pytest.mark.parametrize("name", AVAILABLE)
def test_fmu_validates_with_zero_problems(fmu_dir, name):
    assert validate_fmu(str(fmu_dir / f"{name}.fmu")) == []


@pytest.mark.parametrize("name", AVAILABLE)
def test_model_description_is_post_processed(fmu_dir, name):
    fmu = fmu_dir / f"{name}.fmu"
    root = _md(fmu)
    assert root.get("modelName") == name
    cosim = root.find("CoSimulation")
    assert cosim.get("canGetAndSetFMUstate") == "true"
    assert cosim.get("canSerializeFMUstate") == "true"
    svs = list(root.find("ModelVariables"))
    declared = {u.get("name") for u in root.iter("Unit")}
    for sv in svs:
        assert sv.get("variability") is not None, sv.get("name")
        if sv[0].tag != "Real":
            assert sv.get("variability") != "continuous", sv.get("name")
        unit = sv[0].get("unit")
        assert unit is None or unit in declared
    outputs = [i + 1 for i, sv in enumerate(svs) if sv.get("causality") == "output"]
    structure = root.find("ModelStructure")
    listed = [int(u.get("index")) for u in structure.find("Outputs")]
    assert listed == outputs
    initial = {int(u.get("index")) for u in structure.find("InitialUnknowns")}
    calculated = {i + 1 for i, sv in enumerate(svs) if sv.get("causality") == "calculatedParameter"}
    assert initial == set(outputs) | calculated
    with zipfile.ZipFile(fmu) as zf:
        requirements = zf.read("resources/requirements.txt").decode()
    assert "numpy" in requirements


def test_units_carry_si_exponents(fmu_dir):
    root = _md(fmu_dir / "Aircraft.fmu")
    units = {u.get("name"): u.find("BaseUnit") for u in root.iter("Unit")}
    assert units["rad/s"].attrib == {"s": "-1", "rad": "1"}
    assert units["m"].attrib == {"m": "1"}
    pc = _md(fmu_dir / "PitchController.fmu")
    calc = [sv.get("name") for sv in pc.find("ModelVariables")
            if sv.get("causality") == "calculatedParameter"]
    assert calc == ["k_alpha", "k_q", "k_theta", "k_int"]


_MINIMAL = b"""<?xml version="1.0" encoding="UTF-8"?>
<fmiModelDescription fmiVersion="2.0" modelName="M" guid="g">
  <CoSimulation modelIdentifier="M"/>
  <LogCategories><Category name="logAll"/></LogCategories>
  <ModelVariables>
    <ScalarVariable name="u" valueReference="0" causality="input"><Real start="0"/></ScalarVariable>
    <ScalarVariable name="n" valueReference="1" causality="parameter">
      <Integer start="1"/></ScalarVariable>
    <ScalarVariable name="y" valueReference="2" causality="output"><Real/></ScalarVariable>
    <ScalarVariable name="f" valueReference="3" causality="output"><Boolean/></ScalarVariable>
  </ModelVariables>
  <ModelStructure><Outputs><Unknown index="3"/></Outputs></ModelStructure>
</fmiModelDescription>"""


def test_postprocess_sets_variability_units_dependencies():
    xml, notes = builder.postprocess_model_description(
        _MINIMAL, {"y": {"unit": "furlong", "min": -1.0}, "n": {"max": 4}}, {"y": ["u"]})
    root = ET.fromstring(xml)
    assert [c.tag for c in root][:3] == ["CoSimulation", "UnitDefinitions", "LogCategories"]
    var = {sv.get("name"): sv for sv in root.find("ModelVariables")}
    assert [var[n].get("variability") for n in "unyf"] == ["continuous", "fixed",
                                                           "continuous", "discrete"]
    assert var["y"][0].get("unit") == "furlong" and var["y"][0].get("min") == "-1"
    assert var["n"][0].get("max") == "4"
    assert any("furlong" in n for n in notes)
    outs = root.find("ModelStructure/Outputs")
    deps = {u.get("index"): (u.get("dependencies"), u.get("dependenciesKind")) for u in outs}
    assert deps == {"3": ("1", "dependent"), "4": ("", None)}
    with pytest.raises(ValueError, match="unknown variables"):
        builder.postprocess_model_description(_MINIMAL, {"nope": {}}, {})
    with pytest.raises(ValueError, match="no input"):
        builder.postprocess_model_description(_MINIMAL, {}, {"y": ["n"]})


def test_cli_rejects_unknown_name(tmp_path):
    proc = subprocess.run([sys.executable, str(ROOT / "build_fmu.py"), "--out", str(tmp_path),
                           "NoSuchFMU"], capture_output=True, text=True, timeout=1800)
    assert proc.returncode == 2 and "unknown FMU name" in proc.stderr


@pytest.mark.parametrize("name", AVAILABLE)
def test_every_python_file_ships_with_its_checked_bytecode(fmu_dir, name):
    """Hosts unzip an FMU afresh and may not write into it: each resources/*.py has a
    hash-checked pyc of the building Python beside it, for exactly that source."""
    import importlib.util

    with zipfile.ZipFile(fmu_dir / f"{name}.fmu") as zf:
        names = set(zf.namelist())
        sources = [n for n in names if n.startswith("resources/") and n.endswith(".py")]
        assert sources
        for source in sources:
            pyc = importlib.util.cache_from_source(source)
            assert pyc in names, pyc
            data = zf.read(pyc)
            assert data[:4] == importlib.util.MAGIC_NUMBER
            flags = int.from_bytes(data[4:8], "little")
            assert flags == 0b11, (pyc, flags)  # hash-based, checked
            assert data[8:16] == importlib.util.source_hash(zf.read(source)), source


def test_diagnoser_ships_the_generated_dtg_readout(fmu_dir):
    """resources/sensor_dynamics/dtg_paper_y_q3_1ms.json is the paper DTG's y read-out at
    1 kHz as models/dtg/gd_dtg_readout.py computes it (sensor 3, DC gain 1), and the DTG
    model's sources make the Diagnoser stale."""
    import json

    import numpy as np

    sys.path.insert(0, str(ROOT / "models" / "dtg"))
    import gd_dtg_readout as readout
    import gd_dtg_sets as sets

    with zipfile.ZipFile(fmu_dir / "Diagnoser.fmu") as zf:
        shipped = json.loads(zf.read("resources/sensor_dynamics/dtg_paper_y_q3_1ms.json"))
    expected = readout.readout_dict(sets.paper_set(), "y", 3, 1e-3)
    assert shipped["sensor"] == 3
    d = shipped["discrete"]
    assert d["sample_period_s"] == 1e-3
    for key in ("A", "B", "C"):
        np.testing.assert_allclose(d[key], expected["discrete"][key], rtol=1e-15, atol=0)
    A, B, C = (np.asarray(d[k]) for k in ("A", "B", "C"))
    dc = C @ np.linalg.solve(np.eye(A.shape[0]) - A, B) + d["D"]
    assert dc == pytest.approx(1.0, abs=1e-9)
    entry = next(e for e in builder.REGISTRY if e[0] == "Diagnoser")
    assert ROOT / "models" / "dtg" / "gd_dtg_readout.py" in builder.source_files(entry)
    assert ROOT / "models" / "dtg" / "gd_dtg_core.py" in builder.source_files(entry)
