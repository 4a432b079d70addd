"""Host cost of one step of each plant FMU through fmpy, and of its fmi2Instantiate.

Usage::

    .venv/bin/python benchmarks/bench_plants.py [--steps 5000] [--warmup 500] [--rounds 3]
        [--plants DTG Aircraft ...] [--fmu NAME=PATH ...]

For every plant (DTG, FaultInjector, Aircraft, HRG, PitchController from ``build/fmus``,
rebuilt first if older than their sources) a fresh process instantiates the FMU through
fmpy, initialises it with default parameters and times each host step: set every Real
input (small sines), fmi2DoStep at the FMU's default step size, get every Real output,
which is what the harness master does per step. ``--fmu NAME=PATH`` adds an FMU from
elsewhere (e.g. an older build of DTG.fmu for a before/after comparison); its plant type
is taken from its model name.

Each FMU runs ``--rounds`` times, the rounds interleaved across FMUs (fresh process each:
the pythonfmu FMUs of one process share their Python modules, so two builds of one model
cannot be compared in one process), so that a load change on a shared machine hits all
of them alike. Prints, per FMU, the median µs per host step (median over rounds of the
per-round medians), the fmi2Instantiate wall and CPU time (the FMU's imports: a fresh
process has imported only fmpy and numpy) and the initialisation time. No assertions.
"""

from __future__ import annotations

import argparse
import json
import math
import statistics
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PLANTS = ("DTG", "FaultInjector", "Aircraft", "HRG", "PitchController")


def measure(fmu: str, steps: int, warmup: int) -> dict:
    """Time instantiate, initialisation and ``steps`` host steps of ``fmu`` (this process)."""
    from fmpy import extract, read_model_description
    from fmpy.fmi2 import FMU2Slave

    unzipdir = extract(fmu)
    md = read_model_description(unzipdir)
    h = md.defaultExperiment.stepSize if md.defaultExperiment else 1e-3
    h = float(h) if h else 1e-3
    in_vr = [v.valueReference for v in md.modelVariables
             if v.causality == "input" and v.type == "Real"]
    out_vr = [v.valueReference for v in md.modelVariables
              if v.causality == "output" and v.type == "Real"]
    slave = FMU2Slave(guid=md.guid, unzipDirectory=unzipdir,
                      modelIdentifier=md.coSimulation.modelIdentifier, instanceName="bench")
    t0, c0 = time.perf_counter(), time.process_time()
    slave.instantiate()
    instantiate_s = time.perf_counter() - t0
    instantiate_cpu_s = time.process_time() - c0
    slave.setupExperiment(startTime=0.0)
    t0 = time.perf_counter()
    slave.enterInitializationMode()
    slave.exitInitializationMode()
    initialise_s = time.perf_counter() - t0
    # small, slowly varying inputs: rates of 0.01 rad/s, voltages of 0.01 V, ...
    n = warmup + steps
    rows = [[0.01 * math.sin(2 * math.pi * 0.5 * k * h + i) for i in range(len(in_vr))]
            for k in range(n)]
    per_step = []
    t = 0.0
    for k in range(n):
        s0 = time.perf_counter()
        if in_vr:
            slave.setReal(in_vr, rows[k])
        slave.doStep(currentCommunicationPoint=t, communicationStepSize=h)
        slave.getReal(out_vr)
        s1 = time.perf_counter()
        t = (k + 1) * h
        if k >= warmup:
            per_step.append(s1 - s0)
    slave.terminate()
    slave.freeInstance()
    return {"model": md.modelName, "step_size_s": h, "step_us": 1e6 * statistics.median(per_step),
            "instantiate_s": instantiate_s, "instantiate_cpu_s": instantiate_cpu_s,
            "initialise_s": initialise_s}


def _fresh(fmu: str, steps: int, warmup: int) -> dict:
    out = subprocess.run([sys.executable, __file__, "--child", fmu, "--steps", str(steps),
                          "--warmup", str(warmup)], capture_output=True, text=True,
                         check=True, timeout=3600)
    return json.loads(out.stdout.strip().splitlines()[-1])


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--steps", type=int, default=5000, help="timed steps per round")
    ap.add_argument("--warmup", type=int, default=500, help="untimed steps first")
    ap.add_argument("--rounds", type=int, default=3, help="fresh processes per FMU")
    ap.add_argument("--plants", nargs="*", default=list(PLANTS), choices=PLANTS)
    ap.add_argument("--fmu", nargs="*", default=[], metavar="NAME=PATH",
                    help="extra FMUs to measure alongside, e.g. DTG-old=/tmp/DTG.fmu")
    ap.add_argument("--fmu-dir", type=Path, default=ROOT / "build" / "fmus")
    ap.add_argument("--child", help=argparse.SUPPRESS)
    a = ap.parse_args(argv)
    if a.child:
        print(json.dumps(measure(a.child, a.steps, a.warmup)))
        return 0
    if a.fmu_dir == ROOT / "build" / "fmus":
        sys.path.insert(0, str(ROOT))
        import build_fmu

        stale = build_fmu.stale_fmus(a.fmu_dir, list(a.plants))
        if stale:
            print(f"building {', '.join(stale)} into {a.fmu_dir}", flush=True)
            subprocess.run([sys.executable, str(ROOT / "build_fmu.py"), "--out",
                            str(a.fmu_dir), *stale], check=True, cwd=ROOT,
                           capture_output=True, timeout=3600)
    fmus = {name: str(a.fmu_dir / f"{name}.fmu") for name in a.plants}
    for spec in a.fmu:
        name, _, path = spec.partition("=")
        if not path:
            ap.error(f"--fmu wants NAME=PATH, got {spec!r}")
        fmus[name] = path
    results: dict[str, list[dict]] = {name: [] for name in fmus}
    for _ in range(a.rounds):
        for name, path in fmus.items():
            results[name].append(_fresh(path, a.steps, a.warmup))
    print(f"{'FMU':<18} {'step h':>8} {'µs/step':>9} {'inst. s':>8} {'inst. CPU s':>11} "
          f"{'init s':>7}   (medians of {a.rounds} fresh processes, {a.steps} steps each)")
    for name, runs in results.items():
        def med(key: str, runs: list[dict] = runs) -> float:
            return statistics.median(r[key] for r in runs)
        print(f"{name:<18} {runs[0]['step_size_s']:>8g} {med('step_us'):>9.1f} "
              f"{med('instantiate_s'):>8.3f} {med('instantiate_cpu_s'):>11.3f} "
              f"{med('initialise_s'):>7.3f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
