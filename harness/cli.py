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
are detectable and isolable (:mod:`harness.isolability`, analysis only).
``learn-signatures`` runs DTG training scenarios and writes the fault-signature library
that verification scenarios load through a ``files`` parameter (:mod:`harness.signatures`).

Exit status: 0 all good; 1 a run stopped on an FMU error or an expectation failed;
2 invalid scenario files or command line.

Every command mirrors the Python API: :func:`harness.scenario.load_scenario`,
:func:`harness.master.run_scenario`, ``harness.expectations.verify_results`` and
``harness.report.write_report``.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from pathlib import Path

from harness import campaign, pipeline, signatures
from harness.results import RunResult
from harness.scenario import Scenario, ScenarioError, load_scenario

EXIT_OK = 0
EXIT_FAILED = 1
EXIT_USAGE = 2
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

    signatures.add_parser(sub)
    pipeline.add_parser(sub)
    campaign.add_parser(sub)
    return parser


# --------------------------------------------------------------------------- helpers
def scenario_files(paths: Sequence[Path]) -> list[Path]:
    """Expand folders to their ``*.toml`` files (sorted); files are kept as given."""
    files: list[Path] = []
    for p in paths:
        if p.is_dir():
            found = sorted(p.glob("*.toml"))
            if not found:
                raise FileNotFoundError(f"{p}: no .toml scenario files in this folder")
            files += found
        else:
            files.append(p)
    return files


def load_all(paths: Sequence[Path]) -> list[Scenario]:
    """Load every scenario, reporting all invalid files at once (ScenarioError)."""
    scenarios, errors = [], []
    for f in scenario_files(paths):
        try:
            scenarios.append(load_scenario(f))
        except ScenarioError as exc:
            errors.append(exc)
    if errors:
        raise ScenarioError(errors[0].source, errors[0].problems) if len(errors) == 1 else \
            _merged(errors)
    names = [s.name for s in scenarios]
    for s in scenarios:
        if names.count(s.name) > 1:
            others = [o.source for o in scenarios if o.name == s.name and o is not s]
            raise ScenarioError(s.source, [("name", f"scenario name {s.name!r} is also used by "
                                                    f"{', '.join(others)}: results would "
                                                    "overwrite each other")])
    return scenarios


def _merged(errors: list[ScenarioError]) -> ScenarioError:
    merged = ScenarioError(errors[0].source, errors[0].problems)
    merged.args = ("\n".join(str(e) for e in errors),)
    return merged


def summary_line(result: RunResult, out_dir: Path | None) -> str:
    """One line per run: outcome, samples, simulated and wall time, where it was saved."""
    n = len(result.time)
    where = f" -> {out_dir}" if out_dir is not None else ""
    if result.error is None:
        return (f"{result.scenario}: ok, {n} samples of {len(result.signals)} signals, "
                f"{result.stop_time_s:g} s simulated in {result.wall_time_s:.1f} s{where}")
    first = result.error.strip().splitlines()[0] if result.error.strip() else "error"
    t_end = f"{result.time[-1]:g} s" if n else "nothing"
    return (f"{result.scenario}: ERROR ({t_end} recorded of {result.stop_time_s:g} s): "
            f"{first}{where}")


def run_all(scenarios: Sequence[Scenario], out: Path, fmu_dir: Path | None,
            progress: bool) -> list[RunResult]:
    """Run scenarios one after the other, saving each into ``out/<name>``."""
    from harness.master import run_scenario

    results = []
    for s in scenarios:
        target = out / s.name
        result = run_scenario(s, fmu_dir=fmu_dir, progress=progress, out_dir=target,
                              results_dir=out)
        print(summary_line(result, target), flush=True)
        if result.error is not None and "\n" in result.error.strip():
            print(_indent(result.error), file=sys.stderr, flush=True)
        results.append(result)
    return results


def _indent(text: str) -> str:
    return "\n".join("    " + line for line in text.strip().splitlines())


def verify_and_report(results: Sequence[RunResult], scenarios: Sequence[Scenario],
                      out: Path, junit: Path | None, html: Path | None) -> int:
    """Evaluate expectations, write JUnit + HTML, print a verdict per scenario."""
    from harness.expectations import verify_results
    from harness.report import write_report

    verdicts = verify_results(results, scenarios)
    paths = write_report(verdicts, results, out_dir=out, junit_path=junit, html_path=html,
                         scenarios=scenarios)
    failed = 0
    for v in verdicts:
        n = len(v.expectations)
        if v.passed:
            print(f"{v.scenario}: PASS ({n} expectations)")
            continue
        failed += 1
        reason = f"run error: {v.error.strip().splitlines()[0]}" if v.error else \
            f"{v.n_failed} of {n} expectations failed"
        print(f"{v.scenario}: FAIL ({reason})")
        for e in v.expectations:
            if not e.passed:
                print(f"    {e.name}: {e.message}")
    print(f"{len(verdicts) - failed} of {len(verdicts)} scenarios passed; JUnit: {paths.junit}; "
          f"HTML: {paths.html}")
    return EXIT_FAILED if failed else EXIT_OK


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
    from harness.isolability import render, seed_isolability_report, write

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
