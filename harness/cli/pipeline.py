"""The main job: build the FMUs, learn the DTG signatures, verify every seed scenario.

``python -m gyrodiag_harness all [--out DIR] [--scenarios scenarios] [--fmu-dir build/fmus]
[--no-build] [--workers N] [--exact-signals] [--keep-training-signals] [--no-progress]``
does, in order (``OUT`` is ``--out`` or a new ``results/all-<time>/``, with
``results/latest`` pointing to it):

1. ``build_fmu.py --out FMU_DIR`` in a fresh process (skipped with ``--no-build``);
2. ``learn-signatures`` on ``SCENARIOS/training`` → ``OUT/dtg_signatures.json`` (the
   DTG fault scenarios of the paper's rule load it through their
   ``${out}/dtg_signatures.json`` file parameter), and on ``SCENARIOS/training/patterns``
   → ``OUT/dtg_patterns.json`` (the pattern classifier's library, read by the
   ``dtg_pattern_*`` scenarios).  The training runs are learned from in memory; once
   the libraries are written only their ``run.json`` stays in ``OUT/training/`` (each
   run's feature is in the library; their signals, 66 runs at 1 kHz, would be more than
   all the rest of the results), unless ``--keep-training-signals``;
3. ``verify`` of every ``SCENARIOS/*.toml`` → ``OUT/<name>/``, ``OUT/junit.xml``,
   ``OUT/report.html``;
4. the seed aircraft's isolability report → ``OUT/isolability.html`` and ``.txt``.

Exit status 0 when every scenario passed, 1 when anything failed (build, training,
a run, an expectation), 2 on invalid scenario files, 130 when stopped by Ctrl-C or
SIGTERM (during verification the report is written with what was saved).
"""

from __future__ import annotations

import argparse
import json
import logging
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

from gyrodiag_harness.campaigns.signatures import (
    check_training_scenarios,
    learn_pattern_library,
    learn_signatures,
)
from gyrodiag_harness.cli.common import (
    EXIT_FAILED,
    EXIT_INTERRUPTED,
    EXIT_OK,
    add_exact_signals,
    add_workers,
    new_results_folder,
    signals_precision,
    verify_and_report,
)
from gyrodiag_harness.cosim.batch import load_all, run_all
from gyrodiag_harness.cosim.interrupt import BatchInterrupted
from gyrodiag_harness.cosim.results import SIGNALS_FILE, drop_signals
from gyrodiag_harness.cosim.scenario import RESULTS_PREFIX
from gyrodiag_harness.verification.isolability import render, seed_isolability_report, write

log = logging.getLogger("gyrodiag_harness.cli")

REPO_ROOT = Path(__file__).resolve().parents[2]


def add_parser(sub: Any) -> None:
    """Register ``all`` on the CLI's sub-parsers."""
    p = sub.add_parser(
        "all", help="build the FMUs, learn the DTG signatures, verify every seed scenario "
                    "and write the report")
    p.add_argument("--out", type=Path, default=None,
                   help="results folder (default: a new results/all-<time>/, "
                        "results/latest points to it)")
    p.add_argument("--scenarios", type=Path, default=REPO_ROOT / "scenarios",
                   help="folder of the seed scenarios (training runs in its training/)")
    p.add_argument("--fmu-dir", type=Path, default=REPO_ROOT / "build" / "fmus",
                   help="where the FMUs are built and taken from")
    p.add_argument("--no-build", action="store_true", help="use the FMUs already built")
    add_workers(p)
    add_exact_signals(p)
    p.add_argument("--keep-training-signals", action="store_true",
                   help="keep the signals of the DTG training runs in OUT/training/ "
                        "(default: only their run.json once the libraries are learned)")
    p.add_argument("--no-progress", action="store_true", help="no progress bars")
    p.set_defaults(func=cmd_all)


def build_fmus(fmu_dir: Path) -> int:
    """Run build_fmu.py in a fresh process (the builder imports the model scripts)."""
    script = REPO_ROOT / "build_fmu.py"
    if not script.exists():
        log.error("%s not found: 'all' needs a source checkout of gyrodiag", script)
        return 1
    return subprocess.run([sys.executable, str(script), "--out", str(fmu_dir)],
                          cwd=REPO_ROOT, timeout=1800).returncode


def _drop_training_signals(folder: Path, scenarios: list[Any]) -> None:
    """Keep only run.json of the training runs the libraries were learned from."""
    reason = ("harness all learned the DTG libraries from this run in memory and keeps "
              "only its outcome (the library records the run's feature); "
              "--keep-training-signals or learn-signatures --runs-out DIR keep signals")
    freed = 0
    for s in scenarios:
        run = folder / s.name
        if (run / SIGNALS_FILE).is_file():
            freed += (run / SIGNALS_FILE).stat().st_size
            drop_signals(run, reason)
    log.info("  training runs: signals not kept (%.1f MB; --keep-training-signals keeps "
             "them), run.json of each in %s", freed / 1e6, folder)


def _reads_results(scenario: Any) -> bool:
    """The scenario takes a file from the results folder (``${out}/``, e.g. a library
    learned by this job)."""
    return any(str(spec).startswith(RESULTS_PREFIX)
               for inst in scenario.fmus.values() for spec in inst.files.values())


def cmd_all(args: argparse.Namespace) -> int:
    t0 = time.perf_counter()
    training_dir = args.scenarios / "training"
    patterns_dir = training_dir / "patterns"
    # every file is read first: an invalid one stops the job before anything is built
    training, patterns, scenarios = _load_inputs(args.scenarios, training_dir, patterns_dir)
    out: Path = args.out if args.out is not None else new_results_folder("all")
    out.mkdir(parents=True, exist_ok=True)
    log.info("results: %s", out)
    progress = not args.no_progress
    if not args.no_build:
        log.info("== building the FMUs into %s", args.fmu_dir)
        if build_fmus(args.fmu_dir) != 0:
            log.error("building the FMUs failed")
            return EXIT_FAILED

    # Scenarios that read nothing from the results folder (the learned libraries) run in
    # the same batch as the training runs: one batch tail less on a machine of few cores.
    # (without training runs nothing is learned here: every scenario goes first, and a
    # file one of them reads must be there already, checked before anything runs)
    learns = bool(training or patterns)
    free = [sc for sc in scenarios if not (learns and _reads_results(sc))]
    waiting = [sc for sc in scenarios if learns and _reads_results(sc)]
    first = [*training, *patterns, *free]
    outs = [out / "training"] * (len(training) + len(patterns)) + [out] * len(free)
    stop: BatchInterrupted | None = None
    if training or patterns:
        log.info("== learning the DTG fault signatures from %s and patterns from %s, and "
                 "running the %d seed scenarios that do not read them", training_dir,
                 patterns_dir, len(free))
    else:
        log.info("== verifying the seed scenarios in %s", args.scenarios)
    try:
        first_runs = run_all(first, outs, args.fmu_dir, progress, workers=args.workers,
                             results_dir=out, precision=signals_precision(args))
    except BatchInterrupted as exc:
        if training or patterns:
            log.warning("stopped by %s while learning the signatures and patterns; runs "
                        "saved in %s", exc.reason, out)
            return EXIT_INTERRUPTED
        stop, first_runs = exc, exc.results
    n_train = len(training) + len(patterns)
    train_runs, free_runs = first_runs[:len(training)], first_runs[n_train:]
    pattern_runs = first_runs[len(training):n_train]
    if stop is None and training and not _learn_signatures(out, training, train_runs):
        return EXIT_FAILED
    if stop is None and patterns and not _learn_patterns(out, patterns, pattern_runs):
        return EXIT_FAILED

    if (training or patterns) and not args.keep_training_signals:
        _drop_training_signals(out / "training", [*training, *patterns])

    results = list(free_runs)
    if stop is None and waiting:
        log.info("== verifying the seed scenarios that read the learned libraries")
        try:
            results += run_all(waiting, out, args.fmu_dir, progress, workers=args.workers,
                               precision=signals_precision(args))
        except BatchInterrupted as exc:
            stop = exc
            results += exc.results
    not_started = _not_started(stop, first_runs, waiting, results)
    status = verify_and_report(results, scenarios, out, None, None,
                               not_started=not_started,
                               interrupted_by=stop.reason if stop else None)
    if stop is not None:
        return status

    _write_isolability(out)
    log.info("== done in %.0f s: %s", time.perf_counter() - t0,
             "all scenarios passed" if status == EXIT_OK else "FAILURES, see above")
    return status


def _load_inputs(scenario_dir: Path, training_dir: Path, patterns_dir: Path
                 ) -> tuple[list[Any], list[Any], list[Any]]:
    """The training scenarios, the pattern training scenarios (both checked as training
    sets; empty without their folder) and the seed scenarios, all loaded first."""
    training = load_all([training_dir]) if training_dir.is_dir() else []
    if training:
        check_training_scenarios(training)
    patterns = load_all([patterns_dir]) if patterns_dir.is_dir() else []
    if patterns:
        check_training_scenarios(patterns)
    return training, patterns, load_all([scenario_dir])


def _learn_signatures(out: Path, training: list[Any], train_runs: list[Any]) -> bool:
    """Learn the DTG signature library from the training runs into
    ``out/dtg_signatures.json``; False (logged) if a run or the learning failed."""
    if any(r.error is not None for r in train_runs):
        log.error("a training run failed")
        return False
    try:
        library = learn_signatures(training, train_runs)
    except (ValueError, KeyError) as exc:
        log.error("learning the signatures failed: %s", exc)
        return False
    library.write(out / "dtg_signatures.json")
    for name, sig in library.signatures.items():
        log.info("  signature %s %s: C = %s", library.codes[name], name, sig.tolist())
    return True


def _learn_patterns(out: Path, patterns: list[Any], pattern_runs: list[Any]) -> bool:
    """Learn the DTG pattern library from the pattern runs into ``out/dtg_patterns.json``;
    False (logged) if a run or the learning failed."""
    if any(r.error is not None for r in pattern_runs):
        log.error("a pattern training run failed")
        return False
    try:
        _, content = learn_pattern_library(patterns, pattern_runs)
    except (ValueError, KeyError) as exc:
        log.error("learning the patterns failed: %s", exc)
        return False
    (out / "dtg_patterns.json").write_text(json.dumps(content, indent=1) + "\n",
                                           encoding="utf-8")
    log.info("  %d classes -> %s", len(content["patterns"]["classes"]),
             out / "dtg_patterns.json")
    return True


def _not_started(stop: BatchInterrupted | None, first_runs: list[Any], waiting: list[Any],
                 results: list[Any]) -> list[str]:
    """Names of the scenarios a stop left unstarted (logged with the count saved)."""
    not_started: list[str] = []
    if stop is not None:
        not_started = list(stop.not_started)
        if stop.results is first_runs:  # stopped in the first batch: none of the rest ran
            not_started += [sc.name for sc in waiting]
        log.warning("stopped by %s: %d run(s) saved, %d not started", stop.reason,
                    len(results), len(not_started))
    return not_started


def _write_isolability(out: Path) -> None:
    """The seed aircraft's isolability report beside the results (HTML and text)."""
    report = seed_isolability_report()
    write(out / "isolability.html", report, "html")
    (out / "isolability.txt").write_text(render(report, "text"), encoding="utf-8")
    log.info("isolability report: %s", out / "isolability.html")
