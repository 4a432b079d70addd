"""The Diagnoser with nothing set but ``sample_period_s``, in a fresh process
(tests/test_sample_period.py).

``python _sample_period_runner.py FMU_DIR OUT.npz``

For each period of PERIODS: initialise, then 25 samples one per step (past the
detection filter's calibration at slow rates); and a run with the default experiment's
step (1 ms) for 0.3 s. Saves per period the statuses (0 ok) and the outputs read.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from conftest import FmuSlave

PERIODS = (1e-4, 1e-3, 0.01, 0.1, 0.5, 2.0)
N_SAMPLES = 25
DEFAULT_STEP, DEFAULT_RUN_S = 1e-3, 0.3
OUTPUTS = ("dtg.learning", "df.calibrating", "any_alarm", "inputs_valid")


def run(fmu: Path, period: float, h: float, n: int) -> tuple[int, list[float]]:
    """(steps taken before an error or n, outputs after them)."""
    try:
        d = FmuSlave(fmu, f"diag_{period:g}_{h:g}", {"sample_period_s": period})
    except Exception as exc:  # fmpy raises on a failed initialisation
        print(f"{period}: initialisation failed: {exc}")
        return -1, [0.0] * len(OUTPUTS)
    taken = 0
    try:
        for _ in range(n):
            d.step(h)
            taken += 1
    except Exception as exc:
        print(f"{period}, h={h}: step {taken} failed: {exc}")
    out = [float(d.get(name)) for name in OUTPUTS]
    d.close()
    return taken, out


def main(fmu_dir: str, out: str) -> None:
    fmu = Path(fmu_dir) / "Diagnoser.fmu"
    res: dict[str, np.ndarray] = {"periods": np.array(PERIODS)}
    per_sample = [run(fmu, p, p, N_SAMPLES) for p in PERIODS]
    default_step = [run(fmu, p, DEFAULT_STEP, round(DEFAULT_RUN_S / DEFAULT_STEP))
                    for p in PERIODS]
    res["taken"] = np.array([t for t, _ in per_sample])
    res["outputs"] = np.array([o for _, o in per_sample])
    res["taken_default_step"] = np.array([t for t, _ in default_step])
    np.savez(out, **res)


if __name__ == "__main__":
    main(sys.argv[1], sys.argv[2])
