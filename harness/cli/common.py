"""What the commands share: exit statuses, output folders, logging, the verdict lines."""

from __future__ import annotations

import argparse
import logging
import sys
from collections.abc import Sequence
from pathlib import Path

from gyrodiag_harness.cosim.interrupt import EXIT_INTERRUPTED
from gyrodiag_harness.cosim.results import RunResult
from gyrodiag_harness.cosim.scenario import Scenario
from gyrodiag_harness.reporting.folders import (
    DEFAULT_RESULTS_ROOT,
    LATEST_LINK,
    latest_results_folder,
    new_results_folder,
)

__all__ = [
    "DEFAULT_RESULTS_ROOT",
    "EXIT_FAILED",
    "EXIT_INTERRUPTED",
    "EXIT_OK",
    "EXIT_USAGE",
    "LATEST_LINK",
    "add_exact_signals",
    "add_verbosity",
    "add_workers",
    "configure_logging",
    "latest_results_folder",
    "new_results_folder",
    "signals_precision",
    "verify_and_report",
]

EXIT_OK = 0
EXIT_FAILED = 1
EXIT_USAGE = 2

log = logging.getLogger("gyrodiag_harness")


# ------------------------------------------------------------------------------- logging
class _ConsoleHandler(logging.Handler):
    """Info and debug lines as they are on stdout (they are the command's output);
    warnings and errors on stderr, prefixed ``warning:`` / ``error:``."""

    def emit(self, record: logging.LogRecord) -> None:
        try:
            text = self.format(record)
            if record.levelno >= logging.WARNING:
                stream = sys.stderr
                prefix = "error: " if record.levelno >= logging.ERROR else "warning: "
                if not text.startswith(" "):  # continuation lines are indented already
                    text = prefix + text
            else:
                stream = sys.stdout
            stream.write(text + "\n")
            stream.flush()
        except Exception:  # never let logging break a command
            self.handleError(record)


def add_verbosity(parser: argparse.ArgumentParser, top: bool = False) -> None:
    """``-v`` (debug: FMU log lines, what starts when) and ``-q`` (warnings and errors
    only) on ``parser``; on a sub-command they override the ones given before it."""
    default = 0 if top else argparse.SUPPRESS
    group = parser.add_mutually_exclusive_group()
    group.add_argument("-v", "--verbose", dest="verbosity", action="store_const", const=1,
                       default=default, help="more output (debug)")
    group.add_argument("-q", "--quiet", dest="verbosity", action="store_const", const=-1,
                       default=default, help="only warnings and errors")


def add_workers(p: argparse.ArgumentParser) -> None:
    """``--workers N`` (parallel runs; default: the CPUs)."""
    p.add_argument("--workers", type=_positive_int, default=None, metavar="N",
                   help="scenarios run at the same time, each in its own process "
                        "(default: the number of CPUs)")


def add_exact_signals(p: argparse.ArgumentParser) -> None:
    """``--exact-signals`` (save every signal bit-exactly, float64)."""
    p.add_argument("--exact-signals", action="store_true",
                   help="save every signal with all its bits (float64) instead of "
                        "rounding Real signals as each scenario's record.precision "
                        "says (about 6x the disk space of the default)")


def signals_precision(args: argparse.Namespace) -> str | None:
    """The ``precision`` for :func:`gyrodiag_harness.cosim.batch.run_all` that ``args`` ask for."""
    return "float64" if getattr(args, "exact_signals", False) else None


def _positive_int(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not an integer: {text!r}") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be >= 1, got {value}")
    return value


def configure_logging(verbosity: int) -> None:
    """Route the ``harness`` loggers to the console at the level ``verbosity`` asks."""
    level = {1: logging.DEBUG, -1: logging.WARNING}.get(verbosity, logging.INFO)
    root = logging.getLogger("gyrodiag_harness")
    for h in list(root.handlers):
        if isinstance(h, _ConsoleHandler):
            root.removeHandler(h)
    handler = _ConsoleHandler()
    handler.setFormatter(logging.Formatter("%(message)s"))
    root.addHandler(handler)
    root.setLevel(level)
    root.propagate = False


# ------------------------------------------------------------------------------ verdicts
def verify_and_report(results: Sequence[RunResult], scenarios: Sequence[Scenario],
                      out: Path, junit: Path | None, html: Path | None,
                      not_started: Sequence[str] = (), interrupted_by: str | None = None
                      ) -> int:
    """Evaluate expectations, write JUnit + HTML, log a verdict line per scenario.

    ``not_started`` names scenarios a stop request kept from running: they are reported
    as not run.  Returns the exit status (130 if ``interrupted_by``).
    """
    # deferred: the report imports matplotlib, which commands that do not report skip
    from gyrodiag_harness.reporting.report import write_report
    from gyrodiag_harness.verification.expectations import ScenarioVerdict, verify_results

    skipped = set(not_started)
    verdicts = verify_results(results, [s for s in scenarios if s.name not in skipped])
    reason = f"not started: the command was stopped by {interrupted_by or 'a stop request'}"
    by_name = {v.scenario: v for v in verdicts}
    by_name.update({name: ScenarioVerdict(name, [], reason) for name in not_started})
    ordered = [by_name.pop(s.name) for s in scenarios if s.name in by_name]
    ordered += list(by_name.values())
    paths = write_report(ordered, results, out_dir=out, junit_path=junit, html_path=html,
                         scenarios=scenarios)
    runs = {r.scenario: r for r in results}
    failed = 0
    for v in ordered:
        n = len(v.expectations)
        if v.passed:
            known = [e for e in v.expectations if e.is_known_limitation]
            log.info("%s: PASS (%d expectations%s)", v.scenario, n,
                     f", {len(known)} of them known limitations" if known else "")
            for e in known:
                log.info("    %s: %s", e.name, e.message)
            continue
        failed += 1
        run = runs.get(v.scenario)
        if v.scenario in skipped:
            log.info("%s: NOT RUN (%s)", v.scenario, reason)
        elif v.error is not None:
            outcome = "INTERRUPTED" if run is not None and run.interrupted else "ERROR"
            first = v.error.strip().splitlines()[0] if v.error.strip() else "run failed"
            unevaluated = f"; {n} expectations not evaluated" if n else ""
            log.info("%s: %s (%s%s)", v.scenario, outcome, first, unevaluated)
        else:
            log.info("%s: FAIL (%d of %d expectations failed)", v.scenario, v.n_failed, n)
            for e in v.expectations:
                if not e.passed:
                    log.info("    %s: %s", e.name, e.message)
    log.info("%d of %d scenarios passed; JUnit: %s; HTML: %s", len(ordered) - failed,
             len(ordered), paths.junit, paths.html)
    if interrupted_by is not None:
        return EXIT_INTERRUPTED
    return EXIT_FAILED if failed else EXIT_OK
