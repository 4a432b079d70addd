"""A logged fmpy instance for the FMI-level tests (state bytes, steps, tunables, hosts).

Used only in processes that run FMUs (never imports ``gyrodiag``, docs/methods.md §6.3). fmpy
raises ``FMICallException`` for a status worse than warning; :meth:`Instance.call`
returns the status instead, so that a test can record it together with the log.
"""

from __future__ import annotations

import itertools
from ctypes import byref, c_void_p
from pathlib import Path
from typing import Any, ClassVar

import numpy as np

# fmpy's native logger proxy keeps ONE Python logger per process: one callback, which
# dispatches the messages by the componentEnvironment each instance was given.
_SINKS: dict[int, list[tuple[int, str]]] = {}
_ENV_IDS = itertools.count(1)
_LOGGER: Any = None


def _on_log(env: Any, _inst: Any, status: int, _cat: Any, message: bytes | None) -> None:
    sink = _SINKS.get(int(env or 0))
    if sink is not None:
        sink.append((int(status), message.decode("utf-8", "replace") if message else ""))


def host_signal(k: int, j: int) -> float:
    """Value of the j-th Real input at step k (the C host's signal, bit-identical)."""
    return float((k * (j + 3)) % 11 - 5) * 0.01 * float(j + 1)


class Instance:
    """One co-simulation instance through fmpy with its log captured.

    Parameters
    ----------
    fmu : path
        The .fmu file (extracted once per process and path).
    name : str
        Instance name.
    parameters : dict
        Start values set before initialisation (Real, Integer, Boolean, String).
    step : float, optional
        Communication step (s); default the FMU's DefaultExperiment stepSize.
    """

    _extracted: ClassVar[dict[str, tuple[str, Any]]] = {}

    def __init__(self, fmu: Path | str, name: str, parameters: dict[str, Any] | None = None,
                 step: float | None = None) -> None:
        from fmpy import extract, read_model_description
        from fmpy.fmi2 import (
            FMU2Slave,
            calloc,
            fmi2CallbackAllocateMemoryTYPE,
            fmi2CallbackFreeMemoryTYPE,
            fmi2CallbackFunctions,
            fmi2CallbackLoggerTYPE,
            free,
        )
        from fmpy.logging import addLoggerProxy

        key = str(Path(fmu).resolve())
        if key not in self._extracted:
            unzipdir = extract(key)
            self._extracted[key] = (unzipdir, read_model_description(unzipdir))
        self.unzipdir, self.md = self._extracted[key]
        global _LOGGER
        self.vars = {v.name: v for v in self.md.modelVariables}
        self.log: list[tuple[int, str]] = []
        env = next(_ENV_IDS)
        _SINKS[env] = self.log
        if _LOGGER is None:
            _LOGGER = fmi2CallbackLoggerTYPE(_on_log)
        cb = fmi2CallbackFunctions()
        cb.logger = _LOGGER
        cb.allocateMemory = fmi2CallbackAllocateMemoryTYPE(calloc)
        cb.freeMemory = fmi2CallbackFreeMemoryTYPE(free)
        cb.componentEnvironment = c_void_p(env)
        addLoggerProxy(byref(cb))
        self._callbacks = cb  # keep the ctypes objects alive
        self.fmu = FMU2Slave(guid=self.md.guid, unzipDirectory=self.unzipdir,
                             modelIdentifier=self.md.coSimulation.modelIdentifier,
                             instanceName=name)
        self.fmu.instantiate(callbacks=cb, loggingOn=False)
        default = self.md.defaultExperiment
        self.h = float(step if step is not None else default.stepSize)
        self.k = 0
        self.inputs = [v for v in self.md.modelVariables
                       if v.causality == "input" and v.type == "Real"]
        self.outputs = [v for v in self.md.modelVariables
                        if v.causality == "output" and v.type in ("Real", "Integer", "Boolean")]
        self.fmu.setupExperiment(startTime=0.0)
        for pname, value in (parameters or {}).items():
            self.set(pname, value)
        self.fmu.enterInitializationMode()
        self.init_status = self.call(self.fmu.exitInitializationMode)

    def call(self, fn: Any, *args: Any) -> int:
        from fmpy.fmi1 import FMICallException

        try:
            fn(*args)
        except FMICallException as exc:
            return int(exc.status)
        return 0

    def messages(self, since: int = 0) -> str:
        return "\n".join(m for _, m in self.log[since:])

    def set(self, name: str, value: Any) -> int:
        v = self.vars[name]
        setter = {"Real": (self.fmu.setReal, float), "Integer": (self.fmu.setInteger, int),
                  "Enumeration": (self.fmu.setInteger, int),
                  "Boolean": (self.fmu.setBoolean, bool), "String": (self.fmu.setString, str)}
        fn, cast = setter[v.type]
        return self.call(fn, [v.valueReference], [cast(value)])

    def get(self, name: str) -> Any:
        v = self.vars[name]
        getter = {"Real": self.fmu.getReal, "Integer": self.fmu.getInteger,
                  "Enumeration": self.fmu.getInteger, "Boolean": self.fmu.getBoolean,
                  "String": self.fmu.getString}[v.type]
        return getter([v.valueReference])[0]

    def row(self) -> np.ndarray:
        out = np.empty(len(self.outputs))
        for i, v in enumerate(self.outputs):
            out[i] = float(self.get(v.name))
        return out

    def step(self, n_steps: int = 1, h: float | None = None) -> np.ndarray:
        """``n_steps`` doSteps with the test signal on every Real input; output rows."""
        rows = []
        for _ in range(n_steps):
            if self.inputs:
                self.fmu.setReal([v.valueReference for v in self.inputs],
                                 [host_signal(self.k, j) for j in range(len(self.inputs))])
            status = self.call(self.fmu.doStep, self.k * self.h, h or self.h)
            if status != 0:
                raise RuntimeError(f"doStep {self.k} of {self.md.modelName}: status {status}:"
                                   f" {self.messages()}")
            self.k += 1
            rows.append(self.row())
        return np.array(rows)

    def close(self) -> None:
        """Terminate and free the instance; the shared library stays loaded (§6.11)."""
        self.call(self.fmu.terminate)
        self.fmu.fmi2FreeInstance(self.fmu.component)
