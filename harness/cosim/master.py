"""Co-simulation master: runs a :class:`~gyrodiag_harness.cosim.scenario.Scenario` through fmpy.

The scenario is first resolved into a :class:`~gyrodiag_harness.cosim.plan.RunPlan`
(:func:`~gyrodiag_harness.cosim.plan.resolve`: FMU files, variables, model checks,
coupling order, start values, recorded signals, fault events); this module only executes
that plan, through the FMI access of :mod:`gyrodiag_harness.cosim.fmi`.

Life of a run
-------------
1. Every FMU file is extracted once (per content hash, see :func:`extraction_root`), every
   instance is an fmpy ``FMU2Slave`` on that directory, with its own logger callback
   context so that the FMU's log lines can be quoted in errors.
2. Instantiate, ``setupExperiment``, set parameters (type from the modelDescription;
   injector faults become parameters of the FaultInjector instance, manoeuvres start
   values of the instance that flies them), enter
   initialisation mode, propagate outputs through the connections until nothing changes
   (at most ``len(instances) + 1`` passes), then leave initialisation mode instance by
   instance in coupling order, setting each one's inputs from its sources first (our
   pythonfmu FMUs compute their initial outputs when initialisation ends, so a source's
   final initial output reaches its destination before the destination initialises).
   One last pass sets every input; row 0 is recorded.
3. Per base step ``k`` (time ``t_k = k * step_s``):

   * physical faults due at ``t_k`` set their tunable parameter (restored at ``end_s``);
   * **Gauss-Seidel**: instances in coupling order; each instance due at ``k`` (``k %
     step_ratio == 0``) gets its connected inputs from the *current* source outputs and
     does ``doStep(t_k, step_ratio * step_s)``.  A source earlier in the order has already
     stepped, so the connection adds no latency.  The order is topological; a cycle is
     broken before its first-declared instance (order in ``[fmus]``): that instance's
     inputs from the rest of the cycle are the values at ``t_k``, i.e. **one step of
     latency at that place** (:func:`plan_coupling` lists these connections).
   * **Jacobi**: all due instances get their inputs from the outputs at ``t_k``, then
     all step: one step of latency per FMU boundary.
   * Multi-rate: an instance with ``step_ratio`` r steps every r base steps with
     ``r * step_s``; its inputs are held in between, and its outputs (those of the end
     of its macro step) are read as they are by everybody in between.

4. Recording every ``record.decimation`` base steps (row 0 and the last step always) of
   ``record.variables`` (default: every non-String output) plus every signal that an
   ``[[expect]]`` entry reads.
5. An FMU call that fails (fmi2Error/fmi2Fatal) stops the run: ``RunResult.error`` says
   which instance, which call, at what time, and quotes the FMU's log lines; the rows
   recorded so far are kept (and saved when ``out_dir`` is given).
   Ctrl-C or SIGTERM (:mod:`gyrodiag_harness.cosim.interrupt`) stops the run between two steps,
   never inside an FMU call: the rows so far are kept and saved the same way, marked
   ``interrupted``, and :func:`run_scenario` raises
   :class:`~gyrodiag_harness.cosim.interrupt.RunInterrupted` carrying the partial result.
6. Instances are terminated and freed, but the shared libraries are **never unloaded**
   (fmpy's ``freeInstance`` would call ``freeLibrary``; unloading and reloading a
   pythonfmu binary in one process has crashed before, docs/methods.md §6.11).  Loading the same
   FMU again reuses the loaded library.
"""


from __future__ import annotations

import logging
import sys
import time
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from gyrodiag_harness.cosim.fmi import (
    MAX_LOG_LINES,
    FmuCallError,
    Instance,
    VarGroup,
    extraction_root,
)
from gyrodiag_harness.cosim.interrupt import RunInterrupted, stop_on_signals, stop_requested
from gyrodiag_harness.cosim.plan import (
    CouplingPlan,
    RunPlan,
    fault_windows,
    judged_signals,
    manoeuvre_windows,
    model_info,
    plan_coupling,
    preflight,
    resolve,
    scenario_of,
)
from gyrodiag_harness.cosim.results import PRECISIONS, RunResult

if TYPE_CHECKING:
    from gyrodiag_harness.cosim.scenario import Scenario, VariableInfo

__all__ = [
    "MAX_LOG_LINES", "CouplingPlan", "FmuCallError", "RunPlan", "execute_plan",
    "extraction_root", "fault_windows", "judged_signals", "manoeuvre_windows", "model_info",
    "plan_coupling", "preflight", "run_scenario",
]

log = logging.getLogger(__name__)


# --------------------------------------------------------------------------- the run
def run_scenario(scenario: Scenario | Path | str, fmu_dir: Path | str | None = None,
                 progress: bool = True, out_dir: Path | str | None = None,
                 results_dir: Path | str | None = None,
                 precision: str | None = None) -> RunResult:
    """Run one scenario and return what was recorded.

    Parameters
    ----------
    scenario : Scenario or path
        A validated scenario or its TOML file.
    fmu_dir : path, optional
        Folder of the ``<Name>.fmu`` files; default: see
        :func:`gyrodiag_harness.cosim.scenario.resolve_fmu_dir`.
    progress : bool
        Show a tqdm progress bar (only when stderr is a terminal).
    out_dir : path, optional
        If given, ``signals.npz`` and ``run.json`` are written into this folder (also
        when the run stops on an FMU error).
    results_dir : path, optional
        Results folder of the command: what ``${out}/`` stands for in the instances'
        ``files`` (:func:`gyrodiag_harness.cosim.scenario.resolve_file_parameters`).
    precision : {"compact", "float32", "float64"}, optional
        How the saved file stores Real signals (:meth:`RunResult.save`); default the
        scenario's ``record.precision``.  The returned run keeps full precision.

    Returns
    -------
    RunResult
        ``error`` is None for a completed run, else the failing call and the FMU's log;
        the signals at full precision whatever ``precision`` saved.

    Raises
    ------
    ScenarioError
        Invalid scenario, unknown variable names (checked against the FMUs'
        modelDescriptions before anything is instantiated), a missing ``files`` file.
    FileNotFoundError
        A missing FMU file.
    RunInterrupted
        Ctrl-C or SIGTERM (or :func:`gyrodiag_harness.cosim.interrupt.request_stop`) stopped the
        run between two steps; its ``result`` is the partial run (saved when
        ``out_dir`` is given), marked ``interrupted``.  A KeyboardInterrupt.  The stop
        request stays set, so that a loop over runs starts nothing new
        (:func:`gyrodiag_harness.cosim.interrupt.clear_stop` to go on on purpose).
    """
    scenario = scenario_of(scenario)
    if precision is None:
        precision = scenario.record.precision
    if precision not in PRECISIONS:
        raise ValueError(f"precision must be one of {', '.join(map(repr, PRECISIONS))} or "
                         f"None, got {precision!r}")
    with stop_on_signals():
        plan = resolve(scenario, fmu_dir, results_dir)
        result = execute_plan(plan, progress)
        if out_dir is not None:
            result.save(Path(out_dir), precision, judged=plan.judged_signals(result))
    if result.interrupted:
        raise RunInterrupted(stop_requested() or "interrupted", result)
    return result


def execute_plan(plan: RunPlan, progress: bool = False) -> RunResult:
    """Run a resolved plan (:func:`gyrodiag_harness.cosim.plan.resolve`) and return what
    was recorded; an FMU error or a stop request ends the run early (see
    :func:`run_scenario`, which also saves the result and raises on a stop)."""
    return _Run(plan).execute(progress)


class _Stop(Exception):
    """A stop request seen between two steps."""


class _Run:
    """One execution of a :class:`RunPlan`: the instances, the exchange buffers, the rows."""

    def __init__(self, plan: RunPlan) -> None:
        self.plan = plan
        self.order = plan.coupling.order
        self.step_ratio = {n: i.step_ratio for n, i in plan.instances.items()}
        self.inst = {n: Instance(n, plan.instances[n].unzipdir, plan.instances[n].guid,
                                 plan.instances[n].model_identifier)
                     for n in self.order}
        self._prepare_exchange()
        self._prepare_record()
        # every instance steps every step (the common case): no per-step due list
        self._all_due = (list(self.order)
                         if all(r == 1 for r in self.step_ratio.values()) else [])

    def _prepare_exchange(self) -> None:
        """Source groups (every connected output, cached per instance after it steps) and
        per destination its input group and where each input's value sits in the caches."""
        src_vars: dict[str, list[VariableInfo]] = {n: [] for n in self.inst}
        src_pos: dict[str, int] = {}
        for link in self.plan.links:
            if link.from_ not in src_pos:
                src_pos[link.from_] = len(src_vars[link.src])
                src_vars[link.src].append(link.src_var)
        self.src_group = {n: VarGroup(vs) for n, vs in src_vars.items()}
        self.cache = {n: np.zeros(len(vs)) for n, vs in src_vars.items()}
        dst: dict[str, list[tuple[VariableInfo, str, int]]] = {n: [] for n in self.inst}
        for link in self.plan.links:
            dst[link.dst].append((link.dst_var, link.src, src_pos[link.from_]))
        self.inputs: dict[str, tuple[VarGroup, list[tuple[str, int]]]] = {
            n: (VarGroup([e[0] for e in entries]), [(e[1], e[2]) for e in entries])
            for n, entries in dst.items()}
        # the same, as one fancy-index gather per source instance
        self.gathers: dict[str, list[tuple[str, np.ndarray, np.ndarray]]] = {}
        for n, (_, sources) in self.inputs.items():
            by_src: dict[str, tuple[list[int], list[int]]] = {}
            for dst_pos, (src, pos) in enumerate(sources):
                d, q = by_src.setdefault(src, ([], []))
                d.append(dst_pos)
                q.append(pos)
            self.gathers[n] = [(src, np.asarray(d, dtype=np.intp), np.asarray(q, dtype=np.intp))
                               for src, (d, q) in by_src.items()]

    def _prepare_record(self) -> None:
        """One read group per instance of the recorded signals, with their columns."""
        self.record_names = [r.name for r in self.plan.recorded]
        per_inst: dict[str, list[tuple[int, VariableInfo]]] = {}
        for col, r in enumerate(self.plan.recorded):
            per_inst.setdefault(r.instance, []).append((col, r.var))
        self.record_groups = [(n, [c for c, _ in e], VarGroup([v for _, v in e]))
                              for n, e in per_inst.items()]

    # -- helpers -----------------------------------------------------------------
    def _refresh(self, name: str, t: float) -> None:
        """Read ``name``'s connected outputs into its cache."""
        if self.src_group[name].size:
            self.cache[name] = self.inst[name].read(self.src_group[name], t)

    def _input_values(self, name: str) -> np.ndarray:
        """``name``'s connected inputs gathered from the current source caches."""
        values = np.empty(self.inputs[name][0].size)
        cache = self.cache
        for src, dst_pos, src_pos in self.gathers[name]:
            values[dst_pos] = cache[src][src_pos]
        return values

    def _set_inputs(self, name: str, t: float, values: np.ndarray | None = None) -> None:
        """Write ``name``'s connected inputs (the current sources unless ``values``)."""
        group, _ = self.inputs[name]
        if group.size:
            self.inst[name].write(group, self._input_values(name) if values is None else values,
                                  t)

    def _record(self, t: float) -> None:
        """Append one row of the recorded signals at ``t``."""
        row = np.empty(len(self.record_names))
        for name, cols, group in self.record_groups:
            self.inst[name].read(group, t, row, cols)
        self.times.append(t)
        self.rows.append(row)

    # -- phases ------------------------------------------------------------------
    def _instantiate(self, t0: float) -> None:
        """Instantiate every instance in coupling order and set its start values."""
        plan = self.plan
        for name, var, value in plan.timing_added:
            log.info("%s: %s.%s = %d (sample alignment under %s coupling, "
                     "gyrodiag_harness.cosim.timing)", plan.name, name, var, value,
                     plan.coupling_kind)
        for name in self.order:
            inst = self.inst[name]
            inst.instantiate(t0)
            parameters = plan.instances[name].parameters
            inst.set_values("set parameter", t0, [v for v, _ in parameters],
                            [value for _, value in parameters])

    def _initialise(self, t0: float) -> None:
        """Initialisation mode: the connections' fixed point, then leave it instance by
        instance in coupling order, each one's inputs set from its sources first."""
        self._instantiate(t0)
        for name in self.order:
            self.inst[name].call("enterInitializationMode", t0,
                                 self.inst[name].slave.enterInitializationMode)
        for _ in range(len(self.inst) + 1):
            before = {n: c.copy() for n, c in self.cache.items()}
            for name in self.order:
                self._set_inputs(name, t0)
                self._refresh(name, t0)
            if all(np.array_equal(before[n], self.cache[n], equal_nan=True) for n in before):
                break
        for name in self.order:
            self._set_inputs(name, t0)
            self.inst[name].call("exitInitializationMode", t0,
                                 self.inst[name].slave.exitInitializationMode)
            self.inst[name].initialized = True
            self._refresh(name, t0)
        for name in self.order:
            self._set_inputs(name, t0)

    def _step(self, k: int, t: float) -> None:
        """Base step ``k`` at ``t``: the due instances exchange and step (Jacobi or
        Gauss-Seidel, see the module docstring)."""
        h = self.plan.step_s
        ratio = self.step_ratio
        due = self._all_due if self._all_due else [
            n for n in self.order if k % ratio[n] == 0]
        if self.plan.coupling_kind == "jacobi":
            values = {n: self._input_values(n) for n in due}
            for n in due:
                self._set_inputs(n, t, values[n])
            for n in due:
                self.inst[n].do_step(t, ratio[n] * h)
            for n in due:
                self._refresh(n, t + ratio[n] * h)
        else:
            for n in due:
                self._set_inputs(n, t)
                self.inst[n].do_step(t, ratio[n] * h)
                self._refresh(n, t + ratio[n] * h)

    def _physical_faults(self, t: float) -> None:
        """Apply the fault events due at ``t``: set at start_s, restore at end_s."""
        eps = 1e-9 * self.plan.step_s
        while self.events and t >= self.events[0].time_s - eps:
            e = self.events.pop(0)
            inst = self.inst[e.instance]
            if e.is_end:
                inst.set_values("restore physical fault", t, [e.var], [self.originals[e.fault]])
            else:
                self.originals[e.fault] = _as_type(e.var, inst.read(VarGroup([e.var]), t)[0])
                inst.set_values("set physical fault", t, [e.var], [e.value])

    def _steps(self, t0: float, bar: Any) -> None:
        """Initialise, record row 0, then every base step (stop requests between steps)."""
        n_steps, h, dec = self.plan.n_steps, self.plan.step_s, self.plan.decimation
        if stop_requested():
            raise _Stop
        self._initialise(t0)
        self._record(t0)
        log.debug("%s: initialised, stepping %d steps", self.plan.name, n_steps)
        chunk = max(1, n_steps // 200)
        for k in range(n_steps):
            # the only place a stop request acts: between two steps of every FMU
            if stop_requested():
                raise _Stop
            t = t0 + k * h
            if self.events:
                self._physical_faults(t)
            self._step(k, t)
            if (k + 1) % dec == 0 or k + 1 == n_steps:
                self._record(t0 + (k + 1) * h)
            if bar is not None and (k + 1) % chunk == 0:
                bar.update(chunk)

    def execute(self, progress: bool) -> RunResult:
        """Run the plan; an FMU error or a stop request keeps the rows so far."""
        plan = self.plan
        self.times: list[float] = []
        self.rows: list[np.ndarray] = []
        self.events = list(plan.events)
        self.originals: dict[str, Any] = {}
        error: str | None = None
        interrupted = False
        wall0 = time.perf_counter()
        bar = _progress_bar(plan.name, plan.n_steps, progress)
        try:
            self._steps(0.0, bar)
        except FmuCallError as exc:
            error = str(exc)
        except _Stop:
            interrupted = True
            recorded = f"{self.times[-1]:g} s recorded" if self.times else "nothing recorded"
            error = (f"interrupted by {stop_requested()} after {recorded} of "
                     f"{plan.duration_s:g} s")
        finally:
            if bar is not None:
                bar.close()
            for inst in self.inst.values():
                inst.free()
        return self._result(error, interrupted, time.perf_counter() - wall0)

    def _result(self, error: str | None, interrupted: bool, wall_s: float) -> RunResult:
        """The rows recorded so far as a :class:`RunResult`."""
        plan = self.plan
        table = np.array(self.rows) if self.rows else np.zeros((0, len(self.record_names)))
        return RunResult(
            scenario=plan.name,
            time=np.array(self.times, dtype=float),
            signals={q: table[:, j].copy() for j, q in enumerate(self.record_names)},
            fault_windows=list(plan.fault_windows),
            manoeuvre_windows=list(plan.manoeuvre_windows),
            step_s=plan.step_s,
            error=error,
            wall_time_s=wall_s,
            stop_time_s=plan.duration_s,
            interrupted=interrupted,
        )


def _as_type(var: VariableInfo, value: float) -> Any:
    """A value read as a float, back in the variable's type (to restore it as set)."""
    if var.type in ("Integer", "Enumeration"):
        return round(value)
    if var.type == "Boolean":
        return value > 0.5
    return value


def _progress_bar(name: str, total: int, enabled: bool) -> Any:
    """A tqdm bar on a terminal's stderr, else None."""
    if not enabled or not sys.stderr.isatty():
        return None
    from tqdm import tqdm

    return tqdm(total=total, desc=name, unit="step", leave=False, file=sys.stderr)
