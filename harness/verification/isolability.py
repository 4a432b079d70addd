"""Sensor-fault isolability report of the seed aircraft: ``python -m gyrodiag_harness isolability``.

Which faults on the six sensors (v, α, q, ϑ, γ, h) the detection-filter channel can
detect and from which other sensors it can tell them apart, worked out from the model by
:func:`gyrodiag.df.isolation.isolability_analysis` (docs/methods.md §4: main Beard–Jones filter with
F = I, eigenvalues −1 … −5, plus the bank of observers each without one sensor).

This is analysis, not simulation: the harness still knows the FMUs only through fmpy;
here it imports the algorithm library for the model and the analysis.

Per sensor the report gives

* ``detectable``: ``"steady state"`` when a constant bias keeps a residual in the main
  filter; ``"onset only"`` when the bias is indistinguishable from another initial state
  (no observer sees it once it has settled), so only the step at onset shows, for about
  ``transient_time_constant_s``; ``"no"`` otherwise;
* ``isolable_from``: sensors it can be told apart from by the residual direction of the
  main filter or by the observer-bank pattern (union of the two lists, also given apart);
* ``redundant``: whether the other sensors reproduce it (the plant stays observable).

A second table answers what stays isolable once the gust is decoupled: the visibility of
a bias on each sensor outside the output directions the Dryden gust takes
(:func:`gyrodiag.df.decoupling.decoupled_isolability`, docs/methods.md §4.6), at a slow,
a manoeuvre and a gust frequency.

Output formats: text (the library's detailed report after a summary table), JSON (the
same content as data) and a standalone HTML page.
"""

from __future__ import annotations

import html
import json
import math
from pathlib import Path
from typing import Any

import numpy as np

__all__ = ["FORMATS", "isolability_data", "render", "seed_isolability_report", "write"]

FORMATS = ("text", "json", "html")
_SUFFIX_FORMAT = {".json": "json", ".html": "html", ".htm": "html"}


def seed_isolability_report(eigenvalues: list[float] | None = None) -> Any:
    """Run the isolability analysis on the seed aircraft.

    Parameters
    ----------
    eigenvalues : list of float, optional
        Eigenvalues of A − K C of the main filter, 1/s; default −1 … −5 (the Diagnoser's
        ``df.eigenvalue`` defaults).

    Returns
    -------
    gyrodiag.df.isolation.IsolabilityReport
    """
    from gyrodiag.df.isolation import isolability_analysis
    from gyrodiag.df.plant import seed_aircraft

    model = seed_aircraft()
    return isolability_analysis(model.A, model.C, list(model.output_names),
                                eigenvalues=eigenvalues)


def seed_gust_decoupling() -> Any:
    """The decoupling analysis of the seed aircraft's gust input (α and q columns of A in
    the α̇ and q̇ rows).

    Returns
    -------
    gyrodiag.df.decoupling.DecouplingReport
    """
    from gyrodiag.df.decoupling import decoupled_isolability
    from gyrodiag.df.gust import seed_gust_input
    from gyrodiag.df.plant import seed_aircraft

    model = seed_aircraft()
    return decoupled_isolability(model.A, model.C, seed_gust_input(model.A),
                                 list(model.output_names))


def _detectable(entry: Any) -> str:
    if entry.bias_steady_state_detectable:
        return "steady state"
    if entry.transient_time_constant_s > 0.0:
        return "onset only"
    return "no"


def _floats(a: Any) -> Any:
    """Array → nested lists of floats, NaN → None (JSON has no NaN)."""
    arr = np.asarray(a, dtype=float)
    return [_floats(row) for row in arr] if arr.ndim > 1 else [
        None if math.isnan(v) else float(v) for v in arr]


def isolability_data(report: Any) -> dict[str, Any]:
    """The report as plain JSON-able data (sensor order = output order of the model)."""
    sensors = []
    for entry in report.sensors:
        isolable = sorted(set(entry.direction_isolable_from) | set(entry.bank_isolable_from),
                          key=report.sensor_names.index)
        sensors.append({
            "name": entry.name,
            "detectable": _detectable(entry),
            "isolable_from": isolable,
            "direction_isolable_from": list(entry.direction_isolable_from),
            "bank_isolable_from": list(entry.bank_isolable_from),
            "redundant": bool(entry.redundant),
            "bias_steady_state_detectable": bool(entry.bias_steady_state_detectable),
            "bias_indistinguishable_from_state": bool(entry.bias_indistinguishable_from_state),
            "transient_time_constant_s": float(entry.transient_time_constant_s),
            "bias_signature": _floats(entry.bias_signature),
            "bank_pattern": [bool(b) for b in entry.bank_pattern],
        })
    eig = np.asarray(report.closed_loop_eigenvalues)
    return {
        "model": "seed aircraft (docs/methods.md §4)",
        "sensor_names": list(report.sensor_names),
        "closed_loop_eigenvalues": [float(e.real) for e in eig]
        if np.all(np.abs(eig.imag) < 1e-12) else [[float(e.real), float(e.imag)] for e in eig],
        "K": _floats(report.K),
        "collinear_cos": float(report.collinear_cos),
        "parity_relations": _floats(report.parity_relations),
        "signatures": _floats(report.signatures),
        "cosines": _floats(report.cosines),
        "bank_signatures": _floats(report.bank_signatures),
        "sensors": sensors,
        "gust_decoupled": _decoupling_data(seed_gust_decoupling()),
    }


def _decoupling_data(dec: Any) -> dict[str, Any]:
    return {
        "frequencies_rad_s": [float(w) for w in dec.frequencies],
        "disturbance_rank": [int(r) for r in dec.disturbance_rank],
        "collinear_cos": float(dec.collinear_cos),
        "sensors": [{"name": name, "visibility": [float(v) for v in dec.visibility[:, i]],
                     "isolable_from": list(dec.isolable_from(name))}
                    for i, name in enumerate(dec.sensor_names)],
    }


def _summary_rows(data: dict[str, Any]) -> list[tuple[str, str, str, str]]:
    rows = []
    for s in data["sensors"]:
        detect = s["detectable"]
        if detect == "onset only":
            detect += f" (tau {s['transient_time_constant_s']:.3g} s)"
        rows.append((s["name"], detect, ", ".join(s["isolable_from"]) or "none",
                     "yes" if s["redundant"] else "no"))
    return rows


def _summary_text(data: dict[str, Any]) -> str:
    header = ("SENSOR", "DETECTABLE (constant bias)", "ISOLABLE FROM", "REDUNDANT")
    rows = [header, *_summary_rows(data)]
    widths = [max(len(r[j]) for r in rows) for j in range(len(header))]
    lines = ["  ".join(c.ljust(w) for c, w in zip(r, widths, strict=True)).rstrip()
             for r in rows]
    return "\n".join(lines)


def render(report: Any, fmt: str = "text") -> str:
    """The report as text, JSON or a standalone HTML page.

    Parameters
    ----------
    report : gyrodiag.df.isolation.IsolabilityReport
        From :func:`seed_isolability_report`.
    fmt : {"text", "json", "html"}
        Output format.
    """
    if fmt not in FORMATS:
        raise ValueError(f"fmt must be one of {FORMATS}, got {fmt!r}")
    data = isolability_data(report)
    if fmt == "json":
        return json.dumps(data, indent=2) + "\n"
    summary = _summary_text(data)
    detail = report.to_text() + "\n\n" + seed_gust_decoupling().to_text()
    if fmt == "text":
        return f"Isolability of the six aircraft sensors (seed aircraft)\n\n{summary}\n\n" \
               f"{detail}\n"
    head = "".join(f"<th>{html.escape(h)}</th>" for h in
                   ("Sensor", "Detectable (constant bias)", "Isolable from", "Redundant"))
    body = "".join("<tr>" + "".join(f"<td>{html.escape(c)}</td>" for c in row) + "</tr>"
                   for row in _summary_rows(data))
    return ("<!DOCTYPE html>\n<html><head><meta charset=\"utf-8\">"
            "<title>Sensor-fault isolability</title>"
            "<style>body{font-family:sans-serif}table{border-collapse:collapse}"
            "td,th{border:1px solid #999;padding:2px 8px;text-align:left}</style>"
            "</head><body><h1>Sensor-fault isolability (seed aircraft)</h1>"
            f"<table><tr>{head}</tr>{body}</table>"
            f"<h2>Details</h2><pre>{html.escape(detail)}</pre></body></html>\n")


def write(path: Path | str, report: Any, fmt: str | None = None) -> Path:
    """Write the report to ``path``; the format defaults from the suffix (.json, .html,
    anything else text)."""
    target = Path(path)
    chosen = fmt or _SUFFIX_FORMAT.get(target.suffix.lower(), "text")
    text = render(report, chosen)
    target.parent.mkdir(parents=True, exist_ok=True)
    target.write_text(text, encoding="utf-8")
    return target
