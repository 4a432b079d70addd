"""A scenario resolved once, before any FMU library is loaded, into a :class:`RunPlan`.

:func:`resolve` does every lookup and check of a run up front: the ``files``
parameters, the FMU files and their modelDescriptions (co-simulation interface, variable
names, causalities and types: :func:`~gyrodiag_harness.cosim.scenario.check_against_models`),
the coupling order (:func:`plan_coupling`), the start values of every instance (the
scenario's parameters, injector faults, manoeuvres, ``files``, the Diagnoser's sample
alignment), the connections, recorded signals and physical fault events with their
value references and types. The master (:mod:`gyrodiag_harness.cosim.master`) only
executes the plan: data flows one way, scenario → plan → run.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from gyrodiag_harness.cosim.fmi import extract_fmu, model_description
from gyrodiag_harness.cosim.results import FaultWindow, RunResult
from gyrodiag_harness.cosim.scenario import (
    Connection,
    InjectorFault,
    ModelInfo,
    Scenario,
    ScenarioError,
    VariableInfo,
    check_against_models,
    expected_signals,
    load_scenario,
    resolve_file_parameters,
    resolve_fmu_dir,
    resolve_fmu_file,
    split_name,
)
from gyrodiag_harness.cosim.timing import fill_timing_parameters


# --------------------------------------------------------------------------- the plan
@dataclass(frozen=True)
class InstancePlan:
    """One instance: its FMU file and modelDescription facts, step ratio and start values.

    ``parameters`` are (variable, value) in the order they are set: the scenario's, the
    injector faults', the manoeuvres', the ``files`` paths, then the timing defaults.
    """

    name: str
    fmu_path: Path
    unzipdir: str
    guid: str
    model_identifier: str
    step_ratio: int
    info: ModelInfo
    parameters: tuple[tuple[VariableInfo, Any], ...]


@dataclass(frozen=True)
class Link:
    """One connection with both ends resolved; ``delayed`` if its destination reads the
    source's value of the step before (:attr:`CouplingPlan.delayed`)."""

    from_: str
    to: str
    src: str
    src_var: VariableInfo
    dst: str
    dst_var: VariableInfo
    delayed: bool


@dataclass(frozen=True)
class Recorded:
    """One recorded signal: its qualified name, instance and variable."""

    name: str
    instance: str
    var: VariableInfo


@dataclass(frozen=True)
class FaultEvent:
    """A physical fault's start (set ``value``) or end (restore the value it replaced)."""

    time_s: float
    is_end: bool
    fault: str
    instance: str
    var: VariableInfo
    value: Any


@dataclass(frozen=True)
class RunPlan:
    """Everything a master needs to run a scenario, resolved and checked.

    ``instances`` are in declaration order, ``coupling.order`` is the stepping order;
    ``events`` are sorted by time (starts before ends at the same time); ``judged`` is
    None when every recorded signal is judged (a training scenario).
    """

    name: str
    source: str
    step_s: float
    n_steps: int
    duration_s: float
    decimation: int
    precision: str
    coupling_kind: str
    coupling: CouplingPlan
    instances: Mapping[str, InstancePlan]
    links: tuple[Link, ...]
    recorded: tuple[Recorded, ...]
    events: tuple[FaultEvent, ...]
    timing_added: tuple[tuple[str, str, int], ...]
    fault_windows: tuple[FaultWindow, ...]
    manoeuvre_windows: tuple[FaultWindow, ...]
    judged: frozenset[str] | None

    @property
    def order(self) -> list[str]:
        """Instance names in stepping (and initialisation) order."""
        return self.coupling.order

    def judged_signals(self, result: RunResult) -> set[str]:
        """What is judged from ``result`` (see :func:`judged_signals`)."""
        return set(result.signals) if self.judged is None else set(self.judged)


# --------------------------------------------------------------------------- coupling
@dataclass(frozen=True)
class CouplingPlan:
    """Order in which instances step and the connections that lag one base step.

    Attributes
    ----------
    order : list of str
        Instance names in stepping (and initialisation) order.
    delayed : list of Connection
        Connections whose destination reads the source's value at ``t_k`` (before the
        source stepped): all of them with Jacobi, only the cycle-breaking ones with
        Gauss-Seidel.
    """

    order: list[str]
    delayed: list[Connection]


def plan_coupling(scenario: Scenario) -> CouplingPlan:
    """Topological order of the connection graph, cycles broken before their first
    declared instance (see the module docstring)."""
    names = list(scenario.fmus)
    edges: set[tuple[str, str]] = set()
    for c in scenario.connections:
        src, dst = split_name(c.from_)[0], split_name(c.to)[0]
        if src != dst:
            edges.add((src, dst))
    order = _order(names, edges)
    position = {n: i for i, n in enumerate(order)}
    if scenario.coupling == "jacobi":
        delayed = list(scenario.connections)
    else:
        delayed = [c for c in scenario.connections
                   if position[split_name(c.from_)[0]] >= position[split_name(c.to)[0]]]
    return CouplingPlan(order=order, delayed=delayed)


def _order(nodes: list[str], edges: set[tuple[str, str]]) -> list[str]:
    """Kahn's order of the strongly connected components (ties: declaration order); in a
    component, its first declared node goes first with its incoming edges from the
    component cut, and the rest is ordered the same way."""
    index = {n: i for i, n in enumerate(nodes)}
    succ: dict[str, set[str]] = {n: set() for n in nodes}
    for a, b in edges:
        succ[a].add(b)

    def reachable(start: str) -> set[str]:
        seen, stack = set(), [start]
        while stack:
            for nxt in succ[stack.pop()]:
                if nxt not in seen:
                    seen.add(nxt)
                    stack.append(nxt)
        return seen

    reach = {n: reachable(n) for n in nodes}
    comp_of: dict[str, int] = {}
    comps: list[list[str]] = []
    for n in nodes:
        if n not in comp_of:
            members = [m for m in nodes if m == n or (m in reach[n] and n in reach[m])]
            for m in members:
                comp_of[m] = len(comps)
            comps.append(members)
    preds: dict[int, set[int]] = {i: set() for i in range(len(comps))}
    for a, b in edges:
        if comp_of[a] != comp_of[b]:
            preds[comp_of[b]].add(comp_of[a])
    done: set[int] = set()
    order: list[str] = []
    while len(done) < len(comps):
        ready = [i for i in range(len(comps)) if i not in done and preds[i] <= done]
        nxt = min(ready, key=lambda i: index[comps[i][0]])
        done.add(nxt)
        members = comps[nxt]
        if len(members) == 1:
            order.extend(members)
        else:
            head, inside = members[0], set(members)
            cut = {(a, b) for a, b in edges if a in inside and b in inside and b != head}
            order.extend(_order(members, cut))
    return order


# --------------------------------------------------------------------------- resolution
def scenario_of(scenario: Scenario | Path | str) -> Scenario:
    """``scenario`` itself, or the scenario loaded from that TOML file."""
    return scenario if isinstance(scenario, Scenario) else load_scenario(scenario)


def resolve(scenario: Scenario | Path | str, fmu_dir: Path | str | None = None,
            results_dir: Path | str | None = None) -> RunPlan:
    """Resolve and check ``scenario`` into a :class:`RunPlan` without loading any FMU
    library (only modelDescriptions are read).

    Raises
    ------
    ScenarioError
        A missing ``files`` file, an FMU without co-simulation interface, unknown
        variable names, wrong causality or type (checked against the modelDescriptions).
    FileNotFoundError
        A missing FMU file.
    """
    s = scenario_of(scenario)
    files = resolve_file_parameters(s, results_dir)
    directory = resolve_fmu_dir(s, fmu_dir)
    coupling = plan_coupling(s)
    paths = {name: fmu_path(s, name, directory) for name in s.fmus}
    descriptions = {name: _co_simulation_description(paths[name]) for name in coupling.order}
    models = {name: model_info(md) for name, (_, md) in descriptions.items()}
    check_against_models(s, models)
    params, added = _start_values(s, coupling, models, files)
    instances = {name: _instance(name, paths[name], *descriptions[name], s.fmus[name].step_ratio,
                                 models[name], params[name]) for name in s.fmus}
    return RunPlan(
        name=s.name, source=s.source, step_s=s.step_s, n_steps=s.n_steps,
        duration_s=s.duration_s, decimation=s.record.decimation,
        precision=s.record.precision, coupling_kind=s.coupling, coupling=coupling,
        instances=instances, links=_links(s, coupling, models),
        recorded=recorded_signals(s, models), events=_events(s, models),
        timing_added=tuple(added), fault_windows=tuple(fault_windows(s)),
        manoeuvre_windows=tuple(manoeuvre_windows(s)),
        judged=None if s.training is not None else frozenset(_expected(s)))


def preflight(scenario: Scenario, fmu_dir: Path | str | None = None,
              results_dir: Path | str | None = None) -> None:
    """Every check :func:`~gyrodiag_harness.cosim.master.run_scenario` makes before its
    first FMU call, without loading any FMU library (:func:`resolve`).  Safe in a
    process that must not run FMUs (a batch supervisor).

    Raises
    ------
    ScenarioError, FileNotFoundError
        As :func:`~gyrodiag_harness.cosim.master.run_scenario` would.
    """
    resolve(scenario, fmu_dir, results_dir)


def fmu_path(scenario: Scenario, instance: str, fmu_dir: Path) -> Path:
    """The existing ``.fmu`` file of ``instance``; FileNotFoundError if there is none."""
    path = resolve_fmu_file(scenario, instance, fmu_dir)
    if not path.is_file():
        raise FileNotFoundError(
            f"{scenario.source}: fmus.{instance}.fmu: FMU file {path} not found "
            f"(build it with 'python build_fmu.py' or pass --fmu-dir)")
    return path


def _co_simulation_description(path: Path) -> tuple[str, Any]:
    """Extracted folder and modelDescription of an FMU that must support co-simulation."""
    unzipdir = extract_fmu(path)
    md = model_description(unzipdir)
    if md.coSimulation is None:
        raise ScenarioError(str(path), [("", "the FMU has no co-simulation interface")])
    return unzipdir, md


def _instance(name: str, path: Path, unzipdir: str, md: Any, step_ratio: int, info: ModelInfo,
              params: Mapping[str, Any]) -> InstancePlan:
    return InstancePlan(
        name=name, fmu_path=path, unzipdir=unzipdir, guid=md.guid,
        model_identifier=md.coSimulation.modelIdentifier, step_ratio=step_ratio, info=info,
        parameters=tuple((info.variables[p], v) for p, v in params.items()))


def model_info(md: Any) -> ModelInfo:
    """fmpy ModelDescription → :class:`ModelInfo` (what the scenario checks need)."""
    variables = {
        v.name: VariableInfo(name=v.name, type=v.type, causality=v.causality,
                             variability=v.variability, value_reference=v.valueReference)
        for v in md.modelVariables
    }
    return ModelInfo(fmu_name=md.modelName, variables=variables)


def _start_values(s: Scenario, coupling: CouplingPlan, models: Mapping[str, ModelInfo],
                  files: Mapping[str, Mapping[str, str]]
                  ) -> tuple[dict[str, dict[str, Any]], list[tuple[str, str, int]]]:
    """Start values per instance (scenario, injector faults, manoeuvres, files, then the
    sample alignment of this coupling where the scenario sets none) and what the last
    added."""
    params: dict[str, dict[str, Any]] = {n: dict(i.parameters) for n, i in s.fmus.items()}
    for f in s.injector_faults:
        params[f.injector].update(f.injector_parameters())
    for m in s.manoeuvres:
        params[m.instance].update(m.instance_parameters())
    for name, paths in files.items():
        params[name].update(paths)
    variables = {n: i.variables for n, i in models.items()}
    added = fill_timing_parameters(params, s, coupling.delayed, variables)
    return params, added


def _variable(models: Mapping[str, ModelInfo], qualified: str) -> tuple[str, VariableInfo]:
    inst, var = split_name(qualified)
    return inst, models[inst].variables[var]


def _links(s: Scenario, coupling: CouplingPlan,
           models: Mapping[str, ModelInfo]) -> tuple[Link, ...]:
    """The connections in declaration order, both ends resolved."""
    delayed = {(c.from_, c.to) for c in coupling.delayed}
    links = []
    for c in s.connections:
        src, src_var = _variable(models, c.from_)
        dst, dst_var = _variable(models, c.to)
        links.append(Link(c.from_, c.to, src, src_var, dst, dst_var,
                          (c.from_, c.to) in delayed))
    return tuple(links)


def _expected(s: Scenario) -> list[str]:
    """Signals the expectations read, each once, in order of appearance."""
    names: list[str] = []
    for e in s.expect:
        names += [q for q in expected_signals(e) if q not in names]
    return names


def recorded_signals(s: Scenario, models: Mapping[str, ModelInfo]
                     ) -> tuple[Recorded, ...]:
    """``record.variables`` (default: every non-String output) plus what the
    expectations read, which is always recorded."""
    if s.record.variables is None:
        names = [f"{n}.{v.name}" for n in s.fmus for v in models[n].variables.values()
                 if v.causality == "output" and v.type != "String"]
    else:
        names = list(s.record.variables)
    names += [q for q in _expected(s) if q not in names]
    return tuple(Recorded(q, *_variable(models, q)) for q in names)


def _events(s: Scenario, models: Mapping[str, ModelInfo]) -> tuple[FaultEvent, ...]:
    """Physical fault starts and ends, by time (a start before an end at one time, then
    declaration order)."""
    keyed = sorted([(f.start_s, 0, i) for i, f in enumerate(s.physical_faults)]
                   + [(f.end_s, 1, i) for i, f in enumerate(s.physical_faults)
                      if not math.isinf(f.end_s)])
    events = []
    for t, is_end, i in keyed:
        f = s.physical_faults[i]
        inst, var = _variable(models, f.set)
        events.append(FaultEvent(t, bool(is_end), f.name, inst, var, f.value))
    return tuple(events)


def judged_signals(scenario: Scenario, result: RunResult) -> set[str]:
    """What is judged from a run: the signals its expectations read, and every recorded
    signal of a training scenario (the signature and pattern learners read them all)."""
    if scenario.training is not None:
        return set(result.signals)
    return {q for e in scenario.expect for q in expected_signals(e)}


def manoeuvre_windows(scenario: Scenario) -> list[FaultWindow]:
    """The scenario's manoeuvres as windows (``kind`` = manoeuvre kind, ``target`` = the
    instance that flies it)."""
    return [FaultWindow(m.name, m.instance, m.kind, m.start_s, m.end_s)
            for m in scenario.manoeuvres]


def fault_windows(scenario: Scenario) -> list[FaultWindow]:
    """The scenario's fault schedule as :class:`FaultWindow` entries."""
    windows = []
    for f in scenario.faults:
        if isinstance(f, InjectorFault):
            end = math.inf if f.type == "step" else f.end_s
            windows.append(FaultWindow(f.name, f.target, f.type, f.start_s, end))
        else:
            windows.append(FaultWindow(f.name, f.target, "physical", f.start_s, f.end_s))
    return windows
