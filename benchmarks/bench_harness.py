"""Real-time factor of every seed scenario, and the master's overhead vs fmpy.

Usage::

    .venv/bin/python benchmarks/bench_harness.py [--scenarios scenarios/*.toml]
        [--overhead-steps 20000]

Prints, in one run:

* for each seed scenario (default: ``scenarios/*.toml``): simulated time, wall time and
  real-time factor RTF = simulated / wall (> 1: faster than real time), each scenario
  in its own fresh process (docs/methods.md §6.11);
* the master's overhead on a single FMU: the Aircraft FMU alone (noise on, 10 ms step)
  through ``harness.run_scenario`` and through ``fmpy.simulate_fmu`` with the same
  step and duration, recording the same outputs, each in a fresh process; the ratio
  and the difference per step.

Figures only, no assertions. FMUs are taken from ``build/fmus`` (built first if any is
missing or older than its sources). Scenarios that read a file produced at run time
(``${out}/dtg_signatures.json``: the DTG fault scenarios) get it from a
``learn-signatures`` run into a temporary results folder first (its time is printed, not
counted in the scenarios' figures).
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import subprocess
import sys
import tempfile
import textwrap
import time
from collections.abc import Callable
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
FMU_DIR = ROOT / "build" / "fmus"

_SCENARIO_RUNNER = textwrap.dedent(
    """
    import json, os, sys, time
    from gyrodiag_harness import load_scenario, run_scenario
    s = load_scenario(sys.argv[1])
    results_dir = sys.argv[3] if len(sys.argv) > 3 else None
    t0 = time.perf_counter()
    r = run_scenario(s, fmu_dir=sys.argv[2], progress=False, results_dir=results_dir)
    wall = time.perf_counter() - t0
    print(json.dumps({"name": s.name, "sim_s": s.duration_s, "wall_s": wall,
                      "steps": s.n_steps, "error": r.error}))
    sys.stdout.flush()
    os._exit(0)
    """
)

_FMPY_RUNNER = textwrap.dedent(
    """
    import json, os, sys, time
    from fmpy import simulate_fmu
    fmu, step, stop = sys.argv[1], float(sys.argv[2]), float(sys.argv[3])
    outputs = json.loads(sys.argv[4])
    t0 = time.perf_counter()
    simulate_fmu(fmu, stop_time=stop, output_interval=step, step_size=step,
                 output=outputs, start_values={"noise_std_q": 1e-3})
    print(json.dumps({"wall_s": time.perf_counter() - t0}))
    sys.stdout.flush()
    os._exit(0)
    """
)


def _run_json(code: str, *args: str) -> dict:
    proc = subprocess.run(
        [sys.executable, "-c", code, *args], cwd=ROOT, capture_output=True, text=True,
        timeout=3600,
    )
    lines = [ln for ln in proc.stdout.splitlines() if ln.startswith("{")]
    if proc.returncode != 0 or not lines:
        raise RuntimeError(f"benchmark run failed ({proc.returncode}):\n{proc.stderr[-2000:]}")
    return json.loads(lines[-1])


def build_fmus() -> None:
    """Build the FMUs if any is missing or older than its sources (fresh process)."""
    spec = importlib.util.spec_from_file_location("gd_build_fmu_bench", ROOT / "build_fmu.py")
    builder = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(builder)
    stale = builder.stale_fmus(FMU_DIR)
    if stale:
        print(f"building the FMUs ({', '.join(stale)}) into {FMU_DIR}", flush=True)
        subprocess.run([sys.executable, str(ROOT / "build_fmu.py"), "--out", str(FMU_DIR)],
                       cwd=ROOT, check=True, capture_output=True, timeout=3600)


#: Run-time files the seed scenarios read through ``${out}/``, and the training set each
#: is learned from.
RECIPES = {"dtg_signatures.json": ROOT / "scenarios" / "training",
           "dtg_patterns.json": ROOT / "scenarios" / "training" / "patterns"}


def _learn_signatures(results: Path, name: str = "dtg_signatures.json") -> None:
    subprocess.run([sys.executable, "-m", "gyrodiag_harness", "learn-signatures",
                    str(RECIPES[name]), "--out", str(results / name), "--fmu-dir",
                    str(FMU_DIR), "--no-progress", "-q"], cwd=ROOT, check=True, timeout=3600)


def prepare_results(paths: list[str], results: Path,
                    learn: Callable[[Path, str], None] = _learn_signatures) -> None:
    """Provide in ``results`` the run-time files that the scenarios name through
    ``${out}/`` (the DTG signature and pattern libraries, learned from
    scenarios/training and scenarios/training/patterns)."""
    from gyrodiag_harness.cosim.scenario import RESULTS_PREFIX, load_scenario

    needed = {spec[len(RESULTS_PREFIX):] for p in paths
              for inst in load_scenario(p).fmus.values() for spec in inst.files.values()
              if spec.startswith(RESULTS_PREFIX)}
    unknown = needed - set(RECIPES)
    if unknown:
        raise RuntimeError(f"no recipe for the run-time files {sorted(unknown)}")
    for name in sorted(needed):
        t0 = time.perf_counter()
        learn(results, name)
        print(f"({name} learned for the scenarios that read it in "
              f"{time.perf_counter() - t0:.0f} s)")


def seed_scenarios(paths: list[str], results: Path) -> None:
    print("Seed scenarios (each in a fresh process)")
    print(f"{'scenario':40s} {'sim s':>8s} {'wall s':>8s} {'RTF':>8s} {'us/step':>9s}")
    for path in paths:
        r = _run_json(_SCENARIO_RUNNER, path, str(FMU_DIR), str(results))
        rtf = r["sim_s"] / r["wall_s"]
        per_step = 1e6 * r["wall_s"] / max(r["steps"], 1)
        flag = "" if r["error"] is None else "  (run error)"
        print(f"{r['name']:40s} {r['sim_s']:8.1f} {r['wall_s']:8.2f} {rtf:8.2f} "
              f"{per_step:9.1f}{flag}")


def master_overhead(steps: int) -> None:
    step, stop = 0.01, steps * 0.01
    outputs = ["y_v", "y_alpha", "y_q", "y_theta", "y_gamma", "y_h"]
    scenario = textwrap.dedent(
        f"""
        name = "bench_aircraft_alone"
        duration_s = {stop}
        step_s = {step}
        [fmus.aircraft]
        fmu = "Aircraft"
        parameters = {{ noise_std_q = 1e-3 }}
        [record]
        variables = {json.dumps(["aircraft." + o for o in outputs])}
        """
    )
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "bench_aircraft_alone.toml"
        path.write_text(scenario)
        ours = _run_json(_SCENARIO_RUNNER, str(path), str(FMU_DIR))
    theirs = _run_json(_FMPY_RUNNER, str(FMU_DIR / "Aircraft.fmu"), str(step), str(stop),
                       json.dumps(outputs))
    print(f"\nMaster overhead, Aircraft.fmu alone, {steps} steps of {step} s, 6 outputs")
    print(f"  harness.run_scenario : {ours['wall_s']:.3f} s "
          f"({1e6 * ours['wall_s'] / steps:.1f} us/step)")
    print(f"  fmpy.simulate_fmu    : {theirs['wall_s']:.3f} s "
          f"({1e6 * theirs['wall_s'] / steps:.1f} us/step)")
    print(f"  ratio harness / fmpy : {ours['wall_s'] / theirs['wall_s']:.2f}; "
          f"difference {1e6 * (ours['wall_s'] - theirs['wall_s']) / steps:+.1f} us/step")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenarios", nargs="*", default=None,
                        help="scenario files (default: scenarios/*.toml)")
    parser.add_argument("--overhead-steps", type=int, default=20000)
    args = parser.parse_args(argv)
    paths = args.scenarios
    if paths is None:
        paths = [str(p) for p in sorted((ROOT / "scenarios").glob("*.toml"))]
    build_fmus()
    if paths:
        with tempfile.TemporaryDirectory(prefix="bench-harness-") as tmp:
            prepare_results(paths, Path(tmp))
            seed_scenarios(paths, Path(tmp))
    else:
        print("no seed scenarios found under scenarios/")
    master_overhead(args.overhead_steps)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
