"""Count interpreter-exit aborts of processes that ran pythonfmu FMUs (docs/methods.md §6.11).

Each child process extracts Aircraft, FaultInjector and Diagnoser, instantiates, steps,
terminates and frees them with fmpy, then exits normally (no ``os._exit``).  pythonfmu
0.7 touches a freed heap block at exit unless the status shim resets its interpreter
guard first (fmu_src/shim/fmi2_status_shim.c); glibc then sometimes aborts with
"corrupted double-linked list" (exit status 134 / -6).  The rate depends on heap layout
and machine load (0-40 % before the fix), so run many processes.

Usage::

    python benchmarks/exit_abort_repro.py --runs 50 [--fmu-dir build/fmus] [--jobs 2]
"""

from __future__ import annotations

import argparse
import collections
import os
import shutil
import subprocess
import sys
import tempfile
from concurrent.futures import ThreadPoolExecutor

FMUS = ("Aircraft", "FaultInjector", "Diagnoser")
STEP_S = 0.001  # one sample per step at the Diagnoser's default period


def child(fmu_dir: str, steps: int) -> None:
    from fmpy import extract, read_model_description
    from fmpy.fmi2 import FMU2Slave

    tmp = tempfile.mkdtemp(prefix="exit-abort-")
    slaves = []
    for name in FMUS:
        unzipdir = extract(os.path.join(fmu_dir, f"{name}.fmu"), unzipdir=os.path.join(tmp, name))
        md = read_model_description(unzipdir)
        slave = FMU2Slave(guid=md.guid, unzipDirectory=unzipdir,
                          modelIdentifier=md.coSimulation.modelIdentifier, instanceName=name)
        slave.instantiate()
        slave.setupExperiment(startTime=0.0)
        slave.enterInitializationMode()
        slave.exitInitializationMode()
        slaves.append(slave)
    for k in range(steps):
        for slave in slaves:
            slave.doStep(k * STEP_S, STEP_S)
    for slave in slaves:
        slave.terminate()
        slave.fmi2FreeInstance(slave.component)
    # Deleting the extracted folders while the libraries are mapped is part of the
    # original report; it is harmless once the shim is fixed.
    shutil.rmtree(tmp, ignore_errors=True)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=50)
    parser.add_argument("--jobs", type=int, default=1, help="child processes at a time")
    parser.add_argument("--steps", type=int, default=20)
    parser.add_argument("--fmu-dir", default=os.path.join(os.path.dirname(__file__), "..",
                                                          "build", "fmus"))
    parser.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.child:
        child(args.fmu_dir, args.steps)
        return 0

    def one(_: int) -> int:
        cmd = [sys.executable, __file__, "--child", "--fmu-dir", args.fmu_dir,
               "--steps", str(args.steps)]
        return subprocess.run(cmd, capture_output=True, timeout=300).returncode

    with ThreadPoolExecutor(max_workers=args.jobs) as pool:
        codes = collections.Counter(pool.map(one, range(args.runs)))
    aborts = codes.get(-6, 0) + codes.get(134, 0)
    print(f"{args.runs} runs: exit codes {dict(sorted(codes.items()))}; aborts {aborts}")
    return 1 if aborts else 0


if __name__ == "__main__":
    sys.exit(main())
