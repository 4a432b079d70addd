"""The shipped DTG pattern library: its writer and checker (fmu_src/tools/), and the
channel that uses it when no library file is given. The check against a fresh learning
run is in test_dtg_pattern_scenarios.py."""

from __future__ import annotations

import importlib.util
import json
import subprocess
import sys
from pathlib import Path

import pytest

from gyrodiag.dtg.channel import DTGChannelConfig
from gyrodiag.dtg.patterns import DEFAULT_LIBRARY_FILE, default_library

ROOT = Path(__file__).resolve().parents[1]
TOOL = ROOT / "fmu_src" / "tools" / "default_patterns.py"
CLASSES = ["utx_step", "uty_step", "ux_step", "uy_step", "utx_noise", "uty_noise",
           "ux_noise", "uy_noise", "utx_loss", "uty_loss", "ux_loss", "uy_loss",
           "utx_drift", "uty_drift", "ux_drift", "uy_drift", "spin", "torquer"]


def _tool():
    spec = importlib.util.spec_from_file_location("default_patterns", TOOL)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_the_shipped_library_holds_the_classes_at_1_khz_with_a_levels_only_prior():
    data = json.loads(DEFAULT_LIBRARY_FILE.read_text(encoding="utf-8"))
    lib = default_library()
    assert lib.names == CLASSES and data["codes"] == {n: i + 1 for i, n in enumerate(CLASSES)}
    assert lib.prior is not None and lib.prior.levels_only
    assert lib.prior.to_dict() == data["patterns"]["nominal"]
    assert lib.sample_period_s == 1e-3
    DTGChannelConfig(patterns=lib).validate()
    with pytest.raises(ValueError, match="learn the patterns at this sample period"):
        DTGChannelConfig(sample_period_s=0.01, patterns=lib).validate()


def test_the_tool_marks_the_prior_levels_only_and_checks_what_it_wrote(tmp_path):
    shipped = json.loads(DEFAULT_LIBRARY_FILE.read_text(encoding="utf-8"))
    nominal = {k: v for k, v in shipped["patterns"]["nominal"].items() if k != "levels_only"}
    learned = {"patterns": {**shipped["patterns"], "nominal": nominal},
               "codes": shipped["codes"], "training": {"runs": []}}
    src = tmp_path / "learned.json"
    src.write_text(json.dumps(learned))
    out = tmp_path / "shipped.json"
    run = [sys.executable, str(TOOL), str(src), "--out", str(out)]
    assert subprocess.run(run, timeout=120).returncode == 0
    assert json.loads(out.read_text()) == shipped
    check = subprocess.run([*run, "--check"], capture_output=True, text=True, timeout=120)
    assert check.returncode == 0 and "matches" in check.stdout
    # one response entry off by 1e-6 relative: named, exit 1
    learned["patterns"]["classes"][1]["response"][1] *= 1 + 1e-6
    src.write_text(json.dumps(learned))
    check = subprocess.run([*run, "--check"], capture_output=True, text=True, timeout=120)
    assert check.returncode == 1 and ".patterns.classes[1].response[1]" in check.stdout


def test_the_tool_refuses_a_file_that_is_not_a_pattern_library():
    with pytest.raises(ValueError, match="needs 'patterns' and 'codes'"):
        _tool().shipped_content({"signatures": {}})
