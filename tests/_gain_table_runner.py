"""Diagnoser.fmu detection filter at start-up, in a fresh process (docs/methods.md §6.11), for
test_gain_table.

``python _gain_table_runner.py FMU_DIR OUT.npz RULE PERIOD_S A23`` runs the
detection-filter channel alone (RULE 0 paper, 1 sequential; ``df.A[2,3]`` = A23, or
the default for ``default``) through its calibration window on seeded noise and saves
the thresholds or noise figures in use and whether this process imported
``scipy.signal`` (the FMU runs in this interpreter).  Must not
import ``gyrodiag`` (the FMU loads its own copy, docs/methods.md §6.3).
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from conftest import FmuSlave

M = 6


def main(fmu_dir: Path, out: Path, rule: int, period: float, a23: str) -> None:
    window_s = 50 * period
    parameters = {
        "sample_period_s": period, "dtg.enabled": False, "grey.enabled": False,
        "df.enabled": True, "df.decision": rule, "df.calibrate_s": window_s,
        "df.burn_in_s": 0.1 * window_s, "df.align_auto": False}
    if a23 != "default":
        parameters["df.A[2,3]"] = float(a23)
    slave = FmuSlave(fmu_dir / "Diagnoser.fmu", parameters=parameters)
    before = "scipy.signal" in sys.modules
    rng = np.random.default_rng(7)
    n = 60
    u = rng.normal(0.0, 0.01, (n, 2))
    y = rng.normal(0.0, 1e-3, (n, M))
    for k in range(n):
        for i in range(2):
            slave.set(f"df.u[{i + 1}]", float(u[k, i]))
        for i in range(M):
            slave.set(f"df.y[{i + 1}]", float(y[k, i]))
        slave.step(period)
    names = ([f"df.threshold_in_use[{i + 1}]" for i in range(M)]
             + [f"df.noise_std_in_use[{i + 1}]" for i in range(M)])
    figures = np.array(slave.get_many(names))
    np.savez(out, u=u, y=y, figures=figures,
             signal_before=before, signal_after="scipy.signal" in sys.modules)
    slave.close()


if __name__ == "__main__":
    main(Path(sys.argv[1]), Path(sys.argv[2]), int(sys.argv[3]), float(sys.argv[4]),
         sys.argv[5])
