"""fmpy side of the C-host cross-check and of the step checks, in a fresh process.

``python _host_runner.py FMU_DIR OUT.json MODE``

* ``crosscheck``: every FMU with :data:`HOST_SETS` (those the FMU has), steps of
  :data:`HOST_STEP` over :data:`HOST_STOP` with the C host's input signal, recording the
  outputs after every step (what ``tests/host/gd_fmi2_host.c --out-dir`` writes).
* ``steps``: every plant FMU with irregular steps (accepted) and steps <= 0 or not
  finite (refused), recording statuses and messages.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _fmu_calls import Instance

FMUS = ("Aircraft", "DTG", "Diagnoser", "FaultInjector", "HRG", "PitchController")
HOST_STEP, HOST_STOP = 0.01, 1.0
HOST_SETS = {"sample_period_s": 0.01, "dtg.prefilter_cutoff_hz": 20.0}
IRREGULAR_STEPS = (0.003, 0.0071, 0.02, 0.001)
REFUSED_STEPS = (0.0, -0.01, float("nan"), float("inf"))


def crosscheck(fmu_dir: Path) -> dict[str, Any]:
    out = {}
    for name in FMUS:
        from fmpy import read_model_description

        names = {v.name for v in read_model_description(str(fmu_dir / f"{name}.fmu"))
                 .modelVariables}
        params = {k: v for k, v in HOST_SETS.items() if k in names}
        inst = Instance(fmu_dir / f"{name}.fmu", name, params, step=HOST_STEP)
        assert inst.init_status == 0, inst.messages()
        rows = inst.step(round(HOST_STOP / HOST_STEP))
        out[name] = {"columns": [v.name for v in inst.outputs], "rows": rows.tolist()}
        inst.close()
    return out


def steps(fmu_dir: Path) -> dict[str, Any]:
    out = {}
    for name in FMUS:
        if name == "Diagnoser":  # its steps are tested in test_diagnoser_fmu
            continue
        inst = Instance(fmu_dir / f"{name}.fmu", name)
        res: dict[str, Any] = {"accepted": [], "refused": [], "refused_log": []}
        t = 0.0
        for h in IRREGULAR_STEPS:
            res["accepted"].append(inst.call(inst.fmu.doStep, t, h))
            t += h
        for h in REFUSED_STEPS:
            mark = len(inst.log)
            res["refused"].append(inst.call(inst.fmu.doStep, t, h))
            res["refused_log"].append(inst.messages(mark))
        res["after"] = inst.call(inst.fmu.doStep, t, 0.01)
        out[name] = res
        inst.close()
    return out


if __name__ == "__main__":
    mode = sys.argv[3]
    result = {"crosscheck": crosscheck, "steps": steps}[mode](Path(sys.argv[1]))
    Path(sys.argv[2]).write_text(json.dumps(result), encoding="utf-8")
