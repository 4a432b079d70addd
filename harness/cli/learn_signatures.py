"""``python -m harness learn-signatures``: run DTG training scenarios, write the library.

See :mod:`harness.campaigns.signatures` for how the signatures are learned.
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path
from typing import Any

from harness.campaigns.signatures import (
    DEFAULT_WINDOW_S,
    SignatureLibrary,
    check_training_scenarios,
    is_pattern_training,
    learn_pattern_library,
    learn_signatures,
)
from harness.cli.common import EXIT_FAILED, EXIT_OK, EXIT_USAGE
from harness.cosim.batch import load_all, run_all
from harness.cosim.results import RunResult


def add_parser(sub: Any) -> None:
    """Register ``learn-signatures`` on the CLI's sub-parsers."""
    p = sub.add_parser(
        "learn-signatures",
        help="run DTG training scenarios and write the fault-signature library (JSON)")
    p.add_argument("scenarios", nargs="+", metavar="SCENARIO", type=Path,
                   help="training scenario .toml files (with a [training] table) or folders")
    p.add_argument("--out", type=Path, required=True, metavar="FILE.json",
                   help="signature library to write")
    p.add_argument("--runs-out", type=Path, default=None, metavar="DIR",
                   help="folder of the training runs (default: <folder of FILE>/training)")
    p.add_argument("--window-s", type=float, default=DEFAULT_WINDOW_S,
                   help=f"final window whose median feature describes a run, s "
                        f"(default {DEFAULT_WINDOW_S}; 0: last sample)")
    p.add_argument("--saved", action="store_true",
                   help="learn from the runs saved in --runs-out, run nothing")
    p.add_argument("--fmu-dir", type=Path, default=None, help="folder of the .fmu files")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.set_defaults(func=cmd_learn_signatures)


def cmd_learn_signatures(args: argparse.Namespace) -> int:
    """``learn-signatures``: exit 0 written, 1 a run failed or did not alarm, 2 usage."""
    if not (math.isfinite(args.window_s) and args.window_s >= 0):
        print(f"error: --window-s must be >= 0, got {args.window_s}", file=sys.stderr)
        return EXIT_USAGE
    scenarios = load_all(args.scenarios)
    check_training_scenarios(scenarios)
    runs_dir: Path = args.runs_out or args.out.parent / "training"
    if args.saved:
        results = [RunResult.load(runs_dir / s.name) for s in scenarios]
    else:
        results = run_all(scenarios, runs_dir, args.fmu_dir, not args.no_progress)
    if is_pattern_training(scenarios):
        return _write_patterns(scenarios, results, args.out)
    try:
        lib = learn_signatures(scenarios, results, args.window_s)
    except (ValueError, KeyError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return EXIT_FAILED
    lib.write(args.out)
    _print_library(lib)
    print(f"signature library: {args.out}")
    return EXIT_OK


def _write_patterns(scenarios: Any, results: Any, out: Path) -> int:
    """Learn and write a pattern library (pattern training set)."""
    import json

    try:
        lib, content = learn_pattern_library(scenarios, results)
    except (ValueError, KeyError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return EXIT_FAILED
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(content, indent=1) + "\n", encoding="utf-8")
    for run in content["training"]["runs"]:
        mark = "" if run["classified"] == run["class"] else f"  <- classified {run['classified']!r}"
        print(f"  run {run['scenario']}: class {run['class']}, size {run['size']:g}, "
              f"distance {run['distance']:.2f}{mark}")
    for i, c in enumerate(lib.classes, start=1):
        print(f"class {i} {c.name} ({c.type}, {c.signal or 'physical'}): response "
              + ", ".join(f"{v:.3g}" for v in c.response))
    print(f"growth threshold {lib.growth_threshold:.3f}, max distance "
          f"{lib.max_distance if lib.max_distance is None else round(lib.max_distance, 2)}")
    print(f"pattern library: {out}")
    return EXIT_OK


def _print_library(lib: SignatureLibrary) -> None:
    for r in lib.runs:
        label, d = lib.classify(r.feature)
        mark = "" if label == r.signature else f"  <- nearest is {label!r}"
        dist = ", ".join(f"{n} {v:.1f}" for n, v in d.items())
        print(f"  run {r.scenario}: class {r.signature}, C = {r.feature.tolist()} "
              f"(axis {r.axes}, {r.n_samples} samples; d: {dist}){mark}")
    names = list(lib.signatures)
    for n in names:
        print(f"signature {lib.codes[n]} {n}: C = {lib.signatures[n].tolist()}")
    dist = lib.distances()
    width = max(len(n) for n in names)
    print("eq. 7 distances between the signatures:")
    print(f"  {'':>{width}}  " + "  ".join(f"{n:>{width}}" for n in names))
    for i, n in enumerate(names):
        print(f"  {n:>{width}}  " + "  ".join(f"{dist[i, j]:>{width}.2f}"
                                             for j in range(len(names))))
