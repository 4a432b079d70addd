"""Plots of a co-simulation run (matplotlib, headless).

Every function returns a :class:`matplotlib.figure.Figure` on an Agg canvas, built
without pyplot (headless; no global backend switch, no figure registry to leak). Fault windows
are shaded (``axvspan``) on every panel, manoeuvre windows hatched.

* :func:`plot_signals_with_faults` — stacked signals with ± thresholds (residuals).
* :func:`plot_theta` — θ1..θ5 in five stacked panels, x and y axes of the DTG channel
  and the nominal θ0, as the DTG paper's Fig. 3–5 (batch LS, RLS, RLS with forgetting:
  which one is shown depends on the Diagnoser's ``dtg.estimator`` parameter of the run).
* :func:`plot_grey_prediction` — measurement and one-step grey prediction, the error
  below with its threshold (grey paper).
* :func:`plot_alarm_timeline` — alarm / flag / code signals as step lanes.
* :func:`plot_witnesses` — independent witnesses of one root cause on one timeline
  (a scenario's ``witnesses_agree`` expectations).
* :func:`figures_for_result` — chooses the plots from the recorded signal names.

Long records are reduced to a min/max envelope per pixel-column bucket before plotting,
so spikes (alarms, fault transients) stay visible.
"""

from __future__ import annotations

import io
import math
import re
from collections.abc import Mapping, Sequence
from typing import TYPE_CHECKING, Any

import numpy as np
from matplotlib.axes import Axes
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from numpy.typing import ArrayLike, NDArray

if TYPE_CHECKING:
    from harness.cosim.results import FaultWindow, RunResult

__all__ = [
    "FLAG_PATTERN",
    "figure_to_png",
    "figures_for_result",
    "plot_alarm_timeline",
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
    r"(alarm|detected|fault_active|fault_code|fault_type|isolated\w*)(_\d+)?(\[\d+\])?$"
)
"""Variable names plotted on the alarm/flag timeline (last dotted component)."""

MAX_TIMELINE_LANES = 16

_THETA = re.compile(r"^(?P<prefix>.+)\.theta_(?P<axis>[xy])\[(?P<i>\d+)\]$")
_RESIDUAL = re.compile(r"^(?P<inst>.+)\.df\.residual\[(?P<i>\d+)\]$")
_GREY = re.compile(r"^(?P<inst>.+)\.grey\.prediction$")
_FAULT_COLOURS = ("tab:red", "tab:orange", "tab:purple", "tab:brown", "tab:pink", "tab:olive")


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
                   alpha=0.15, lw=0, label=f"fault: {w.name}" if label else None)


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


def _shade(ax: Axes, result: RunResult, *, label: bool) -> None:
    shade_fault_windows(ax, result.fault_windows, _t_end(result), label=label)
    shade_manoeuvre_windows(ax, result.manoeuvre_windows, _t_end(result), label=label)


def _t_end(result: RunResult) -> float:
    t = np.asarray(result.time, dtype=float)
    return float(t[-1]) if t.size else 0.0


def _new_figure(rows: int, height_per_row: float, width: float = 9.0) -> tuple[Figure, list[Axes]]:
    fig = Figure(figsize=(width, max(2.2, rows * height_per_row)), layout="constrained")
    # an explicit Agg canvas instead of pyplot: headless, and no global backend switch or
    # figure registry that a caller's interactive session would notice
    FigureCanvasAgg(fig)
    axes = fig.subplots(rows, 1, sharex=True, squeeze=False)[:, 0]
    return fig, list(axes)


def _robust_ylim(ax: Axes, curves: Sequence[NDArray[np.float64]]) -> None:
    # RLS starts from θ = 0 with a huge P, observers from x̂ = 0: the first samples
    # dwarf the converged trajectory; clip the axis to the bulk of the data
    data = np.concatenate([c[np.isfinite(c)] for c in curves]) if curves else np.array([])
    if data.size < 10:
        return
    lo, hi = np.percentile(data, [1.0, 99.0])
    span = hi - lo
    full = float(data.max() - data.min())
    if span > 0 and full > 3.0 * span:
        ax.set_ylim(lo - 0.25 * span, hi + 0.25 * span)


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
        ax.text(0.99, 0.02, f"estimate clipped (range {oth.min():.3g} … {oth.max():.3g})",
                transform=ax.transAxes, ha="right", va="bottom", fontsize=7)


def figure_to_png(fig: Figure, dpi: int = 80) -> bytes:
    """Render a figure to PNG bytes (Agg)."""
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=dpi)
    return buf.getvalue()


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


# ------------------------------------------------------------------- plots
def plot_signals_with_faults(
    result: RunResult,
    names: Sequence[str],
    thresholds: Mapping[str, float | ArrayLike] | None = None,
    *,
    title: str | None = None,
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

    Returns
    -------
    Figure
    """
    if not names:
        raise ValueError("names must name at least one recorded signal")
    thresholds = thresholds or {}
    t = np.asarray(result.time, dtype=float)
    fig, axes = _new_figure(len(names), 1.6)
    for k, (ax, name) in enumerate(zip(axes, names, strict=True)):
        _shade(ax, result, label=k == 0)
        _plot(ax, t, result.signal(name), lw=0.8, color="tab:blue", label=name)
        thr = thresholds.get(name)
        curves = [np.asarray(result.signal(name), dtype=float)]
        if thr is not None:
            thr_arr = np.broadcast_to(np.asarray(thr, dtype=float), t.shape)
            for sign in (1.0, -1.0):
                _plot(ax, t, sign * thr_arr, lw=0.8, ls="--", color="k",
                      label="± threshold" if sign > 0 else None)
                curves.append(sign * np.asarray(thr_arr, dtype=float))
        # an observer's start-up transient must not squash the thresholds into a line
        _robust_ylim(ax, curves)
        ax.set_ylabel(name.rsplit(".", 1)[-1], fontsize=8)
        ax.legend(loc="upper left", fontsize=7)
        ax.grid(alpha=0.3)
    axes[-1].set_xlabel("time (s)")
    fig.suptitle(title or "signals")
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
        _shade(ax, result, label=i == 1)
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
        _robust_ylim(ax, curves)
        ax.set_ylabel(f"θ{i}")
        ax.grid(alpha=0.3)
        if i == 1:
            ax.legend(loc="upper right", fontsize=7, ncol=2)
    axes[-1].set_xlabel("time (s)")
    if sample_period_s and sample_period_s > 0 and t.size:
        t0 = float(t[0])
        top = axes[0].secondary_xaxis(
            "top", functions=(lambda x: (x - t0) / sample_period_s,
                              lambda k: k * sample_period_s + t0))
        top.set_xlabel("sample index", fontsize=8)
    fig.suptitle(title or f"θ trajectories ({prefix})")
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
    """Measurement vs. one-step grey prediction, and the prediction error below.

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
    t = np.asarray(result.time, dtype=float)
    p = np.asarray(result.signal(predicted), dtype=float)
    fig, (top, bottom) = _new_figure(2, 2.3)
    for k, ax in enumerate((top, bottom)):
        _shade(ax, result, label=k == 0)
    if measured is not None:
        y = np.asarray(result.signal(measured), dtype=float)
        _plot(top, t, y, lw=0.9, color="tab:blue", label=f"measured ({measured})")
        err = np.abs(y - p)
    elif error is not None:
        err = np.abs(np.asarray(result.signal(error), dtype=float))
    else:
        raise ValueError("give measured or error: the error panel needs one of them")
    _plot(top, t, p, lw=0.9, ls="--", color="tab:orange", label=f"prediction ({predicted})")
    if measured is not None:
        _limit_to_reference(top, y, p)
    top.set_ylabel("signal")
    top.legend(loc="upper left", fontsize=7)
    _plot(bottom, t, err, lw=0.8, color="tab:red", label="|y − ŷ|")
    if threshold is not None:
        bottom.axhline(threshold, ls="--", color="k", lw=0.8, label=f"threshold {threshold:g}")
    positive = err[np.isfinite(err) & (err > 0.0)]
    if positive.size and positive.max() > 1e3 * np.median(positive):
        bottom.set_yscale("log")  # errors spanning decades: keep the threshold readable
    bottom.set_ylabel("|error|")
    bottom.set_xlabel("time (s)")
    bottom.legend(loc="upper left", fontsize=7)
    for ax in (top, bottom):
        ax.grid(alpha=0.3)
    fig.suptitle(title or "grey prediction")
    return fig


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
        _shade(ax, result, label=k == 0)
        _plot(ax, t, result.signal(name), lw=1.0, color="tab:blue", drawstyle="steps-post")
        ax.set_ylabel(name, rotation=0, ha="right", va="center", fontsize=7)
        ax.tick_params(axis="y", labelsize=6)
        values = np.asarray(result.signal(name), dtype=float)
        if np.all(np.isin(values[np.isfinite(values)], (0.0, 1.0))):
            ax.set_ylim(-0.2, 1.2)  # fixed for 0/1 flags: a flag that never fires stays at 0
            ax.set_yticks([0, 1])
        else:
            ax.margins(y=0.2)
        ax.grid(alpha=0.3)
    if result.fault_windows:
        axes[0].legend(loc="upper left", fontsize=6)
    axes[-1].set_xlabel("time (s)")
    fig.suptitle(title or "alarms and flags")
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
        _shade(ax, result, label=k == 0)
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
    if result.fault_windows or result.manoeuvre_windows:
        axes[0].legend(loc="upper left", fontsize=6)
    axes[-1].set_xlabel("time (s)")
    fig.suptitle(title or "witnesses")
    return fig


def _witness_specs(scenario: Any) -> list[tuple[list[str], list[str], str]]:
    """(witnesses, details, label) of the scenario's witnesses_agree expectations."""
    if scenario is None:
        return []
    from harness.verification import expectations as ex

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


def _number(value: Any) -> float | None:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return None
    return float(value) if math.isfinite(value) else None


def _carries_data(values: ArrayLike) -> bool:
    x = np.asarray(values, dtype=float)
    return bool(np.any(np.isfinite(x) & (x != 0.0)))


def _is_constant(values: ArrayLike) -> bool:
    x = np.asarray(values, dtype=float)
    return bool(x.size == 0 or np.all(x == x[0]) or np.all(np.isnan(x)))


def _is_flag(values: NDArray[np.float64]) -> bool:
    finite = values[np.isfinite(values)]
    return bool(finite.size == 0 or np.all(finite == np.round(finite)))


def figures_for_result(result: RunResult, scenario: Any = None) -> list[tuple[str, Figure]]:
    """The plots a run's recorded signals call for.

    * ``<prefix>.theta_x[i]`` / ``theta_y[i]`` → :func:`plot_theta` per prefix.
    * ``<inst>.df.residual[i]`` → :func:`plot_signals_with_faults` per instance, with
      thresholds from recorded ``<inst>.df.threshold_in_use[i]`` (the Diagnoser's
      learned or given thresholds) or ``<inst>.df.threshold[i]`` signals, else from the
      scenario's ``df.threshold[i]`` parameters of ``<inst>`` (none if calibrated).
    * ``<inst>.grey.prediction`` → :func:`plot_grey_prediction`; the measurement is
      ``<inst>.grey.y`` if recorded, else the recorded source connected to it in the
      scenario; threshold from ``<inst>.grey.threshold`` (signal, then parameter).
    * signals matching :data:`FLAG_PATTERN` with integer values → one timeline, switching
      flags first, at most :data:`MAX_TIMELINE_LANES` lanes.

    A θ prefix whose signals are all zero or NaN (channel disabled) gets no plot.

    Parameters
    ----------
    result : RunResult
        The run.
    scenario : Scenario or dict, optional
        Its parameters and connections refine thresholds and the grey measurement.

    Returns
    -------
    list of (title, Figure)
    """
    names = list(result.signals)
    figures: list[tuple[str, Figure]] = []

    for prefix in dict.fromkeys(m["prefix"] for n in names if (m := _THETA.match(n))):
        if not any(_carries_data(result.signals[n]) for n in names
                   if n.startswith(prefix + ".theta_")):
            continue  # a disabled channel records zeros: nothing to see
        period = _number(scenario_parameters(scenario, prefix.split(".")[0]).get(
            "sample_period_s"))
        title = f"θ trajectories — {prefix}"
        figures.append((title, plot_theta(result, prefix, sample_period_s=period, title=title)))

    residuals: dict[str, list[str]] = {}
    for n in names:
        if m := _RESIDUAL.match(n):
            residuals.setdefault(m["inst"], []).append(n)
    for inst, group in residuals.items():
        group.sort(key=_index)
        params = scenario_parameters(scenario, inst.split(".")[0])
        thresholds: dict[str, Any] = {}
        for n in group:
            in_use = f"{inst}.df.threshold_in_use[{_index(n)}]"
            thr_signal = f"{inst}.df.threshold[{_index(n)}]"
            if in_use in result.signals:
                # 0 while the Diagnoser calibrates: draw nothing there
                curve = np.asarray(result.signals[in_use], dtype=float)
                thresholds[n] = np.where(curve > 0.0, curve, np.nan)
            elif thr_signal in result.signals:
                thresholds[n] = result.signals[thr_signal]
            elif (v := _number(params.get(f"df.threshold[{_index(n)}]"))) is not None:
                thresholds[n] = v
        title = f"detection-filter residuals — {inst}"
        figures.append((title, plot_signals_with_faults(result, group, thresholds, title=title)))

    connections = scenario_connections(scenario)
    for n in names:
        if not (m := _GREY.match(n)):
            continue
        inst = m["inst"]
        measured = f"{inst}.grey.y" if f"{inst}.grey.y" in result.signals else next(
            (src for src, dst in connections if dst == f"{inst}.grey.y"
             and src in result.signals), None)
        error = f"{inst}.grey.error" if f"{inst}.grey.error" in result.signals else None
        if measured is None and error is None:
            continue
        thr_name = f"{inst}.grey.threshold"
        threshold = (float(np.nanmax(result.signals[thr_name])) if thr_name in result.signals
                     else _number(scenario_parameters(scenario, inst.split(".")[0]).get(
                         "grey.threshold")))
        title = f"grey prediction — {inst}"
        figures.append((title, plot_grey_prediction(result, n, measured, error=error,
                                                    threshold=threshold, title=title)))

    for witnesses, details, label in _witness_specs(scenario):
        shown = [n for n in witnesses if n in result.signals]
        if len(shown) >= 2:
            extra = [n for n in details if n in result.signals]
            figures.append((label, plot_witnesses(result, shown, extra, title=label)))

    flags = [n for n in names if FLAG_PATTERN.search(n.rsplit(".", 1)[-1])
             and _is_flag(np.asarray(result.signals[n], dtype=float))]
    if flags:
        # flags that switch tell the story; constant ones fill the remaining lanes
        changing = [n for n in flags if not _is_constant(result.signals[n])]
        constant = [n for n in flags if n not in changing]
        lanes = (changing + constant)[:MAX_TIMELINE_LANES]
        hidden = len(flags) - len(lanes)
        title = "alarms and flags" + (f" ({hidden} constant flags not shown)" if hidden else "")
        figures.append(("alarms and flags", plot_alarm_timeline(result, lanes, title=title)))
    return figures
