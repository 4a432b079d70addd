"""Sample alignment of the Diagnoser's inputs from the coupling plan.

A master's coupling decides when each input of an FMU was produced. Under Gauss-Seidel in
topological order every connection is fresh; under Jacobi (libcosim's default) every FMU
boundary adds one step. The Diagnoser pairs signals that describe the same instant:

* the DTG channel pairs the DTG's voltages with the case rate that drove the rotor; with
  the aircraft feeding both the DTG plant and ``dtg.case_rate_y`` directly, Jacobi
  coupling delivers the case rate one step before the voltages it explains
  (``dtg.case_rate_delay_samples`` = 1);
* the detection filter compares every sensor with one model; a sensor read through one
  FMU more (the DTG read-out as ``df.y[3]``) arrives one step after the aircraft's own
  sensors (``df.sensor_delay[3]`` = 1).

Measured without these settings (the σ_w 1.5 m/s doublet scenario with a torquer gain
of 1.05, Jacobi): both witnesses false-alarm at the first doublet edge, the DTG channel
for 10.5 s, the detection filter for 10.9 s (docs/notes.md, 2026-11-26).

:func:`timing_parameters` derives both from the plan: the age of a Diagnoser input is the
latency of its connection plus the least latency from a reference FMU (the source of the
case rate; the source most of the ``df.y`` come from) to the input's source FMU, each
lagged connection counting one step. The master applies them unless the scenario sets
the parameter itself, and says so in the run's log.
"""

from __future__ import annotations

import heapq
from collections import Counter
from collections.abc import Container, Iterable, Mapping
from typing import Any

from .scenario import Connection, Scenario, split_name

__all__ = ["fill_timing_parameters", "timing_parameters"]

_VOLTAGES = ("dtg.Utx", "dtg.Uty", "dtg.Ux", "dtg.Uy")
_CASE_RATES = ("dtg.case_rate_y", "dtg.case_rate_x")
_DF_Y = "df.y["


def timing_parameters(scenario: Scenario, delayed: Iterable[Connection]
                      ) -> dict[str, dict[str, int]]:
    """Alignment parameters of every Diagnoser instance that the plan needs.

    Parameters
    ----------
    scenario : Scenario
        The scenario (its connections and instances).
    delayed : iterable of Connection
        The connections whose destination reads the source's value of the step before
        (:attr:`gyrodiag_harness.cosim.plan.CouplingPlan.delayed`).

    Returns
    -------
    dict
        ``{instance: {parameter: value}}`` with only the parameters that differ from 0;
        an instance's multi-rate step, or an input whose source cannot be traced to the
        reference, leaves its parameters out.
    """
    lagged = {(c.from_, c.to) for c in delayed}
    lag = {c.to: int((c.from_, c.to) in lagged) for c in scenario.connections}
    source = {c.to: split_name(c.from_)[0] for c in scenario.connections}
    graph: dict[str, list[tuple[str, int]]] = {n: [] for n in scenario.fmus}
    for c in scenario.connections:
        a, b = split_name(c.from_)[0], split_name(c.to)[0]
        if a != b:
            graph[a].append((b, lag[c.to]))
    out: dict[str, dict[str, int]] = {}
    for name, inst in scenario.fmus.items():
        if inst.step_ratio != 1:
            continue
        found: dict[str, int] = {}

        def key(var: str, inst_name: str = name) -> str:
            return f"{inst_name}.{var}"

        # DTG channel: voltages against the case rate
        rate = next((key(v) for v in _CASE_RATES if key(v) in source), None)
        volts = [key(v) for v in _VOLTAGES if key(v) in source]
        if rate is not None and volts:
            reach = _latencies(graph, source[rate])
            ages = {reach.get(source[v], -1) + lag[v] for v in volts
                    if source[v] in reach}
            if len(ages) == 1:
                d = ages.pop() - lag[rate]
                if d:
                    found["dtg.case_rate_delay_samples"] = d
        # detection filter: each sensor against the plant most of them come from
        ys = {int(to[len(key(_DF_Y)):-1]): to for to in source
              if to.startswith(key(_DF_Y)) and to.endswith("]")}
        if ys:
            plant = Counter(source[t] for t in ys.values()).most_common(1)[0][0]
            reach = _latencies(graph, plant)
            age = {j: reach[source[t]] + lag[t] for j, t in ys.items() if source[t] in reach}
            if len(age) == len(ys):
                base = min(age.values())
                for j, a in sorted(age.items()):
                    if a > base:
                        found[f"df.sensor_delay[{j}]"] = a - base
        if found:
            out[name] = found
    return out


def fill_timing_parameters(params: dict[str, dict[str, Any]], scenario: Scenario,
                           delayed: Iterable[Connection],
                           variables: Mapping[str, Container[str]]
                           ) -> list[tuple[str, str, int]]:
    """Add :func:`timing_parameters` to ``params`` (instance → {name: value}) where the
    scenario gives no value and the instance's FMU has the parameter (``variables``:
    instance → its variable names); return what was added as (instance, name, value)."""
    added = []
    for inst, hints in timing_parameters(scenario, delayed).items():
        for name, value in hints.items():
            if name not in params[inst] and name in variables[inst]:
                params[inst][name] = value
                added.append((inst, name, value))
    return added


def _latencies(graph: dict[str, list[tuple[str, int]]], start: str) -> dict[str, int]:
    """Least summed lag from ``start`` to every reachable instance (Dijkstra on 0/1)."""
    best = {start: 0}
    heap = [(0, start)]
    while heap:
        d, n = heapq.heappop(heap)
        if d > best.get(n, d):
            continue
        for m, w in graph[n]:
            if d + w < best.get(m, 1 << 30):
                best[m] = d + w
                heapq.heappush(heap, (d + w, m))
    return best
