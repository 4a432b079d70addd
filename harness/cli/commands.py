"""Command line of the harness: ``python -m gyrodiag_harness COMMAND``.

::

    python -m gyrodiag_harness run SCENARIO... [--out DIR] [--fmu-dir DIR] [--workers N]
                                      [--exact-signals]
    python -m gyrodiag_harness verify SCENARIO... [--out DIR] [--fmu-dir DIR] [--workers N]
                                         [--exact-signals] [--junit PATH] [--html PATH]
    python -m gyrodiag_harness report SCENARIO... [--out DIR] [--junit PATH] [--html PATH]
    python -m gyrodiag_harness list [DIR]
    python -m gyrodiag_harness all [--out DIR] [--scenarios DIR] [--fmu-dir DIR] [--no-build]
                          [--workers N] [--exact-signals]
    python -m gyrodiag_harness campaign SPEC.toml [--out DIR] [--workers N] [--dask local|ADDRESS]
                               [--timeout S] [--fraction F] [--group NAME]
                               [--condition NAME] [--report-only]
    python -m gyrodiag_harness campaign-summary DIR... --out DIR [--title TEXT]
    python -m gyrodiag_harness compare-results A B [--rtol R] [--atol A] [--max-diffs N]
    python -m gyrodiag_harness isolability [--out FILE] [--format text|json|html]
    python -m gyrodiag_harness learn-signatures SCENARIO... [--out FILE.json] [--runs-out DIR]
                                       [--window-s S] [--saved] [--fmu-dir DIR]
                                       [--exact-signals]
    python -m gyrodiag_harness export-csv RUN... [--out FILE]
    python -m gyrodiag_harness export-ssp SCENARIO --out FILE.ssp [--fmu-dir DIR] [--results DIR]
    python -m gyrodiag_harness schema [--markdown] [--campaign]

Every command takes ``-v`` (debug) and ``-q`` (warnings and errors only).

A SCENARIO argument is a ``.toml`` file or a folder (all its ``*.toml``, sorted).
Without ``--out``, ``run``, ``verify``, ``all`` and ``learn-signatures`` write into a
new folder ``results/<command>-<YYYYmmdd-HHMMSS>/`` and point ``results/latest`` to it,
so that no command overwrites another one's results; ``report`` reads and writes
``results/latest`` unless told otherwise.  ``run`` writes ``<out>/<name>/signals.npz``
and ``run.json`` per scenario and logs one line per scenario; Real signals are saved
rounded (what an expectation reads to float32, relative error <= 2**-24, the rest to
13 significant bits, <= 2**-13) unless the scenario's ``record.precision`` or
``--exact-signals`` asks for more; time, integer, Boolean and constant signals are
always exact (:mod:`gyrodiag_harness.cosim.results`).
``verify`` runs the scenarios, evaluates their ``[[expect]]`` tables on the runs at full
precision and writes a JUnit XML and an HTML report (default ``<out>/junit.xml``,
``<out>/report.html``).  ``report`` does the same from runs saved earlier in ``<out>``
(the saved values) without running anything.  ``isolability`` prints
which sensor faults of the seed aircraft are detectable and isolable
(:mod:`gyrodiag_harness.verification.isolability`, analysis only).  ``learn-signatures`` runs DTG
training scenarios and writes the fault-signature library that verification scenarios
load through a ``files`` parameter (:mod:`gyrodiag_harness.campaigns.signatures`).
``export-csv`` writes a saved run's signals as CSV.  ``compare-results`` compares two
results folders (verdicts, signals bit for bit, campaign summaries; exit 0 identical, 1
different: :mod:`gyrodiag_harness.cli.compare`).  ``export-ssp`` writes a scenario as
an SSP package for other SSP tools (:mod:`gyrodiag_harness.cosim.ssp`).  ``schema`` prints
the JSON Schema of scenario files (for editors), or with ``--markdown`` the reference of
``docs/scenarios.md``.

Scenarios run in worker processes, ``--workers`` at a time (default: the number of
CPUs); the results are the same for any number of workers.

Exit status: 0 all good; 1 a run stopped on an FMU error or an expectation failed;
2 invalid scenario files or command line; 130 stopped by Ctrl-C or SIGTERM (the runs in
flight are saved as far as they got, marked interrupted, and reported).

Every command mirrors the Python API: :func:`gyrodiag_harness.cosim.scenario.load_scenario`,
:func:`gyrodiag_harness.cosim.master.run_scenario`, :func:`gyrodiag_harness.cosim.batch.run_all`,
``gyrodiag_harness.verification.expectations.verify_results`` and
``gyrodiag_harness.reporting.report.write_report``.
"""

from __future__ import annotations

import argparse
import json
import logging
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from gyrodiag_harness.cli import campaign, compare, learn_signatures, pipeline, ssp
from gyrodiag_harness.cli.common import (
    DEFAULT_RESULTS_ROOT,
    EXIT_FAILED,
    EXIT_INTERRUPTED,
    EXIT_OK,
    EXIT_USAGE,
    add_exact_signals,
    add_verbosity,
    add_workers,
    configure_logging,
    latest_results_folder,
    new_results_folder,
    signals_precision,
    verify_and_report,
)
from gyrodiag_harness.cosim.batch import load_all, preflight_all, run_all
from gyrodiag_harness.cosim.interrupt import BatchInterrupted
from gyrodiag_harness.cosim.results import META_FILE, RunResult, signals_dropped
from gyrodiag_harness.cosim.scenario import Scenario, ScenarioError, load_scenario

DEFAULT_SCENARIO_DIR = "scenarios"

log = logging.getLogger("gyrodiag_harness.cli")


def main(argv: Sequence[str] | None = None) -> int:
    """Run the command line; returns the exit status."""
    parser = _parser()
    args = parser.parse_args(argv)
    configure_logging(getattr(args, "verbosity", 0))
    try:
        return int(args.func(args))
    except ScenarioError as exc:
        log.error("%s", exc)
        return EXIT_USAGE
    except FileNotFoundError as exc:
        log.error("%s", exc)
        return EXIT_USAGE
    except KeyboardInterrupt as exc:  # outside any run (a run's stop is handled in place)
        log.error("interrupted%s", f": {exc}" if str(exc) else "")
        return EXIT_INTERRUPTED


def _parser() -> argparse.ArgumentParser:
    # the console script gyrodiag (pyproject.toml) runs this same parser
    prog = "gyrodiag" if Path(sys.argv[0]).name == "gyrodiag" else "python -m gyrodiag_harness"
    parser = argparse.ArgumentParser(
        prog=prog,
        description="Run gyrodiag co-simulation scenarios (fmpy master), verify their "
                    "expectations and report.")
    add_verbosity(parser, top=True)
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    _add_scenario_commands(sub)
    _add_tool_commands(sub)
    learn_signatures.add_parser(sub)
    pipeline.add_parser(sub)
    campaign.add_parser(sub)
    campaign.add_summary_parser(sub)
    compare.add_parser(sub)
    ssp.add_parser(sub)
    for p in sub.choices.values():
        add_verbosity(p)
    return parser


def _scenario_args(p: argparse.ArgumentParser, running: bool) -> None:
    """The scenario files and ``--out`` (a new results folder if ``running``, else the
    saved one), plus the running options."""
    p.add_argument("scenarios", nargs="+", metavar="SCENARIO", type=Path,
                   help="scenario .toml files or folders of them")
    if running:
        p.add_argument("--out", type=Path, default=None,
                       help=f"results folder, one sub-folder per scenario (default: a "
                            f"new {DEFAULT_RESULTS_ROOT}/<command>-<time>/, "
                            f"{DEFAULT_RESULTS_ROOT}/latest points to it)")
        p.add_argument("--fmu-dir", type=Path, default=None,
                       help="folder of the .fmu files (default: the scenario's fmu_dir, "
                            "$GYRODIAG_FMU_DIR or build/fmus)")
        add_workers(p)
        add_exact_signals(p)
        p.add_argument("--no-progress", action="store_true", help="no progress bar")
    else:
        p.add_argument("--out", type=Path, default=None,
                       help=f"results folder of the saved runs, where the report is "
                            f"written too (default {DEFAULT_RESULTS_ROOT}/latest)")


def _report_args(p: argparse.ArgumentParser) -> None:
    """Where the JUnit and HTML reports go."""
    p.add_argument("--junit", type=Path, default=None,
                   help="JUnit XML file (default <out>/junit.xml)")
    p.add_argument("--html", type=Path, default=None,
                   help="HTML report (default <out>/report.html)")


def _add_scenario_commands(sub: Any) -> None:
    """``run``, ``verify`` and ``report``: the commands on scenario files."""
    p_run = sub.add_parser("run", help="run scenarios and save their signals")
    _scenario_args(p_run, running=True)
    p_run.set_defaults(func=cmd_run)

    p_verify = sub.add_parser("verify", help="run scenarios, check expectations, report")
    _scenario_args(p_verify, running=True)
    _report_args(p_verify)
    p_verify.set_defaults(func=cmd_verify)

    p_report = sub.add_parser("report", help="check expectations and report on saved runs")
    _scenario_args(p_report, running=False)
    _report_args(p_report)
    p_report.set_defaults(func=cmd_report)


def _add_tool_commands(sub: Any) -> None:
    """``list``, ``isolability``, ``export-csv`` and ``schema``: the commands that run
    nothing."""
    p_list = sub.add_parser("list", help="list the scenarios of a folder")
    p_list.add_argument("directory", nargs="?", type=Path, default=Path(DEFAULT_SCENARIO_DIR),
                        metavar="DIR", help=f"folder of .toml files (default "
                                            f"{DEFAULT_SCENARIO_DIR}/)")
    p_list.set_defaults(func=cmd_list)

    p_iso = sub.add_parser("isolability",
                           help="print the sensor-fault isolability report of the seed "
                                "aircraft (analysis with the gyrodiag library, no FMU)")
    p_iso.add_argument("--out", type=Path, default=None, metavar="FILE",
                       help="also write the report to FILE (format from the suffix: .json, "
                            ".html, else text)")
    p_iso.add_argument("--format", choices=("text", "json", "html"), default=None,
                       help="format of FILE (default from its suffix); printing is text")
    p_iso.set_defaults(func=cmd_isolability)

    p_csv = sub.add_parser("export-csv", help="write the signals of saved runs as CSV")
    p_csv.add_argument("runs", nargs="+", type=Path, metavar="RUN",
                       help="a run folder (with run.json) or a results folder (every run "
                            "in it)")
    p_csv.add_argument("--out", type=Path, default=None, metavar="FILE",
                       help="CSV file, for a single run (default: signals.csv in each run "
                            "folder)")
    p_csv.set_defaults(func=cmd_export_csv)

    p_schema = sub.add_parser("schema", help="print the JSON Schema of scenario files (for "
                                             "editors) or their Markdown reference")
    p_schema.add_argument("--markdown", action="store_true",
                          help="the Markdown reference (docs/scenarios.md) instead")
    p_schema.add_argument("--campaign", action="store_true",
                          help="the JSON Schema of campaign specs instead")
    p_schema.set_defaults(func=cmd_schema)


def output_folder(out: Path | None, command: str, scenarios: Sequence[Scenario],
                  fmu_dir: Path | None) -> Path:
    """``out`` or a new ``results/<command>-<time>/``, created once every scenario passed
    its checks (an invalid scenario leaves no empty folder behind)."""
    planned = out if out is not None else DEFAULT_RESULTS_ROOT / f"{command}-<time>"
    preflight_all(scenarios, fmu_dir, planned)
    if out is not None:
        out.mkdir(parents=True, exist_ok=True)
        return out
    folder = new_results_folder(command)
    log.info("results: %s", folder)
    return folder


def run_scenarios(scenarios: Sequence[Scenario], out: Path,
                  args: argparse.Namespace) -> tuple[list[RunResult], BatchInterrupted | None]:
    """Run with the command's options; a stop request returns what was saved."""
    try:
        return run_all(scenarios, out, args.fmu_dir, not args.no_progress,
                       workers=args.workers, precision=signals_precision(args)), None
    except BatchInterrupted as stop:
        return stop.results, stop


def log_interruption(stop: BatchInterrupted, out: Path) -> None:
    """Say what a stop request left behind."""
    partial = [r.scenario for r in stop.results if r.interrupted]
    log.warning("stopped by %s: %d run(s) finished, %s, %d not started; saved in %s",
                stop.reason, sum(not r.interrupted for r in stop.results),
                f"{len(partial)} interrupted ({', '.join(partial)})" if partial
                else "none interrupted", len(stop.not_started), out)


# --------------------------------------------------------------------------- commands
def cmd_run(args: argparse.Namespace) -> int:
    scenarios = load_all(args.scenarios)
    out = output_folder(args.out, "run", scenarios, args.fmu_dir)
    results, stop = run_scenarios(scenarios, out, args)
    if stop is not None:
        log_interruption(stop, out)
        return EXIT_INTERRUPTED
    return EXIT_FAILED if any(r.error is not None for r in results) else EXIT_OK


def cmd_verify(args: argparse.Namespace) -> int:
    scenarios = load_all(args.scenarios)
    out = output_folder(args.out, "verify", scenarios, args.fmu_dir)
    results, stop = run_scenarios(scenarios, out, args)
    if stop is not None:
        log_interruption(stop, out)
    return verify_and_report(results, scenarios, out, args.junit, args.html,
                             not_started=stop.not_started if stop else (),
                             interrupted_by=stop.reason if stop else None)


def cmd_report(args: argparse.Namespace) -> int:
    scenarios = load_all(args.scenarios)
    out = args.out if args.out is not None else latest_results_folder()
    results = []
    for s in scenarios:
        directory = out / s.name
        try:
            results.append(RunResult.load(directory))
        except FileNotFoundError:
            log.warning("%s: no saved run in %s (run it first)", s.name, directory)
    return verify_and_report(results, scenarios, out, args.junit, args.html)


def cmd_isolability(args: argparse.Namespace) -> int:
    from gyrodiag_harness.verification.isolability import render, seed_isolability_report, write

    report = seed_isolability_report()
    log.info("%s", render(report, "text").rstrip("\n"))
    if args.out is not None:
        path = write(args.out, report, args.format)
        log.info("written: %s", path)
    return EXIT_OK


def cmd_export_csv(args: argparse.Namespace) -> int:
    runs: list[Path] = []
    for p in args.runs:
        if (p / META_FILE).is_file():
            runs.append(p)
        elif p.is_dir():
            found = sorted(m.parent for m in p.rglob(META_FILE))
            if not found:
                raise FileNotFoundError(f"{p}: no saved run in this folder")
            kept = [r for r in found if signals_dropped(r) is None]
            if len(kept) < len(found):
                log.info("%s: %d run(s) without signals passed over (e.g. %s: %s)", p,
                         len(found) - len(kept), next(r for r in found if r not in kept),
                         signals_dropped(next(r for r in found if r not in kept)))
            runs += kept
        else:
            raise FileNotFoundError(f"{p}: not a run folder (no {META_FILE})")
    if args.out is not None and len(runs) != 1:
        log.error("--out names one file, but %d runs were given", len(runs))
        return EXIT_USAGE
    for run in runs:
        path = RunResult.load(run).export_csv(args.out or run / "signals.csv")
        log.info("%s", path)
    return EXIT_OK


def cmd_schema(args: argparse.Namespace) -> int:
    from gyrodiag_harness.cli import reference

    if args.markdown:
        log.info("%s", reference.markdown().rstrip("\n"))
    else:
        schema = reference.campaign_schema() if args.campaign else reference.scenario_schema()
        log.info("%s", json.dumps(schema, indent=2))
    return EXIT_OK


def cmd_list(args: argparse.Namespace) -> int:
    directory: Path = args.directory
    if not directory.is_dir():
        raise FileNotFoundError(f"{directory}: not a folder")
    files = sorted(directory.glob("*.toml"))
    rows: list[tuple[str, ...]] = []
    bad = 0
    for f in files:
        try:
            s = load_scenario(f)
        except ScenarioError as exc:
            bad += 1
            log.error("invalid: %s", exc)
            continue
        fmus = ", ".join(f"{n}={i.fmu}" for n, i in s.fmus.items())
        rows.append((s.name, f"{s.duration_s:g} s", fmus, str(len(s.expect)), str(f)))
    if rows:
        header = ("NAME", "DURATION", "FMUS", "EXPECT", "FILE")
        widths = [max(len(r[j]) for r in [header, *rows]) for j in range(len(header) - 1)]
        for r in [header, *rows]:
            log.info("%s", "  ".join(c.ljust(w) for c, w in zip(r[:-1], widths, strict=True))
                     + "  " + r[-1])
    log.info("%s", f"{len(rows)} scenario(s) in {directory}" + (f", {bad} invalid" if bad
                                                                 else ""))
    return EXIT_USAGE if bad else EXIT_OK
