"""Call-sequence fuzzer, long run: thousands of random FMI call sequences per FMU.

::

    .venv/bin/python benchmarks/bench_call_sequences.py [--sequences 2000] [--steps 40]
        [--fmu-dir build/fmus] [NAME ...]

Runs tests/_fmi_fuzz_runner.py (a Hypothesis rule-based state machine on a raw ctypes
host, issue 37 item 2) once per FMU in a fresh process, with random sequences (the suite
runs 50 fixed ones per FMU), and prints per FMU the sequences and calls made, how many
were legal and illegal, the legal calls the FMU refused with a message (a parameter out
of range, a step of no whole number of samples), the legal doSteps, fmi2Fatal returns,
and the outcome: "OK", the property that failed, or the call in which the process died.
FMUs in ``--fmu-dir`` are rebuilt first if older than their sources.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
RUNNER = ROOT / "tests" / "_fmi_fuzz_runner.py"
FMUS = ("FaultInjector", "HRG", "Aircraft", "PitchController", "DTG", "Diagnoser")


def fuzz(fmu: Path, sequences: int, steps: int) -> tuple[dict, str, float]:
    """The runner's summary (or a stand-in if it died), the outcome, the wall time."""
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="gd-fuzz-") as work:
        proc = subprocess.run([sys.executable, str(RUNNER), str(fmu), work, "--sequences",
                               str(sequences), "--steps", str(steps)],
                              capture_output=True, text=True, timeout=36000)
        trace = Path(work) / "sequence.log"
        last = trace.read_text().splitlines()[-1:] if trace.exists() else []
    seconds = time.perf_counter() - t0
    lines = [ln for ln in proc.stdout.splitlines() if ln.startswith("{")]
    if not lines:
        return {}, f"DIED (exit {proc.returncode}) in {last}", seconds
    summary = json.loads(lines[-1])
    if summary["failure"]:
        sys.stderr.write(proc.stderr[-8000:])
        return summary, f"FAILED: {summary['failure'][:200]}", seconds
    return summary, "OK", seconds


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("names", nargs="*", help=f"FMUs (default: {' '.join(FMUS)})")
    parser.add_argument("--sequences", type=int, default=2000)
    parser.add_argument("--steps", type=int, default=40, help="calls per sequence at most")
    parser.add_argument("--fmu-dir", type=Path, default=ROOT / "build" / "fmus")
    args = parser.parse_args(argv)
    if args.fmu_dir.resolve() == (ROOT / "build" / "fmus").resolve():
        sys.path.insert(0, str(ROOT))
        import build_fmu

        build_fmu.rebuild_stale(args.fmu_dir, args.names or None)
    print(f"{args.sequences} random sequences per FMU, up to {args.steps} calls each")
    print(f"{'FMU':16} {'sequences':>9} {'calls':>7} {'legal':>6} {'illegal':>7} "
          f"{'refused':>7} {'steps':>6} {'fatal':>5} {'s':>6}  outcome")
    bad = 0
    for name in args.names or FMUS:
        s, outcome, seconds = fuzz(args.fmu_dir / f"{name}.fmu", args.sequences, args.steps)
        bad += outcome != "OK"
        steps = s.get("calls_by_kind", {}).get("fmi2DoStep legal 0", 0)
        print(f"{name:16} {s.get('sequences', 0):9} {s.get('calls', 0):7} "
              f"{s.get('legal', 0):6} {s.get('illegal', 0):7} {s.get('legal refused', 0):7} "
              f"{steps:6} {s.get('status 4', 0):5} {seconds:6.0f}  {outcome}", flush=True)
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
