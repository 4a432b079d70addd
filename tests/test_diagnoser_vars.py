"""The Diagnoser's variable tables (fmu_src/gd_diagnoser_vars, issue 31 item 3): one
record per variable, consistent families, config fields the library accepts, and the
tables shipped in the FMU.

The checks run in a subprocess (``python tests/test_diagnoser_vars.py``): importing the
facade's modules into the test process would make them the copy that FMUs loaded
in-process later share.
"""

from __future__ import annotations

import dataclasses
import subprocess
import sys
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]


def test_variable_tables() -> None:
    proc = subprocess.run([sys.executable, __file__], cwd=ROOT,
                          capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    assert proc.stdout.strip().endswith("checked")


def _defaults(gv: Any) -> dict:
    return {v.name: v.start for v in gv.VARIABLES}


def check_one_record_per_variable_and_meta_from_the_tables() -> None:
    import gd_diagnoser_vars as gv
    from gd_diagnoser_vars.spec import SCALAR_CONVERSIONS

    names = [v.name for v in gv.VARIABLES]
    assert len(names) == len(set(names))
    assert {v.kind for v in gv.VARIABLES} <= {"Real", "Integer", "Boolean", "String"}
    for v in gv.VARIABLES:
        assert v.unit is None or v.kind == "Real", v.name
        assert v.to in (*SCALAR_CONVERSIONS, "array", "list"), v.name
        assert (v.to in ("array", "list")) == bool(v.index), v.name
        assert not v.tunable or v.causality == "parameter", v.name
        assert gv.VARIABLE_META.get(v.name, {}) == v.meta
    tunable = {n for group in gv.TUNABLE.values() for n in group}
    assert tunable == {v.name for v in gv.VARIABLES if v.tunable}


def check_families_fill_arrays_of_their_shape() -> None:
    import gd_diagnoser_vars as gv
    from gd_diagnoser_vars.df import SEED
    from gd_diagnoser_vars.spec import config_fields

    from gyrodiag.dtg.channel import DTGChannelConfig

    fields = config_fields(gv.df.PARAMETERS, _defaults(gv), "config")
    for key in ("A", "B", "C"):
        assert np.array_equal(fields[key], getattr(SEED, key))
    m = SEED.C.shape[0]
    assert fields["bank_thresholds"].shape == (m, m - 1)
    assert fields["sensor_delay_samples"] == [0] * m
    dtg = config_fields(gv.dtg.PARAMETERS, _defaults(gv), "config")
    assert dtg["monitored"] == [True] * 5 and dtg["theta0"] == [1.0] * 5
    assert dtg["forgetting"] is None and dtg["prefilter_cutoff_hz"] is None
    # every DTG field is an argument of the config it fills
    assert set(dtg) <= {f.name for f in dataclasses.fields(DTGChannelConfig)}


def check_the_tables_ship_in_the_diagnoser_fmu() -> None:
    import build_fmu

    entry = next(e for e in build_fmu.REGISTRY if e[0] == "Diagnoser")
    shipped = {p.name for p in build_fmu.project_files(entry)}
    assert "gd_diagnoser_vars" in shipped


if __name__ == "__main__":
    sys.path[:0] = [str(ROOT / "fmu_src"), str(ROOT)]
    check_one_record_per_variable_and_meta_from_the_tables()
    check_families_fill_arrays_of_their_shape()
    check_the_tables_ship_in_the_diagnoser_fmu()
    print("checked")
