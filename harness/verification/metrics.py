"""Detection, false-alarm, isolation and estimation metrics of a co-simulation run.

Two layers:

* Pure functions on arrays (``time_s`` in seconds, signal values in the signal's own
  units) — :func:`detection_time_s`, :func:`detection_delay_s`, :func:`missed_detection`,
  :func:`false_alarms`, :func:`isolation_result`, :func:`signal_statistics`,
  :func:`theta_statistics`, :func:`prediction_errors_percent`, :func:`absolute_errors`.
* The registry :data:`METRICS` (name -> :class:`MetricSpec`): the same metrics on a
  :class:`gyrodiag_harness.cosim.results.RunResult`, addressed by recorded signal names and
  fault names, so that a scenario's ``[[expect]] kind = "metric"`` can call them by name
  with keyword arguments from TOML.  :func:`check_metric_args` validates such a call before the run,
  :func:`compute_metric` evaluates it.

Conventions shared by every function:

* An alarm signal is "on" where its value is strictly greater than ``level`` (default
  0.5, so Booleans recorded as 0/1 work); NaN counts as "off".
* Times are compared with a tolerance of :data:`TIME_TOL_S` so that a sample recorded at
  ``9.999999999998`` counts as being at ``10`` s (communication points accumulate
  rounding error).
* Row k of a run holds the outputs after every FMU was stepped to ``t_k`` (harness
  contract); a delay is ``t_k - t_fault`` of the first alarm row and therefore includes
  the co-simulation master's latency (none along the Gauss-Seidel order, one step per
  FMU boundary with Jacobi). The raw delay is reported, not corrected.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray

if TYPE_CHECKING:
    from gyrodiag_harness.cosim.results import FaultWindow, RunResult

__all__ = [
    "METRICS",
    "TIME_TOL_S",
    "AbsoluteErrors",
    "FalseAlarms",
    "MetricParam",
    "MetricSpec",
    "PredictionErrors",
    "SignalStatistics",
    "absolute_errors",
    "check_metric_args",
    "compute_metric",
    "detection_delay_s",
    "detection_time_s",
    "false_alarms",
    "fault_free_time_s",
    "find_fault_window",
    "isolation_result",
    "missed_detection",
    "prediction_errors_percent",
    "rising_edge_times_s",
    "signal_statistics",
    "theta_statistics",
]

TIME_TOL_S = 1e-9
"""Tolerance, s, of every time comparison (sample time vs. fault start, window edges)."""

DEFAULT_LEVEL = 0.5
"""An alarm is on where its value exceeds this level (Booleans are recorded as 0/1)."""

SECONDS_PER_HOUR = 3600.0


# --------------------------------------------------------------------------- checks
def _time_array(time_s: ArrayLike) -> NDArray[np.float64]:
    t = np.asarray(time_s, dtype=float)
    if t.ndim != 1:
        raise ValueError(f"time_s must be 1-D, got shape {t.shape}")
    if t.size and not np.all(np.isfinite(t)):
        raise ValueError("time_s must be finite")
    if t.size > 1 and np.any(np.diff(t) < 0.0):
        raise ValueError("time_s must be non-decreasing")
    return t


def _values(name: str, values: ArrayLike, t: NDArray[np.float64]) -> NDArray[np.float64]:
    x = np.asarray(values, dtype=float)
    if x.shape != t.shape:
        raise ValueError(f"{name} must have the shape of time_s {t.shape}, got {x.shape}")
    return x


def _real(name: str, value: Any) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise TypeError(f"{name} must be a number, got {type(value).__name__}")
    v = float(value)
    if math.isnan(v):
        raise ValueError(f"{name} must not be NaN")
    return v


def _non_negative(name: str, value: Any) -> float:
    v = _real(name, value)
    if v < 0.0:
        raise ValueError(f"{name} must be >= 0, got {v}")
    return v


def _on(x: NDArray[np.float64], level: float) -> NDArray[np.bool_]:
    # NaN > level is False: an undefined alarm sample is not an alarm
    return np.greater(x, level, where=np.isfinite(x), out=np.zeros(x.shape, dtype=bool))


def _window_mask(
    t: NDArray[np.float64], t0_s: float | None, t1_s: float | None
) -> NDArray[np.bool_]:
    lo = -math.inf if t0_s is None else _real("t0_s", t0_s)
    hi = math.inf if t1_s is None else _real("t1_s", t1_s)
    if hi < lo:
        raise ValueError(f"t1_s ({hi}) must be >= t0_s ({lo})")
    return (t >= lo - TIME_TOL_S) & (t <= hi + TIME_TOL_S)


# ------------------------------------------------------------------ alarm timing
def rising_edge_times_s(
    time_s: ArrayLike, alarm: ArrayLike, level: float = DEFAULT_LEVEL
) -> NDArray[np.float64]:
    """Times at which an alarm switches on.

    Parameters
    ----------
    time_s : array_like, shape (n,)
        Sample times, s, non-decreasing.
    alarm : array_like, shape (n,)
        Alarm signal (0/1 or any real); on where ``alarm > level``.
    level : float
        Switching level, signal units.

    Returns
    -------
    ndarray
        Times, s, of the samples that are on while the previous one was off. A signal
        already on in the first sample counts as switching on there.
    """
    t = _time_array(time_s)
    on = _on(_values("alarm", alarm, t), _real("level", level))
    previous = np.concatenate(([False], on[:-1]))
    return t[on & ~previous]


def detection_time_s(
    time_s: ArrayLike,
    alarm: ArrayLike,
    after_s: float = -math.inf,
    level: float = DEFAULT_LEVEL,
) -> float:
    """Time of the first alarm sample at or after a given time.

    Parameters
    ----------
    time_s : array_like, shape (n,)
        Sample times, s.
    alarm : array_like, shape (n,)
        Alarm signal; on where ``alarm > level``.
    after_s : float
        Earliest time, s, that counts (e.g. a fault onset).
    level : float
        Switching level, signal units.

    Returns
    -------
    float
        Time, s, of the first sample with ``t >= after_s`` that is on; NaN if none.
        An alarm already on at ``after_s`` is detected at the first sample at or after
        ``after_s`` (check earlier alarms with :func:`false_alarms`).
    """
    t = _time_array(time_s)
    on = _on(_values("alarm", alarm, t), _real("level", level))
    candidates = np.flatnonzero(on & (t >= _real("after_s", after_s) - TIME_TOL_S))
    return float(t[candidates[0]]) if candidates.size else math.nan


def detection_delay_s(
    time_s: ArrayLike,
    alarm: ArrayLike,
    fault_start_s: float,
    level: float = DEFAULT_LEVEL,
) -> float:
    """Delay from a fault's onset to the first alarm sample at or after it.

    Parameters
    ----------
    time_s : array_like, shape (n,)
        Sample times, s.
    alarm : array_like, shape (n,)
        Alarm signal; on where ``alarm > level``.
    fault_start_s : float
        Fault onset, s.
    level : float
        Switching level, signal units.

    Returns
    -------
    float
        ``detection_time_s(...) - fault_start_s``, s; NaN if the alarm never comes.
        Includes the co-simulation master's latency (raw delay).
    """
    start = _real("fault_start_s", fault_start_s)
    return detection_time_s(time_s, alarm, start, level) - start


def missed_detection(
    time_s: ArrayLike,
    alarm: ArrayLike,
    fault_start_s: float,
    max_delay_s: float = math.inf,
    level: float = DEFAULT_LEVEL,
) -> bool:
    """Whether an alarm fails to come within a deadline after a fault's onset.

    Parameters
    ----------
    time_s : array_like, shape (n,)
        Sample times, s.
    alarm : array_like, shape (n,)
        Alarm signal; on where ``alarm > level``.
    fault_start_s : float
        Fault onset, s.
    max_delay_s : float
        Deadline after the onset, s (default: until the end of the record). Pass the
        fault window's length to require the alarm while the fault is active.
    level : float
        Switching level, signal units.

    Returns
    -------
    bool
        True if no alarm sample lies in ``[fault_start_s, fault_start_s + max_delay_s]``.
    """
    delay = detection_delay_s(time_s, alarm, fault_start_s, level)
    limit = _non_negative("max_delay_s", max_delay_s)
    return bool(math.isnan(delay) or delay > limit + TIME_TOL_S)


@dataclass(frozen=True)
class FalseAlarms:
    """False alarms of one alarm signal.

    Attributes
    ----------
    count : int
        Rising edges of the alarm outside every fault window (plus margin).
    fault_free_time_s : float
        Recorded time outside every fault window (plus margin), s.
    rate_per_h : float
        ``count`` per hour of fault-free time, 1/h; NaN if there is no fault-free time.
    times_s : tuple of float
        Times, s, of the counted rising edges.
    """

    count: int
    fault_free_time_s: float
    rate_per_h: float
    times_s: tuple[float, ...] = field(default=())


def _windows(
    windows: Iterable[tuple[float, float]], margin_s: float
) -> list[tuple[float, float]]:
    margin = _non_negative("margin_s", margin_s)
    out = []
    for i, (start, end) in enumerate(windows):
        lo, hi = _real(f"windows[{i}] start", start), _real(f"windows[{i}] end", end)
        if hi < lo:
            raise ValueError(f"windows[{i}]: end ({hi}) must be >= start ({lo})")
        out.append((lo, hi + margin))
    return out


def _inside_any(t: NDArray[np.float64], windows: list[tuple[float, float]]) -> NDArray[np.bool_]:
    inside = np.zeros(t.shape, dtype=bool)
    for lo, hi in windows:
        inside |= (t >= lo - TIME_TOL_S) & (t <= hi + TIME_TOL_S)
    return inside


def fault_free_time_s(
    time_s: ArrayLike, windows: Iterable[tuple[float, float]], margin_s: float = 0.0
) -> float:
    """Recorded time outside every fault window, s.

    Parameters
    ----------
    time_s : array_like, shape (n,)
        Sample times, s; the record spans ``[time_s[0], time_s[-1]]``.
    windows : iterable of (start_s, end_s)
        Fault windows, s (``end_s`` may be ``inf``).
    margin_s : float
        Time, s, added after each window's end (alarm clearing time).

    Returns
    -------
    float
        Length, s, of the record span minus the union of ``[start, end + margin]``.
    """
    t = _time_array(time_s)
    if t.size < 2:
        return 0.0
    t0, t1 = float(t[0]), float(t[-1])
    clipped = sorted(
        (max(lo, t0), min(hi, t1)) for lo, hi in _windows(windows, margin_s) if hi > t0 and lo < t1
    )
    covered, cur_lo, cur_hi = 0.0, None, None
    for lo, hi in clipped:
        if cur_hi is None or lo > cur_hi:
            if cur_hi is not None:
                covered += cur_hi - cur_lo
            cur_lo, cur_hi = lo, hi
        else:
            cur_hi = max(cur_hi, hi)
    if cur_hi is not None:
        covered += cur_hi - cur_lo
    return max(t1 - t0 - covered, 0.0)


def false_alarms(
    time_s: ArrayLike,
    alarm: ArrayLike,
    windows: Iterable[tuple[float, float]] = (),
    margin_s: float = 0.0,
    level: float = DEFAULT_LEVEL,
) -> FalseAlarms:
    """Count the alarm's rising edges outside fault windows and their rate.

    Parameters
    ----------
    time_s : array_like, shape (n,)
        Sample times, s.
    alarm : array_like, shape (n,)
        Alarm signal; on where ``alarm > level``.
    windows : iterable of (start_s, end_s)
        Fault windows, s (``end_s`` may be ``inf``). An edge at ``t`` with
        ``start <= t <= end + margin_s`` is not a false alarm.
    margin_s : float
        Time, s, after each window's end during which alarms still count as caused by
        the fault (detection latency, alarm clearing).
    level : float
        Switching level, signal units.

    Returns
    -------
    FalseAlarms
        Count, fault-free time (s), rate per hour of fault-free time (1/h) and edge times.
    """
    t = _time_array(time_s)
    edges = rising_edge_times_s(t, alarm, level)
    win = _windows(list(windows), margin_s)
    outside = edges[~_inside_any(edges, win)]
    free_s = fault_free_time_s(t, win, 0.0)
    rate = outside.size / (free_s / SECONDS_PER_HOUR) if free_s > 0.0 else math.nan
    return FalseAlarms(int(outside.size), free_s, float(rate), tuple(float(x) for x in outside))


# ------------------------------------------------------------------- isolation
def isolation_result(
    time_s: ArrayLike,
    isolation: ArrayLike,
    how: Literal["end", "mode"] = "end",
    after_s: float | None = None,
    ignore: Sequence[float] = (),
) -> float:
    """Value of an isolation signal (e.g. the isolated sensor's index).

    Parameters
    ----------
    time_s : array_like, shape (n,)
        Sample times, s.
    isolation : array_like, shape (n,)
        Isolation output (Integer recorded as float).
    how : {"end", "mode"}
        ``"end"``: the last sample's value. ``"mode"``: the most frequent value over the
        samples at or after ``after_s`` (ties go to the smaller value).
    after_s : float, optional
        Earliest time, s, for ``how="mode"`` (typically the detection time); default:
        the whole record.
    ignore : sequence of float
        Values left out of the mode (e.g. 0 = "nothing isolated").

    Returns
    -------
    float
        The value; NaN if no sample qualifies.
    """
    t = _time_array(time_s)
    x = _values("isolation", isolation, t)
    if how == "end":
        return float(x[-1]) if x.size else math.nan
    if how != "mode":
        raise ValueError(f"how must be 'end' or 'mode', got {how!r}")
    keep = np.isfinite(x)
    if after_s is not None:
        keep &= t >= _real("after_s", after_s) - TIME_TOL_S
    for value in ignore:
        keep &= x != _real("ignore", value)
    if not np.any(keep):
        return math.nan
    values, counts = np.unique(x[keep], return_counts=True)
    return float(values[np.argmax(counts)])  # np.unique sorts: argmax picks the smallest tie


# ----------------------------------------------------------------- statistics
@dataclass(frozen=True)
class SignalStatistics:
    """Statistics of a signal over a time window (signal units; ``n`` samples used)."""

    mean: float
    std: float
    min: float
    max: float
    n: int


def signal_statistics(
    time_s: ArrayLike,
    values: ArrayLike,
    t0_s: float | None = None,
    t1_s: float | None = None,
) -> SignalStatistics:
    """Mean, standard deviation (population), minimum and maximum over ``[t0_s, t1_s]``.

    Parameters
    ----------
    time_s : array_like, shape (n,)
        Sample times, s.
    values : array_like, shape (n,)
        Signal, its own units. NaN samples are ignored.
    t0_s, t1_s : float, optional
        Window, s, inclusive; default: the whole record.

    Returns
    -------
    SignalStatistics
        All NaN with ``n = 0`` if no finite sample lies in the window.
    """
    t = _time_array(time_s)
    x = _values("values", values, t)
    sel = x[_window_mask(t, t0_s, t1_s) & np.isfinite(x)]
    if sel.size == 0:
        return SignalStatistics(math.nan, math.nan, math.nan, math.nan, 0)
    return SignalStatistics(
        float(sel.mean()), float(sel.std()), float(sel.min()), float(sel.max()), int(sel.size)
    )


def theta_statistics(
    time_s: ArrayLike,
    signals: Mapping[str, ArrayLike],
    t0_s: float | None = None,
    t1_s: float | None = None,
) -> dict[str, SignalStatistics]:
    """:func:`signal_statistics` of several signals (e.g. θ1..θ5) over one window.

    Parameters
    ----------
    time_s : array_like, shape (n,)
        Sample times, s.
    signals : mapping of name -> array_like, shape (n,)
        Signals, their own units (θ1..θ5 are dimensionless).
    t0_s, t1_s : float, optional
        Window, s, inclusive; default: the whole record.

    Returns
    -------
    dict of name -> SignalStatistics
    """
    return {name: signal_statistics(time_s, x, t0_s, t1_s) for name, x in signals.items()}


@dataclass(frozen=True)
class PredictionErrors:
    """Relative one-step prediction errors, percent of the measured value.

    ``n_used`` samples entered; ``n_excluded`` had a finite prediction but a zero or
    non-finite measurement (no relative error exists there).
    """

    mean_percent: float
    max_percent: float
    n_used: int
    n_excluded: int


def prediction_errors_percent(
    time_s: ArrayLike,
    measured: ArrayLike,
    predicted: ArrayLike,
    t0_s: float | None = None,
    t1_s: float | None = None,
    valid: ArrayLike | None = None,
) -> PredictionErrors:
    """Mean and maximum of ``100·|y − ŷ|/|y|`` over a window (the grey paper's figure).

    Parameters
    ----------
    time_s : array_like, shape (n,)
        Sample times, s.
    measured : array_like, shape (n,)
        Measured samples y, signal units.
    predicted : array_like, shape (n,)
        Predictions ŷ of the same samples (row k predicts row k), signal units; NaN where
        no prediction was made (warm-up) is ignored.
    t0_s, t1_s : float, optional
        Window, s, inclusive; default: the whole record.
    valid : array_like, shape (n,), optional
        Where false, the row has no prediction and is ignored like NaN (an FMU's
        validity output, e.g. ``grey.prediction_valid``, whose prediction output then
        holds a sentinel).

    Returns
    -------
    PredictionErrors
        Mean and max in percent (NaN if no sample qualifies) and the sample counts.
    """
    t = _time_array(time_s)
    y = _values("measured", measured, t)
    p = _values("predicted", predicted, t)
    candidates = _window_mask(t, t0_s, t1_s) & np.isfinite(p)
    if valid is not None:
        candidates &= _values("valid", valid, t) != 0.0
    used = candidates & np.isfinite(y) & (y != 0.0)
    n_excluded = int(np.count_nonzero(candidates & ~used))
    if not np.any(used):
        return PredictionErrors(math.nan, math.nan, 0, n_excluded)
    rel = 100.0 * np.abs(y[used] - p[used]) / np.abs(y[used])
    return PredictionErrors(float(rel.mean()), float(rel.max()), int(rel.size), n_excluded)


@dataclass(frozen=True)
class AbsoluteErrors:
    """Absolute errors ``|y − ŷ|`` in signal units over ``n`` samples."""

    mean: float
    max: float
    rms: float
    n: int


def absolute_errors(
    time_s: ArrayLike,
    measured: ArrayLike,
    predicted: ArrayLike,
    t0_s: float | None = None,
    t1_s: float | None = None,
) -> AbsoluteErrors:
    """Mean, maximum and RMS of ``|y − ŷ|`` over a window, ignoring NaN samples.

    Parameters
    ----------
    time_s : array_like, shape (n,)
        Sample times, s.
    measured, predicted : array_like, shape (n,)
        Measurement and its estimate, same units.
    t0_s, t1_s : float, optional
        Window, s, inclusive; default: the whole record.

    Returns
    -------
    AbsoluteErrors
        In the signals' units; NaN with ``n = 0`` if no sample qualifies.
    """
    t = _time_array(time_s)
    y = _values("measured", measured, t)
    p = _values("predicted", predicted, t)
    used = _window_mask(t, t0_s, t1_s) & np.isfinite(y) & np.isfinite(p)
    if not np.any(used):
        return AbsoluteErrors(math.nan, math.nan, math.nan, 0)
    err = np.abs(y[used] - p[used])
    return AbsoluteErrors(
        float(err.mean()), float(err.max()), float(np.sqrt(np.mean(err**2))), int(err.size)
    )


# -------------------------------------------------------------------- registry
ParamKind = Literal["signal", "fault", "number", "string", "bool", "number_list"]


@dataclass(frozen=True)
class MetricParam:
    """One keyword argument of a registered metric.

    ``kind``: ``"signal"`` (a recorded signal name), ``"fault"`` (a fault window name),
    ``"number"``, ``"string"``, ``"bool"`` or ``"number_list"``. ``choices`` restricts a
    string.
    """

    name: str
    kind: ParamKind
    doc: str
    required: bool = False
    default: Any = None
    choices: tuple[str, ...] = ()


@dataclass(frozen=True)
class MetricSpec:
    """A metric callable by name on a run.

    ``function(result, **kwargs)`` returns a float (``fields`` empty) or a dict of
    floats keyed by ``fields``; ``unit`` describes the value (or each field).
    """

    name: str
    function: Callable[..., float | dict[str, float]]
    params: tuple[MetricParam, ...]
    doc: str
    unit: str = ""
    fields: tuple[str, ...] = ()

    def param(self, name: str) -> MetricParam | None:
        """The parameter called ``name``, or None."""
        return next((p for p in self.params if p.name == name), None)

    def describe(self) -> str:
        """One paragraph: what the metric is, its arguments and its fields."""
        args = ", ".join(
            f"{p.name}{'' if p.required else '=' + repr(p.default)} ({p.kind}): {p.doc}"
            for p in self.params
        )
        fields = f" Fields: {', '.join(self.fields)}." if self.fields else ""
        return f"{self.name} [{self.unit}]: {self.doc} Arguments: {args}.{fields}"


def find_fault_window(result: RunResult, name: str) -> FaultWindow:
    """The run's fault window called ``name`` (KeyError listing the known ones)."""
    for w in result.fault_windows:
        if w.name == name:
            return w
    known = ", ".join(repr(w.name) for w in result.fault_windows) or "none"
    raise KeyError(f"no fault named {name!r} in run {result.scenario!r} (faults: {known})")


def _default_fault(result: RunResult, fault: str | None) -> FaultWindow:
    if fault is not None:
        return find_fault_window(result, fault)
    if len(result.fault_windows) == 1:
        return result.fault_windows[0]
    raise ValueError(
        f"argument 'fault' is required: run {result.scenario!r} has "
        f"{len(result.fault_windows)} fault windows"
    )


def _windows_of(result: RunResult) -> list[tuple[float, float]]:
    return [(w.start_s, w.end_s) for w in result.fault_windows]


def _m_detection_time(
    result: RunResult, signal: str, fault: str | None = None, after_s: float | None = None,
    level: float = DEFAULT_LEVEL,
) -> float:
    if fault is not None and after_s is not None:
        raise ValueError("give either 'fault' or 'after_s', not both")
    after = find_fault_window(result, fault).start_s if fault is not None else after_s
    return detection_time_s(
        result.time, result.signal(signal), -math.inf if after is None else after, level
    )


def _m_detection_delay(
    result: RunResult, signal: str, fault: str | None = None, level: float = DEFAULT_LEVEL
) -> float:
    w = _default_fault(result, fault)
    return detection_delay_s(result.time, result.signal(signal), w.start_s, level)


def _m_missed(
    result: RunResult, signal: str, fault: str | None = None, max_delay_s: float = math.inf,
    level: float = DEFAULT_LEVEL,
) -> float:
    w = _default_fault(result, fault)
    return float(missed_detection(result.time, result.signal(signal), w.start_s, max_delay_s,
                                  level))


def _m_false_alarms(
    result: RunResult, signal: str, margin_s: float = 0.0, level: float = DEFAULT_LEVEL
) -> dict[str, float]:
    fa = false_alarms(result.time, result.signal(signal), _windows_of(result), margin_s, level)
    return {"count": float(fa.count), "rate_per_h": fa.rate_per_h,
            "fault_free_time_s": fa.fault_free_time_s}


def _m_isolation(
    result: RunResult, signal: str, how: str = "end", alarm: str | None = None,
    fault: str | None = None, ignore: Sequence[float] = (), level: float = DEFAULT_LEVEL,
    delay_s: float = 0.0,
) -> float:
    after: float | None = None
    if fault is not None:
        after = find_fault_window(result, fault).start_s
    if alarm is not None:
        after = detection_time_s(result.time, result.signal(alarm),
                                 -math.inf if after is None else after, level)
        if math.isnan(after):
            return math.nan  # never detected: nothing was isolated after detection
    if delay_s:
        if _real("delay_s", delay_s) < 0:
            raise ValueError(f"delay_s must be >= 0, got {delay_s!r}")
        if after is None or how != "mode":
            raise ValueError("delay_s needs how='mode' and 'fault' or 'alarm' to count from")
        after += delay_s
    return isolation_result(result.time, result.signal(signal), how, after, ignore)  # type: ignore[arg-type]


def _m_statistics(
    result: RunResult, signal: str, t0_s: float | None = None, t1_s: float | None = None
) -> dict[str, float]:
    s = signal_statistics(result.time, result.signal(signal), t0_s, t1_s)
    return {"mean": s.mean, "std": s.std, "min": s.min, "max": s.max, "n": float(s.n)}


def _m_prediction(
    result: RunResult, measured: str, predicted: str, t0_s: float | None = None,
    t1_s: float | None = None, valid: str | None = None,
) -> dict[str, float]:
    e = prediction_errors_percent(result.time, result.signal(measured),
                                  result.signal(predicted), t0_s, t1_s,
                                  None if valid is None else result.signal(valid))
    return {"mean_percent": e.mean_percent, "max_percent": e.max_percent,
            "n_used": float(e.n_used)}


def _m_absolute(
    result: RunResult, measured: str, predicted: str, t0_s: float | None = None,
    t1_s: float | None = None,
) -> dict[str, float]:
    e = absolute_errors(result.time, result.signal(measured), result.signal(predicted),
                        t0_s, t1_s)
    return {"mean": e.mean, "max": e.max, "rms": e.rms, "n": float(e.n)}


_SIGNAL = MetricParam("signal", "signal", "recorded alarm signal, on where > level",
                      required=True)
_LEVEL = MetricParam("level", "number", "switching level of the alarm", default=DEFAULT_LEVEL)
_FAULT = MetricParam("fault", "fault",
                     "fault window name (default: the run's only fault window)")
_T0 = MetricParam("t0_s", "number", "window start, s (default: record start)")
_T1 = MetricParam("t1_s", "number", "window end, s (default: record end)")
_MEASURED = MetricParam("measured", "signal", "recorded measurement y", required=True)
_PREDICTED = MetricParam("predicted", "signal", "recorded estimate ŷ of the same sample",
                         required=True)
_STATISTICS = MetricSpec(
    "theta_statistics", _m_statistics,
    (MetricParam("signal", "signal", "recorded signal", required=True), _T0, _T1),
    "Mean, population std, min and max of a signal over [t0_s, t1_s], NaN ignored.",
    "signal units", ("mean", "std", "min", "max", "n"),
)

METRICS: dict[str, MetricSpec] = {
    spec.name: spec
    for spec in (
        MetricSpec(
            "detection_time_s", _m_detection_time,
            (_SIGNAL,
             MetricParam("fault", "fault", "count alarms from this fault's start"),
             MetricParam("after_s", "number", "count alarms from this time, s"), _LEVEL),
            "Time of the first alarm sample at/after the start time (NaN if none).", "s",
        ),
        MetricSpec(
            "detection_delay_s", _m_detection_delay, (_SIGNAL, _FAULT, _LEVEL),
            "First alarm time at/after the fault's start minus that start (NaN if none); "
            "includes master latency.", "s",
        ),
        MetricSpec(
            "missed_detection", _m_missed,
            (_SIGNAL, _FAULT,
             MetricParam("max_delay_s", "number", "deadline after the fault start, s",
                         default=math.inf), _LEVEL),
            "1 if no alarm sample within max_delay_s of the fault's start, else 0.",
            "1 = missed",
        ),
        MetricSpec(
            "false_alarms", _m_false_alarms,
            (_SIGNAL,
             MetricParam("margin_s", "number",
                         "time after each fault window's end still attributed to it, s",
                         default=0.0), _LEVEL),
            "Rising edges outside all fault windows [start, end + margin_s]; rate per hour "
            "of fault-free time.", "count, 1/h, s",
            ("count", "rate_per_h", "fault_free_time_s"),
        ),
        MetricSpec(
            "isolation_result", _m_isolation,
            (MetricParam("signal", "signal", "recorded isolation output", required=True),
             MetricParam("how", "string", "'end': last value; 'mode': most frequent value",
                         default="end", choices=("end", "mode")),
             MetricParam("alarm", "signal",
                         "for how='mode': count from this alarm's first rise (after fault)"),
             MetricParam("fault", "fault", "for how='mode': count from this fault's start"),
             MetricParam("ignore", "number_list", "values left out of the mode, e.g. [0]",
                         default=()),
             _LEVEL,
             MetricParam("delay_s", "number",
                         "for how='mode': count from this long after that start, s",
                         default=0.0)),
            "Value of an isolation signal at the end, or its mode after detection "
            "(NaN if never detected).", "signal units",
        ),
        _STATISTICS,
        MetricSpec("signal_statistics", _m_statistics, _STATISTICS.params, _STATISTICS.doc,
                   _STATISTICS.unit, _STATISTICS.fields),
        MetricSpec(
            "prediction_errors_percent", _m_prediction,
            (_MEASURED, _PREDICTED, _T0, _T1,
             MetricParam("valid", "signal", "recorded validity of the prediction (rows "
                         "where it is false are ignored)")),
            "Mean and max of 100·|y − ŷ|/|y| over [t0_s, t1_s], NaN or invalid predictions "
            "and y = 0 ignored.", "%", ("mean_percent", "max_percent", "n_used"),
        ),
        MetricSpec(
            "absolute_errors", _m_absolute, (_MEASURED, _PREDICTED, _T0, _T1),
            "Mean, max and RMS of |y − ŷ| over [t0_s, t1_s], NaN ignored.", "signal units",
            ("mean", "max", "rms", "n"),
        ),
    )
}
"""Metrics callable by name from a scenario's ``[[expect]] kind = "metric"``."""


def _check_arg(metric: str, p: MetricParam, value: Any) -> Any:
    where = f"metric {metric!r}: argument {p.name!r}"
    if p.kind in ("signal", "fault", "string"):
        if not isinstance(value, str) or not value:
            raise TypeError(f"{where} must be a non-empty string, got {value!r}")
        if p.choices and value not in p.choices:
            raise ValueError(f"{where} must be one of {list(p.choices)}, got {value!r}")
        return value
    if p.kind == "bool":
        if not isinstance(value, bool):
            raise TypeError(f"{where} must be true or false, got {value!r}")
        return value
    if p.kind == "number":
        try:
            return _real(where, value)
        except (TypeError, ValueError) as exc:
            raise type(exc)(f"{exc} ({value!r})") from None
    if p.kind == "number_list":
        if isinstance(value, (str, bytes)) or not isinstance(value, (list, tuple)):
            raise TypeError(f"{where} must be a list of numbers, got {value!r}")
        return tuple(_real(f"{where}[{i}]", v) for i, v in enumerate(value))
    raise AssertionError(f"unknown parameter kind {p.kind}")  # registry bug


def check_metric_args(
    metric: str, args: Mapping[str, Any], field: str | None = None
) -> dict[str, Any]:
    """Validate a call of a registered metric before any run.

    Parameters
    ----------
    metric : str
        Name in :data:`METRICS`.
    args : mapping
        Keyword arguments as read from TOML.
    field : str, optional
        Field selected from a metric that returns several values.

    Returns
    -------
    dict
        The arguments, converted (numbers to float, lists to tuples).

    Raises
    ------
    ValueError, TypeError
        Naming the metric and the offending argument (unknown metric or argument,
        missing required argument, wrong type, unknown or missing field).
    """
    spec = METRICS.get(metric)
    if spec is None:
        raise ValueError(f"unknown metric {metric!r}; known metrics: {', '.join(METRICS)}")
    if not isinstance(args, Mapping):
        raise TypeError(f"metric {metric!r}: args must be a table, got {type(args).__name__}")
    accepted = ", ".join(p.name for p in spec.params)
    checked = {}
    for name, value in args.items():
        p = spec.param(name)
        if p is None:
            raise ValueError(
                f"metric {metric!r}: unknown argument {name!r} (accepted: {accepted})"
            )
        checked[name] = _check_arg(metric, p, value)
    for p in spec.params:
        if p.required and p.name not in checked:
            raise ValueError(f"metric {metric!r}: missing required argument {p.name!r}")
    if spec.fields and field is None:
        raise ValueError(
            f"metric {metric!r} returns several values: choose field = one of "
            f"{list(spec.fields)}"
        )
    if field is not None and field not in spec.fields:
        raise ValueError(
            f"metric {metric!r}: unknown field {field!r}"
            + (f" (fields: {list(spec.fields)})" if spec.fields else " (it returns one value)")
        )
    return checked


def compute_metric(
    metric: str, result: RunResult, args: Mapping[str, Any], field: str | None = None
) -> float:
    """Evaluate a registered metric on a run.

    Parameters
    ----------
    metric : str
        Name in :data:`METRICS`.
    result : RunResult
        The run.
    args : mapping
        Keyword arguments (validated with :func:`check_metric_args`).
    field : str, optional
        Required for metrics with several fields (see :class:`MetricSpec`).

    Returns
    -------
    float
        The metric's value (NaN where it is undefined, e.g. a delay never reached).

    Raises
    ------
    ValueError, TypeError, KeyError
        Bad arguments, or a signal / fault name that the run does not have.
    """
    checked = check_metric_args(metric, args, field)
    value = METRICS[metric].function(result, **checked)
    if isinstance(value, dict):
        return float(value[field])  # type: ignore[index]
    return float(value)
