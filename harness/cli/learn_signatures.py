"""``python -m gyrodiag_harness learn-signatures``: run DTG training scenarios, write the library.

See :mod:`gyrodiag_harness.campaigns.signatures` for how the signatures are learned.
"""

from __future__ import annotations

import argparse
import logging
import math
from pathlib import Path
from typing import Any

from gyrodiag_harness.campaigns.signatures import (
    DEFAULT_WINDOW_S,
    SignatureLibrary,
    check_training_scenarios,
    is_pattern_training,
    learn_pattern_library,
    learn_signatures,
)
from gyrodiag_harness.cli.common import (
    EXIT_FAILED,
    EXIT_INTERRUPTED,
    EXIT_OK,
    EXIT_USAGE,
    add_exact_signals,
    add_workers,
    new_results_folder,
    signals_precision,
)
from gyrodiag_harness.cosim.batch import load_all, run_all
from gyrodiag_harness.cosim.interrupt import BatchInterrupted
from gyrodiag_harness.cosim.results import RunResult

log = logging.getLogger("gyrodiag_harness.cli")


def add_parser(sub: Any) -> None:
    """Register ``learn-signatures`` on the CLI's sub-parsers."""
    p = sub.add_parser(
        "learn-signatures",
        help="run DTG training scenarios and write the fault-signature library (JSON)")
    p.add_argument("scenarios", nargs="+", metavar="SCENARIO", type=Path,
                   help="training scenario .toml files (with a [training] table) or folders")
    p.add_argument("--out", type=Path, default=None, metavar="FILE.json",
                   help="signature library to write (default: dtg_signatures.json in a new "
                        "results/learn-signatures-<time>/)")
    p.add_argument("--runs-out", type=Path, default=None, metavar="DIR",
                   help="folder of the training runs (default: <folder of FILE>/training)")
    p.add_argument("--window-s", type=float, default=DEFAULT_WINDOW_S,
                   help=f"final window whose median feature describes a run, s "
                        f"(default {DEFAULT_WINDOW_S}; 0: last sample)")
    p.add_argument("--saved", action="store_true",
                   help="learn from the runs saved in --runs-out, run nothing (runs saved "
                        "with float32 Real signals give signatures within 2**-24 "
                        "relative of the full-precision ones)")
    p.add_argument("--fmu-dir", type=Path, default=None, help="folder of the .fmu files")
    add_workers(p)
    add_exact_signals(p)
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.set_defaults(func=cmd_learn_signatures)


def cmd_learn_signatures(args: argparse.Namespace) -> int:
    """``learn-signatures``: exit 0 written, 1 a run failed or did not alarm, 2 usage."""
    if not (math.isfinite(args.window_s) and args.window_s >= 0):
        log.error("--window-s must be >= 0, got %s", args.window_s)
        return EXIT_USAGE
    scenarios = load_all(args.scenarios)
    check_training_scenarios(scenarios)
    if args.out is None:
        if args.saved and args.runs_out is None:
            log.error("--saved needs --runs-out or --out (where the saved runs are)")
            return EXIT_USAGE
        target: Path = new_results_folder("learn-signatures") / "dtg_signatures.json"
    else:
        target = args.out
    runs_dir: Path = args.runs_out or target.parent / "training"
    if args.saved:
        results = [RunResult.load(runs_dir / s.name) for s in scenarios]
    else:
        try:
            results = run_all(scenarios, runs_dir, args.fmu_dir, not args.no_progress,
                              workers=args.workers, results_dir=target.parent,
                              precision=signals_precision(args))
        except BatchInterrupted as stop:
            log.warning("stopped by %s: no library written; training runs saved in %s",
                        stop.reason, runs_dir)
            return EXIT_INTERRUPTED
    if is_pattern_training(scenarios):
        return _write_patterns(scenarios, results, target)
    try:
        lib = learn_signatures(scenarios, results, args.window_s)
    except (ValueError, KeyError) as exc:
        log.error("%s", exc)
        return EXIT_FAILED
    lib.write(target)
    _print_library(lib)
    log.info("signature library: %s", target)
    return EXIT_OK


def _write_patterns(scenarios: Any, results: Any, out: Path) -> int:
    """Learn and write a pattern library (pattern training set)."""
    import json

    try:
        lib, content = learn_pattern_library(scenarios, results)
    except (ValueError, KeyError) as exc:
        log.error("%s", exc)
        return EXIT_FAILED
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(content, indent=1) + "\n", encoding="utf-8")
    for run in content["training"]["runs"]:
        mark = "" if run["classified"] == run["class"] else f"  <- classified {run['classified']!r}"
        log.info("  run %s: class %s, size %g, distance %.2f%s", run["scenario"], run["class"],
                 run["size"], run["distance"], mark)
    for i, c in enumerate(lib.classes, start=1):
        log.info("class %d %s (%s, %s): response %s", i, c.name, c.type,
                 c.signal or "physical", ", ".join(f"{v:.3g}" for v in c.response))
    log.info("growth threshold %.3f, max distance %s", lib.growth_threshold,
             None if lib.max_distance is None else round(lib.max_distance, 2))
    log.info("pattern library: %s", out)
    return EXIT_OK


def _print_library(lib: SignatureLibrary) -> None:
    for r in lib.runs:
        label, d = lib.classify(r.feature)
        mark = "" if label == r.signature else f"  <- nearest is {label!r}"
        dist = ", ".join(f"{n} {v:.1f}" for n, v in d.items())
        log.info(f"  run {r.scenario}: class {r.signature}, C = {r.feature.tolist()} "
              f"(axis {r.axes}, {r.n_samples} samples; d: {dist}){mark}")
    names = list(lib.signatures)
    for n in names:
        log.info(f"signature {lib.codes[n]} {n}: C = {lib.signatures[n].tolist()}")
    dist = lib.distances()
    width = max(len(n) for n in names)
    log.info("eq. 7 distances between the signatures:")
    log.info(f"  {'':>{width}}  " + "  ".join(f"{n:>{width}}" for n in names))
    for i, n in enumerate(names):
        log.info(f"  {n:>{width}}  " + "  ".join(f"{dist[i, j]:>{width}.2f}"
                                             for j in range(len(names))))
