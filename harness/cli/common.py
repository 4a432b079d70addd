"""What the commands share: exit statuses and the verdict printed after a verification."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

from harness.cosim.results import RunResult
from harness.cosim.scenario import Scenario

EXIT_OK = 0
EXIT_FAILED = 1
EXIT_USAGE = 2
EXIT_INTERRUPTED = 130


def verify_and_report(results: Sequence[RunResult], scenarios: Sequence[Scenario],
                      out: Path, junit: Path | None, html: Path | None) -> int:
    """Evaluate expectations, write JUnit + HTML, print a verdict per scenario."""
    # deferred: the report imports matplotlib, which commands that do not report skip
    from harness.reporting.report import write_report
    from harness.verification.expectations import verify_results

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
