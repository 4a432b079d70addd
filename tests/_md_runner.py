"""Runtime side of test_model_descriptions, in a fresh process (docs/methods.md §6.11).

``python _md_runner.py FMU_DIR OUT.json`` records, for every FMU:

* ``bounds``: for every Real/Integer parameter with a declared min or max (the first
  member of an indexed family such as ``df.threshold[i]`` standing for the family), the
  status and log of initialising with a value just outside the bound and with the bound;
* ``non_finite``: outputs that were NaN/Inf at any point of a run with the C host's input
  signal (and, for the Diagnoser, of a run with NaN and Inf inputs).
"""

from __future__ import annotations

import json
import math
import re
import sys
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _fmu_calls import Instance
from _host_runner import FMUS

#: Diagnoser set-up for the output checks: short learning and calibration windows, so
#: that 300 samples reach the decisions (alarms, isolation, typing).
DIAG_RUN = {"dtg.learn_start_s": 0.05, "dtg.learn_end_s": 0.1, "df.calibrate_s": 0.15,
            "df.burn_in_s": 0.05}
N_RUN = 300
#: Other parameters set with a bound that is only reachable with them.
COMPANIONS: dict[tuple[str, str], dict[str, Any]] = {
    ("Diagnoser", "grey.window"): {"grey.model": 0},  # 0 = whole record, classic only
    ("Diagnoser", "df.persistence_n"): {"df.persistence_k": 1},
    ("PitchController", "command_source"): {"cmd_duration_s": 1.0},  # 4 = sweep needs it
    ("PitchController", "cmd_period"): {"command_source": 3},  # 0 = a doublet flown once
}


def _outside(value: float, side: str, integer: bool) -> float:
    if integer:
        return value - 1 if side == "min" else value + 1
    delta = max(abs(value) * 1e-6, 1e-12)
    return value - delta if side == "min" else value + delta


def bounds(fmu: Path) -> list[dict[str, Any]]:
    from fmpy import read_model_description

    md = read_model_description(str(fmu))
    checks: list[dict[str, Any]] = []
    families: set[tuple[str, str]] = set()
    for v in md.modelVariables:
        if v.causality != "parameter" or v.type not in ("Real", "Integer"):
            continue
        integer = v.type == "Integer"
        for side in ("min", "max"):
            text = getattr(v, side)
            if text is None:
                continue
            bound = int(text) if integer else float(text)
            extra = dict(COMPANIONS.get((md.modelName, v.name), {}))
            if md.modelName == "Diagnoser":  # build only the parameter's own channel
                extra.update({f"{c}.enabled": False for c in ("dtg", "grey", "df")
                              if not v.name.startswith(f"{c}.")})
            # one member of an indexed family (df.threshold[i], noise_std_i) stands for all
            family = (re.sub(r"\[[\d,]+\]$|_\d+$", "", v.name), side)
            if family in families:
                continue
            families.add(family)
            for outside, value in ((True, _outside(bound, side, integer)), (False, bound)):
                inst = Instance(fmu, f"bound_{len(checks)}", {**extra, v.name: value})
                checks.append({"name": v.name, "side": side, "value": value,
                               "outside": outside, "status": inst.init_status,
                               "log": inst.messages()})
                inst.close()
    return checks


def non_finite(fmu: Path) -> tuple[list[str], int]:
    name = fmu.stem
    params = DIAG_RUN if name == "Diagnoser" else {}
    bad: set[str] = set()
    n_rows = 0
    runs = [("signal", params)]
    if name == "Diagnoser":
        runs.append(("non-finite inputs", params))
    for label, p in runs:
        inst = Instance(fmu, f"finite_{label}", p)
        assert inst.init_status == 0, inst.messages()
        rows = [inst.row()]
        if label == "signal":
            rows.extend(inst.step(N_RUN))
        else:
            vrs = [v.valueReference for v in inst.inputs]
            for k in range(N_RUN):
                values = [float("nan") if (k + j) % 7 == 0 else
                          float("inf") if (k + j) % 11 == 0 else 0.1 * ((k + j) % 5)
                          for j in range(len(vrs))]
                inst.fmu.setReal(vrs, values)
                status = inst.call(inst.fmu.doStep, k * inst.h, inst.h)
                assert status == 0, inst.messages()
                rows.append(inst.row())
        for row in rows:
            for v, x in zip(inst.outputs, row, strict=True):
                if not math.isfinite(x):
                    bad.add(f"{v.name} ({label})")
        n_rows += len(rows)
        inst.close()
    return sorted(bad), n_rows


def main(fmu_dir: Path, out: Path) -> None:
    result = {}
    for name in FMUS:
        fmu = fmu_dir / f"{name}.fmu"
        bad, n_rows = non_finite(fmu)
        result[name] = {"bounds": bounds(fmu), "non_finite": bad, "n_rows": n_rows}
    out.write_text(json.dumps(result), encoding="utf-8")


if __name__ == "__main__":
    main(Path(sys.argv[1]), Path(sys.argv[2]))
