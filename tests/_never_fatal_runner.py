"""A raw ctypes FMI 2.0 host that makes wrong calls on purpose, in a fresh process.

``python _never_fatal_runner.py FMU_PATH WORK_DIR MODE [ARGS]``

Every FMI call is made on the FMU's binary through ctypes (no fmpy wrapper that raises or
checks), so that a test sees the raw status of each call. Before each call a line
``{"begin": CALL}`` is printed and after it the record ``{"call", "status", "log"}``
(the messages the FMU logged during the call), one JSON object a line, flushed: if the
process dies (a segfault), the test knows in which call.

Modes

* ``types``: initialise, then for every variable type the FMU has, a wrong-typed get and
  set of one variable of that type through every other accessor; get and set of unknown
  value references; a doStep; terminate; free.
* ``types-no-md``: ``types`` without modelDescription.xml next to the resources (the
  shim then has no table of variables; the Python facades refuse the wrong calls).
* ``states``: calls in the wrong state (doStep before initialisation, setupExperiment or
  enterInitializationMode twice, set of a fixed parameter or an output after
  initialisation, doStep after terminate, terminate twice), NULL arrays with n > 0,
  NULL or non-UTF-8 strings, NULL pointers to the FMU-state functions, then free.
* ``instantiate``: fmi2Instantiate with a NULL or wrong GUID, NULL instance name, NULL
  resource location, model exchange; then a good instance that runs.
* ``single ACCESSOR get|set TYPE``: one wrong-typed call (ACCESSOR on a variable of
  TYPE) after initialisation, then doStep, terminate, free (the measurement of issue 32).

Used only in processes that run FMUs (never imports ``gyrodiag``, docs/methods.md §6.3).
"""

from __future__ import annotations

import json
import sys
import xml.etree.ElementTree as ET
import zipfile
from ctypes import (
    CDLL,
    byref,
    c_char_p,
    c_double,
    c_int,
    c_size_t,
    c_uint,
    c_void_p,
)
from pathlib import Path
from typing import Any

TYPES = ("Real", "Integer", "Boolean", "String")
_CTYPE = {"Real": c_double, "Integer": c_int, "Boolean": c_int, "String": c_char_p}
_SAMPLE = {"Real": 0.25, "Integer": 1, "Boolean": 1, "String": b"x"}
OK, WARNING, DISCARD, ERROR, FATAL = range(5)


def _out(obj: dict[str, Any]) -> None:
    sys.stdout.write(json.dumps(obj) + "\n")
    sys.stdout.flush()


class RawFmu:
    """One FMU's binary loaded with ctypes, with a logger that records every message."""

    def __init__(self, fmu: Path, work: Path) -> None:
        from fmpy.fmi2 import (
            calloc,
            fmi2CallbackAllocateMemoryTYPE,
            fmi2CallbackFreeMemoryTYPE,
            fmi2CallbackFunctions,
            fmi2CallbackLoggerTYPE,
            free,
        )
        from fmpy.logging import addLoggerProxy

        self.dir = work / fmu.stem
        with zipfile.ZipFile(fmu) as zf:
            zf.extractall(self.dir)
        root = ET.parse(self.dir / "modelDescription.xml").getroot()
        self.guid = root.get("guid")
        self.model = root.get("modelName")
        ident = root.find("CoSimulation").get("modelIdentifier")
        default = root.find("DefaultExperiment")
        self.h = float(default.get("stepSize")) if default is not None and default.get(
            "stepSize") else 0.01
        self.vars: list[dict[str, Any]] = []
        for sv in root.iter("ScalarVariable"):
            kind = sv[0].tag
            self.vars.append({"name": sv.get("name"), "vr": int(sv.get("valueReference")),
                              "type": "Integer" if kind == "Enumeration" else kind,
                              "causality": sv.get("causality", "local"),
                              "variability": sv.get("variability", "continuous")})
        self.log: list[tuple[int, str]] = []
        self._logger = fmi2CallbackLoggerTYPE(self._on_log)
        cb = fmi2CallbackFunctions()
        cb.logger = self._logger
        cb.allocateMemory = fmi2CallbackAllocateMemoryTYPE(calloc)
        cb.freeMemory = fmi2CallbackFreeMemoryTYPE(free)
        cb.componentEnvironment = None
        addLoggerProxy(byref(cb))  # formats the variadic message
        self.callbacks = cb
        self.dll = CDLL(str(self.dir / "binaries" / "linux64" / f"{ident}.so"))
        d = self.dll
        d.fmi2Instantiate.restype = c_void_p
        d.fmi2Instantiate.argtypes = [c_char_p, c_int, c_char_p, c_char_p, c_void_p, c_int,
                                      c_int]
        d.fmi2FreeInstance.restype = None
        d.fmi2FreeInstance.argtypes = [c_void_p]
        for name, args in {
            "fmi2SetupExperiment": [c_void_p, c_int, c_double, c_double, c_int, c_double],
            "fmi2EnterInitializationMode": [c_void_p],
            "fmi2ExitInitializationMode": [c_void_p],
            "fmi2Terminate": [c_void_p], "fmi2Reset": [c_void_p],
            "fmi2DoStep": [c_void_p, c_double, c_double, c_int],
            "fmi2GetFMUstate": [c_void_p, c_void_p], "fmi2FreeFMUstate": [c_void_p, c_void_p],
            "fmi2SerializedFMUstateSize": [c_void_p, c_void_p, c_void_p],
            "fmi2SerializeFMUstate": [c_void_p, c_void_p, c_void_p, c_size_t],
            **{f"fmi2{a}{t}": [c_void_p, c_void_p, c_size_t, c_void_p]
               for a in ("Get", "Set") for t in TYPES},
        }.items():
            fn = getattr(d, name)
            fn.restype, fn.argtypes = c_int, args
        self.c: int | None = None
        self.t = 0.0

    def _on_log(self, _env: Any, _inst: Any, status: int, _cat: Any, msg: bytes | None) -> None:
        self.log.append((int(status), msg.decode("utf-8", "replace") if msg else ""))

    # -- calls ---------------------------------------------------------------------------
    def call(self, label: str, fn: str, *args: Any) -> int:
        _out({"begin": label})
        mark = len(self.log)
        status = getattr(self.dll, fn)(*args)
        _out({"call": label, "status": status, "log": self.log[mark:]})
        return status

    def instantiate(self, label: str = "fmi2Instantiate", name: bytes | None = b"inst",
                    kind: int = 1, guid: bytes | str | None = "md",
                    resources: bytes | str | None = "dir") -> int | None:
        guid_b = self.guid.encode() if guid == "md" else guid
        res_b = (self.dir / "resources").as_uri().encode() if resources == "dir" else resources
        _out({"begin": label})
        mark = len(self.log)
        c = self.dll.fmi2Instantiate(name, kind, guid_b, res_b, byref(self.callbacks), 0, 0)
        _out({"call": label, "status": OK if c else None, "log": self.log[mark:]})
        return c

    def setup(self) -> int:
        return self.call("fmi2SetupExperiment", "fmi2SetupExperiment", self.c, 0, 0.0, 0.0,
                         0, 0.0)

    def init(self) -> None:
        self.c = self.instantiate()
        if not self.c:
            raise SystemExit(f"fmi2Instantiate failed: {self.log}")
        self.setup()
        self.call("fmi2EnterInitializationMode", "fmi2EnterInitializationMode", self.c)
        self.call("fmi2ExitInitializationMode", "fmi2ExitInitializationMode", self.c)

    def get(self, acc: str, vrs: list[int] | None, n: int | None = None,
            values: bool = True, label: str | None = None) -> int:
        n = len(vrs or []) if n is None else n
        arr = (c_uint * len(vrs))(*vrs) if vrs is not None else None
        out = (_CTYPE[acc] * max(n, 1))() if values else None
        return self.call(label or f"fmi2Get{acc}{vrs}", f"fmi2Get{acc}", self.c, arr, n, out)

    def set(self, acc: str, vrs: list[int] | None, n: int | None = None,
            values: Any = "sample", label: str | None = None) -> int:
        n = len(vrs or []) if n is None else n
        arr = (c_uint * len(vrs))(*vrs) if vrs is not None else None
        if values == "sample":
            vals = (_CTYPE[acc] * max(n, 1))(*([_SAMPLE[acc]] * max(n, 1)))
        else:
            vals = values
        return self.call(label or f"fmi2Set{acc}{vrs}", f"fmi2Set{acc}", self.c, arr, n, vals)

    def step(self, label: str = "fmi2DoStep") -> int:
        status = self.call(label, "fmi2DoStep", self.c, self.t, self.h, 1)
        if status <= WARNING:
            self.t += self.h
        return status

    def close(self) -> None:
        self.call("fmi2Terminate", "fmi2Terminate", self.c)
        _out({"begin": "fmi2FreeInstance"})
        self.dll.fmi2FreeInstance(self.c)
        _out({"call": "fmi2FreeInstance", "status": OK, "log": []})

    # -- choices -------------------------------------------------------------------------
    def pick(self, kind: str) -> dict[str, Any] | None:
        """A variable of ``kind``, preferring one a host may set after initialisation."""
        rank = {"input": 0, "parameter": 1, "output": 2}
        cands = [v for v in self.vars if v["type"] == kind]
        cands.sort(key=lambda v: (rank.get(v["causality"], 3), v["variability"] != "tunable"))
        return cands[0] if cands else None

    def unknown_vr(self) -> int:
        return max(v["vr"] for v in self.vars) + 1000


def mode_types(fmu: RawFmu) -> None:
    fmu.init()
    fmu.step("fmi2DoStep before")
    for kind in TYPES:
        var = fmu.pick(kind)
        if var is None:
            continue
        for acc in TYPES:
            if acc == kind:
                continue
            fmu.get(acc, [var["vr"]], label=f"wrong get {acc} {kind} {var['vr']}")
            fmu.set(acc, [var["vr"]], label=f"wrong set {acc} {kind} {var['vr']}")
    unknown = fmu.unknown_vr()
    for acc in TYPES:
        fmu.get(acc, [unknown], label=f"unknown get {acc} {unknown}")
        fmu.set(acc, [unknown], label=f"unknown set {acc} {unknown}")
    # a right vr and a wrong one in one call: refused as a whole
    real = fmu.pick("Real")
    fmu.get("Real", [real["vr"], unknown], label=f"mixed get Real {real['vr']} {unknown}")
    for kind in TYPES:  # the right-typed calls still work
        var = fmu.pick(kind)
        if var is not None:
            fmu.get(kind, [var["vr"]], label=f"right get {kind} {var['vr']}")
    fmu.step("fmi2DoStep after")
    fmu.step("fmi2DoStep after 2")
    fmu.close()


def mode_types_no_md(fmu: RawFmu) -> None:
    """``types`` with modelDescription.xml removed after reading it: the shim has no
    table, the Python facades check."""
    (fmu.dir / "modelDescription.xml").unlink()
    mode_types(fmu)


def mode_states(fmu: RawFmu) -> None:
    fmu.c = fmu.instantiate()
    fmu.step("doStep before initialisation")
    fmu.call("exit before enter", "fmi2ExitInitializationMode", fmu.c)
    fmu.setup()
    fmu.call("fmi2EnterInitializationMode", "fmi2EnterInitializationMode", fmu.c)
    fmu.call("setupExperiment in initialisation mode", "fmi2SetupExperiment", fmu.c, 0, 0.0,
             0.0, 0, 0.0)
    fmu.step("doStep in initialisation mode")
    fmu.call("enter twice", "fmi2EnterInitializationMode", fmu.c)
    string = fmu.pick("String")
    if string is not None:  # in initialisation mode, where a String parameter may be set
        fmu.set("String", [string["vr"]], values=(c_char_p * 1)(None),
                label=f"set String NULL string {string['vr']}")
        fmu.set("String", [string["vr"]], values=(c_char_p * 1)(b"\xff\xfe"),
                label=f"set String invalid UTF-8 {string['vr']}")
    fmu.call("fmi2ExitInitializationMode", "fmi2ExitInitializationMode", fmu.c)
    fmu.call("exit twice", "fmi2ExitInitializationMode", fmu.c)
    fixed = [v for v in fmu.vars if v["causality"] == "parameter" and v["variability"] == "fixed"]
    if fixed:
        v = fixed[0]
        fmu.set(v["type"], [v["vr"]], label=f"set fixed parameter {v['type']} {v['vr']}")
    output = next(v for v in fmu.vars if v["causality"] == "output")
    fmu.set(output["type"], [output["vr"]],
            label=f"set output {output['type']} {output['vr']}")
    real = fmu.pick("Real")
    fmu.get("Real", None, n=1, label="get Real vr NULL")
    fmu.set("Real", None, n=1, label="set Real vr NULL")
    fmu.get("Real", [real["vr"]], values=False, label="get Real values NULL")
    fmu.set("Real", [real["vr"]], values=None, label="set Real values NULL")
    fmu.get("Real", None, n=0, values=False, label="get Real n 0 NULL")
    fmu.step("fmi2DoStep after")
    state = c_void_p()
    fmu.call("fmi2GetFMUstate", "fmi2GetFMUstate", fmu.c, byref(state))
    fmu.call("state size NULL", "fmi2SerializedFMUstateSize", fmu.c, state, None)
    fmu.call("serialize NULL bytes", "fmi2SerializeFMUstate", fmu.c, state, None, 1 << 20)
    fmu.call("fmi2FreeFMUstate", "fmi2FreeFMUstate", fmu.c, byref(state))
    fmu.call("fmi2Terminate", "fmi2Terminate", fmu.c)
    fmu.step("doStep after terminate")
    fmu.call("terminate twice", "fmi2Terminate", fmu.c)
    fmu.get("Real", [real["vr"]], label="get after terminate")
    _out({"begin": "fmi2FreeInstance"})
    fmu.dll.fmi2FreeInstance(fmu.c)
    _out({"call": "fmi2FreeInstance", "status": OK, "log": []})
    fmu.call("null component doStep", "fmi2DoStep", None, 0.0, fmu.h, 1)


def mode_instantiate(fmu: RawFmu) -> None:
    fmu.instantiate("instantiate NULL GUID", guid=None)
    fmu.instantiate("instantiate wrong GUID", guid=b"{not-this-fmu}")
    fmu.instantiate("instantiate NULL name", name=None)
    fmu.instantiate("instantiate NULL resources", resources=None)
    fmu.instantiate("instantiate model exchange", kind=0)
    fmu.init()
    fmu.step()
    fmu.close()


def mode_single(fmu: RawFmu, acc: str, what: str, kind: str) -> None:
    fmu.init()
    var = fmu.pick(kind)
    if what == "get":
        fmu.get(acc, [var["vr"]], label=f"wrong get {acc} {kind} {var['vr']}")
    else:
        fmu.set(acc, [var["vr"]], label=f"wrong set {acc} {kind} {var['vr']}")
    fmu.step("fmi2DoStep after")
    fmu.close()


if __name__ == "__main__":
    fmu_path, work, mode, *rest = sys.argv[1:]
    raw = RawFmu(Path(fmu_path), Path(work))
    {"types": mode_types, "types-no-md": mode_types_no_md, "states": mode_states,
     "instantiate": mode_instantiate, "single": mode_single}[mode](raw, *rest)
    _out({"end": True})
    sys.exit(0)

