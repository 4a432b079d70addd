"""Verification reports: JUnit XML for CI and one self-contained HTML page for people.

* :func:`write_junit` — one ``<testsuite>`` per scenario, one ``<testcase>`` per
  expectation plus a ``run`` testcase (an ``<error>`` when the run failed, was
  interrupted or no run result exists: the reason is said there, once); failed
  expectations carry ``<failure message=...>``, expectations that could not be evaluated
  (no complete run) ``<skipped>``, every testcase its message in ``<system-out>`` so
  passing cases show what was measured too.
* :func:`write_html` — summary table, and per scenario: run facts, fault windows,
  expectations (pass/fail, measured value, message), a table of standard metrics
  (:func:`summary_metrics`) and the plots of
  :func:`gyrodiag_harness.reporting.plots.figures_for_result` embedded as base64 PNG.
* :func:`write_report` — both, into one directory.
"""

from __future__ import annotations

import base64
import datetime as _dt
import html
import logging
import math
import multiprocessing
import os
import pickle
import re
import xml.etree.ElementTree as ET
from collections.abc import Sequence
from concurrent.futures import ProcessPoolExecutor
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, NamedTuple

import numpy as np

from gyrodiag_harness.reporting import plots
from gyrodiag_harness.verification import metrics
from gyrodiag_harness.verification.expectations import ScenarioVerdict

_log = logging.getLogger(__name__)

if TYPE_CHECKING:
    from gyrodiag_harness.cosim.results import RunResult

__all__ = [
    "MetricRow",
    "ReportPaths",
    "summary_metrics",
    "write_html",
    "write_junit",
    "write_report",
]

JUNIT_FILE = "junit.xml"
HTML_FILE = "report.html"

# XML 1.0 forbids most control characters (HTML calls them parse errors); FMU log lines
# may carry them (ANSI colours)
_XML_INVALID = re.compile("[^\t\n\r\x20-\ud7ff\ue000-\ufffd\U00010000-\U0010ffff]")
_ALARM = re.compile(r"(alarm|detected)(\[\d+\])?$")
_THETA = re.compile(r"\.theta_[xy]\[\d+\]$")


def _xml_text(text: str) -> str:
    return _XML_INVALID.sub("\ufffd", text)


def _by_name(items: Sequence[Any] | None, name_of: Any) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for item in items or []:
        out.setdefault(name_of(item), item)
    return out


def _scenario_name(s: Any) -> str:
    return str(s["name"] if isinstance(s, dict) else s.name)


def _unique(names: list[str]) -> list[str]:
    seen: dict[str, int] = {}
    out = []
    for n in names:
        seen[n] = seen.get(n, 0) + 1
        out.append(n if seen[n] == 1 else f"{n} #{seen[n]}")
    return out


def _evaluated(e: Any) -> bool:
    return bool(getattr(e, "evaluated", True))


# ------------------------------------------------------------------- JUnit
def write_junit(
    verdicts: Sequence[ScenarioVerdict],
    path: Path | str,
    results: Sequence[RunResult] | None = None,
    *,
    suite_name: str = "gyrodiag",
) -> Path:
    """Write JUnit XML of scenario verdicts.

    Parameters
    ----------
    verdicts : sequence of ScenarioVerdict
        From :func:`gyrodiag_harness.verification.expectations.verify_results`.
    path : path-like
        Output file (parent directories are created).
    results : sequence of RunResult, optional
        Supplies each suite's wall time (s).
    suite_name : str
        Name of the ``<testsuites>`` root.

    Returns
    -------
    Path
        ``path``. Counts: ``tests`` = expectations + 1 run case per scenario,
        ``failures`` = failed expectations, ``errors`` = failed or missing runs,
        ``skipped`` = expectations not evaluated for want of a complete run.
    """
    path = Path(path)
    runs = _by_name(results, lambda r: r.scenario)
    root = ET.Element("testsuites", name=suite_name)
    totals = {"tests": 0, "failures": 0, "errors": 0, "skipped": 0}
    total_time = 0.0
    for v in verdicts:
        run = runs.get(v.scenario)
        wall = float(run.wall_time_s) if run is not None else 0.0
        total_time += wall
        n_skipped = sum(not _evaluated(e) for e in v.expectations)
        n_failures = sum(not e.passed and _evaluated(e) for e in v.expectations)
        n_errors = int(v.error is not None)
        suite = ET.SubElement(root, "testsuite", name=_xml_text(v.scenario),
                              tests=str(len(v.expectations) + 1), failures=str(n_failures),
                              errors=str(n_errors), skipped=str(n_skipped),
                              time=f"{wall:.3f}")
        case = ET.SubElement(suite, "testcase", classname=_xml_text(v.scenario), name="run",
                             time=f"{wall:.3f}")
        if v.error is not None:
            first = v.error.strip().splitlines()[0] if v.error.strip() else "run failed"
            err = ET.SubElement(case, "error", message=_xml_text(first), type="RunError")
            err.text = _xml_text(v.error)
        for e, label in zip(v.expectations, _unique([e.name for e in v.expectations]),
                            strict=True):
            case = ET.SubElement(suite, "testcase", classname=_xml_text(v.scenario),
                                 name=_xml_text(label), time="0")
            if not _evaluated(e):
                ET.SubElement(case, "skipped", message=_xml_text(e.message))
            elif not e.passed:
                fail = ET.SubElement(case, "failure", message=_xml_text(e.message),
                                     type=e.kind or "expectation")
                fail.text = _xml_text(e.message)
            out = ET.SubElement(case, "system-out")
            out.text = _xml_text(e.message)
        totals["tests"] += len(v.expectations) + 1
        totals["failures"] += n_failures
        totals["errors"] += n_errors
        totals["skipped"] += n_skipped
    for key, value in totals.items():
        root.set(key, str(value))
    root.set("time", f"{total_time:.3f}")
    ET.indent(root)
    path.parent.mkdir(parents=True, exist_ok=True)
    ET.ElementTree(root).write(path, encoding="utf-8", xml_declaration=True)
    return path


# ----------------------------------------------------------------- metrics
@dataclass(frozen=True)
class MetricRow:
    """One row of a scenario's metric table.

    ``value`` is the number (None if undefined, e.g. a missed detection), ``text`` its
    display form, ``unit`` its unit.
    """

    metric: str
    subject: str
    condition: str
    value: float | None
    unit: str
    text: str


def _is_binary(x: np.ndarray) -> bool:
    finite = x[np.isfinite(x)]
    return bool(np.all((finite == 0.0) | (finite == 1.0)))


def summary_metrics(result: RunResult, scenario: Any = None) -> list[MetricRow]:
    """Standard metrics of a run, chosen by the recorded signal names.

    * every 0/1 signal whose variable ends in ``alarm`` / ``detected`` (``[i]``):
      detection delay (s) per fault window, false alarms (count, rate per hour of
      fault-free time);
    * every grey prediction with a known measurement (see
      :func:`gyrodiag_harness.reporting.plots.figures_for_result`): prediction error, % of y,
      before the first fault (the whole run without faults);
    * every θ signal: statistics over the second half of the fault-free time before the
      first fault (the first half holds the estimator's convergence transient).

    Parameters
    ----------
    result : RunResult
        The run.
    scenario : Scenario or dict, optional
        Connections locate the grey measurement.

    Returns
    -------
    list of MetricRow
    """
    rows: list[MetricRow] = []
    t = np.asarray(result.time, dtype=float)
    if t.size == 0:
        return rows
    windows = [(w.start_s, w.end_s) for w in result.fault_windows]
    first_fault = min((w.start_s for w in result.fault_windows), default=math.inf)
    pre_end = min(first_fault, float(t[-1]))
    for name, values in result.signals.items():
        x = np.asarray(values, dtype=float)
        if not (_ALARM.search(name.rsplit(".", 1)[-1]) and _is_binary(x)):
            continue
        for w in result.fault_windows:
            delay = metrics.detection_delay_s(t, x, w.start_s)
            rows.append(MetricRow("detection delay", name, f"fault {w.name} @ {w.start_s:g} s",
                                  None if math.isnan(delay) else delay, "s",
                                  "missed" if math.isnan(delay) else f"{delay:.4g}"))
        fa = metrics.false_alarms(t, x, windows)
        rate = "n/a" if math.isnan(fa.rate_per_h) else f"{fa.rate_per_h:.3g} /h"
        rows.append(MetricRow("false alarms", name, "outside fault windows", float(fa.count),
                              "count", f"{fa.count} ({rate} over {fa.fault_free_time_s:g} s)"))
    connections = plots.scenario_connections(scenario)
    for name in result.signals:
        if not name.endswith(".grey.prediction"):
            continue
        inst = name[: -len(".grey.prediction")]
        measured = f"{inst}.grey.y" if f"{inst}.grey.y" in result.signals else next(
            (s for s, d in connections if d == f"{inst}.grey.y" and s in result.signals), None)
        if measured is None:
            continue
        e = metrics.prediction_errors_percent(t, result.signals[measured], result.signals[name],
                                              None, pre_end)
        cond = f"{measured}, t ≤ {pre_end:g} s"
        rows.append(MetricRow("prediction error mean", name, cond,
                              None if math.isnan(e.mean_percent) else e.mean_percent, "%",
                              f"{e.mean_percent:.3g}"))
        rows.append(MetricRow("prediction error max", name, cond,
                              None if math.isnan(e.max_percent) else e.max_percent, "%",
                              f"{e.max_percent:.3g}"))
    t_lo = float(t[0]) + 0.5 * (pre_end - float(t[0]))
    for name, values in result.signals.items():
        if not _THETA.search(name) or not np.any(np.isfinite(values) & (values != 0.0)):
            continue  # zeros throughout: a disabled channel
        s = metrics.signal_statistics(t, values, t_lo, pre_end)
        rows.append(MetricRow("statistics", name, f"{t_lo:g} ≤ t ≤ {pre_end:g} s",
                              None if math.isnan(s.mean) else s.mean, "1",
                              f"mean {s.mean:.5g}, std {s.std:.3g}, "
                              f"range [{s.min:.5g}, {s.max:.5g}]"))
    return rows


# -------------------------------------------------------------------- HTML
_CSS = """
body{font-family:system-ui,sans-serif;margin:1.5em;color:#222}
table{border-collapse:collapse;margin:.5em 0 1em}
th,td{border:1px solid #ccc;padding:.25em .5em;text-align:left;vertical-align:top;font-size:.9em}
th{background:#f0f0f0}
.pass{color:#176f2c;font-weight:bold}.fail{color:#b00020;font-weight:bold}
.other{color:#8a5a00;font-weight:bold}
pre{background:#f7f7f7;padding:.5em;white-space:pre-wrap}
figure{margin:1em 0}img{max-width:100%;border:1px solid #ddd}
"""


def _status(passed: bool) -> str:
    return '<span class="pass">PASS</span>' if passed else '<span class="fail">FAIL</span>'


def verdict_status(v: ScenarioVerdict, run: RunResult | None) -> str:
    """PASS, FAIL (an expectation failed), ERROR (the run failed), INTERRUPTED (a stop
    request ended the run) or NOT RUN (no run result)."""
    if v.passed:
        return "PASS"
    if run is None:
        return "NOT RUN"
    if getattr(run, "interrupted", False):
        return "INTERRUPTED"
    return "ERROR" if v.error is not None else "FAIL"


def _status_html(status: str) -> str:
    css = "pass" if status == "PASS" else "fail" if status in ("FAIL", "ERROR") else "other"
    return f'<span class="{css}">{status}</span>'


def _expectation_status(e: Any) -> str:
    if not _evaluated(e):
        return '<span class="other">NOT EVALUATED</span>'
    if getattr(e, "is_known_limitation", False):
        return '<span class="other">KNOWN LIMITATION</span>'
    return _status(e.passed)


def _esc(x: Any) -> str:
    return html.escape(_xml_text(str(x)))


def _num(x: float | None) -> str:
    return "" if x is None else f"{x:.6g}"


def _anchor(name: str) -> str:
    return "s-" + re.sub(r"[^A-Za-z0-9_-]", "_", name)


def _table(header: Sequence[str], rows: list[list[str]]) -> str:
    head = "".join(f"<th>{_esc(h)}</th>" for h in header)
    body = "".join("<tr>" + "".join(f"<td>{c}</td>" for c in r) + "</tr>\n" for r in rows)
    return f"<table><tr>{head}</tr>\n{body}</table>\n"


def _scenario_section(
    v: ScenarioVerdict, result: RunResult | None, scenario: Any
) -> str:
    status = _status_html(verdict_status(v, result))
    parts = [f'<h2 id="{_anchor(v.scenario)}">{_esc(v.scenario)} {status}</h2>']
    desc = (scenario.get("description") if isinstance(scenario, dict)
            else getattr(scenario, "description", "")) if scenario is not None else ""
    if desc:
        parts.append(f"<p>{_esc(desc)}</p>")
    if result is not None:
        t = np.asarray(result.time, dtype=float)
        span = f"{t[0]:g} … {t[-1]:g} s, {t.size} samples" if t.size else "no samples"
        parts.append(_table(["step (s)", "planned (s)", "recorded", "wall time (s)", "signals"],
                            [[_num(result.step_s), _num(result.stop_time_s), _esc(span),
                              f"{result.wall_time_s:.2f}", str(len(result.signals))]]))
        if result.fault_windows:
            parts.append("<h3>Fault windows</h3>")
            parts.append(_table(["name", "target", "kind", "start (s)", "end (s)"], [
                [_esc(w.name), _esc(w.target), _esc(w.kind), _num(w.start_s),
                 "open" if math.isinf(w.end_s) else _num(w.end_s)]
                for w in result.fault_windows]))
        if result.manoeuvre_windows:
            parts.append("<h3>Manoeuvres (fault-free time)</h3>")
            parts.append(_table(["name", "flown by", "kind", "start (s)", "end (s)"], [
                [_esc(w.name), _esc(w.target), _esc(w.kind), _num(w.start_s),
                 "open" if math.isinf(w.end_s) else _num(w.end_s)]
                for w in result.manoeuvre_windows]))
    if v.error is not None:
        heading = ("Run interrupted" if result is not None and getattr(result, "interrupted",
                                                                        False)
                   else "Not run" if result is None else "Run error")
        parts.append(f"<h3>{heading}</h3><pre>{_esc(v.error)}</pre>")
    parts.append("<h3>Expectations</h3>")
    if v.expectations:
        parts.append(_table(["status", "expectation", "kind", "measured", "message"], [
            [_expectation_status(e), _esc(e.name), _esc(e.kind), _num(e.value),
             _esc(e.message)]
            for e in v.expectations]))
    else:
        parts.append("<p>none</p>")
    if result is not None and np.asarray(result.time).size:
        rows = summary_metrics(result, scenario)
        if rows:
            parts.append("<h3>Metrics</h3>")
            parts.append(_table(["metric", "signal", "condition", "value", "unit"], [
                [_esc(r.metric), _esc(r.subject), _esc(r.condition), _esc(r.text),
                 _esc(r.unit)] for r in rows]))
        parts.append(_figures_html(result, scenario, v))
    return "\n".join(parts)


def _figures_html(result: RunResult, scenario: Any, verdict: ScenarioVerdict) -> str:
    try:
        figures = plots.figures_for_result(result, scenario, verdict)
    except Exception as exc:  # a broken plot must not hide the verdicts; show why instead
        return f'<p class="fail">plots failed: {_esc(repr(exc))}</p>'
    out = ["<h3>Plots</h3>"] if figures else []
    for title, fig in figures:
        data = base64.b64encode(plots.figure_to_png(fig)).decode("ascii")
        out.append(f'<figure><img alt="{_esc(title)}" src="data:image/png;base64,{data}">'
                   f"<figcaption>{_esc(title)}</figcaption></figure>")
    return "\n".join(out)


def default_workers() -> int:
    """CPUs this process may run on (the report's default number of plot workers)."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # not on Linux
        return max(1, os.cpu_count() or 1)


def _section_job(job: tuple[ScenarioVerdict, RunResult | None, Any]) -> str:
    return _scenario_section(*job)


def _render_sections(jobs: list[tuple[ScenarioVerdict, RunResult | None, Any]],
                     workers: int) -> list[str]:
    """The scenario sections in order; their plots (matplotlib, ~0.6 s of CPU each) in
    ``workers`` processes when there is more than one section.

    The processes come from a fork server (a clean interpreter, not a fork of a caller
    that may hold FMU libraries or threads); if they cannot be had, or a job cannot be
    sent to them, the sections are rendered here, one after the other.
    """
    workers = min(int(workers), len(jobs))
    if workers > 1:
        try:
            context = multiprocessing.get_context("forkserver")
            with ProcessPoolExecutor(max_workers=workers, mp_context=context) as pool:
                return list(pool.map(_section_job, jobs))
        except (OSError, BrokenProcessPool, pickle.PicklingError, TypeError,
                AttributeError, ValueError) as exc:
            _log.warning("report: plots in parallel failed (%s: %s); rendering them here",
                         type(exc).__name__, exc)
    return [_section_job(job) for job in jobs]


def witness_table(verdicts: Sequence[ScenarioVerdict]) -> str:
    """The report section "One root cause, independent witnesses": one row per
    ``witnesses_agree`` expectation of any scenario (fault-free runs too), saying whether
    the witnesses agree and what each one did (the expectation's message: each witness's
    delay, "missed", "quiet" or its alarm time, and the quoted details); "" when no
    scenario has one.  Every witness's alarm is drawn on one timeline in the scenario's
    section (:func:`gyrodiag_harness.reporting.plots.plot_witnesses`)."""
    rows = []
    for v in verdicts:
        for e in v.expectations:
            if e.kind != "witnesses_agree" or not e.evaluated:
                continue
            rows.append([f'<a href="#{_anchor(v.scenario)}">{_esc(v.scenario)}</a>',
                         _esc(e.name), ('<span class="pass">AGREE</span>' if e.passed
                          else '<span class="fail">DISAGREE</span>'),
                         _esc(e.message)])
    if not rows:
        return ""
    return ("\n<h2>One root cause, independent witnesses</h2>\n"
            + _table(["scenario", "expectation", "verdict", "what each witness did"], rows))


def write_html(
    verdicts: Sequence[ScenarioVerdict],
    results: Sequence[RunResult],
    path: Path | str,
    scenarios: Sequence[Any] | None = None,
    workers: int | None = None,
) -> Path:
    """Write one self-contained HTML page (tables, plots as base64 PNG).

    Parameters
    ----------
    verdicts : sequence of ScenarioVerdict
        From :func:`gyrodiag_harness.verification.expectations.verify_results`.
    results : sequence of RunResult
        The runs (matched to verdicts by scenario name); plots and metrics come from them.
    path : path-like
        Output file (parent directories are created).
    scenarios : sequence of Scenario or dict, optional
        Descriptions, parameters (thresholds) and connections (grey measurement).
    workers : int, optional
        Processes that draw the plots (default: the CPUs available; 1 draws them here).

    Returns
    -------
    Path
        ``path``.
    """
    path = Path(path)
    runs = _by_name(results, lambda r: r.scenario)
    specs = _by_name(scenarios, _scenario_name)
    n_pass = sum(v.passed for v in verdicts)
    summary = _table(["scenario", "status", "expectations passed", "wall time (s)", "error"], [
        [f'<a href="#{_anchor(v.scenario)}">{_esc(v.scenario)}</a>',
         _status_html(verdict_status(v, runs.get(v.scenario))),
         f"{len(v.expectations) - v.n_failed}/{len(v.expectations)}",
         f"{runs[v.scenario].wall_time_s:.2f}" if v.scenario in runs else "",
         _esc((v.error or "").strip().splitlines()[0] if (v.error or "").strip() else "")]
        for v in verdicts])
    summary += witness_table(verdicts)
    stamp = _dt.datetime.now(_dt.UTC).strftime("%Y-%m-%d %H:%M:%S UTC")
    sections = _render_sections(
        [(v, runs.get(v.scenario), specs.get(v.scenario)) for v in verdicts],
        default_workers() if workers is None else workers)
    page = (
        "<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\">"
        f"<title>gyrodiag verification report</title><style>{_CSS}</style></head><body>\n"
        f"<h1>gyrodiag verification report</h1>\n<p>{n_pass}/{len(verdicts)} scenarios "
        f"passed — generated {stamp}</p>\n{summary}\n" + "\n<hr>\n".join(sections)
        + "\n</body></html>\n"
    )
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(page, encoding="utf-8")
    return path


class ReportPaths(NamedTuple):
    """Files written by :func:`write_report`."""

    junit: Path
    html: Path


def write_report(
    verdicts: Sequence[ScenarioVerdict],
    results: Sequence[RunResult],
    out_dir: Path | str,
    junit_path: Path | str | None = None,
    html_path: Path | str | None = None,
    scenarios: Sequence[Any] | None = None,
    workers: int | None = None,
) -> ReportPaths:
    """Write the JUnit XML and the HTML report.

    Parameters
    ----------
    verdicts : sequence of ScenarioVerdict
        From :func:`gyrodiag_harness.verification.expectations.verify_results`.
    results : sequence of RunResult
        The runs.
    out_dir : path-like
        Directory for files without an explicit path (created if needed).
    junit_path, html_path : path-like, optional
        Defaults ``out_dir/junit.xml`` and ``out_dir/report.html``.
    scenarios : sequence of Scenario or dict, optional
        See :func:`write_html`.
    workers : int, optional
        Plot processes, see :func:`write_html`.

    Returns
    -------
    ReportPaths
        The two files written.
    """
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    junit = write_junit(verdicts, junit_path or out / JUNIT_FILE, results)
    page = write_html(verdicts, results, html_path or out / HTML_FILE, scenarios, workers)
    return ReportPaths(junit, page)
