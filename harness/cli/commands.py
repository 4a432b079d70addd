"""Command line of the harness: ``python -m harness run | verify | report | list``.

::

    python -m harness run SCENARIO... [--out results] [--fmu-dir DIR] [--no-progress]
    python -m harness verify SCENARIO... [--out results] [--fmu-dir DIR] [--no-progress]
                                         [--junit PATH] [--html PATH]
    python -m harness report SCENARIO... [--out results] [--junit PATH] [--html PATH]
    python -m harness list [DIR]
    python -m harness all [--out results] [--scenarios DIR] [--fmu-dir DIR] [--no-build]
    python -m harness campaign SPEC.toml [--out DIR] [--workers N] [--dask local|ADDRESS]
                               [--timeout S] [--fraction F] [--report-only]
    python -m harness isolability [--out FILE] [--format text|json|html]
    python -m harness learn-signatures SCENARIO... --out FILE.json [--runs-out DIR]
                                       [--window-s S] [--saved] [--fmu-dir DIR]

A SCENARIO argument is a ``.toml`` file or a folder (all its ``*.toml``, sorted).
``run`` writes ``<out>/<name>/signals.csv`` and ``run.json`` per scenario and prints one
line per scenario.  ``verify`` runs the scenarios, evaluates their ``[[expect]]`` tables
and writes a JUnit XML and an HTML report (default ``<out>/junit.xml``,
``<out>/report.html``).  ``report`` does the same from runs saved earlier in ``<out>``
without running anything.  ``isolability`` prints which sensor faults of the seed aircraft
are detectable and isolable (:mod:`harness.verification.isolability`, analysis only).
``learn-signatures`` runs DTG training scenarios and writes the fault-signature library
that verification scenarios load through a ``files`` parameter
(:mod:`harness.campaigns.signatures`).

Exit status: 0 all good; 1 a run stopped on an FMU error or an expectation failed;
2 invalid scenario files or command line.

Every command mirrors the Python API: :func:`harness.cosim.scenario.load_scenario`,
:func:`harness.cosim.master.run_scenario`,
``harness.verification.expectations.verify_results`` and
``harness.reporting.report.write_report``.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from pathlib import Path

from harness.cli import campaign, learn_signatures, pipeline
from harness.cli.common import EXIT_FAILED, EXIT_OK, EXIT_USAGE, verify_and_report
from harness.cosim.batch import load_all, run_all
from harness.cosim.results import RunResult
from harness.cosim.scenario import ScenarioError, load_scenario

DEFAULT_OUT = "results"
DEFAULT_SCENARIO_DIR = "scenarios"


def main(argv: Sequence[str] | None = None) -> int:
    """Run the command line; returns the exit status."""
    parser = _parser()
    args = parser.parse_args(argv)
    try:
        return int(args.func(args))
    except ScenarioError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return EXIT_USAGE
    except FileNotFoundError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return EXIT_USAGE


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="python -m harness",
        description="Run gyrodiag co-simulation scenarios (fmpy master), verify their "
                    "expectations and report.")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")

    def scenario_args(p: argparse.ArgumentParser, running: bool) -> None:
        p.add_argument("scenarios", nargs="+", metavar="SCENARIO", type=Path,
                       help="scenario .toml files or folders of them")
        p.add_argument("--out", type=Path, default=Path(DEFAULT_OUT),
                       help=f"results folder, one sub-folder per scenario (default "
                            f"{DEFAULT_OUT}/)")
        if running:
            p.add_argument("--fmu-dir", type=Path, default=None,
                           help="folder of the .fmu files (default: the scenario's fmu_dir, "
                                "$GYRODIAG_FMU_DIR or build/fmus)")
            p.add_argument("--no-progress", action="store_true", help="no progress bar")

    def report_args(p: argparse.ArgumentParser) -> None:
        p.add_argument("--junit", type=Path, default=None,
                       help="JUnit XML file (default <out>/junit.xml)")
        p.add_argument("--html", type=Path, default=None,
                       help="HTML report (default <out>/report.html)")

    p_run = sub.add_parser("run", help="run scenarios and save their signals")
    scenario_args(p_run, running=True)
    p_run.set_defaults(func=cmd_run)

    p_verify = sub.add_parser("verify", help="run scenarios, check expectations, report")
    scenario_args(p_verify, running=True)
    report_args(p_verify)
    p_verify.set_defaults(func=cmd_verify)

    p_report = sub.add_parser("report", help="check expectations and report on saved runs")
    scenario_args(p_report, running=False)
    report_args(p_report)
    p_report.set_defaults(func=cmd_report)

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

    learn_signatures.add_parser(sub)
    pipeline.add_parser(sub)
    campaign.add_parser(sub)
    return parser


# --------------------------------------------------------------------------- commands
def cmd_run(args: argparse.Namespace) -> int:
    scenarios = load_all(args.scenarios)
    results = run_all(scenarios, args.out, args.fmu_dir, not args.no_progress)
    return EXIT_FAILED if any(r.error is not None for r in results) else EXIT_OK


def cmd_verify(args: argparse.Namespace) -> int:
    scenarios = load_all(args.scenarios)
    results = run_all(scenarios, args.out, args.fmu_dir, not args.no_progress)
    return verify_and_report(results, scenarios, args.out, args.junit, args.html)


def cmd_report(args: argparse.Namespace) -> int:
    scenarios = load_all(args.scenarios)
    results = []
    for s in scenarios:
        directory = args.out / s.name
        try:
            results.append(RunResult.load(directory))
        except FileNotFoundError:
            print(f"{s.name}: no saved run in {directory} (run it first)", file=sys.stderr)
    return verify_and_report(results, scenarios, args.out, args.junit, args.html)


def cmd_isolability(args: argparse.Namespace) -> int:
    from harness.verification.isolability import render, seed_isolability_report, write

    report = seed_isolability_report()
    print(render(report, "text"), end="")
    if args.out is not None:
        path = write(args.out, report, args.format)
        print(f"written: {path}")
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
            print(f"invalid: {exc}", file=sys.stderr)
            continue
        fmus = ", ".join(f"{n}={i.fmu}" for n, i in s.fmus.items())
        rows.append((s.name, f"{s.duration_s:g} s", fmus, str(len(s.expect)), str(f)))
    if rows:
        header = ("NAME", "DURATION", "FMUS", "EXPECT", "FILE")
        widths = [max(len(r[j]) for r in [header, *rows]) for j in range(len(header) - 1)]
        for r in [header, *rows]:
            print("  ".join(c.ljust(w) for c, w in zip(r[:-1], widths, strict=True)) + "  "
                  + r[-1])
    print(f"{len(rows)} scenario(s) in {directory}" + (f", {bad} invalid" if bad else ""))
    return EXIT_USAGE if bad else EXIT_OK
