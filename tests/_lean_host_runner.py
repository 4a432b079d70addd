"""Diagnoser.fmu in a host whose Python has neither SciPy nor python-control.

``python _lean_host_runner.py FMU_DIR OUT.npz IN.npz [python]`` blocks ``scipy`` and
``control`` (an import of either raises ModuleNotFoundError), then runs the Diagnoser
through fmpy: DTG and grey channels on the record in IN.npz with the detection filter
off, and an instance with the defaults (detection filter on), whose initialisation must
fail with fmi2Error naming the missing package. With the extra argument ``python`` the
FMU runs its plain-Python kernels (GYRODIAG_KERNELS=python).

Must not import gyrodiag (the FMU loads the copy in its resources; docs/methods.md §6.3).
"""

from __future__ import annotations

import os
import sys
from pathlib import Path

import numpy as np

sys.modules["scipy"] = None  # type: ignore[assignment]
sys.modules["control"] = None  # type: ignore[assignment]

LEAN_PARAMS = {
    "sample_period_s": 1e-3, "df.enabled": False, "dtg.p0": 1e8, "dtg.learn_start_s": 0.2,
    "dtg.learn_end_s": 0.8, "grey.window": 10, "grey.decision": 0,
    "grey.threshold": 0.05,
}


def main(fmu_dir: Path, out: Path, inp: Path, kernels: str) -> None:
    if kernels == "python":
        os.environ["GYRODIAG_KERNELS"] = "python"
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from _diagnoser_runner import Diag
    from fmpy import extract, read_model_description

    unzipdir = extract(str(fmu_dir / "Diagnoser.fmu"))
    md = read_model_description(unzipdir)
    record = np.load(inp)["record"]
    d = Diag(unzipdir, md, "lean", LEAN_PARAMS)
    assert d.init_status == 0, d.log
    rows = d.run(record)
    d.close()
    accel = sys.modules["gyrodiag.common._accel"]
    kernel_file = getattr(accel.kernels, "__file__", "")
    full = Diag(unzipdir, md, "with_df", {"grey.decision": 0})
    init_log = "\n".join(f"[{s}] {m}" for s, m in full.log)
    full.log.clear()
    step_status = full.step(np.zeros(13))
    full.close()
    learned = Diag(unzipdir, md, "learned_grey", {"df.enabled": False})  # grey's default
    learned_log = "\n".join(f"[{s}] {m}" for s, m in learned.log)
    learned_status = learned.init_status
    learned.close()
    loaded = sorted(m for m, mod in sys.modules.items()
                    if m.split(".")[0] in ("scipy", "control") and mod is not None)
    np.savez(out, rows=rows, names=np.array(d.out_names), accelerated=accel.ACCELERATED,
             kernel_file=kernel_file, resources=str(Path(unzipdir) / "resources"),
             init_status=full.init_status, init_log=init_log, step_status=step_status,
             learned_status=learned_status, learned_log=learned_log,
             loaded=np.array(loaded, dtype=str))


if __name__ == "__main__":
    main(Path(sys.argv[1]), Path(sys.argv[2]), Path(sys.argv[3]),
         sys.argv[4] if len(sys.argv) > 4 else "default")
