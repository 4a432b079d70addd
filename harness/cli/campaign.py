"""``python -m gyrodiag_harness campaign SPEC.toml``: run or resume a Monte Carlo campaign.

See :mod:`gyrodiag_harness.campaigns.campaign` for the spec, the execution and what a run records.
"""

from __future__ import annotations

import argparse
import logging
import os
from pathlib import Path
from typing import Any

from gyrodiag_harness.campaigns.campaign import (
    REPO_ROOT,
    CampaignInterrupted,
    expand_runs,
    load_campaign,
    load_campaign_output,
    load_records,
    run_campaign,
    select,
)
from gyrodiag_harness.campaigns.campaign_report import summarize, summarize_campaigns, write_report

log = logging.getLogger("gyrodiag_harness.cli")


def add_parser(sub: Any) -> None:
    """Register ``campaign`` on the CLI's sub-parsers."""
    p = sub.add_parser("campaign", help="run (or resume) a Monte Carlo fault-injection "
                                        "campaign and write its summary")
    p.add_argument("spec", type=Path, help="campaign .toml (see campaigns/)")
    p.add_argument("--out", type=Path, default=None,
                   help="output folder (default build/campaigns/<name>)")
    p.add_argument("--workers", type=int, default=os.cpu_count() or 1,
                   help="parallel runs (default: the number of CPUs)")
    p.add_argument("--dask", default=None, metavar="local|ADDRESS",
                   help="run on dask.distributed: 'local' (a LocalCluster) or a scheduler "
                        "address; default: a local process pool")
    p.add_argument("--fmu-dir", type=Path, default=None,
                   help="folder of the .fmu files (default: $GYRODIAG_FMU_DIR, the spec's "
                        "fmu_dir, or each base scenario's); the run ids do not depend on "
                        "it, so a campaign resumes with the FMUs it started with")
    p.add_argument("--timeout", type=float, default=None, help="per-run time limit, s")
    p.add_argument("--max-runs", type=int, default=None,
                   help="start at most this many pending runs, then stop")
    p.add_argument("--fraction", type=float, default=1.0,
                   help="run a deterministic fraction of the runs (e.g. 0.1)")
    p.add_argument("--group", action="append", default=None, dest="groups", metavar="NAME",
                   help="run only this condition group (repeatable; e.g. level)")
    p.add_argument("--condition", action="append", default=None, dest="conditions",
                   metavar="NAME", help="run only this flight condition (repeatable)")
    p.add_argument("--retry-failed", action="store_true", help="re-run failed runs")
    p.add_argument("--report-only", action="store_true",
                   help="summarise the records already written, run nothing")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.set_defaults(func=cmd_campaign)


def add_summary_parser(sub: Any) -> None:
    """Register ``campaign-summary`` on the CLI's sub-parsers."""
    p = sub.add_parser("campaign-summary",
                       help="one summary (summary.md/.json, report.html) of several "
                            "campaigns' output folders")
    p.add_argument("folders", type=Path, nargs="+",
                   help="campaign output folders (each with campaign.json and runs/)")
    p.add_argument("--out", type=Path, required=True, help="folder for the summary")
    p.add_argument("--title", default="all families", help="the summary's title")
    p.set_defaults(func=cmd_campaign_summary)


def cmd_campaign_summary(args: argparse.Namespace) -> int:
    """Exit 0 when every planned run of every campaign finished without failing."""
    try:
        outputs = [load_campaign_output(folder) for folder in args.folders]
        if Path(args.out).resolve() in {Path(o.out_dir).resolve() for o in outputs}:
            raise ValueError(f"--out {args.out}: one of the campaign folders (its own "
                             "summary would be overwritten); give another folder")
        summary = summarize_campaigns(outputs)
    except ValueError as exc:
        log.error("%s", exc)
        return 2
    records = [r for o in outputs for r in o.records]
    paths = write_report(summary, records, Path(args.out), title=args.title)
    for c in summary["campaigns"]:
        log.info("%s: %d of %d runs finished, %d failed, %.2f nominal h judged",
                 c["campaign"], c["n_finished"], c["n_planned"], c["n_failed"],
                 c["nominal_hours"])
    log.info("%s", summary_text(summary))
    log.info("summary: %s, %s; report: %s", paths["json"], paths["markdown"], paths["html"])
    return 0 if summary["n_finished"] == summary["n_planned"] and not summary["n_failed"] \
        else 1


def cmd_campaign(args: argparse.Namespace) -> int:
    spec, base_dir = load_campaign(args.spec)
    out = args.out or REPO_ROOT / "build" / "campaigns" / spec.name
    if args.report_only:
        try:
            runs = select(expand_runs(spec, base_dir, Path(out)), args.fraction,
                          groups=args.groups, conditions=args.conditions)
        except ValueError as exc:
            log.error("%s", exc)
            return 2
        ids = {r.run_id for r in runs}
        records = [r for rid, r in load_records(Path(out) / "runs").items() if rid in ids]
        n_total = len(runs)
    else:
        try:
            outcome = run_campaign(spec, base_dir, Path(out), workers=args.workers,
                                   dask=args.dask, timeout_s=args.timeout,
                                   max_runs=args.max_runs, retry_failed=args.retry_failed,
                                   fraction=args.fraction, progress=not args.no_progress,
                                   fmu_dir=args.fmu_dir, groups=args.groups,
                                   conditions=args.conditions)
        except CampaignInterrupted as exc:
            log.warning("%s", exc)
            return 130
        except ValueError as exc:  # a bad --group/--condition/--fraction/--workers
            log.error("%s", exc)
            return 2
        records, n_total = outcome.records, outcome.n_total
        log.info(f"{spec.name}: {outcome.n_executed} runs executed, {outcome.n_skipped} "
              f"already done, {len(outcome.failed)} failed, in {outcome.wall_s:.0f} s")
    summary = summarize(records, n_planned=n_total)
    paths = write_report(summary, records, Path(out), title=spec.name)
    log.info("%s", summary_text(summary))
    log.info("summary: %s, %s; report: %s", paths["json"], paths["markdown"], paths["html"])
    return 0 if summary["n_finished"] == n_total and not summary["n_failed"] else 1


def summary_text(summary: dict[str, Any]) -> str:
    """A few lines: runs, false alarms per hour, detection per class."""
    lines = [f"runs: {summary['n_finished']} of {summary['n_planned']} finished, "
             f"{summary['n_failed']} failed"]
    for ch, fa in summary["false_alarms"].items():
        lines.append(f"[{ch}] false alarms: {fa['count']} in {fa['hours']:.3g} h = "
                     f"{fa['rate_per_h']:.3g}/h (95 % upper bound {fa['upper_95']:.3g}/h)")
    for row in summary["detection"]:
        mag = "" if row["magnitude"] is None else f" {row['magnitude']:g}"
        lines.append(f"  {row['class']} {row['fault_type']}{mag}: "
                     f"{row['detected']}/{row['n']} detected, "
                     + (f"{row['isolated']}/{row['n']} isolated right"
                        if row.get("isolated") is not None else "no isolation (n/a)"))
    for key, d in summary["delay"].items():
        if d["n"]:
            lines.append(f"  delay {key}: median {d['median_s']:.3g} s, p95 {d['p95_s']:.3g} s, "
                         f"max {d['max_s']:.3g} s (n={d['n']})")
    return "\n".join(lines)
