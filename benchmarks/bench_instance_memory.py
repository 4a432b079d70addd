"""Memory per instance: instantiate and free each FMU many times in one process.

::

    .venv/bin/python benchmarks/bench_instance_memory.py [--cycles 1000] [--warmup 100]
        [--steps 10] [--fmu-dir build/fmus] [--keep-states] [NAME ...]

Issue 37's host: one process per FMU (tests/_instance_cycles_runner.py) loads the binary
once and runs ``--cycles`` cycles of instantiate, initialise, ``--steps`` doSteps, FMU
state get/serialize/free, one more state left for fmi2FreeInstance (a host that forgets
its states; ``--keep-states`` leaves that out), terminate and free, after ``--warmup``
cycles. Prints, per FMU, the growth of the resident set size per cycle (the target:
at most 5 KB), the objects the garbage collector tracks per cycle, the time per cycle
and the length of ``sys.path`` before and after. FMUs in ``--fmu-dir`` are rebuilt first
if older than their sources.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
RUNNER = ROOT / "tests" / "_instance_cycles_runner.py"
FMUS = ("FaultInjector", "HRG", "Aircraft", "PitchController", "DTG", "Diagnoser")
TARGET_KB = 5.0


def measure(fmu: Path, cycles: int, warmup: int, steps: int, forget: bool) -> dict:
    """One FMU's figures (the runner's JSON line), in a fresh process."""
    with tempfile.TemporaryDirectory(prefix="gd-cycles-") as work:
        cmd = [sys.executable, str(RUNNER), str(fmu), work, "--cycles", str(cycles),
               "--warmup", str(warmup), "--steps", str(steps)]
        proc = subprocess.run(cmd + (["--forget-state"] if forget else []),
                              capture_output=True, text=True, timeout=7200)
    lines = [ln for ln in proc.stdout.splitlines() if ln.startswith("{")]
    if proc.returncode != 0 or not lines:
        raise RuntimeError(f"{fmu.stem}: runner failed (exit {proc.returncode}):\n"
                           f"{proc.stderr[-3000:]}")
    return json.loads(lines[-1])


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("names", nargs="*", help=f"FMUs (default: {' '.join(FMUS)})")
    parser.add_argument("--cycles", type=int, default=1000)
    parser.add_argument("--warmup", type=int, default=100)
    parser.add_argument("--steps", type=int, default=10)
    parser.add_argument("--fmu-dir", type=Path, default=ROOT / "build" / "fmus")
    parser.add_argument("--keep-states", action="store_true",
                        help="free every FMU state before fmi2FreeInstance")
    args = parser.parse_args(argv)
    if args.fmu_dir.resolve() == (ROOT / "build" / "fmus").resolve():
        sys.path.insert(0, str(ROOT))
        import build_fmu

        build_fmu.rebuild_stale(args.fmu_dir, args.names or None)
    print(f"{args.cycles} cycles after {args.warmup} (instantiate, initialise, "
          f"{args.steps} steps, states{'' if args.keep_states else ' + one forgotten'}, "
          "terminate, free); target <= 5 KB per cycle")
    print(f"{'FMU':16} {'KB/cycle':>9} {'objects/cycle':>14} {'ms/cycle':>9} "
          f"{'sys.path':>10}  verdict")
    failed = 0
    for name in args.names or FMUS:
        r = measure(args.fmu_dir / f"{name}.fmu", args.cycles, args.warmup, args.steps,
                    not args.keep_states)
        ok = r["kb_per_cycle"] <= TARGET_KB
        failed += not ok
        print(f"{name:16} {r['kb_per_cycle']:9.2f} {r['objects_per_cycle']:14.2f} "
              f"{1e3 * r['s_per_cycle']:9.1f} {r['sys_path'][0]:>4} -> {r['sys_path'][1]:<4} "
              f"{'OK' if ok else 'ABOVE TARGET'}", flush=True)
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
