"""Diagnoser.fmu grey-channel options, run in a fresh process (docs/methods.md §6.11) by
test_diagnoser_grey_options.

``python _grey_options_runner.py FMU_DIR OUT.npz IN.npz`` runs the grey channel alone
with every parameter set of :data:`CASES` on the signal ``y`` of IN.npz and writes the
outputs, a save/restore re-run and the statuses and logs of :data:`INVALID`.

Must not import ``gyrodiag`` (the FMU's shipped copy has to be the first one loaded).
"""

from __future__ import annotations

import shutil
import sys
from pathlib import Path
from typing import Any

import numpy as np
from _diagnoser_runner import IN_NAMES, Diag

H = 0.5
BASE: dict[str, Any] = {
    "sample_period_s": H, "dtg.enabled": False, "df.enabled": False,
    "grey.decision": 0, "grey.threshold": 0.05, "grey.clear_after_s": 10.0,
}
#: label -> (grey.model, grey.window, grey.classic_evaluation)
CASES: dict[str, tuple[int, int, int]] = {
    "ordinary_textbook": (0, 0, 1),
    "ordinary_careful": (0, 0, 0),
    "moving_textbook": (0, 8, 1),
    "improved": (1, 10, 0),
}
#: Learned rules (run on the noisy signal ``y_noisy``): label -> parameters. The first
#: 15 s are fault-free: the 10-sample warm-up (5 s), then 20 calibration errors.
_LEARNED = {"grey.model": 1, "grey.window": 10, "grey.learn_end_s": 15.0,
            "grey.threshold_floor": 0.01, "grey.auto_order": False}
CALIBRATED: dict[str, dict[str, Any]] = {
    "calibrated_k_sigma": {**_LEARNED, "grey.decision": 2, "grey.k_sigma": 5.0},
    "calibrated_sequential_auto": {**_LEARNED, "grey.decision": 1, "grey.auto_order": True},
    "calibrated_sequential_cusum_only": {**_LEARNED, "grey.decision": 1, "grey.lag_max": 0,
                                         "grey.suspicion_sigma": 3.0},
    "calibrated_sequential_lag2_ref30": {**_LEARNED, "grey.decision": 1, "grey.lag_max": 2,
                                         "grey.reference_window_s": 15.0,
                                         "grey.reference_order": 2},
}
#: Steps before the calibrated sequential detector's state is saved (restored, re-run).
K_SAVE_CALIBRATED = 80
#: Steps before the FMU state is saved in the whole-record run (restored, re-run).
K_SAVE = 150
#: Invalid parameter sets: label -> parameters.
INVALID: dict[str, dict[str, Any]] = {
    "window 0 with the improved model": {"grey.model": 1, "grey.window": 0},
    "classic_evaluation 2": {"grey.model": 0, "grey.classic_evaluation": 2},
    "classic window 3": {"grey.model": 0, "grey.window": 3},
    "grey.decision 3": {"grey.decision": 3},
    "grey.learn_end_s negative": {"grey.decision": 1, "grey.learn_end_s": -6.0},
    "grey.cusum_k 0": {"grey.decision": 1, "grey.cusum_k": 0.0},
    "grey.lag_max 5": {"grey.decision": 1, "grey.lag_max": 5},
    "grey.reference_window_s 0": {"grey.decision": 1, "grey.reference_window_s": 0.0},
}


def params(model: int, window: int, evaluation: int) -> dict[str, Any]:
    return {**BASE, "grey.model": model, "grey.window": window,
            "grey.classic_evaluation": evaluation}


def main(fmu_dir: Path, out: Path, inp: Path) -> None:
    from fmpy import extract, read_model_description

    unzipdir = extract(str(fmu_dir / "Diagnoser.fmu"))
    md = read_model_description(unzipdir)
    y = np.load(inp)["y"]
    record = np.zeros((y.size, len(IN_NAMES)))
    record[:, IN_NAMES.index("grey.y")] = y
    res: dict[str, Any] = {}
    d = None
    for label, case in CASES.items():
        d = Diag(unzipdir, md, label, params(*case), h=H)
        assert d.init_status == 0, d.log
        res[label] = d.run(record)
        d.close()
    assert d is not None
    res["columns"] = np.array(d.out_names)
    noisy = np.zeros((y.size, len(IN_NAMES)))
    noisy[:, IN_NAMES.index("grey.y")] = np.load(inp)["y_noisy"]
    for label, extra in CALIBRATED.items():
        d = Diag(unzipdir, md, label, {**BASE, **extra}, h=H)
        assert d.init_status == 0, d.log
        res[label] = d.run(noisy)
        d.close()
    d = Diag(unzipdir, md, "state_cal", {**BASE, **CALIBRATED["calibrated_sequential_auto"]},
             h=H)
    d.run(noisy[:K_SAVE_CALIBRATED])
    state = d.fmu.serializeFMUstate(d.fmu.getFMUstate())
    res["cal_first"] = d.run(noisy[K_SAVE_CALIBRATED:])
    d.fmu.setFMUstate(d.fmu.deSerializeFMUstate(state))
    d.k = K_SAVE_CALIBRATED
    res["cal_again"] = d.run(noisy[K_SAVE_CALIBRATED:])
    d.close()

    # whole-record model: its state grows with the record, save and restore it
    d = Diag(unzipdir, md, "state", params(*CASES["ordinary_textbook"]), h=H)
    d.run(record[:K_SAVE])
    state = d.fmu.serializeFMUstate(d.fmu.getFMUstate())
    res["state_first"] = d.run(record[K_SAVE:])
    d.fmu.setFMUstate(d.fmu.deSerializeFMUstate(state))
    d.k = K_SAVE
    res["state_again"] = d.run(record[K_SAVE:])
    d.close()

    statuses, logs = [], []
    for i, extra in enumerate(INVALID.values()):
        d = Diag(unzipdir, md, f"bad_{i}", {**BASE, **extra}, h=H)
        statuses.append(d.init_status)
        logs.append("\n".join(m for _, m in d.log))
        d.close()
    res["invalid_status"] = np.array(statuses)
    res["invalid_log"] = np.array(logs)
    np.savez(out, **res)
    shutil.rmtree(unzipdir, ignore_errors=True)


if __name__ == "__main__":
    main(Path(sys.argv[1]), Path(sys.argv[2]), Path(sys.argv[3]))
