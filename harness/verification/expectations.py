"""Expectations of a scenario (``[[expect]]`` tables) and their evaluation on a run.

Each ``[[expect]]`` table is one of the pydantic models below, chosen by its ``kind``
(discriminated union :data:`Expectation`, unknown keys rejected):

========================== ==============================================================
kind                       passes when
========================== ==============================================================
detected_within            ``signal`` rises above ``level`` within ``max_delay_s`` of the
                           named ``fault``'s start (delay reported, s)
no_alarm_before            ``signal`` stays at or below ``level`` before ``t_s`` (default:
                           the first fault's start; the whole run if it has no faults)
no_alarm_outside_faults    ``signal`` at or below ``level`` outside every fault window
                           ``[start, end + margin_s]``; manoeuvre windows are fault-free
                           time: an alarm during a manoeuvre fails it
no_alarm_during_manoeuvres ``signal`` at or below ``level`` inside every manoeuvre window
                           ``[start, end + margin_s]`` (or the one named ``manoeuvre``)
witnesses_agree            two or more independent alarm ``witnesses`` tell the same story:
                           with ``fault``, each rises above ``level`` within
                           ``max_delay_s`` of its start; without, none ever does
                           (``details`` are quoted at the end of the run)
value_at_end / value_at    the last sample (or the sample held at ``t_s``) equals
                           ``equals`` ± ``tol`` or lies in ``[min, max]``
value_in_window            every sample in ``[t0_s, t1_s]`` lies in ``[min, max]``
metric                     a metric of :data:`~gyrodiag_harness.verification.metrics.METRICS`,
                           called with ``args`` (``field`` picks one value), lies in ``[min, max]``
========================== ==============================================================

Every kind also takes an optional ``name`` (label in reports; default built from the
kind and its signal) and an optional ``known_limitation``: the expectation states the
right behaviour, and the text says why the product does not meet it yet. Such an
expectation is a strict expected failure: it passes (reported "KNOWN LIMITATION") while
its check fails, and fails ("promote it") once the check holds, so a fix is noticed.
The measured ``value`` of an :class:`ExpectationResult` is: the
detection delay (s) for detected_within; the first alarm time (s) for no_alarm_before;
the time the alarm is on outside the windows (s) for no_alarm_outside_faults, inside them
for no_alarm_during_manoeuvres; the spread of the witnesses' detection delays (s) for
witnesses_agree; the sample
for value_at_end / value_at; the sample nearest to (or farthest beyond) a bound for
value_in_window; the metric's value for metric. None where nothing was measured.

:func:`evaluate` turns one expectation and a
:class:`gyrodiag_harness.cosim.results.RunResult` into an :class:`ExpectationResult`;
:func:`verify_results` does it for whole scenarios and returns
:class:`ScenarioVerdict` objects. Evaluation never raises on a bad run: an unknown
signal or fault, or a failed run, fails the expectation with the reason as message.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Annotated, Any, Literal, Protocol, Self

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, TypeAdapter, ValidationError, model_validator

from gyrodiag_harness.verification import metrics
from gyrodiag_harness.verification.strict_model import StrictModel

if TYPE_CHECKING:
    from gyrodiag_harness.cosim.results import RunResult

__all__ = [
    "DetectedWithin",
    "Expectation",
    "ExpectationResult",
    "MetricExpectation",
    "NoAlarmBefore",
    "NoAlarmDuringManoeuvres",
    "NoAlarmOutsideFaults",
    "ScenarioLike",
    "ScenarioVerdict",
    "ValueAt",
    "ValueAtEnd",
    "ValueInWindow",
    "WitnessesAgree",
    "evaluate",
    "parse_expectation",
    "parse_expectations",
    "referenced_signals",
    "verify_results",
]


# ------------------------------------------------------------------- results
@dataclass(frozen=True)
class ExpectationResult:
    """Outcome of one expectation on one run.

    Attributes
    ----------
    name : str
        Label of the expectation.
    passed : bool
        Whether it holds.
    message : str
        What was expected and what was measured, with units.
    value : float or None
        The measured quantity (delay s, sample value, metric value ...); None if nothing
        could be measured.
    kind : str
        The expectation's kind ("" if it could not be parsed).
    evaluated : bool
        False when there was nothing to evaluate it on (the run failed, was interrupted
        or is missing): it does not pass, and the reason is the verdict's ``error``,
        said once there rather than under every expectation.
    """

    name: str
    passed: bool
    message: str
    value: float | None = None
    kind: str = ""
    evaluated: bool = True
    known_limitation: str = ""

    @property
    def is_known_limitation(self) -> bool:
        """True for a known limitation that still holds (its check failed, as stated)."""
        return bool(self.known_limitation) and self.passed


@dataclass
class ScenarioVerdict:
    """All expectation outcomes of one scenario.

    Attributes
    ----------
    scenario : str
        Scenario name.
    expectations : list of ExpectationResult
        One per ``[[expect]]`` table, in file order.
    error : str or None
        Why the run did not complete (RunResult.error), or that no run result exists.
    """

    scenario: str
    expectations: list[ExpectationResult] = field(default_factory=list)
    error: str | None = None

    @property
    def passed(self) -> bool:
        """True if the run completed and every expectation passed."""
        return self.error is None and all(e.passed for e in self.expectations)

    @property
    def n_failed(self) -> int:
        """Number of failed expectations."""
        return sum(not e.passed for e in self.expectations)


class ScenarioLike(Protocol):
    """What :func:`verify_results` needs of a scenario: its name and ``expect`` list
    (raw dicts from TOML or the models of this module). Plain dicts with the keys
    ``name`` and ``expect`` are accepted too."""

    name: str
    expect: Sequence[Any]


# -------------------------------------------------------------------- models
class _Base(StrictModel):
    # attribute docstrings are the field descriptions of the JSON Schema and of
    # docs/scenarios.md (python -m gyrodiag_harness schema); extra="forbid" from StrictModel
    model_config = ConfigDict(frozen=True, use_attribute_docstrings=True)

    name: str | None = Field(default=None, description="Label in reports")
    known_limitation: str | None = Field(
        default=None, min_length=1,
        description="Why the product does not meet this (right) expectation yet: a strict "
                    "expected failure, failing once the check holds")

    def label(self) -> str:
        """The ``name`` if given, else kind and signal (and fault / metric)."""
        return self.name or self._default_label()

    def _default_label(self) -> str:
        return f"{self.kind}({self.signal})"  # type: ignore[attr-defined]


class DetectedWithin(_Base):
    """``signal`` rises above ``level`` within ``max_delay_s`` (s) of ``fault``'s start."""

    kind: Literal["detected_within"]
    signal: str
    """Alarm signal (on where > ``level``)."""
    fault: str
    """The fault whose start the delay counts from."""
    max_delay_s: float = Field(ge=0.0)
    """Longest delay that passes, s."""
    level: float = metrics.DEFAULT_LEVEL
    """Switching level of the alarm."""

    def _default_label(self) -> str:
        return f"detected_within({self.signal}, {self.fault}, {self.max_delay_s:g} s)"


class NoAlarmBefore(_Base):
    """``signal`` stays at or below ``level`` before ``t_s`` (s; default first fault)."""

    kind: Literal["no_alarm_before"]
    signal: str
    """Alarm signal (on where > ``level``)."""
    t_s: float | None = None
    """End of the quiet time, s (default: the first fault's start, or the whole run)."""
    level: float = metrics.DEFAULT_LEVEL
    """Switching level of the alarm."""


class NoAlarmOutsideFaults(_Base):
    """``signal`` at or below ``level`` outside all fault windows [start, end + margin_s]."""

    kind: Literal["no_alarm_outside_faults"]
    signal: str
    """Alarm signal (on where > ``level``)."""
    margin_s: float = Field(default=0.0, ge=0.0)
    """Time after each fault's end still attributed to it, s."""
    level: float = metrics.DEFAULT_LEVEL
    """Switching level of the alarm."""


class NoAlarmDuringManoeuvres(_Base):
    """``signal`` at or below ``level`` inside every manoeuvre window [start, end + margin_s]
    (only the one named ``manoeuvre`` when given)."""

    kind: Literal["no_alarm_during_manoeuvres"]
    signal: str
    manoeuvre: str | None = None
    margin_s: float = Field(default=0.0, ge=0.0)
    level: float = metrics.DEFAULT_LEVEL


class WitnessesAgree(_Base):
    """Independent alarms (``witnesses``) agree: all detect ``fault`` within
    ``max_delay_s`` (s) of its start and none was on before it (an alarm already on
    does not witness the fault), or — without ``fault`` — all stay at or below
    ``level`` for the whole run.  ``details`` (recorded signals, e.g. a class code, an
    isolated sensor, an estimated gain) are quoted with their values at the end."""

    kind: Literal["witnesses_agree"]
    witnesses: list[str] = Field(min_length=2)
    fault: str | None = None
    max_delay_s: float = Field(default=math.inf, ge=0.0)
    details: list[str] = Field(default_factory=list)
    level: float = metrics.DEFAULT_LEVEL

    def _default_label(self) -> str:
        what = f"on {self.fault}" if self.fault else "fault-free"
        return f"witnesses_agree({', '.join(self.witnesses)}, {what})"


class _Bounds(_Base):
    min: float | None = None
    """Lowest value that passes."""
    max: float | None = None
    """Highest value that passes."""

    @model_validator(mode="after")
    def _ordered(self) -> Self:
        if self.min is not None and self.max is not None and self.min > self.max:
            raise ValueError(f"min ({self.min}) must be <= max ({self.max})")
        return self

    def _check_bounds_given(self) -> None:
        if self.min is None and self.max is None:
            raise ValueError("give min and/or max")

    def bounds_text(self) -> str:
        """``[min, max]`` in words."""
        if self.min is not None and self.max is not None:
            return f"in [{self.min:g}, {self.max:g}]"
        return f">= {self.min:g}" if self.min is not None else f"<= {self.max:g}"

    def within(self, value: float) -> bool:
        """Whether ``value`` meets the bounds (NaN never does)."""
        if math.isnan(value):
            return False
        return (self.min is None or value >= self.min) and (self.max is None or value <= self.max)


class _ValueCheck(_Bounds):
    equals: float | None = None
    """Value that passes (± ``tol``); instead of ``min``/``max``."""
    tol: float = Field(default=1e-9, ge=0.0)
    """Tolerance of ``equals``."""

    @model_validator(mode="after")
    def _one_check(self) -> Self:
        if self.equals is not None and (self.min is not None or self.max is not None):
            raise ValueError("give either equals (with tol) or min/max, not both")
        if self.equals is None:
            self._check_bounds_given()
        return self

    def expected_text(self) -> str:
        """What the value must be, in words."""
        if self.equals is not None:
            return f"== {self.equals:g} ± {self.tol:g}"
        return self.bounds_text()

    def holds(self, value: float) -> bool:
        """Whether the measured value meets ``equals``/``tol`` or the bounds."""
        if self.equals is not None:
            return not math.isnan(value) and abs(value - self.equals) <= self.tol
        return self.within(value)


class ValueAtEnd(_ValueCheck):
    """The last sample of ``signal`` equals ``equals`` ± ``tol`` or lies in [min, max]."""

    kind: Literal["value_at_end"]
    signal: str
    """Recorded signal."""


class ValueAt(_ValueCheck):
    """The sample of ``signal`` held at ``t_s`` (last row with t <= t_s) meets the check."""

    kind: Literal["value_at"]
    signal: str
    """Recorded signal."""
    t_s: float
    """Time, s: the last sample at or before it is checked."""

    def _default_label(self) -> str:
        return f"value_at({self.signal}, {self.t_s:g} s)"


class ValueInWindow(_Bounds):
    """Every sample of ``signal`` in [t0_s, t1_s] (s) lies in [min, max]."""

    kind: Literal["value_in_window"]
    signal: str
    """Recorded signal."""
    t0_s: float
    """Window start, s."""
    t1_s: float
    """Window end, s."""

    @model_validator(mode="after")
    def _window(self) -> Self:
        self._check_bounds_given()
        if self.t1_s < self.t0_s:
            raise ValueError(f"t1_s ({self.t1_s}) must be >= t0_s ({self.t0_s})")
        return self

    def _default_label(self) -> str:
        return f"value_in_window({self.signal}, {self.t0_s:g}..{self.t1_s:g} s)"


class MetricExpectation(_Bounds):
    """A registered metric (:data:`gyrodiag_harness.verification.metrics.METRICS`) lies in
    [min, max]."""

    kind: Literal["metric"]
    metric: str
    """Metric name (table below)."""
    args: dict[str, Any] = Field(default_factory=dict)
    """The metric's arguments (signal names, fault names, numbers)."""
    field: str | None = None
    """Which value of a metric that returns several (e.g. ``mean``)."""

    @model_validator(mode="after")
    def _metric_call(self) -> Self:
        self._check_bounds_given()
        try:
            metrics.check_metric_args(self.metric, self.args, self.field)
        except TypeError as exc:
            raise ValueError(str(exc)) from None  # pydantic reports only ValueErrors
        return self

    def _default_label(self) -> str:
        sig = self.args.get("signal") or self.args.get("predicted")
        suffix = f".{self.field}" if self.field else ""
        return f"metric {self.metric}{suffix}" + (f"({sig})" if sig else "")


Expectation = Annotated[
    DetectedWithin | NoAlarmBefore | NoAlarmOutsideFaults | NoAlarmDuringManoeuvres
    | WitnessesAgree | ValueAtEnd | ValueAt | ValueInWindow | MetricExpectation,
    Field(discriminator="kind"),
]
"""Any expectation model, chosen by its ``kind`` key."""

_ADAPTER: TypeAdapter[Any] = TypeAdapter(Expectation, config=ConfigDict(title="expect"))
_LIST_ADAPTER: TypeAdapter[Any] = TypeAdapter(list[Expectation],
                                              config=ConfigDict(title="expect"))
_MODELS = (DetectedWithin, NoAlarmBefore, NoAlarmOutsideFaults, NoAlarmDuringManoeuvres,
           WitnessesAgree, ValueAtEnd, ValueAt, ValueInWindow, MetricExpectation)


def parse_expectation(raw: Mapping[str, Any] | BaseModel) -> Expectation:
    """Validate one ``[[expect]]`` table (or re-validate a model from elsewhere).

    Raises
    ------
    pydantic.ValidationError
        With the offending key's path (e.g. ``metric.args``), the kind's allowed keys.
    """
    if isinstance(raw, _MODELS):
        return raw
    if isinstance(raw, BaseModel):
        raw = raw.model_dump(exclude_none=True, by_alias=True)
    return _ADAPTER.validate_python(raw)


def parse_expectations(raw: Iterable[Mapping[str, Any] | BaseModel]) -> list[Expectation]:
    """Validate a whole ``expect`` list (errors carry the index, e.g. ``2.max_delay_s``)."""
    items = list(raw)
    if all(isinstance(x, _MODELS) for x in items):
        return items  # type: ignore[return-value]
    return _LIST_ADAPTER.validate_python(
        [x.model_dump(exclude_none=True, by_alias=True)
         if isinstance(x, BaseModel) and not isinstance(x, _MODELS) else x for x in items]
    )


def referenced_signals(expectation: Expectation | Mapping[str, Any] | BaseModel) -> list[str]:
    """Recorded signal names an expectation reads (its ``signal`` and, for a metric, every
    argument of kind "signal"), so that a loader can check them against the FMUs."""
    exp = parse_expectation(expectation)
    if isinstance(exp, MetricExpectation):
        spec = metrics.METRICS[exp.metric]
        return [str(v) for k, v in exp.args.items()
                if (p := spec.param(k)) is not None and p.kind == "signal"]
    if isinstance(exp, WitnessesAgree):
        return [*exp.witnesses, *exp.details]
    return [exp.signal]


# ----------------------------------------------------------------- evaluation
def _fmt(x: float | None, unit: str = "") -> str:
    if x is None or (isinstance(x, float) and math.isnan(x)):
        return "n/a"
    return f"{x:.6g}{(' ' + unit) if unit else ''}"


_Outcome = tuple[bool, str, float | None]
"""passed, message, measured value."""


def _eval_detected_within(exp: DetectedWithin, result: RunResult) -> _Outcome:
    w = metrics.find_fault_window(result, exp.fault)
    t = np.asarray(result.time, dtype=float)
    x = np.asarray(result.signal(exp.signal), dtype=float)
    delay = metrics.detection_delay_s(t, x, w.start_s, exp.level)
    expected = (f"{exp.signal} > {exp.level:g} within {exp.max_delay_s:g} s of fault "
                f"{exp.fault!r} (start {w.start_s:g} s)")
    if math.isnan(delay):
        end = f"{t[-1]:g} s" if t.size else "start"
        return (False, f"expected {expected}; measured: no alarm up to the end of the run "
                f"({end})", None)
    note = ""
    before = x[t < w.start_s - metrics.TIME_TOL_S]
    if before.size and before[-1] > exp.level:
        note = " (signal was already on before the fault started)"
    passed = delay <= exp.max_delay_s + metrics.TIME_TOL_S
    return passed, f"expected {expected}; measured delay {_fmt(delay, 's')}{note}", delay


def _eval_no_alarm_before(exp: NoAlarmBefore, result: RunResult) -> _Outcome:
    t = np.asarray(result.time, dtype=float)
    x = np.asarray(result.signal(exp.signal), dtype=float)
    if exp.t_s is not None:
        limit, why = exp.t_s, f"{exp.t_s:g} s"
    elif result.fault_windows:
        first = min(result.fault_windows, key=lambda w: w.start_s)
        limit, why = first.start_s, f"{first.start_s:g} s (start of fault {first.name!r})"
    else:
        limit, why = math.inf, "the end of the run (no faults)"
    sel = t < limit - metrics.TIME_TOL_S
    on = np.flatnonzero(sel & (x > exp.level))
    expected = f"{exp.signal} <= {exp.level:g} before {why}"
    if on.size == 0:
        return True, f"expected {expected}; measured: no alarm", None
    first_s = float(t[on[0]])
    edges = metrics.rising_edge_times_s(t[sel], x[sel], exp.level).size
    return (False, f"expected {expected}; measured: first alarm at {first_s:g} s "
            f"({edges} rising edge(s) before the limit)", first_s)


def _eval_no_alarm_outside(exp: NoAlarmOutsideFaults, result: RunResult) -> _Outcome:
    t = np.asarray(result.time, dtype=float)
    x = np.asarray(result.signal(exp.signal), dtype=float)
    windows = [(w.start_s, w.end_s + exp.margin_s) for w in result.fault_windows]
    inside = np.zeros(t.shape, dtype=bool)
    for lo, hi in windows:
        inside |= (t >= lo - metrics.TIME_TOL_S) & (t <= hi + metrics.TIME_TOL_S)
    bad = ~inside & (x > exp.level)
    expected = (f"{exp.signal} <= {exp.level:g} outside {len(windows)} fault window(s) "
                f"[start, end + {exp.margin_s:g} s]")
    fa = metrics.false_alarms(t, x, [(w.start_s, w.end_s) for w in result.fault_windows],
                              exp.margin_s, exp.level)
    if not np.any(bad):
        return True, f"expected {expected}; measured: none", 0.0
    dt = np.diff(t, append=t[-1] + (t[-1] - t[-2] if t.size > 1 else result.step_s))
    on_s = float(np.sum(dt[bad]))
    return (False, f"expected {expected}; measured: alarm on for {on_s:g} s outside, first at "
            f"{float(t[np.flatnonzero(bad)[0]]):g} s, {fa.count} false-alarm rising edge(s) "
            f"({_fmt(fa.rate_per_h, '/h')} of fault-free time)", on_s)


def _eval_no_alarm_during(exp: NoAlarmDuringManoeuvres, result: RunResult) -> _Outcome:
    t = np.asarray(result.time, dtype=float)
    x = np.asarray(result.signal(exp.signal), dtype=float)
    chosen = (result.manoeuvre_windows if exp.manoeuvre is None
              else [result.manoeuvre(exp.manoeuvre)])
    if not chosen:
        return False, "the run has no manoeuvre window to check", None
    inside = np.zeros(t.shape, dtype=bool)
    for w in chosen:
        inside |= ((t >= w.start_s - metrics.TIME_TOL_S)
                   & (t <= w.end_s + exp.margin_s + metrics.TIME_TOL_S))
    bad = inside & (x > exp.level)
    names = ", ".join(repr(w.name) for w in chosen)
    expected = (f"{exp.signal} <= {exp.level:g} during manoeuvre(s) {names} "
                f"[start, end + {exp.margin_s:g} s]")
    if not np.any(bad):
        return True, f"expected {expected}; measured: none", 0.0
    dt = np.diff(t, append=t[-1] + (t[-1] - t[-2] if t.size > 1 else result.step_s))
    on_s = float(np.sum(dt[bad]))
    return (False, f"expected {expected}; measured: alarm on for {on_s:g} s, first at "
            f"{float(t[np.flatnonzero(bad)[0]]):g} s", on_s)


def _eval_witnesses(exp: WitnessesAgree, result: RunResult) -> _Outcome:
    t = np.asarray(result.time, dtype=float)
    parts, delays = [], []
    start = metrics.find_fault_window(result, exp.fault).start_s if exp.fault else None
    for name in exp.witnesses:
        x = np.asarray(result.signal(name), dtype=float)
        on = np.flatnonzero(x > exp.level)
        if start is None:
            parts.append(f"{name}: " + (f"alarm at {t[on[0]]:g} s" if on.size else "quiet"))
            delays.append(math.inf if on.size else 0.0)
            continue
        delay = metrics.detection_delay_s(t, x, start, exp.level)
        before = bool(on.size) and t[on[0]] < start - metrics.TIME_TOL_S
        delays.append(math.nan if before else delay)
        parts.append(f"{name}: " + (f"alarm at {t[on[0]]:g} s, before the fault" if before
                                    else "missed" if math.isnan(delay) else
                                    f"detected after {delay:.4g} s"))
    for name in exp.details:
        x = np.asarray(result.signal(name), dtype=float)
        parts.append(f"{name} = {x[-1]:.6g} at the end" if x.size else f"{name}: no samples")
    if start is None:
        agree = all(d == 0.0 for d in delays)
        story = "all quiet" if agree else "not all quiet"
        return agree, f"fault-free run: {story}; " + "; ".join(parts), 0.0 if agree else None
    ok = [not math.isnan(d) and d <= exp.max_delay_s + metrics.TIME_TOL_S for d in delays]
    agree = all(ok)
    spread = (max(delays) - min(delays)) if agree else None
    verdict = ("the witnesses agree" if agree else
               "the witnesses disagree" if any(ok) else "no witness detected it in time")
    limit = "" if math.isinf(exp.max_delay_s) else f" within {exp.max_delay_s:g} s"
    return (agree, f"fault {exp.fault!r} (start {start:g} s){limit}: {verdict}; "
            + "; ".join(parts), spread)


def _check_value(exp: _ValueCheck, x: float, where: str) -> _Outcome:
    passed = exp.holds(x)
    return passed, f"expected {exp.signal} {where} {exp.expected_text()}; measured {x:.6g}", x  # type: ignore[attr-defined]


def _eval_value_at_end(exp: ValueAtEnd, result: RunResult) -> _Outcome:
    x = np.asarray(result.signal(exp.signal), dtype=float)
    if x.size == 0:
        return False, f"expected {exp.signal} at the end {exp.expected_text()}; no samples", None
    t_end = float(np.asarray(result.time)[-1])
    return _check_value(exp, float(x[-1]), f"at the end ({t_end:g} s)")


def _eval_value_at(exp: ValueAt, result: RunResult) -> _Outcome:
    t = np.asarray(result.time, dtype=float)
    x = np.asarray(result.signal(exp.signal), dtype=float)
    idx = np.flatnonzero(t <= exp.t_s + metrics.TIME_TOL_S)
    if idx.size == 0:
        start = f"{t[0]:g} s" if t.size else "no samples"
        return (False, f"expected {exp.signal} at {exp.t_s:g} s {exp.expected_text()}; "
                f"no sample at or before {exp.t_s:g} s (run starts at {start})", None)
    k = int(idx[-1])
    return _check_value(exp, float(x[k]), f"at {exp.t_s:g} s (sample at {t[k]:g} s)")


def _eval_value_in_window(exp: ValueInWindow, result: RunResult) -> _Outcome:
    t = np.asarray(result.time, dtype=float)
    x = np.asarray(result.signal(exp.signal), dtype=float)
    sel = ((t >= exp.t0_s - metrics.TIME_TOL_S) & (t <= exp.t1_s + metrics.TIME_TOL_S))
    expected = f"{exp.signal} {exp.bounds_text()} for all t in [{exp.t0_s:g}, {exp.t1_s:g}] s"
    if not np.any(sel):
        return False, f"expected {expected}; no samples in the window", None
    xs, ts = x[sel], t[sel]
    # slack to the nearest bound: negative outside; the sample with the least slack is
    # the one that decides the verdict, so it is the value reported
    slack = np.full(xs.shape, np.inf)
    if exp.min is not None:
        slack = np.minimum(slack, xs - exp.min)
    if exp.max is not None:
        slack = np.minimum(slack, exp.max - xs)
    slack[np.isnan(xs)] = -np.inf
    worst = int(np.argmin(slack))
    finite = xs[~np.isnan(xs)]
    lo, hi = (float(finite.min()), float(finite.max())) if finite.size else (math.nan, math.nan)
    measured = f"measured range [{_fmt(lo)}, {_fmt(hi)}] over {xs.size} samples"
    bad = np.flatnonzero(slack < 0.0)
    if bad.size == 0:
        return True, f"expected {expected}; {measured}", float(xs[worst])
    return (False, f"expected {expected}; {measured}, {bad.size} outside, first at "
            f"{ts[bad[0]]:g} s ({xs[bad[0]]:.6g})", float(xs[worst]))


def _eval_metric(exp: MetricExpectation, result: RunResult) -> _Outcome:
    spec = metrics.METRICS[exp.metric]
    value = metrics.compute_metric(exp.metric, result, exp.args, exp.field)
    args = ", ".join(f"{k}={v!r}" for k, v in exp.args.items())
    what = f"{exp.metric}({args})" + (f".{exp.field}" if exp.field else "")
    return (exp.within(value), f"expected {what} {exp.bounds_text()} [{spec.unit}]; "
            f"measured {_fmt(value)}", None if math.isnan(value) else value)


_EVALUATORS: dict[type, Any] = {
    DetectedWithin: _eval_detected_within,
    NoAlarmBefore: _eval_no_alarm_before,
    NoAlarmOutsideFaults: _eval_no_alarm_outside,
    NoAlarmDuringManoeuvres: _eval_no_alarm_during,
    WitnessesAgree: _eval_witnesses,
    ValueAtEnd: _eval_value_at_end,
    ValueAt: _eval_value_at,
    ValueInWindow: _eval_value_in_window,
    MetricExpectation: _eval_metric,
}


def evaluate(expectation: Expectation | Mapping[str, Any], result: RunResult) -> ExpectationResult:
    """Evaluate one expectation on one run.

    Parameters
    ----------
    expectation : Expectation or mapping
        A model of this module or a raw ``[[expect]]`` table.
    result : RunResult
        The run. If ``result.error`` is set, the expectation is not evaluated (it fails,
        ``evaluated`` False; the error itself belongs to the scenario's verdict).

    Returns
    -------
    ExpectationResult
        Never raises for problems of the run (missing signal, unknown fault): those fail
        the expectation with the reason as message. An invalid raw table fails too.
    """
    try:
        exp = parse_expectation(expectation)
    except ValidationError as exc:
        kind = str(expectation.get("kind", "")) if isinstance(expectation, Mapping) else ""
        return ExpectationResult(f"invalid expectation {kind}".strip(), False,
                                 f"invalid expectation: {exc}", None, kind)
    name = exp.label()
    if result.error is not None:
        what = "was interrupted" if getattr(result, "interrupted", False) else "did not complete"
        return ExpectationResult(name, False, f"not evaluated: the run {what}", None, exp.kind,
                                 evaluated=False)
    try:
        passed, message, value = _EVALUATORS[type(exp)](exp, result)
    except (KeyError, ValueError, TypeError) as exc:
        reason = exc.args[0] if isinstance(exc, KeyError) and exc.args else str(exc)
        return ExpectationResult(name, False, f"cannot evaluate: {reason}", None, exp.kind)
    if value is not None and math.isnan(value):
        value = None
    if exp.known_limitation:
        return _as_known_limitation(exp, bool(passed), message, value)
    return ExpectationResult(name, bool(passed), message, value, exp.kind)


def _as_known_limitation(exp: Expectation, held: bool, message: str,
                         value: float | None) -> ExpectationResult:
    """A strict expected failure: it passes while the check fails, and fails once it holds."""
    limitation = str(exp.known_limitation)
    if held:
        text = (f"known limitation no longer holds ({message}): the check passes now; "
                f"promote it to a plain expectation (was: {limitation})")
    else:
        text = f"known limitation: {limitation} ({message})"
    return ExpectationResult(exp.label(), not held, text, value, exp.kind,
                             known_limitation=limitation)


# --------------------------------------------------------------- scenario level
def _scenario_name(scenario: Any) -> str:
    if isinstance(scenario, Mapping):
        return str(scenario["name"])
    return str(scenario.name)


def _scenario_expect(scenario: Any) -> list[Any]:
    raw = scenario.get("expect") if isinstance(scenario, Mapping) else getattr(
        scenario, "expect", None)
    return list(raw or [])


def verify_results(
    results: Sequence[RunResult], scenarios: Sequence[ScenarioLike | Mapping[str, Any]]
) -> list[ScenarioVerdict]:
    """Evaluate every scenario's expectations on its run.

    Parameters
    ----------
    results : sequence of RunResult
        Runs, matched to scenarios by ``RunResult.scenario == scenario.name`` (several
        scenarios of one name are matched in order).
    scenarios : sequence of scenario objects or dicts
        Anything with ``name`` and ``expect`` (raw dicts or models of this module).

    Returns
    -------
    list of ScenarioVerdict
        One per scenario, in order, then one per run without a scenario (no
        expectations). A scenario without a run gets ``error = "no run result"`` and
        fails all its expectations; a run with ``RunResult.error`` fails them with
        that error.
    """
    pending: dict[str, list[RunResult]] = {}
    for r in results:
        pending.setdefault(r.scenario, []).append(r)
    verdicts = []
    for scenario in scenarios:
        name = _scenario_name(scenario)
        runs = pending.get(name)
        result = runs.pop(0) if runs else None
        expect = _scenario_expect(scenario)
        if result is None:
            error = f"no run result for scenario {name!r}"
            outcomes = [_failed_without_run(e, "not evaluated: no run result") for e in expect]
        else:
            error = result.error
            outcomes = [evaluate(e, result) for e in expect]
        verdicts.append(ScenarioVerdict(name, outcomes, error))
    for runs in pending.values():
        verdicts.extend(ScenarioVerdict(r.scenario, [], r.error) for r in runs)
    return verdicts


def _failed_without_run(raw: Any, error: str) -> ExpectationResult:
    try:
        exp = parse_expectation(raw)
    except ValidationError as exc:
        return ExpectationResult("invalid expectation", False, f"invalid expectation: {exc}")
    return ExpectationResult(exp.label(), False, error, None, exp.kind, evaluated=False)
