"""Co-simulation master: runs a :class:`~gyrodiag_harness.cosim.scenario.Scenario` through fmpy.

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

import ctypes
import hashlib
import itertools
import logging
import math
import os
import shutil
import sys
import tempfile
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from gyrodiag_harness.cosim.interrupt import RunInterrupted, stop_on_signals, stop_requested
from gyrodiag_harness.cosim.results import PRECISIONS, FaultWindow, RunResult
from gyrodiag_harness.cosim.scenario import (
    Connection,
    InjectorFault,
    ModelInfo,
    PhysicalFault,
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

log = logging.getLogger(__name__)
_STATUS = ["OK", "WARNING", "DISCARD", "ERROR", "FATAL", "PENDING"]
_FMI_WARNING = 1
_FMI_ERROR = 3
_FMI_FATAL = 4
#: Log lines quoted in an error message (the last ones of the failing call).
MAX_LOG_LINES = 20


# --------------------------------------------------------------------------- FMU files
_EXTRACTED: dict[tuple[str, int, int], str] = {}
_DESCRIPTIONS: dict[str, Any] = {}


def extraction_root() -> Path:
    """Where FMUs are unzipped: one folder per FMU content hash, shared by processes.

    The folders are never deleted by the harness, since a pythonfmu library stays mapped
    until the process exits; keyed by content they do not pile up. (Deleting them at
    exit only shifted the heap layout of pythonfmu's own use-after-free at exit, which
    the status shim now prevents.)
    """
    user = os.getuid() if hasattr(os, "getuid") else 0
    return Path(tempfile.gettempdir()) / f"gyrodiag-fmus-{user}"


def _extract(fmu: Path) -> str:
    """Unzip ``fmu`` into :func:`extraction_root` once (per content, across processes)."""
    from fmpy import extract

    st = fmu.stat()
    key = (str(fmu.resolve()), st.st_size, st.st_mtime_ns)
    if key not in _EXTRACTED:
        digest = hashlib.sha256(fmu.read_bytes()).hexdigest()[:20]
        root = extraction_root()
        target = root / f"{fmu.stem}-{digest}"
        if not (target / "modelDescription.xml").is_file():
            root.mkdir(parents=True, exist_ok=True)
            staging = tempfile.mkdtemp(prefix=f".{fmu.stem}-", dir=root)
            extract(str(fmu), unzipdir=staging)
            try:
                os.rename(staging, target)  # atomic: a concurrent process may win
            except OSError:
                shutil.rmtree(staging, ignore_errors=True)
        _EXTRACTED[key] = str(target)
    return _EXTRACTED[key]


def _model_description(unzipdir: str) -> Any:
    from fmpy import read_model_description

    if unzipdir not in _DESCRIPTIONS:
        _DESCRIPTIONS[unzipdir] = read_model_description(unzipdir)
    return _DESCRIPTIONS[unzipdir]


def model_info(md: Any) -> ModelInfo:
    """fmpy ModelDescription → :class:`ModelInfo` (what the scenario checks need)."""
    variables = {
        v.name: VariableInfo(name=v.name, type=v.type, causality=v.causality,
                             variability=v.variability, value_reference=v.valueReference)
        for v in md.modelVariables
    }
    return ModelInfo(fmu_name=md.modelName, variables=variables)


# --------------------------------------------------------------------------- logging
# fmpy's native logger proxy (which formats the message's printf arguments) keeps ONE
# Python logger for the whole process, so a single callback receives every message and
# dispatches it by the componentEnvironment each instance was given.
_LOG_SINKS: dict[int, list[tuple[int, str]]] = {}
_ENV_IDS = itertools.count(1)
_CALLBACKS_ALIVE: dict[int, Any] = {}


def _on_log(env: Any, instance_name: bytes | None, status: int, category: bytes | None,
            message: bytes | None) -> None:
    try:
        text = message.decode("utf-8", "replace") if message else ""
        sink = _LOG_SINKS.get(int(env or 0))
        if sink is not None:
            sink.append((int(status), text))
            if log.isEnabledFor(logging.DEBUG):
                name = instance_name.decode("utf-8", "replace") if instance_name else "?"
                label = _STATUS[status] if 0 <= status < len(_STATUS) else str(status)
                log.debug("%s [%s] %s", name, label, text.rstrip())
        else:  # an FMU not run by this master: behave like fmpy's default logger
            label = _STATUS[status] if 0 <= status < len(_STATUS) else str(status)
            log.warning("[%s] %s", label, text)
    except Exception:  # an exception must never cross the C boundary
        pass


_LOGGER: Any = None


def _make_callbacks(env_id: int) -> Any:
    global _LOGGER
    from fmpy import calloc, free
    from fmpy.fmi2 import (
        fmi2CallbackAllocateMemoryTYPE,
        fmi2CallbackFreeMemoryTYPE,
        fmi2CallbackFunctions,
        fmi2CallbackLoggerTYPE,
    )
    from fmpy.logging import addLoggerProxy

    if _LOGGER is None:
        _LOGGER = fmi2CallbackLoggerTYPE(_on_log)
    callbacks = fmi2CallbackFunctions()
    callbacks.logger = _LOGGER
    callbacks.allocateMemory = fmi2CallbackAllocateMemoryTYPE(calloc)
    callbacks.freeMemory = fmi2CallbackFreeMemoryTYPE(free)
    callbacks.componentEnvironment = ctypes.c_void_p(env_id)
    addLoggerProxy(ctypes.byref(callbacks))
    return callbacks


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


# --------------------------------------------------------------------------- instances
class FmuCallError(RuntimeError):
    """An FMU call returned fmi2Error/fmi2Fatal (message quotes the FMU's log)."""

    def __init__(self, message: str, fatal: bool) -> None:
        super().__init__(message)
        self.fatal = fatal


class _VarGroup:
    """Variables read or written together, batched by FMI type.

    Each batch keeps its value references and a value buffer as ctypes arrays made once,
    so a step's reads and writes are one foreign call per batch without per-call
    allocation (fmpy's wrappers build both arrays and a list on every call).
    """

    def __init__(self, variables: Sequence[VariableInfo]) -> None:
        self.size = len(variables)
        self.by_type: dict[str, tuple[list[int], list[int]]] = {}
        for pos, v in enumerate(variables):
            kind = "Integer" if v.type == "Enumeration" else v.type
            positions, vrs = self.by_type.setdefault(kind, ([], []))
            positions.append(pos)
            vrs.append(v.value_reference)
        self.batches = [_Batch(kind, positions, vrs)
                        for kind, (positions, vrs) in self.by_type.items()
                        if kind in _C_VALUE]
        # the common case (every variable Real, in order): one foreign call, no scatter
        only = self.batches[0] if len(self.batches) == 1 else None
        self.real_in_order: _Batch | None = (
            only if only is not None and only.kind == "Real" and only.n == self.size
            and only.positions.tolist() == list(range(self.size)) else None)


#: ctypes value type and numpy view type of the batched FMI types
_C_VALUE = {"Real": (ctypes.c_double, np.float64), "Integer": (ctypes.c_int, np.intc),
            "Boolean": (ctypes.c_int, np.intc)}


class _Batch:
    """One FMI type's share of a :class:`_VarGroup`: positions, references, buffer."""

    def __init__(self, kind: str, positions: list[int], vrs: list[int]) -> None:
        c_type, np_type = _C_VALUE[kind]
        self.kind = kind
        self.n = len(vrs)
        self.positions = np.asarray(positions, dtype=np.intp)
        self.vr_array = (ctypes.c_uint * self.n)(*vrs)
        self.buffer = (c_type * self.n)()
        self.view = np.frombuffer(self.buffer, dtype=np_type)
        self._columns: tuple[Any, np.ndarray] | None = None

    def columns(self, cols: Any) -> np.ndarray:
        """``cols[positions]``: where this batch's values go in a row laid out by
        ``cols`` (one array per group, made at the first call)."""
        cached = self._columns
        if cached is None or cached[0] is not cols:
            cached = self._columns = (cols, np.asarray(cols, dtype=np.intp)[self.positions])
        return cached[1]


class _RawFmi2:
    """The FMI 2.0 get/set/doStep entry points of one loaded FMU, called directly.

    Own function objects (``dll[name]`` makes a new one each time), so fmpy's wrappers
    keep theirs; statuses are checked by the caller.
    """

    def __init__(self, dll: Any) -> None:
        vp, vr_p, size = ctypes.c_void_p, ctypes.POINTER(ctypes.c_uint), ctypes.c_size_t

        def fn(name: str, *argtypes: Any) -> Any:
            f = dll[name]
            f.argtypes = argtypes
            f.restype = ctypes.c_int
            return f

        real_p, int_p = ctypes.POINTER(ctypes.c_double), ctypes.POINTER(ctypes.c_int)
        self.get = {"Real": fn("fmi2GetReal", vp, vr_p, size, real_p),
                    "Integer": fn("fmi2GetInteger", vp, vr_p, size, int_p),
                    "Boolean": fn("fmi2GetBoolean", vp, vr_p, size, int_p)}
        self.set = {"Real": fn("fmi2SetReal", vp, vr_p, size, real_p),
                    "Integer": fn("fmi2SetInteger", vp, vr_p, size, int_p),
                    "Boolean": fn("fmi2SetBoolean", vp, vr_p, size, int_p)}
        self.do_step = fn("fmi2DoStep", vp, ctypes.c_double, ctypes.c_double, ctypes.c_int)


class _Instance:
    """One FMU instance with its log sink; every FMI call goes through :meth:`call`."""

    def __init__(self, name: str, fmu_path: Path, step_ratio: int) -> None:
        from fmpy.fmi2 import FMU2Slave

        self.name = name
        self.step_ratio = step_ratio
        unzipdir = _extract(fmu_path)
        self.md = _model_description(unzipdir)
        if self.md.coSimulation is None:
            raise ScenarioError(str(fmu_path), [("", "the FMU has no co-simulation interface")])
        self.info = model_info(self.md)
        self.env_id = next(_ENV_IDS)
        self.log: list[tuple[int, str]] = []
        self.slave = FMU2Slave(guid=self.md.guid, unzipDirectory=unzipdir,
                               modelIdentifier=self.md.coSimulation.modelIdentifier,
                               instanceName=name)
        self.instantiated = False
        self.initialized = False
        self.failed = False
        self.fatal = False

    def call(self, what: str, t: float, fn: Callable[..., Any], *args: Any) -> Any:
        mark = len(self.log)
        try:
            return fn(*args)
        except Exception as exc:
            raise self._failure(what, t, getattr(exc, "status", None), exc, mark) from None

    def _checked(self, what: str, t: float, status: int, mark: int) -> None:
        """Raise as :meth:`call` would for a status from a direct call (> fmi2Warning)."""
        if status > _FMI_WARNING:
            raise self._failure(what, t, status, None, mark)

    def _failure(self, what: str, t: float, status: Any, exc: BaseException | None,
                 mark: int) -> FmuCallError:
        self.failed = True
        self.fatal = status == _FMI_FATAL or not self.instantiated
        lines = [text.rstrip() for _, text in self.log[mark:]] or [
            text.rstrip() for st, text in self.log if st >= _FMI_ERROR][-3:]
        lines = lines[-MAX_LOG_LINES:]
        label = _STATUS[status] if isinstance(status, int) and 0 <= status < 6 else None
        head = f"instance {self.name}: {what} at t={t:.9g}"
        head += f" returned {label}" if label else f" failed: {exc}"
        body = "\n".join(lines) if lines else "(the FMU logged nothing)"
        return FmuCallError(f"{head}: {body}", self.fatal)

    def instantiate(self, start_time: float) -> None:
        self.callbacks = _make_callbacks(self.env_id)
        _LOG_SINKS[self.env_id] = self.log
        _CALLBACKS_ALIVE[self.env_id] = self.callbacks
        self.call("instantiate", start_time, self.slave.instantiate, False, self.callbacks,
                  False)
        self.instantiated = True
        self.call("setupExperiment", start_time, self.slave.setupExperiment, None, start_time)
        self.component = self.slave.component
        self.raw = _RawFmi2(self.slave.dll)

    def set_values(self, what: str, t: float, variables: Sequence[VariableInfo],
                   values: Sequence[Any]) -> None:
        s = self.slave
        for v, value in zip(variables, values, strict=True):
            if v.type == "Real":
                self.call(f"{what} {v.name}", t, s.setReal, [v.value_reference], [float(value)])
            elif v.type in ("Integer", "Enumeration"):
                self.call(f"{what} {v.name}", t, s.setInteger, [v.value_reference], [int(value)])
            elif v.type == "Boolean":
                self.call(f"{what} {v.name}", t, s.setBoolean, [v.value_reference], [bool(value)])
            else:
                self.call(f"{what} {v.name}", t, s.setString, [v.value_reference], [str(value)])

    def read(self, group: _VarGroup, t: float, out: np.ndarray | None = None,
             cols: Any = None) -> np.ndarray:
        """Values of ``group`` in its order; into ``out[cols]`` when given."""
        if out is None:
            b = group.real_in_order
            if b is not None:
                mark = len(self.log)
                status = self.raw.get["Real"](self.component, b.vr_array, b.n, b.buffer)
                if status > _FMI_WARNING:
                    raise self._failure("getReal", t, status, None, mark)
                return b.view.copy()
            out = np.empty(group.size)
            cols = None
        get, c = self.raw.get, self.component
        for b in group.batches:
            mark = len(self.log)
            status = get[b.kind](c, b.vr_array, b.n, b.buffer)
            if status > _FMI_WARNING:
                raise self._failure(f"get{b.kind}", t, status, None, mark)
            out[b.positions if cols is None else b.columns(cols)] = b.view
        return out

    def write(self, group: _VarGroup, values: np.ndarray, t: float) -> None:
        set_, c = self.raw.set, self.component
        b = group.real_in_order
        if b is not None:
            b.view[:] = values
            mark = len(self.log)
            status = set_["Real"](c, b.vr_array, b.n, b.buffer)
            if status > _FMI_WARNING:
                raise self._failure("setReal", t, status, None, mark)
            return
        for b in group.batches:
            vals = values[b.positions]
            if b.kind == "Real":
                b.view[:] = vals
            elif b.kind == "Integer":
                b.view[:] = np.rint(vals)
            else:
                b.view[:] = vals > 0.5
            mark = len(self.log)
            status = set_[b.kind](c, b.vr_array, b.n, b.buffer)
            if status > _FMI_WARNING:
                raise self._failure(f"set{b.kind}", t, status, None, mark)

    def do_step(self, t: float, h: float) -> None:
        mark = len(self.log)
        status = self.raw.do_step(self.component, t, h, 1)
        if status > _FMI_WARNING:
            raise self._failure("doStep", t, status, None, mark)

    def free(self) -> None:
        """Terminate (if healthy) and free the instance; never unload the library."""
        try:
            if self.instantiated and not self.fatal:
                if self.initialized and not self.failed:
                    self.slave.terminate()
                self.slave.fmi2FreeInstance(self.slave.component)
        except Exception:  # freeing is best effort; the run's outcome is already known
            pass
        finally:
            self.instantiated = False
            _LOG_SINKS.pop(self.env_id, None)
            _CALLBACKS_ALIVE.pop(self.env_id, None)


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
    if not isinstance(scenario, Scenario):
        scenario = load_scenario(scenario)
    if precision is None:
        precision = scenario.record.precision
    if precision not in PRECISIONS:
        raise ValueError(f"precision must be one of {', '.join(map(repr, PRECISIONS))} or "
                         f"None, got {precision!r}")
    files = resolve_file_parameters(scenario, results_dir)
    with stop_on_signals():
        run = _Run(scenario, resolve_fmu_dir(scenario, fmu_dir), files)
        result = run.execute(progress)
        if out_dir is not None:
            result.save(Path(out_dir), precision, judged=judged_signals(scenario, result))
    if result.interrupted:
        raise RunInterrupted(stop_requested() or "interrupted", result)
    return result


def judged_signals(scenario: Scenario, result: RunResult) -> set[str]:
    """What is judged from a run: the signals its expectations read, and every recorded
    signal of a training scenario (the signature and pattern learners read them all)."""
    if scenario.training is not None:
        return set(result.signals)
    return {q for e in scenario.expect for q in expected_signals(e)}


def preflight(scenario: Scenario, fmu_dir: Path | str | None = None,
              results_dir: Path | str | None = None) -> None:
    """Every check :func:`run_scenario` makes before its first FMU call, without loading
    any FMU library: ``files`` parameters, FMU files, variable names against the
    modelDescriptions.  Safe in a process that must not run FMUs (a batch supervisor).

    Raises
    ------
    ScenarioError, FileNotFoundError
        As :func:`run_scenario` would.
    """
    resolve_file_parameters(scenario, results_dir)
    directory = resolve_fmu_dir(scenario, fmu_dir)
    models = {}
    for name in scenario.fmus:
        path = _fmu_path(scenario, name, directory)
        md = _model_description(_extract(path))
        if md.coSimulation is None:
            raise ScenarioError(str(path), [("", "the FMU has no co-simulation interface")])
        models[name] = model_info(md)
    check_against_models(scenario, models)


def _fmu_path(scenario: Scenario, instance: str, fmu_dir: Path) -> Path:
    path = resolve_fmu_file(scenario, instance, fmu_dir)
    if not path.is_file():
        raise FileNotFoundError(
            f"{scenario.source}: fmus.{instance}.fmu: FMU file {path} not found "
            f"(build it with 'python build_fmu.py' or pass --fmu-dir)")
    return path


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


class _Stop(Exception):
    """A stop request seen between two steps."""


class _Run:
    def __init__(self, scenario: Scenario, fmu_dir: Path,
                 files: dict[str, dict[str, str]] | None = None) -> None:
        self.s = scenario
        self.files = files or {}
        self.plan = plan_coupling(scenario)
        paths = {name: _fmu_path(scenario, name, fmu_dir) for name in scenario.fmus}
        self.inst = {n: _Instance(n, paths[n], scenario.fmus[n].step_ratio)
                     for n in self.plan.order}
        check_against_models(scenario, {n: i.info for n, i in self.inst.items()})
        self._prepare_io()
        # every instance steps every step (the common case): no per-step due list
        self._all_due = (list(self.plan.order)
                         if all(i.step_ratio == 1 for i in self.inst.values()) else [])

    def _var(self, qualified: str) -> tuple[str, VariableInfo]:
        inst, var = split_name(qualified)
        return inst, self.inst[inst].info.variables[var]

    def _prepare_io(self) -> None:
        s = self.s
        # sources: every connected output, cached per instance after it steps
        src_vars: dict[str, list[VariableInfo]] = {n: [] for n in self.inst}
        src_pos: dict[str, int] = {}
        for c in s.connections:
            inst, v = self._var(c.from_)
            if c.from_ not in src_pos:
                src_pos[c.from_] = len(src_vars[inst])
                src_vars[inst].append(v)
        self.src_group = {n: _VarGroup(vs) for n, vs in src_vars.items()}
        self.cache = {n: np.zeros(len(vs)) for n, vs in src_vars.items()}
        # destinations: (source instance, position in its cache) per input
        self.inputs: dict[str, tuple[_VarGroup, list[tuple[str, int]]]] = {}
        dst: dict[str, list[tuple[VariableInfo, str, int]]] = {n: [] for n in self.inst}
        for c in s.connections:
            src_inst = split_name(c.from_)[0]
            inst, v = self._var(c.to)
            dst[inst].append((v, src_inst, src_pos[c.from_]))
        for n, entries in dst.items():
            self.inputs[n] = (_VarGroup([e[0] for e in entries]), [(e[1], e[2]) for e in entries])
        # the same, as one fancy-index gather per source instance
        self.gathers: dict[str, list[tuple[str, np.ndarray, np.ndarray]]] = {}
        for n, (_, sources) in self.inputs.items():
            by_src: dict[str, tuple[list[int], list[int]]] = {}
            for dst_pos, (src, src_pos) in enumerate(sources):
                d, p = by_src.setdefault(src, ([], []))
                d.append(dst_pos)
                p.append(src_pos)
            self.gathers[n] = [(src, np.asarray(d, dtype=np.intp), np.asarray(p, dtype=np.intp))
                               for src, (d, p) in by_src.items()]
        # recorded variables
        if s.record.variables is None:
            names = [f"{n}.{v.name}" for n in s.fmus for v in self.inst[n].info.variables.values()
                     if v.causality == "output" and v.type != "String"]
        else:
            names = list(s.record.variables)
        # what the expectations read is always recorded
        for e in s.expect:
            names += [q for q in expected_signals(e) if q not in names]
        self.record_names = names
        per_inst: dict[str, list[tuple[int, VariableInfo]]] = {}
        for col, q in enumerate(names):
            inst, v = self._var(q)
            per_inst.setdefault(inst, []).append((col, v))
        self.record_groups = [(n, [c for c, _ in e], _VarGroup([v for _, v in e]))
                              for n, e in per_inst.items()]

    # -- helpers -----------------------------------------------------------------
    def _refresh(self, name: str, t: float) -> None:
        if self.src_group[name].size:
            self.cache[name] = self.inst[name].read(self.src_group[name], t)

    def _input_values(self, name: str) -> np.ndarray:
        values = np.empty(self.inputs[name][0].size)
        cache = self.cache
        for src, dst_pos, src_pos in self.gathers[name]:
            values[dst_pos] = cache[src][src_pos]
        return values

    def _set_inputs(self, name: str, t: float, values: np.ndarray | None = None) -> None:
        group, _ = self.inputs[name]
        if group.size:
            self.inst[name].write(group, self._input_values(name) if values is None else values,
                                  t)

    def _record(self, t: float) -> None:
        row = np.empty(len(self.record_names))
        for name, cols, group in self.record_groups:
            self.inst[name].read(group, t, row, cols)
        self.times.append(t)
        self.rows.append(row)

    # -- phases ------------------------------------------------------------------
    def _initialise(self, t0: float) -> None:
        s = self.s
        params: dict[str, dict[str, Any]] = {n: dict(i.parameters) for n, i in s.fmus.items()}
        for f in s.injector_faults:
            params[f.injector].update(f.injector_parameters())
        for m in s.manoeuvres:
            params[m.instance].update(m.instance_parameters())
        for name, paths in self.files.items():
            params[name].update(paths)
        variables = {n: i.info.variables for n, i in self.inst.items()}
        for name, var, value in fill_timing_parameters(params, s, self.plan.delayed,
                                                       variables):
            log.info("%s: %s.%s = %d (sample alignment under %s coupling, "
                     "gyrodiag_harness.cosim.timing)", s.name, name, var, value, s.coupling)
        for name in self.plan.order:
            inst = self.inst[name]
            inst.instantiate(t0)
            variables = [inst.info.variables[p] for p in params[name]]
            inst.set_values("set parameter", t0, variables, list(params[name].values()))
        for name in self.plan.order:
            self.inst[name].call("enterInitializationMode", t0,
                                 self.inst[name].slave.enterInitializationMode)
        # fixed point of the connections in initialisation mode
        for _ in range(len(self.inst) + 1):
            before = {n: c.copy() for n, c in self.cache.items()}
            for name in self.plan.order:
                self._set_inputs(name, t0)
                self._refresh(name, t0)
            if all(np.array_equal(before[n], self.cache[n], equal_nan=True) for n in before):
                break
        for name in self.plan.order:
            self._set_inputs(name, t0)
            self.inst[name].call("exitInitializationMode", t0,
                                 self.inst[name].slave.exitInitializationMode)
            self.inst[name].initialized = True
            self._refresh(name, t0)
        for name in self.plan.order:
            self._set_inputs(name, t0)

    def _step(self, k: int, t: float) -> None:
        h = self.s.step_s
        due = self._all_due if self._all_due else [
            n for n in self.plan.order if k % self.inst[n].step_ratio == 0]
        if self.s.coupling == "jacobi":
            values = {n: self._input_values(n) for n in due}
            for n in due:
                self._set_inputs(n, t, values[n])
            for n in due:
                self.inst[n].do_step(t, self.inst[n].step_ratio * h)
            for n in due:
                self._refresh(n, t + self.inst[n].step_ratio * h)
        else:
            for n in due:
                self._set_inputs(n, t)
                self.inst[n].do_step(t, self.inst[n].step_ratio * h)
                self._refresh(n, t + self.inst[n].step_ratio * h)

    def _physical_faults(self, t: float) -> None:
        """Apply the fault events due at ``t``: set at start_s, restore at end_s."""
        eps = 1e-9 * self.s.step_s
        while self.events and t >= self.events[0][0] - eps:
            _, is_end, _, f = self.events.pop(0)
            inst, var = self._var(f.set)
            if is_end:
                self.inst[inst].set_values("restore physical fault", t, [var],
                                           [self.originals[f.name]])
            else:
                self.originals[f.name] = _as_type(var, self.inst[inst].read(_VarGroup([var]),
                                                                            t)[0])
                self.inst[inst].set_values("set physical fault", t, [var], [f.value])

    def execute(self, progress: bool) -> RunResult:
        s = self.s
        self.times: list[float] = []
        self.rows: list[np.ndarray] = []
        self.events: list[tuple[float, int, int, PhysicalFault]] = sorted(
            [(f.start_s, 0, i, f) for i, f in enumerate(s.physical_faults)]
            + [(f.end_s, 1, i, f) for i, f in enumerate(s.physical_faults)
               if not math.isinf(f.end_s)])
        self.originals: dict[str, Any] = {}
        n_steps, h, dec = s.n_steps, s.step_s, s.record.decimation
        t0 = 0.0
        error: str | None = None
        interrupted = False
        wall0 = time.perf_counter()
        bar = _progress_bar(s.name, n_steps, progress)
        try:
            t = t0
            if stop_requested():
                raise _Stop
            self._initialise(t0)
            self._record(t0)
            log.debug("%s: initialised, stepping %d steps", s.name, n_steps)
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
        except FmuCallError as exc:
            error = str(exc)
        except _Stop:
            interrupted = True
            recorded = f"{self.times[-1]:g} s recorded" if self.times else "nothing recorded"
            error = (f"interrupted by {stop_requested()} after {recorded} of "
                     f"{s.duration_s:g} s")
        finally:
            if bar is not None:
                bar.close()
            for inst in self.inst.values():
                inst.free()
        table = np.array(self.rows) if self.rows else np.zeros((0, len(self.record_names)))
        return RunResult(
            scenario=s.name,
            time=np.array(self.times, dtype=float),
            signals={q: table[:, j].copy() for j, q in enumerate(self.record_names)},
            fault_windows=fault_windows(s),
            manoeuvre_windows=manoeuvre_windows(s),
            step_s=h,
            error=error,
            wall_time_s=time.perf_counter() - wall0,
            stop_time_s=s.duration_s,
            interrupted=interrupted,
        )


def _as_type(var: VariableInfo, value: float) -> Any:
    if var.type in ("Integer", "Enumeration"):
        return round(value)
    if var.type == "Boolean":
        return value > 0.5
    return value


def _progress_bar(name: str, total: int, enabled: bool) -> Any:
    if not enabled or not sys.stderr.isatty():
        return None
    from tqdm import tqdm

    return tqdm(total=total, desc=name, unit="step", leave=False, file=sys.stderr)
