"""Diagnoser.fmu on the system chain with the case rate and the read-out dynamics, run in
a fresh process (docs/methods.md §6.11) by test_system_diagnosis.

``python _system_diagnoser_runner.py FMU_DIR OUT.npz IN.npz``: IN.npz holds the chain
record (columns of :data:`DTG_IN` and :data:`DF_IN`) and the read-out file's path. Must
not import ``gyrodiag`` (the FMU loads its own copy).
"""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _diagnoser_runner import Diag

H = 1e-3
DTG_IN = ("dtg.Utx", "dtg.Uty", "dtg.Ux", "dtg.Uy", "dtg.case_rate_x", "dtg.case_rate_y")
DF_IN = ("df.u[1]", "df.u[2]", *(f"df.y[{i}]" for i in range(1, 7)))
#: The DTG channel of the system scenarios, with the case rate (central scheme).
DTG_PARAMS: dict[str, Any] = {
    "sample_period_s": H, "grey.enabled": False, "df.enabled": False,
    "dtg.classifier": "paper", "dtg.forgetting": 0.9998, "dtg.learn_start_s": 2.0,
    "dtg.learn_end_s": 10.0, "dtg.low": 0.93, "dtg.high": 1.07, "dtg.case_rate": 1,
}
#: The detection filter at 1 kHz (paper rule), the read-out file set at run time.
DF_PARAMS: dict[str, Any] = {
    "sample_period_s": H, "dtg.enabled": False, "grey.enabled": False,
    "df.decision": 0, "df.align_auto": False, "df.calibrate_s": 10.0, "df.burn_in_s": 2.0,
}
#: Save point of the state round trip (inside the DTG learning window), samples.
K_SAVE, K_RERUN = 6000, 1500
#: The pattern classifier with the case rate (the reference refined in the manoeuvre):
#: state saved after learning, just before the square wave's second edge (14 s).
DTG_PATTERN_PARAMS: dict[str, Any] = {**DTG_PARAMS, "dtg.classifier": "pattern"}
K_SAVE_PATTERN, K_RERUN_PATTERN = 13900, 1000
INVALID = {
    "dtg.case_rate": ({"dtg.case_rate": 3}, {}),
    "dtg.pickoff_scale": ({"dtg.pickoff_scale": 0.0}, {}),
    "df.sensor_dynamics_file": ({}, {"df.sensor_dynamics_file": "/nonexistent/readout.json"}),
    "dtg.case_rate_delay_samples": ({"dtg.case_rate": 1, "dtg.case_rate_delay_samples": 3,
                                     "dtg.case_rate_align_max": 2}, {}),
    "dtg.case_rate_align_max": ({"dtg.case_rate_align_max": 51}, {}),
    "dtg.case_rate_lookahead_s": ({"dtg.case_rate": 1, "dtg.case_rate_align_max": 2,
                                   "dtg.case_rate_lookahead_s": 0.001}, {}),
    "df.sensor_delay[3]": ({"df.sensor_delay[3]": 51}, {}),
}


def run(fmu_dir: Path, out: Path, inp: Path) -> None:
    from fmpy import extract, read_model_description

    unzipdir = extract(str(fmu_dir / "Diagnoser.fmu"))
    md = read_model_description(unzipdir)
    data = dict(np.load(inp))
    res: dict[str, Any] = {}

    def new(name: str, params: dict[str, Any], inputs: tuple[str, ...],
            strings: dict[str, str] | None = None) -> Diag:
        d = Diag(unzipdir, md, name, params, h=H, initialise=False)
        d._in_vr = [d.vars[n].valueReference for n in inputs]
        d.init_status = d.initialise(params, strings)
        return d

    def run_saving(d, k_save: int):
        """Step through the DTG record, serialising the FMU state before sample k_save."""
        rows, state = [], None
        for k, x in enumerate(data["dtg"]):
            if k == k_save:
                state = d.fmu.serializeFMUstate(d.fmu.getFMUstate())
            status = d.step(x)
            if status != 0:
                raise RuntimeError(f"doStep at k={k} returned {status}: {d.log}")
            rows.append(d.outputs())
        d.close()
        return np.array(rows), state

    d = new("dtg", DTG_PARAMS, DTG_IN)
    assert d.init_status == 0, d.log
    res["columns"] = np.array(d.out_names)
    res["dtg"], state = run_saving(d, K_SAVE)
    d = new("dtg_restored", {"sample_period_s": H}, DTG_IN)
    d.fmu.setFMUstate(d.fmu.deSerializeFMUstate(state))
    d.k = K_SAVE
    res["dtg_restored"] = d.run(data["dtg"][K_SAVE:K_SAVE + K_RERUN])
    d.close()

    d = new("dtg_pattern", DTG_PATTERN_PARAMS, DTG_IN)
    assert d.init_status == 0, d.log
    res["dtg_pattern"], state = run_saving(d, K_SAVE_PATTERN)
    d = new("dtg_pattern_restored", {"sample_period_s": H}, DTG_IN)
    d.fmu.setFMUstate(d.fmu.deSerializeFMUstate(state))
    d.k = K_SAVE_PATTERN
    res["dtg_pattern_restored"] = d.run(
        data["dtg"][K_SAVE_PATTERN:K_SAVE_PATTERN + K_RERUN_PATTERN])
    d.close()

    d = new("df", DF_PARAMS, DF_IN, {"df.sensor_dynamics_file": str(data["readout_path"])})
    assert d.init_status == 0, d.log
    res["df"] = d.run(data["df"])
    d.close()

    # the default df.decision (2, auto) with a read-out model must be the paper rule
    auto = {k: v for k, v in DF_PARAMS.items() if k != "df.decision"}
    d = new("df_auto", auto, DF_IN, {"df.sensor_dynamics_file": str(data["readout_path"])})
    assert d.init_status == 0, d.log
    res["df_auto"] = d.run(data["df"])
    res["auto_log"] = np.array("\n".join(f"[{s}] {m}" for s, m in d.log))
    d.close()

    d = new("df_sequential", {**DF_PARAMS, "df.decision": 1}, DF_IN,
            {"df.sensor_dynamics_file": str(data["readout_path"])})
    res["sequential_status"] = np.array(d.init_status)
    res["sequential_log"] = np.array("\n".join(f"[{s}] {m}" for s, m in d.log))
    d.close()

    labels, status, logs = [], [], []
    for label, (params, strings) in INVALID.items():
        d = new(f"bad_{len(labels)}", {**DF_PARAMS, "dtg.enabled": True, **params}, DF_IN,
                strings)
        labels.append(label)
        status.append(d.init_status)
        logs.append("\n".join(f"[{s}] {m}" for s, m in d.log))
        d.close()
    res["invalid_labels"] = np.array(labels)
    res["invalid_status"] = np.array(status)
    res["invalid_log"] = np.array(logs)
    np.savez(out, **res)


if __name__ == "__main__":
    run(Path(sys.argv[1]), Path(sys.argv[2]), Path(sys.argv[3]))
