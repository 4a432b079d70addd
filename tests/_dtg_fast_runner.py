"""Runs DTG.fmu through fmpy in a host without SciPy (blocked), for test_dtg_fast_path.py.

Usage: ``python _dtg_fast_runner.py FMU_DIR OUT.npz``. Writes, per case of CASES, the
outputs after every step (and for a case with ``restore_at``, the steps after restoring
the FMU state saved there), and the SciPy modules loaded in this process (none expected:
DTG.fmu needs only numpy). Nothing here imports the DTG model sources: the FMU must run
its own packaged copy.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

OUT = ["Utx", "Uty", "Ux", "Uy", "omega_x_read", "omega_y_read"]
INPUTS = ("omega_x", "omega_y", "Ux_in", "Uy_in")

#: name → parameters, step sizes (s), input seed, tunable changes {step: {name: value}},
#: step after which the FMU state is saved and later restored (or None)
CASES: dict[str, dict] = {
    "paper_loop_faults": {
        "params": {"parameter_set": 1, "seed": 3, "noise_std": 1e-3, "dither_std": 0.5},
        "steps": [1e-3] * 1500, "input_seed": 11,
        "events": {300: {"spin_fraction": 0.9, "k_offset": 2e-4},
                   700: {"noise_std": 0.0, "torquer_scale": 1.1},
                   900: {"noise_std": 2e-3, "pickoff_scale": 0.95, "damping_scale": 2.0}},
        "restore_at": 1000,
    },
    "paper_open_odd_steps": {
        "params": {"parameter_set": 1, "rebalance_on": False, "seed": 4,
                   "noise_std": 1e-3, "dither_std": 0.1},
        "steps": list(np.random.default_rng(5).uniform(2e-4, 3.1e-3, 800)),
        "input_seed": 12, "events": {400: {"spin_fraction": 0.8}}, "restore_at": None,
    },
    "production_loop_0p7ms": {
        "params": {"parameter_set": 2, "seed": 7, "noise_std": 1e-3, "dither_std": 1.0},
        "steps": [0.7e-3] * 400, "input_seed": 13,
        "events": {200: {"k_offset": -1e-3, "dither_std": 0.0}}, "restore_at": 250,
    },
}


def inputs_of(case: dict) -> np.ndarray:
    """[ωx, ωy, Ux_in, Uy_in] held over each step (rad/s, V)."""
    n = len(case["steps"])
    rng = np.random.default_rng(case["input_seed"])
    return np.column_stack([0.01 * rng.standard_normal((n, 2)),
                            0.05 * rng.standard_normal((n, 2))])


def _drive(s, case: dict, inputs: np.ndarray, first: int) -> list[list[float]]:
    rows = []
    for k in range(first, len(case["steps"])):
        for name, value in case["events"].get(k, {}).items():
            s.set(name, value)
        for name, value in zip(INPUTS, inputs[k], strict=True):
            s.set(name, value)
        s.step(case["steps"][k])
        rows.append(s.get_many(OUT))
    return rows


def main(fmu_dir: Path, out: Path) -> None:
    sys.modules["scipy"] = None  # a host without SciPy: importing it raises ImportError
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from conftest import FmuSlave

    res: dict[str, np.ndarray] = {}
    for name, case in CASES.items():
        s = FmuSlave(fmu_dir / "DTG.fmu", name, case["params"])
        inputs = inputs_of(case)
        k_save = case["restore_at"]
        if k_save is None:
            res[name] = np.array(_drive(s, case, inputs, 0))
        else:
            head = _drive(s, {**case, "steps": case["steps"][:k_save]}, inputs, 0)
            t_saved, state = s.time, s.fmu.getFMUstate()
            tail = _drive(s, case, inputs, k_save)
            s.fmu.setFMUstate(state)
            s.time = t_saved
            res[name + "_restored"] = np.array(_drive(s, case, inputs, k_save))
            res[name] = np.array(head + tail)
        s.close()
    res["scipy_loaded"] = np.array(sorted(m for m in sys.modules
                                          if m.split(".")[0] == "scipy" and sys.modules[m]))
    np.savez(out, **res)


if __name__ == "__main__":
    main(Path(sys.argv[1]), Path(sys.argv[2]))
