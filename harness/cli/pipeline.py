"""The main job: build the FMUs, learn the DTG signatures, verify every seed scenario.

``python -m harness all [--out results] [--scenarios scenarios] [--fmu-dir build/fmus]
[--no-build] [--no-progress]`` does, in order:

1. ``build_fmu.py --out FMU_DIR`` in a fresh process (skipped with ``--no-build``);
2. ``learn-signatures`` on ``SCENARIOS/training`` → ``OUT/dtg_signatures.json`` (the
   DTG fault scenarios of the paper's rule load it through their
   ``${out}/dtg_signatures.json`` file parameter), and on ``SCENARIOS/training/patterns``
   → ``OUT/dtg_patterns.json`` (the pattern classifier's library, read by the
   ``dtg_pattern_*`` scenarios);
3. ``verify`` of every ``SCENARIOS/*.toml`` → ``OUT/<name>/``, ``OUT/junit.xml``,
   ``OUT/report.html``;
4. the seed aircraft's isolability report → ``OUT/isolability.html`` and ``.txt``.

Exit status 0 when every scenario passed, 1 when anything failed (build, training,
a run, an expectation), 2 on invalid scenario files.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

from harness.campaigns.signatures import (
    check_training_scenarios,
    learn_pattern_library,
    learn_signatures,
)
from harness.cli.common import EXIT_FAILED, EXIT_OK, verify_and_report
from harness.cosim.batch import load_all, run_all
from harness.verification.isolability import render, seed_isolability_report, write

REPO_ROOT = Path(__file__).resolve().parents[2]


def add_parser(sub: Any) -> None:
    """Register ``all`` on the CLI's sub-parsers."""
    p = sub.add_parser(
        "all", help="build the FMUs, learn the DTG signatures, verify every seed scenario "
                    "and write the report")
    p.add_argument("--out", type=Path, default=Path("results"), help="results folder")
    p.add_argument("--scenarios", type=Path, default=REPO_ROOT / "scenarios",
                   help="folder of the seed scenarios (training runs in its training/)")
    p.add_argument("--fmu-dir", type=Path, default=REPO_ROOT / "build" / "fmus",
                   help="where the FMUs are built and taken from")
    p.add_argument("--no-build", action="store_true", help="use the FMUs already built")
    p.add_argument("--no-progress", action="store_true", help="no progress bars")
    p.set_defaults(func=cmd_all)


def build_fmus(fmu_dir: Path) -> int:
    """Run build_fmu.py in a fresh process (the builder imports the model scripts)."""
    script = REPO_ROOT / "build_fmu.py"
    if not script.exists():
        print(f"error: {script} not found: 'all' needs a source checkout of gyrodiag",
              file=sys.stderr)
        return 1
    return subprocess.run([sys.executable, str(script), "--out", str(fmu_dir)],
                          cwd=REPO_ROOT).returncode


def cmd_all(args: argparse.Namespace) -> int:
    t0 = time.perf_counter()
    out: Path = args.out
    out.mkdir(parents=True, exist_ok=True)
    progress = not args.no_progress
    if not args.no_build:
        print(f"== building the FMUs into {args.fmu_dir}", flush=True)
        if build_fmus(args.fmu_dir) != 0:
            print("error: building the FMUs failed", file=sys.stderr)
            return EXIT_FAILED

    training_dir = args.scenarios / "training"
    if training_dir.is_dir():
        print(f"== learning the DTG fault signatures from {training_dir}", flush=True)
        training = load_all([training_dir])
        check_training_scenarios(training)
        runs = run_all(training, out / "training", args.fmu_dir, progress)
        if any(r.error is not None for r in runs):
            print("error: a training run failed", file=sys.stderr)
            return EXIT_FAILED
        try:
            library = learn_signatures(training, runs)
        except (ValueError, KeyError) as exc:
            print(f"error: learning the signatures failed: {exc}", file=sys.stderr)
            return EXIT_FAILED
        library.write(out / "dtg_signatures.json")
        for name, sig in library.signatures.items():
            print(f"  signature {library.codes[name]} {name}: C = {sig.tolist()}")
    patterns_dir = training_dir / "patterns"
    if patterns_dir.is_dir():
        print(f"== learning the DTG fault patterns from {patterns_dir}", flush=True)
        training = load_all([patterns_dir])
        check_training_scenarios(training)
        runs = run_all(training, out / "training", args.fmu_dir, progress)
        if any(r.error is not None for r in runs):
            print("error: a pattern training run failed", file=sys.stderr)
            return EXIT_FAILED
        try:
            _, content = learn_pattern_library(training, runs)
        except (ValueError, KeyError) as exc:
            print(f"error: learning the patterns failed: {exc}", file=sys.stderr)
            return EXIT_FAILED
        (out / "dtg_patterns.json").write_text(json.dumps(content, indent=1) + "\n",
                                               encoding="utf-8")
        print(f"  {len(content['patterns']['classes'])} classes -> "
              f"{out / 'dtg_patterns.json'}")

    print(f"== verifying the seed scenarios in {args.scenarios}", flush=True)
    scenarios = load_all([args.scenarios])
    results = run_all(scenarios, out, args.fmu_dir, progress)
    status = verify_and_report(results, scenarios, out, None, None)

    report = seed_isolability_report()
    write(out / "isolability.html", report, "html")
    (out / "isolability.txt").write_text(render(report, "text"), encoding="utf-8")
    print(f"isolability report: {out / 'isolability.html'}")
    print(f"== done in {time.perf_counter() - t0:.0f} s: "
          f"{'all scenarios passed' if status == EXIT_OK else 'FAILURES, see above'}")
    return status
