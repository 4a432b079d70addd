"""FMI 2.0 access for the co-simulation master: FMU files, log callbacks, instances.

What :mod:`gyrodiag_harness.cosim.master` calls to run a plan, kept apart from its
orchestration (as FMPy keeps ``fmi2.py`` apart from ``simulation.py``):

* FMU files are extracted once per content hash (:func:`extraction_root`) and their
  modelDescriptions read once per folder (:func:`model_description`);
* one fmpy logger callback serves every instance and dispatches each message to the
  instance's log sink by its ``componentEnvironment``, so errors can quote the FMU;
* :class:`Instance` wraps one ``FMU2Slave``: every call is checked, a failure raises
  :class:`FmuCallError` quoting the FMU's log lines; batched get/set by FMI type go
  through :class:`VarGroup` with ctypes buffers made once.
* The shared libraries are **never unloaded** (fmpy's ``freeInstance`` would call
  ``freeLibrary``; unloading and reloading a pythonfmu binary in one process has crashed
  before, docs/methods.md §6.11).
"""

from __future__ import annotations

import ctypes
import hashlib
import itertools
import logging
import os
import shutil
import tempfile
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:
    from gyrodiag_harness.cosim.scenario import VariableInfo

#: Logger of the FMUs' messages (the master's, whose name the run logs have always used).
log = logging.getLogger("gyrodiag_harness.cosim.master")
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


def extract_fmu(fmu: Path) -> str:
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


def model_description(unzipdir: str) -> Any:
    """fmpy's ModelDescription of an extracted FMU (read once per folder)."""
    from fmpy import read_model_description

    if unzipdir not in _DESCRIPTIONS:
        _DESCRIPTIONS[unzipdir] = read_model_description(unzipdir)
    return _DESCRIPTIONS[unzipdir]


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


# --------------------------------------------------------------------------- instances
class FmuCallError(RuntimeError):
    """An FMU call returned fmi2Error/fmi2Fatal (message quotes the FMU's log)."""

    def __init__(self, message: str, fatal: bool) -> None:
        super().__init__(message)
        self.fatal = fatal


class VarGroup:
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
    """One FMI type's share of a :class:`VarGroup`: positions, references, buffer."""

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


class Instance:
    """One FMU instance with its log sink; every FMI call goes through :meth:`call`."""

    def __init__(self, name: str, unzipdir: str, guid: str, model_identifier: str) -> None:
        """Load the FMU's library (once per process) for instance ``name``; nothing is
        instantiated until :meth:`instantiate`."""
        from fmpy.fmi2 import FMU2Slave

        self.name = name
        self.env_id = next(_ENV_IDS)
        self.log: list[tuple[int, str]] = []
        self.slave = FMU2Slave(guid=guid, unzipDirectory=unzipdir,
                               modelIdentifier=model_identifier, instanceName=name)
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

    def read(self, group: VarGroup, t: float, out: np.ndarray | None = None,
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

    def write(self, group: VarGroup, values: np.ndarray, t: float) -> None:
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


