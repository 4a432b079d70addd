"""Plots of a co-simulation run (matplotlib, headless), one figure per diagnosis channel.

Every function returns a :class:`matplotlib.figure.Figure` on an Agg canvas, built
without pyplot (headless; no global backend switch, no figure registry to leak).

What a reader needs from a plot, and how each one gives it:

* **What passed.** :func:`figures_for_result` titles each channel's figure with the
  verdict of the expectations that read that channel's signals ("2 of 2 expectations
  passed", or which failed).
* **When things happen.** Fault windows are shaded in colour on every panel,
  manoeuvre windows hatched;
  calibration (detection filter) and learning (DTG θ0) windows in grey, taken from the
  Diagnoser's own ``df.calibrating`` / ``dtg.learning`` outputs when recorded, else from
  its threshold / θ0 outputs (0 until calibrated / learned), else from the scenario's
  parameters.
* **Readable values.** The y range of a panel comes from the data after the start-up
  (calibration, learning or the first 5 % of the record), always including the
  thresholds drawn on it; what lies outside (an observer's start-up transient, a
  diverging estimate) is clipped and the panel says so with the full range.
* **Nothing hidden.** Legends sit below the panels, never on the data; alarm, flag and
  code signals are step lanes under the signals they belong to.

Figures: :func:`plot_dtg_channel` (θ1..θ5 and/or η1..η5 panels, the DTG paper's Fig.
3–5, with the η band; alarm and fault-code lanes), :func:`plot_grey_channel`
(measurement and prediction, |error| with the threshold; alarm lane),
:func:`plot_df_channel` (residuals with ± thresholds; detection, isolation and alarm
lanes), :func:`plot_alarm_timeline` (the flags of no channel, e.g. fault injection).
The older single-purpose plots (:func:`plot_theta`, :func:`plot_signals_with_faults`)
remain for scripts, and :func:`plot_grey_prediction`, the grey channel's figure without
its lanes.
Independent witnesses of one root cause (``witnesses_agree`` expectations) share
one timeline (:func:`plot_witnesses`).

Long records are reduced to a min/max envelope per pixel-column bucket before plotting,
so spikes (alarms, fault transients) stay visible.
"""

from __future__ import annotations

import io
import math
import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np
from matplotlib.axes import Axes
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from numpy.typing import ArrayLike, NDArray

from gyrodiag_harness.verification import expectations as _expectations

if TYPE_CHECKING:
    from gyrodiag_harness.cosim.results import FaultWindow, RunResult
    from gyrodiag_harness.verification.expectations import ScenarioVerdict

__all__ = [
    "FLAG_PATTERN",
    "Shade",
    "figure_to_png",
    "figures_for_result",
    "plot_alarm_timeline",
    "plot_df_channel",
    "plot_dtg_channel",
    "plot_grey_channel",
    "plot_grey_prediction",
    "plot_signals_with_faults",
    "plot_theta",
    "plot_witnesses",
    "scenario_connections",
    "scenario_parameters",
    "shade_fault_windows",
    "shade_manoeuvre_windows",
]

MAX_PLOT_POINTS = 3000
"""Buckets of the min/max envelope; longer records are reduced to 2× this many points."""

FLAG_PATTERN = re.compile(
    r"(alarm|detected|fault_active|fault_code|fault_type|isolated\w*|calibrating|learning)"
    r"(_\d+)?(\[\d+\])?$"
)
"""Variable names plotted as step lanes (last dotted component)."""

MAX_TIMELINE_LANES = 16
#: Share of the record treated as start-up when no calibration/learning window is known.
STARTUP_FRACTION = 0.05

_THETA = re.compile(r"^(?P<prefix>.+)\.theta_(?P<axis>[xy])\[(?P<i>\d+)\]$")
_RESIDUAL = re.compile(r"^(?P<inst>.+)\.df\.residual\[(?P<i>\d+)\]$")
_GREY = re.compile(r"^(?P<inst>.+)\.grey\.prediction$")
_CHANNEL = re.compile(r"^(?P<inst>[^.]+)\.(?P<ch>dtg|grey|df)\.")
_FAULT_COLOURS = ("tab:red", "tab:orange", "tab:purple", "tab:brown", "tab:pink", "tab:olive")
_FAULT_ALPHA = 0.15
_STARTUP_ALPHA = 0.22
_CHANNEL_TITLES = {"dtg": "DTG channel", "grey": "grey-prediction channel",
                   "df": "detection-filter channel"}


@dataclass(frozen=True)
class Shade:
    """A shaded time span: ``label`` (legend), ``start_s``, ``end_s``."""

    label: str
    start_s: float
    end_s: float


# ------------------------------------------------------------------ helpers
def _envelope(
    t: NDArray[np.float64], y: NDArray[np.float64], max_points: int = MAX_PLOT_POINTS
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    if t.size <= 2 * max_points:
        return t, y
    edges = np.linspace(0, t.size, max_points + 1).astype(int)[:-1]
    with np.errstate(invalid="ignore"):
        lo = np.fmin.reduceat(y, edges)
        hi = np.fmax.reduceat(y, edges)
    mid = np.append(edges[1:], t.size)
    t_mid = t[(edges + mid - 1) // 2]
    tt = np.column_stack((t[edges], t_mid)).ravel()
    yy = np.column_stack((lo, hi)).ravel()
    return tt, yy


def _plot(ax: Axes, t: ArrayLike, y: ArrayLike, **kwargs: Any) -> None:
    tt, yy = _envelope(np.asarray(t, dtype=float), np.asarray(y, dtype=float))
    ax.plot(tt, yy, **kwargs)


def shade_fault_windows(
    ax: Axes, fault_windows: Sequence[FaultWindow], t_end_s: float, *, label: bool = True
) -> None:
    """Shade each fault window ``[start_s, min(end_s, t_end_s)]`` on ``ax``.

    Parameters
    ----------
    ax : Axes
        Target axes (time in s on x).
    fault_windows : sequence of FaultWindow
        Windows of the run.
    t_end_s : float
        End of the record, s (open windows are shaded up to here).
    label : bool
        Add ``fault: <name>`` legend labels.
    """
    for i, w in enumerate(fault_windows):
        end = min(w.end_s, t_end_s)
        if end < w.start_s:
            continue
        ax.axvspan(w.start_s, max(end, w.start_s), color=_FAULT_COLOURS[i % len(_FAULT_COLOURS)],
                   alpha=_FAULT_ALPHA, lw=0, label=f"fault: {w.name}" if label else None)


def _shade(ax: Axes, result: RunResult, startup: Sequence[Shade], label: bool) -> None:
    for s in startup:
        # plain grey: hatching marks manoeuvres
        ax.axvspan(s.start_s, s.end_s, color="0.55", alpha=_STARTUP_ALPHA, lw=0,
                   label=s.label if label else None)
    shade_fault_windows(ax, result.fault_windows, _t_end(result), label=label)
    shade_manoeuvre_windows(ax, result.manoeuvre_windows, _t_end(result), label=label)


def shade_manoeuvre_windows(
    ax: Axes, manoeuvre_windows: Sequence[FaultWindow], t_end_s: float, *, label: bool = True
) -> None:
    """Mark each manoeuvre window on ``ax`` (grey hatch: fault-free time, unlike faults).

    Parameters are those of :func:`shade_fault_windows`; labels read
    ``manoeuvre: <name> (<kind>)``.
    """
    for w in manoeuvre_windows:
        end = min(w.end_s, t_end_s)
        if end < w.start_s:
            continue
        ax.axvspan(w.start_s, max(end, w.start_s), facecolor="none", edgecolor="0.55",
                   hatch="//", lw=0, alpha=0.6,
                   label=f"manoeuvre: {w.name} ({w.kind})" if label else None)


def _t_end(result: RunResult) -> float:
    t = np.asarray(result.time, dtype=float)
    return float(t[-1]) if t.size else 0.0


def _new_figure(rows: int, height_per_row: float, width: float = 9.0,
                ratios: Sequence[float] | None = None) -> tuple[Figure, list[Axes]]:
    heights = list(ratios) if ratios is not None else [1.0] * rows
    total = sum(heights) * height_per_row + 1.0
    fig = Figure(figsize=(width, max(2.4, total)), layout="constrained")
    # an explicit Agg canvas instead of pyplot: headless, and no global backend switch or
    # figure registry that a caller's interactive session would notice
    FigureCanvasAgg(fig)
    axes = fig.subplots(rows, 1, sharex=True, squeeze=False,
                        gridspec_kw={"height_ratios": heights})[:, 0]
    return fig, list(axes)


def _legend_below(fig: Figure, axes: Sequence[Axes]) -> None:
    # one legend for the figure, under the panels: it never covers data
    handles: dict[str, Any] = {}
    for ax in axes:
        for h, label in zip(*ax.get_legend_handles_labels(), strict=True):
            if label and not label.startswith("_"):
                handles.setdefault(label, h)
    if handles:
        fig.legend(list(handles.values()), list(handles), loc="outside lower center",
                   ncol=min(len(handles), 4), fontsize=7, frameon=False)


def _startup_end(t: NDArray[np.float64], startup: Sequence[Shade]) -> float:
    if startup:
        return max(s.end_s for s in startup)
    if t.size == 0:
        return 0.0
    return float(t[0] + STARTUP_FRACTION * (t[-1] - t[0]))


def _robust_ylim(ax: Axes, t: NDArray[np.float64], curves: Sequence[ArrayLike],
                 t_from: float | None = None, levels: Sequence[float] = ()) -> None:
    """Y range from the data after ``t_from`` (default: the first 5 % are start-up) plus
    the ``levels`` that must stay visible (thresholds); data beyond it is clipped and
    the panel says so."""
    arrays = [np.asarray(c, dtype=float) for c in curves]
    if t_from is None:
        t_from = _startup_end(t, ())
    keep = t >= t_from
    if np.count_nonzero(keep) < 10:
        keep = np.ones(t.shape, dtype=bool)
    steady = np.concatenate([c[keep & np.isfinite(c)] for c in arrays]) if arrays else \
        np.array([])
    every = np.concatenate([c[np.isfinite(c)] for c in arrays]) if arrays else np.array([])
    marks = [v for v in levels if math.isfinite(v)]
    if steady.size < 10 and not marks:
        return
    lo_hi = list(np.percentile(steady, [0.5, 99.5])) if steady.size >= 10 else []
    lo = min([*lo_hi[:1], *marks])
    hi = max([*lo_hi[1:], *marks])
    span = hi - lo
    if span <= 0:
        span = max(abs(hi), 1e-12)
    lo, hi = lo - 0.12 * span, hi + 0.12 * span
    if every.size == 0:
        ax.set_ylim(lo, hi)
        return
    full_lo, full_hi = float(every.min()), float(every.max())
    if full_lo >= lo - 0.5 * span and full_hi <= hi + 0.5 * span:
        ax.set_ylim(min(lo, full_lo - 0.05 * span), max(hi, full_hi + 0.05 * span))
        return
    ax.set_ylim(lo, hi)
    ax.text(0.995, 0.03, f"y clipped (data {full_lo:.3g} … {full_hi:.3g})",
            transform=ax.transAxes, ha="right", va="bottom", fontsize=6, color="0.35",
            bbox={"facecolor": "white", "alpha": 0.7, "lw": 0, "pad": 1})


def _limit_to_reference(
    ax: Axes, reference: NDArray[np.float64], other: NDArray[np.float64]
) -> None:
    # a diverging estimate (e.g. a predictor fed its own predictions) must not flatten
    # the measurement into a line at zero: keep the measurement's range, say so
    ref = reference[np.isfinite(reference)]
    oth = other[np.isfinite(other)]
    if ref.size == 0 or oth.size == 0:
        return
    lo, hi = float(ref.min()), float(ref.max())
    span = max(hi - lo, 1e-12)
    if oth.min() < lo - 10.0 * span or oth.max() > hi + 10.0 * span:
        ax.set_ylim(lo - 0.5 * span, hi + 0.5 * span)
        ax.text(0.995, 0.03, f"estimate clipped (range {oth.min():.3g} … {oth.max():.3g})",
                transform=ax.transAxes, ha="right", va="bottom", fontsize=6, color="0.35")


def _lane(ax: Axes, t: NDArray[np.float64], values: ArrayLike, name: str) -> None:
    y = np.asarray(values, dtype=float)
    _plot(ax, t, y, lw=1.0, color="tab:blue", drawstyle="steps-post")
    ax.set_ylabel(name, rotation=0, ha="right", va="center", fontsize=7)
    ax.tick_params(axis="y", labelsize=6)
    finite = y[np.isfinite(y)]
    if finite.size == 0 or np.all(np.isin(finite, (0.0, 1.0))):
        ax.set_ylim(-0.2, 1.2)  # fixed for 0/1 flags: a flag that never fires stays at 0
        ax.set_yticks([0, 1])
    else:
        ax.margins(y=0.2)
        top = int(np.nanmax(finite))
        if 0 <= top <= 10 and np.all(finite == np.round(finite)):
            ax.set_yticks(sorted(set(int(v) for v in np.unique(finite))))
    ax.grid(alpha=0.3)


_INDEXED = re.compile(r"^(?P<base>.+)\[(?P<i>\d+)\]$")


def _lane_rows(names: Sequence[str], sig: Mapping[str, ArrayLike]) -> list[list[str]]:
    """Lanes to draw: 0/1 flags named ``base[i]`` (two or more of one base) share one
    raster lane; every other flag or code has a lane of its own."""
    groups: dict[str, list[str]] = {}
    for n in names:
        m = _INDEXED.match(n)
        values = np.asarray(sig[n], dtype=float)
        finite = values[np.isfinite(values)]
        if m and np.all(np.isin(finite, (0.0, 1.0))):
            groups.setdefault(m["base"], []).append(n)
    rows: list[list[str]] = []
    done: set[str] = set()
    for n in names:
        if n in done:
            continue
        m = _INDEXED.match(n)
        group = groups.get(m["base"], []) if m else []
        if len(group) >= 2:
            rows.append(sorted(group, key=_index))
            done.update(group)
        else:
            rows.append([n])
            done.add(n)
    return rows


def _raster_lane(ax: Axes, t: NDArray[np.float64], sig: Mapping[str, ArrayLike],
                 names: Sequence[str]) -> None:
    # one row per index: a bar where the flag is on
    for n in names:
        i = _index(n)
        spans = _on_spans(t, sig[n])
        ax.broken_barh([(a, max(b - a, 0.0)) for a, b in spans], (i - 0.35, 0.7),
                       color="tab:blue", lw=0)
    indices = [_index(n) for n in names]
    ax.set_ylim(min(indices) - 0.6, max(indices) + 0.6)
    ax.set_yticks(indices)
    ax.tick_params(axis="y", labelsize=6)
    base = names[0].rsplit(".", 1)[-1].split("[")[0]
    ax.set_ylabel(f"{base}[i]", rotation=0, ha="right", va="center", fontsize=7)
    ax.grid(alpha=0.3, axis="x")


def _draw_lanes(axes: Sequence[Axes], result: RunResult, rows: Sequence[Sequence[str]],
                startup: Sequence[Shade], first_label: bool) -> None:
    t = np.asarray(result.time, dtype=float)
    for k, (ax, row) in enumerate(zip(axes, rows, strict=True)):
        _shade(ax, result, startup, label=first_label and k == 0)
        if len(row) == 1:
            _lane(ax, t, result.signals[row[0]], row[0].rsplit(".", 1)[-1])
        else:
            _raster_lane(ax, t, result.signals, row)


def _lane_ratio(row: Sequence[str]) -> float:
    return 0.35 if len(row) == 1 else 0.2 + 0.12 * len(row)


def _symlog_if_needed(ax: Axes, values: ArrayLike, threshold: float | None) -> bool:
    """Residuals far beyond their threshold (a large fault): linear within ± 2 thresholds,
    logarithmic beyond, so that both the noise against the threshold and the fault's
    size are readable.  Returns whether it switched."""
    if threshold is None or not threshold > 0:
        return False
    x = np.asarray(values, dtype=float)
    x = x[np.isfinite(x)]
    if x.size == 0 or np.percentile(np.abs(x), 99.5) < 10.0 * threshold:
        return False
    ax.set_yscale("symlog", linthresh=2.0 * threshold, linscale=1.5)
    top = float(np.max(np.abs(x)))
    ax.set_ylim(-1.5 * top, 1.5 * top)
    return True


def figure_to_png(fig: Figure, dpi: int = 80, colors: int | None = 256) -> bytes:
    """Render a figure to PNG bytes (Agg).

    Parameters
    ----------
    fig : Figure
        The figure (opaque background).
    dpi : int
        Resolution, dots per inch.
    colors : int or None
        Palette size (2-256) of an 8-bit palette PNG; None: 32-bit RGBA as matplotlib
        writes it.  A plot of a few line colours, grey shading and anti-aliased edges
        looks the same with 256 colours (median cut) and takes 2.7x less space: the seed
        scenarios' 44 plots 2.2 MB -> 0.83 MB, most of report.html.
    """
    if colors is not None and not 2 <= colors <= 256:
        raise ValueError(f"colors must be 2..256 or None, got {colors!r}")
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=dpi)
    if colors is None:
        return buf.getvalue()
    # Pillow is matplotlib's own dependency (its PNG writer)
    from PIL import Image

    buf.seek(0)
    with Image.open(buf) as image:
        palette = image.convert("RGB").quantize(colors, method=Image.Quantize.MEDIANCUT)
    out = io.BytesIO()
    palette.save(out, format="PNG", optimize=True)
    return out.getvalue()


# -------------------------------------------------------------- scenario access
def _as_plain(obj: Any) -> Any:
    dump = getattr(obj, "model_dump", None)
    return dump(by_alias=True) if callable(dump) else obj


def scenario_parameters(scenario: Any, instance: str) -> dict[str, Any]:
    """Parameters set for ``instance`` in a scenario (model or dict); {} if unknown."""
    if scenario is None:
        return {}
    fmus = _as_plain(scenario).get("fmus", {}) if isinstance(_as_plain(scenario), Mapping) else {}
    inst = fmus.get(instance) or {}
    return dict(inst.get("parameters") or {})


def scenario_connections(scenario: Any) -> list[tuple[str, str]]:
    """``(from, to)`` pairs of a scenario (model or dict); [] if none."""
    if scenario is None:
        return []
    plain = _as_plain(scenario)
    out = []
    for c in (plain.get("connections") or []) if isinstance(plain, Mapping) else []:
        src = c.get("from", c.get("from_"))
        if src is not None and c.get("to") is not None:
            out.append((str(src), str(c["to"])))
    return out


def _scenario_expect(scenario: Any) -> list[Any]:
    if scenario is None:
        return []
    if isinstance(scenario, Mapping):
        return list(scenario.get("expect") or [])
    return list(getattr(scenario, "expect", None) or [])


# ------------------------------------------------------- start-up windows of channels
def _on_spans(t: NDArray[np.float64], flag: ArrayLike) -> list[tuple[float, float]]:
    on = np.asarray(flag, dtype=float) > 0.5
    if t.size == 0 or not on.any():
        return []
    edges = np.flatnonzero(np.diff(np.concatenate(([0], on.astype(np.int8), [0]))))
    spans = []
    for start, stop in zip(edges[::2], edges[1::2], strict=True):
        end = t[stop] if stop < t.size else t[-1]
        spans.append((float(t[start]), float(end)))
    return spans


def _leading_zero_span(t: NDArray[np.float64], values: ArrayLike) -> tuple[float, float] | None:
    v = np.asarray(values, dtype=float)
    nonzero = np.flatnonzero(np.isfinite(v) & (v != 0.0))
    if t.size == 0 or nonzero.size == 0 or nonzero[0] == 0:
        return None
    return float(t[0]), float(t[nonzero[0]])


def _number(value: Any) -> float | None:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return None
    return float(value) if math.isfinite(value) else None


def startup_shades(result: RunResult, scenario: Any, inst: str, channel: str) -> list[Shade]:
    """Calibration (df) or θ0 learning (dtg) windows of one Diagnoser channel.

    From the channel's own flag output if recorded (``df.calibrating``,
    ``dtg.learning``), else from the outputs that are 0 until it is ready
    (``df.threshold_in_use[i]``, ``dtg.theta0_used[i]``), else from the scenario's
    parameters (``df.burn_in_s``/``df.calibrate_s``, ``dtg.learn_start_s``/
    ``dtg.learn_end_s``) when it sets them; [] if none of these is known.
    """
    t = np.asarray(result.time, dtype=float)
    sig = result.signals
    params = scenario_parameters(scenario, inst)
    if channel == "df":
        label = "calibration"
        flag, ready, keys = f"{inst}.df.calibrating", f"{inst}.df.threshold_in_use[", \
            ("df.burn_in_s", "df.calibrate_s")
    elif channel == "dtg":
        label = "θ0 learning"
        flag, ready, keys = f"{inst}.dtg.learning", f"{inst}.dtg.theta0_used[", \
            ("dtg.learn_start_s", "dtg.learn_end_s")
    else:
        return []
    if flag in sig:
        return [Shade(label, a, b) for a, b in _on_spans(t, sig[flag])]
    for name in sorted(n for n in sig if n.startswith(ready)):
        span = _leading_zero_span(t, sig[name])
        if span is not None:
            return [Shade(label, *span)]
    start, end = (_number(params.get(k)) for k in keys)
    if end is not None and end > 0:
        begin = start if (start is not None and channel == "dtg") else 0.0
        return [Shade(label, begin, end)]
    return []


# ------------------------------------------------------------------- verdict titles
def _verdict_text(verdict: ScenarioVerdict | None, scenario: Any, prefixes: Sequence[str]
                  ) -> str:
    """What the expectations reading signals that start with ``prefixes`` say."""
    if verdict is None:
        return ""
    raw = _scenario_expect(scenario)
    mine = []
    for i, e in enumerate(verdict.expectations):
        if i >= len(raw):
            break
        try:
            signals = _expectations.referenced_signals(raw[i])
        except Exception:  # an invalid table cannot be attributed to a channel
            continue
        if any(s.startswith(p) for s in signals for p in prefixes):
            mine.append(e)
    if not mine:
        return "no expectation on it"
    if not all(getattr(e, "evaluated", True) for e in mine):
        return f"{len(mine)} expectations not evaluated (run incomplete)"
    failed = [e.name for e in mine if not e.passed]
    if not failed:
        return f"{len(mine)} of {len(mine)} expectations passed"
    shown = "; ".join(failed[:2]) + (" …" if len(failed) > 2 else "")
    return f"{len(failed)} of {len(mine)} expectations FAILED: {shown}"


def _title(label: str, inst: str, verdict_text: str) -> str:
    head = f"{label} — {inst}"
    return f"{head}: {verdict_text}" if verdict_text else head


# ------------------------------------------------------------------- channel figures
def plot_dtg_channel(
    result: RunResult,
    inst: str,
    *,
    scenario: Any = None,
    startup: Sequence[Shade] = (),
    sample_period_s: float | None = None,
    title: str | None = None,
) -> Figure:
    """The DTG channel of Diagnoser instance ``inst``: θ1..θ5 panels (x and y axis, the
    nominal θ0 dashed; the paper's Fig. 3–5), η1..η5 panels with the alarm band
    (``dtg.low``/``dtg.high`` of the scenario), then the alarm / code / learning lanes,
    whichever are recorded."""
    t = np.asarray(result.time, dtype=float)
    sig = result.signals
    prefix = f"{inst}.dtg"
    theta = [i for i in range(1, 6) if any(f"{prefix}.theta_{a}[{i}]" in sig for a in "xy")
             and any(_carries_data(sig[n]) for n in (f"{prefix}.theta_x[{i}]",
                                                     f"{prefix}.theta_y[{i}]") if n in sig)]
    eta = [i for i in range(1, 6) if any(f"{prefix}.eta_{a}[{i}]" in sig for a in "xy")]
    lanes = _lane_rows([n for n in sig if n.startswith(prefix + ".") and _is_lane(n, sig[n])],
                       sig)
    if not (theta or eta or lanes):
        raise ValueError(f"no {prefix}.theta_*, eta_* or alarm signal recorded")
    params = scenario_parameters(scenario, inst)
    low, high = _number(params.get("dtg.low")), _number(params.get("dtg.high"))
    panels = len(theta) + len(eta)
    fig, axes = _new_figure(panels + len(lanes), 1.5,
                            ratios=[1.0] * panels + [_lane_ratio(r) for r in lanes])
    t_from = _startup_end(t, startup)
    k = 0
    for i in theta:
        ax = axes[k]
        _shade(ax, result, startup, label=k == 0)
        curves = []
        for axis, colour in (("x", "tab:blue"), ("y", "tab:green")):
            name = f"{prefix}.theta_{axis}[{i}]"
            if name in sig:
                _plot(ax, t, sig[name], lw=0.8, color=colour, label=f"{axis} axis")
                curves.append(sig[name])
        ref = f"{prefix}.theta0_used[{i}]"
        if ref in sig:
            y0 = np.where(np.asarray(sig[ref], dtype=float) != 0.0, sig[ref], np.nan)
            _plot(ax, t, y0, lw=0.8, ls="--", color="k", label="θ0 (nominal)")
            curves.append(y0)
        _robust_ylim(ax, t, curves, t_from)
        ax.set_ylabel(f"θ{i}")
        ax.grid(alpha=0.3)
        k += 1
    for i in eta:
        ax = axes[k]
        _shade(ax, result, startup, label=k == 0)
        curves = []
        for axis, colour in (("x", "tab:blue"), ("y", "tab:green")):
            name = f"{prefix}.eta_{axis}[{i}]"
            if name in sig:
                _plot(ax, t, sig[name], lw=0.8, color=colour, label=f"{axis} axis")
                curves.append(sig[name])
        band = [v for v in (low, high) if v is not None]
        for v in band:
            ax.axhline(v, ls="--", lw=0.8, color="k", label="alarm band")
        _robust_ylim(ax, t, curves, t_from, levels=band)
        ax.set_ylabel(f"η{i}")
        ax.grid(alpha=0.3)
        k += 1
    _draw_lanes(axes[k:], result, lanes, startup, first_label=k == 0)
    axes[-1].set_xlabel("time (s)")
    if sample_period_s and sample_period_s > 0 and t.size:
        t0 = float(t[0])
        top = axes[0].secondary_xaxis(
            "top", functions=(lambda x: (x - t0) / sample_period_s,
                              lambda n: n * sample_period_s + t0))
        top.set_xlabel("sample index", fontsize=8)
    _legend_below(fig, axes)
    fig.suptitle(title or f"DTG channel — {inst}", fontsize=10)
    return fig


def plot_grey_channel(
    result: RunResult,
    inst: str,
    *,
    measured: str | None = None,
    threshold: float | None = None,
    title: str | None = None,
    predicted: str | None = None,
    error: str | None = None,
    lanes: bool = True,
) -> Figure:
    """The grey-prediction channel of ``inst``: measurement and prediction, |error| with
    the threshold, the alarm lane (whichever are recorded).

    ``predicted`` / ``error`` name the prediction ŷ and the error ``y − ŷ`` (default
    ``<inst>.grey.prediction`` / ``<inst>.grey.error``); the error panel is
    ``|measured − ŷ|``, or ``|error|`` without ``measured``.  ``lanes=False`` draws the
    two prediction panels alone (:func:`plot_grey_prediction`)."""
    t = np.asarray(result.time, dtype=float)
    sig = result.signals
    predicted = predicted or f"{inst}.grey.prediction"
    if error is None:
        error = f"{inst}.grey.error" if f"{inst}.grey.error" in sig else None
    lanes = _lane_rows([n for n in sig if n.startswith(f"{inst}.grey.")
                        and _is_lane(n, sig[n])], sig) if lanes else []
    has_pred = predicted in sig and (measured is not None or error is not None)
    if not has_pred and not lanes:
        raise ValueError(f"no {predicted} with its measurement, nor a grey alarm, recorded")
    n_top = 2 if has_pred else 0
    fig, axes = _new_figure(n_top + len(lanes), 1.9,
                            ratios=[1.2] * n_top + [_lane_ratio(r) for r in lanes])
    k = 0
    if has_pred:
        top, bottom = axes[0], axes[1]
        for j, ax in enumerate((top, bottom)):
            _shade(ax, result, (), label=j == 0)
        p = np.asarray(sig[predicted], dtype=float)
        if measured is not None:
            y = np.asarray(sig[measured], dtype=float)
            _plot(top, t, y, lw=0.9, color="tab:blue", label=f"measured ({measured})")
            err = np.abs(y - p)
        else:
            err = np.abs(np.asarray(sig[error], dtype=float))
        _plot(top, t, p, lw=0.9, ls="--", color="tab:orange", label="prediction")
        if measured is not None:
            _limit_to_reference(top, y, p)
        top.set_ylabel("signal")
        _plot(bottom, t, err, lw=0.8, color="tab:red", label="|y − ŷ|")
        if threshold is not None:
            bottom.axhline(threshold, ls="--", color="k", lw=0.8,
                           label=f"threshold {threshold:g}")
        positive = err[np.isfinite(err) & (err > 0.0)]
        if positive.size and positive.max() > 1e3 * np.median(positive):
            bottom.set_yscale("log")  # errors spanning decades: keep the threshold readable
            floor = float(positive.min())
            if threshold and floor < 1e-4 * threshold:  # round-off zeros say nothing
                bottom.set_ylim(1e-4 * threshold, 3.0 * float(positive.max()))
        else:
            _robust_ylim(bottom, t, [err], levels=[0.0] + ([threshold] if threshold else []))
        bottom.set_ylabel("|error|")
        for ax in (top, bottom):
            ax.grid(alpha=0.3)
        k = 2
    _draw_lanes(axes[k:], result, lanes, (), first_label=k == 0)
    axes[-1].set_xlabel("time (s)")
    _legend_below(fig, axes)
    fig.suptitle(title or f"grey-prediction channel — {inst}", fontsize=10)
    return fig


def plot_df_channel(
    result: RunResult,
    inst: str,
    *,
    scenario: Any = None,
    startup: Sequence[Shade] = (),
    title: str | None = None,
) -> Figure:
    """The detection-filter channel of ``inst``: one panel per recorded residual with its
    ± threshold (recorded ``df.threshold_in_use[i]`` or ``df.threshold[i]``, else the
    scenario's ``df.threshold[i]`` parameter), then the detection / isolation / alarm
    lanes."""
    t = np.asarray(result.time, dtype=float)
    sig = result.signals
    residuals = sorted((n for n in sig if (m := _RESIDUAL.match(n)) and m["inst"] == inst),
                       key=_index)
    lanes = _lane_rows([n for n in sig if n.startswith(f"{inst}.df.") and _is_lane(n, sig[n])],
                       sig)
    if not residuals and not lanes:
        raise ValueError(f"no {inst}.df.residual[i] or detection signal recorded")
    params = scenario_parameters(scenario, inst)
    fig, axes = _new_figure(len(residuals) + len(lanes), 1.5,
                            ratios=[1.2] * len(residuals) + [_lane_ratio(r) for r in lanes])
    t_from = _startup_end(t, startup)
    k = 0
    for name in residuals:
        ax = axes[k]
        _shade(ax, result, startup, label=k == 0)
        _plot(ax, t, sig[name], lw=0.8, color="tab:blue", label="residual")
        thr = _df_threshold(result, inst, _index(name), params)
        levels: list[float] = []
        if thr is not None:
            thr_arr = np.broadcast_to(np.asarray(thr, dtype=float), t.shape)
            for sign in (1.0, -1.0):
                _plot(ax, t, sign * thr_arr, lw=0.8, ls="--", color="k",
                      label="± threshold" if sign > 0 else None)
            finite = thr_arr[np.isfinite(thr_arr)]
            if finite.size:
                levels = [float(finite.max()), -float(finite.max())]
        # an observer's start-up transient must not squash the thresholds into a line,
        # nor a large fault: beyond ten thresholds the axis turns logarithmic
        steady = np.asarray(sig[name], dtype=float)[t >= t_from]
        if not _symlog_if_needed(ax, steady, max(levels) if levels else None):
            _robust_ylim(ax, t, [sig[name]], t_from, levels=levels)
        ax.set_ylabel(f"r{_index(name)}", fontsize=8)
        ax.grid(alpha=0.3)
        k += 1
    _draw_lanes(axes[k:], result, lanes, startup, first_label=k == 0)
    axes[-1].set_xlabel("time (s)")
    _legend_below(fig, axes)
    fig.suptitle(title or f"detection-filter channel — {inst}", fontsize=10)
    return fig


def _df_threshold(result: RunResult, inst: str, i: int, params: Mapping[str, Any]) -> Any:
    in_use = f"{inst}.df.threshold_in_use[{i}]"
    thr_signal = f"{inst}.df.threshold[{i}]"
    if in_use in result.signals:
        # 0 while the Diagnoser calibrates: draw nothing there
        curve = np.asarray(result.signals[in_use], dtype=float)
        return np.where(curve > 0.0, curve, np.nan)
    if thr_signal in result.signals:
        return result.signals[thr_signal]
    return _number(params.get(f"df.threshold[{i}]"))


# ------------------------------------------------------------ single-purpose plots
def plot_signals_with_faults(
    result: RunResult,
    names: Sequence[str],
    thresholds: Mapping[str, float | ArrayLike] | None = None,
    *,
    title: str | None = None,
    startup: Sequence[Shade] = (),
) -> Figure:
    """Stacked panels of recorded signals with ± thresholds and shaded fault windows.

    Parameters
    ----------
    result : RunResult
        The run.
    names : sequence of str
        Recorded signal names, one panel each.
    thresholds : mapping of name -> float or array_like, optional
        Detection threshold of a signal (its units): a constant or a recorded
        time-varying curve; drawn as ±threshold (alarms fire on ``|signal| > threshold``).
    title : str, optional
        Figure title.
    startup : sequence of Shade, optional
        Calibration/learning windows to shade; the y range ignores them.

    Returns
    -------
    Figure
    """
    if not names:
        raise ValueError("names must name at least one recorded signal")
    thresholds = thresholds or {}
    t = np.asarray(result.time, dtype=float)
    fig, axes = _new_figure(len(names), 1.6)
    t_from = _startup_end(t, startup)
    for k, (ax, name) in enumerate(zip(axes, names, strict=True)):
        _shade(ax, result, startup, label=k == 0)
        _plot(ax, t, result.signal(name), lw=0.8, color="tab:blue", label=name)
        thr = thresholds.get(name)
        levels: list[float] = []
        if thr is not None:
            thr_arr = np.broadcast_to(np.asarray(thr, dtype=float), t.shape)
            for sign in (1.0, -1.0):
                _plot(ax, t, sign * thr_arr, lw=0.8, ls="--", color="k",
                      label="± threshold" if sign > 0 else None)
            finite = thr_arr[np.isfinite(thr_arr)]
            if finite.size:
                levels = [float(finite.max()), -float(finite.max())]
        _robust_ylim(ax, t, [result.signal(name)], t_from, levels=levels)
        ax.set_ylabel(name.rsplit(".", 1)[-1], fontsize=8)
        ax.grid(alpha=0.3)
    axes[-1].set_xlabel("time (s)")
    _legend_below(fig, axes)
    fig.suptitle(title or "signals", fontsize=10)
    return fig


def plot_theta(
    result: RunResult,
    prefix: str,
    *,
    n_theta: int = 5,
    sample_period_s: float | None = None,
    title: str | None = None,
) -> Figure:
    """θ1..θn trajectories of a DTG parameter channel, one panel per θi (paper Fig. 3–5).

    Parameters
    ----------
    result : RunResult
        The run.
    prefix : str
        Signal prefix, e.g. ``"diag.dtg"``: plots ``{prefix}.theta_x[i]`` and
        ``{prefix}.theta_y[i]`` (both torquer axes) and, dashed, the nominal
        ``{prefix}.theta0_used[i]``, whichever are recorded.
    n_theta : int
        Number of parameters (panels).
    sample_period_s : float, optional
        DTG sample period, s; if given, a top axis shows the sample index (the paper
        plots against time in s, its text speaks in samples).
    title : str, optional
        Figure title.

    Returns
    -------
    Figure
        Dimensionless θ on y, time (s) on x. The y range of a panel is clipped to the
        bulk of its data when the estimator's start-up transient would dominate it.
    """
    t = np.asarray(result.time, dtype=float)
    found = [n for i in range(1, n_theta + 1)
             for n in (f"{prefix}.theta_x[{i}]", f"{prefix}.theta_y[{i}]")
             if n in result.signals]
    if not found:
        raise ValueError(f"no {prefix}.theta_x[i] / theta_y[i] signal recorded")
    fig, axes = _new_figure(n_theta, 1.7)
    for i, ax in enumerate(axes, start=1):
        _shade(ax, result, (), label=i == 1)
        curves = []
        for axis, colour in (("x", "tab:blue"), ("y", "tab:green")):
            name = f"{prefix}.theta_{axis}[{i}]"
            if name in result.signals:
                y = np.asarray(result.signals[name], dtype=float)
                _plot(ax, t, y, lw=0.8, color=colour, label=f"{axis} axis")
                curves.append(y)
        ref = f"{prefix}.theta0_used[{i}]"
        if ref in result.signals:
            y0 = np.asarray(result.signals[ref], dtype=float)
            _plot(ax, t, y0, lw=0.8, ls="--", color="k", label="θ0 (nominal)")
            curves.append(y0)
        _robust_ylim(ax, t, curves)
        ax.set_ylabel(f"θ{i}")
        ax.grid(alpha=0.3)
    axes[-1].set_xlabel("time (s)")
    if sample_period_s and sample_period_s > 0 and t.size:
        t0 = float(t[0])
        top = axes[0].secondary_xaxis(
            "top", functions=(lambda x: (x - t0) / sample_period_s,
                              lambda k: k * sample_period_s + t0))
        top.set_xlabel("sample index", fontsize=8)
    _legend_below(fig, axes)
    fig.suptitle(title or f"θ trajectories ({prefix})", fontsize=10)
    return fig


def plot_grey_prediction(
    result: RunResult,
    predicted: str,
    measured: str | None = None,
    *,
    error: str | None = None,
    threshold: float | None = None,
    title: str | None = None,
) -> Figure:
    """Measurement vs. one-step grey prediction, and the prediction error below: the two
    prediction panels of :func:`plot_grey_channel` without its lanes (kept for scripts).

    Parameters
    ----------
    result : RunResult
        The run.
    predicted : str
        Recorded prediction ŷ (row k predicts row k), signal units.
    measured : str, optional
        Recorded measurement y fed to the predictor. Without it only ŷ is drawn and the
        error comes from ``error``.
    error : str, optional
        Recorded error signal ``y − ŷ``; used when ``measured`` is missing.
    threshold : float, optional
        Alarm threshold on ``|y − ŷ|``, signal units.
    title : str, optional
        Figure title.

    Returns
    -------
    Figure
        Two panels: y and ŷ; |y − ŷ| with the threshold.
    """
    if measured is None and error is None:
        raise ValueError("give measured or error: the error panel needs one of them")
    for name in (predicted, measured, error):
        if name is not None:
            result.signal(name)  # a missing signal raises, naming it
    inst = predicted.removesuffix(".grey.prediction")
    return plot_grey_channel(result, inst, measured=measured, threshold=threshold,
                             title=title or "grey prediction", predicted=predicted,
                             error=error, lanes=False)


def plot_alarm_timeline(
    result: RunResult, names: Sequence[str], *, title: str | None = None
) -> Figure:
    """Alarms, flags and codes as step lanes over time, fault windows shaded.

    Parameters
    ----------
    result : RunResult
        The run.
    names : sequence of str
        Recorded 0/1 or integer signals, one lane each.
    title : str, optional
        Figure title.

    Returns
    -------
    Figure
    """
    if not names:
        raise ValueError("names must name at least one recorded signal")
    t = np.asarray(result.time, dtype=float)
    fig, axes = _new_figure(len(names), 0.7)
    for k, (ax, name) in enumerate(zip(axes, names, strict=True)):
        _shade(ax, result, (), label=k == 0)
        _lane(ax, t, result.signal(name), name)
    axes[-1].set_xlabel("time (s)")
    _legend_below(fig, axes)
    fig.suptitle(title or "alarms and flags", fontsize=10)
    return fig


def plot_witnesses(
    result: RunResult, witnesses: Sequence[str], details: Sequence[str] = (), *,
    title: str | None = None,
) -> Figure:
    """One timeline for independent witnesses of one root cause.

    Each witness's alarm is a filled lane (first rise marked with its time); ``details``
    (class codes, isolated sensor, estimated size) follow as step lanes; fault windows
    are shaded and manoeuvre windows hatched on every lane.

    Parameters
    ----------
    result : RunResult
        The run.
    witnesses : sequence of str
        Recorded alarm signals (0/1), one per witness.
    details : sequence of str
        Further recorded signals shown under the witnesses.
    title : str, optional
        Figure title.
    """
    if not witnesses:
        raise ValueError("witnesses must name at least one recorded signal")
    t = np.asarray(result.time, dtype=float)
    names = [*witnesses, *details]
    fig, axes = _new_figure(len(names), 0.75)
    for k, (ax, name) in enumerate(zip(axes, names, strict=True)):
        _shade(ax, result, (), label=k == 0)
        x = np.asarray(result.signal(name), dtype=float)
        if k < len(witnesses):
            colour = _FAULT_COLOURS[k % len(_FAULT_COLOURS)]
            ax.fill_between(t, 0.0, np.where(x > 0.5, 1.0, 0.0), step="post", color=colour,
                            alpha=0.55, lw=0)
            on = np.flatnonzero(x > 0.5)
            if on.size:
                ax.annotate(f"{t[on[0]]:.2f} s", (t[on[0]], 1.0), fontsize=6,
                            xytext=(2, -8), textcoords="offset points")
            ax.set_ylim(-0.1, 1.3)
            ax.set_yticks([])
        else:
            _plot(ax, t, x, lw=1.0, color="tab:blue", drawstyle="steps-post")
            ax.margins(y=0.2)
            ax.tick_params(axis="y", labelsize=6)
        ax.set_ylabel(name, rotation=0, ha="right", va="center", fontsize=7)
        ax.grid(alpha=0.3)
    axes[-1].set_xlabel("time (s)")
    _legend_below(fig, axes)
    fig.suptitle(title or "witnesses", fontsize=10)
    return fig


def _witness_specs(scenario: Any) -> list[tuple[list[str], list[str], str]]:
    """(witnesses, details, label) of the scenario's witnesses_agree expectations."""
    if scenario is None:
        return []
    from gyrodiag_harness.verification import expectations as ex

    raw = scenario.get("expect", []) if isinstance(scenario, Mapping) else getattr(
        scenario, "expect", [])
    specs = []
    for e in raw or []:
        kind = e.get("kind") if isinstance(e, Mapping) else getattr(e, "kind", None)
        if kind != "witnesses_agree":
            continue
        try:
            w = ex.parse_expectation(e)
        except Exception:
            continue
        specs.append((list(w.witnesses), list(w.details), w.label()))
    return specs


# --------------------------------------------------------------- selection
def _index(name: str) -> int:
    m = re.search(r"\[(\d+)\]$", name)
    return int(m.group(1)) if m else 0


def _carries_data(values: ArrayLike) -> bool:
    x = np.asarray(values, dtype=float)
    return bool(np.any(np.isfinite(x) & (x != 0.0)))


def _is_constant(values: ArrayLike) -> bool:
    x = np.asarray(values, dtype=float)
    return bool(x.size == 0 or np.all(x == x[0]) or np.all(np.isnan(x)))


def _is_flag(values: NDArray[np.float64]) -> bool:
    finite = values[np.isfinite(values)]
    return bool(finite.size == 0 or np.all(finite == np.round(finite)))


def _is_lane(name: str, values: ArrayLike) -> bool:
    last = name.rsplit(".", 1)[-1]
    if last in ("calibrating", "learning") and re.search(r"\.(df|dtg)\.[^.]+$", name):
        return False  # a Diagnoser channel's start-up flag is drawn as the grey shading
    return bool(FLAG_PATTERN.search(last) and _is_flag(np.asarray(values, dtype=float)))


def figures_for_result(result: RunResult, scenario: Any = None,
                       verdict: ScenarioVerdict | None = None) -> list[tuple[str, Figure]]:
    """The plots a run's recorded signals call for: one figure per Diagnoser channel.

    * ``<inst>.dtg.*`` → :func:`plot_dtg_channel` (θ if recorded and not all zero, η,
      alarm / code / learning lanes);
    * ``<inst>.df.*`` → :func:`plot_df_channel`;
    * ``<inst>.grey.*`` → :func:`plot_grey_channel`: the measurement is ``<inst>.grey.y``
      if recorded, else the recorded source connected to it in the scenario; threshold
      from ``<inst>.grey.threshold`` (signal, then parameter with the paper rule,
      ``grey.decision = 0``);
    * flags of no channel (fault injection, plant) → one timeline, switching flags first,
      at most :data:`MAX_TIMELINE_LANES` lanes.

    A channel whose signals are all zero (disabled) and carry no alarm gets no figure.

    Parameters
    ----------
    result : RunResult
        The run.
    scenario : Scenario or dict, optional
        Its parameters (thresholds, bands, windows), connections (grey measurement) and
        expectations (for the titles).
    verdict : ScenarioVerdict, optional
        Outcomes of the scenario's expectations, in ``scenario.expect`` order: each
        figure's title says how the expectations reading its signals did.

    Returns
    -------
    list of (title, Figure)
    """
    names = list(result.signals)
    sig = result.signals
    used: set[str] = set()
    figures = _channel_figures(result, scenario, verdict, used)
    for witnesses, details, label in _witness_specs(scenario):
        shown = [n for n in witnesses if n in result.signals]
        if len(shown) >= 2:
            extra = [n for n in details if n in result.signals]
            figures.append((label, plot_witnesses(result, shown, extra, title=label)))

    flags = [n for n in names if n not in used and _is_lane(n, sig[n])]
    if flags:
        figures.append(("fault injection and other flags", _flag_timeline(result, flags)))
    return figures


def _channel_figures(result: RunResult, scenario: Any, verdict: ScenarioVerdict | None,
                     used: set[str]) -> list[tuple[str, Figure]]:
    """One figure per Diagnoser channel that carries data (:func:`figures_for_result`);
    adds the signals drawn to ``used``."""
    names = list(result.signals)
    sig = result.signals
    figures: list[tuple[str, Figure]] = []
    channels = list(dict.fromkeys((m["inst"], m["ch"]) for n in names
                                  if (m := _CHANNEL.match(n))))
    connections = scenario_connections(scenario)
    for inst, ch in channels:
        mine = [n for n in names if n.startswith(f"{inst}.{ch}.")]
        if not any(_carries_data(sig[n]) for n in mine):
            continue  # a disabled channel records zeros: nothing to see
        used.update(mine)
        verdict_text = _verdict_text(verdict, scenario, [f"{inst}.{ch}."])
        title = _title(_CHANNEL_TITLES[ch], inst, verdict_text)
        startup = startup_shades(result, scenario, inst, ch)
        if ch == "dtg":
            period = _number(scenario_parameters(scenario, inst).get("sample_period_s"))
            try:
                fig = plot_dtg_channel(result, inst, scenario=scenario, startup=startup,
                                       sample_period_s=period, title=title)
            except ValueError:
                continue
        elif ch == "df":
            try:
                fig = plot_df_channel(result, inst, scenario=scenario, startup=startup,
                                      title=title)
            except ValueError:
                continue
        else:
            grey = _grey_figure(result, scenario, inst, connections, title)
            if grey is None:
                continue
            fig = grey
        figures.append((title, fig))
    return figures


def _grey_figure(result: RunResult, scenario: Any, inst: str,
                 connections: Sequence[tuple[str, str]], title: str) -> Figure | None:
    """A grey channel's figure: its measurement (``<inst>.grey.y`` or the recorded source
    connected to it) and its threshold where the rule has a fixed one; None where
    :func:`plot_grey_channel` finds nothing to draw (ValueError)."""
    sig = result.signals
    measured = f"{inst}.grey.y" if f"{inst}.grey.y" in sig else next(
        (src for src, dst in connections if dst == f"{inst}.grey.y" and src in sig),
        None)
    thr_name = f"{inst}.grey.threshold"
    params = scenario_parameters(scenario, inst)
    # a fixed threshold is the paper rule's (grey.decision = 0); the learned
    # rules' (the default) is in grey.statistic
    threshold = (float(np.nanmax(sig[thr_name])) if thr_name in sig
                 else _number(params.get("grey.threshold"))
                 if _number(params.get("grey.decision")) == 0 else None)
    try:
        return plot_grey_channel(result, inst, measured=measured, threshold=threshold,
                                 title=title)
    except ValueError:
        return None


def _flag_timeline(result: RunResult, flags: list[str]) -> Figure:
    """The timeline of flags of no channel: switching ones first, at most
    :data:`MAX_TIMELINE_LANES` lanes."""
    sig = result.signals
    # flags that switch tell the story; constant ones fill the remaining lanes
    changing = [n for n in flags if not _is_constant(sig[n])]
    constant = [n for n in flags if n not in changing]
    lanes = (changing + constant)[:MAX_TIMELINE_LANES]
    hidden = len(flags) - len(lanes)
    title = "fault injection and other flags" + (
        f" ({hidden} constant flags not shown)" if hidden else "")
    return plot_alarm_timeline(result, lanes, title=title)
