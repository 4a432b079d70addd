"""Call-sequence fuzzer: random legal and illegal FMI 2.0 calls on one FMU, in a fresh process.

``python _fmi_fuzz_runner.py FMU_PATH WORK_DIR [--sequences N] [--steps S] [--seed K]``

A Hypothesis rule-based state machine (issue 37 item 2) drives the FMU's binary through
ctypes (tests/_never_fatal_runner.py's ``RawFmu``: no fmpy wrapper that checks or raises).
Each sequence instantiates the FMU, makes up to S random calls and ends with
fmi2Terminate (where legal) and fmi2FreeInstance. The machine tracks the FMI state
(instantiated, initialisation, step mode, terminated) and the FMU states it holds, and
classes every call:

* legal: setup/enter/exit/doStep/terminate in their state, reset, get and set of every
  type on the variables a host may set then, FMU state get (new or into a state it
  holds), set, free, serialize and deserialize, debug logging;
* illegal: the same calls in the wrong state, wrong-typed and unknown value references,
  NULL arrays with n > 0, sets the FMI forbids (after initialisation anything but inputs
  and tunable parameters, anything after fmi2Terminate), steps of size <= 0 or NaN,
  NULL, freed and made-up FMU states, NULL size pointers and byte arrays, truncated and
  corrupt serialized states.

Properties: no call returns fmi2Fatal or logs a fatal message, every fmi2Error comes with
an error message, every illegal call is fmi2Error, no instance becomes unusable, and
after any error fmi2Terminate (where legal) succeeds and fmi2FreeInstance returns. The
calls of the running sequence are written to ``WORK_DIR/sequence.log`` as they are made,
so that a test can name the call in which the process died. The last line of stdout is a
JSON summary; exit status 1 with a falsifying sequence on stderr if a property fails.

Used only in processes that run FMUs (never imports ``gyrodiag``, docs/methods.md §6.3).
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import traceback
import xml.etree.ElementTree as ET
from collections import Counter
from ctypes import (
    addressof,
    byref,
    c_char_p,
    c_int,
    c_size_t,
    c_uint,
    c_void_p,
    create_string_buffer,
)
from pathlib import Path
from typing import Any

from _never_fatal_runner import _CTYPE, _SAMPLE, TYPES, RawFmu
from hypothesis import HealthCheck, settings
from hypothesis import strategies as st
from hypothesis.stateful import (
    RuleBasedStateMachine,
    initialize,
    rule,
    run_state_machine_as_test,
)

OK, WARNING, DISCARD, ERROR, FATAL = range(5)
INSTANTIATED, INIT, STEP, TERMINATED = "instantiated", "init", "step", "terminated"

FMU: FuzzHost | None = None
STATS: Counter[str] = Counter()
#: "function legality status" -> calls (the summary's "calls_by_kind")
CALLS: Counter[str] = Counter()


class FuzzHost(RawFmu):
    """``RawFmu`` that logs each call of the running sequence to a file, not stdout."""

    def __init__(self, fmu: Path, work: Path) -> None:
        super().__init__(fmu, work)
        self.trace = open(work / "sequence.log", "w", buffering=1)
        for name, args in {"fmi2DeSerializeFMUstate": [c_void_p, c_void_p, c_size_t,
                                                       c_void_p],
                           "fmi2SetFMUstate": [c_void_p, c_void_p],
                           "fmi2SetDebugLogging": [c_void_p, c_int, c_size_t, c_void_p]}.items():
            fn = getattr(self.dll, name)
            fn.restype, fn.argtypes = c_int, args
        root = ET.parse(self.dir / "modelDescription.xml").getroot()
        for var, sv in zip(self.vars, root.iter("ScalarVariable"), strict=True):
            var["start"] = sv[0].get("start")
        self.kinds = [k for k in TYPES if any(v["type"] == k for v in self.vars)]
        self.unknown = max(v["vr"] for v in self.vars) + 1

    def new_sequence(self) -> None:
        self.trace.seek(0)
        self.trace.truncate()

    def call(self, label: str, fn: str, *args: Any) -> int:
        self.trace.write(label + "\n")
        mark = len(self.log)
        status = getattr(self.dll, fn)(*args)
        self.last_log = self.log[mark:]
        del self.log[:]
        return status

    def create(self) -> int:
        self.trace.write("fmi2Instantiate\n")
        res = (self.dir / "resources").as_uri().encode()
        c = self.dll.fmi2Instantiate(b"fuzz", 1, self.guid.encode(), res,
                                     byref(self.callbacks), 0, 0)
        if not c:
            raise AssertionError(f"fmi2Instantiate failed: {self.log}")
        del self.log[:]
        return c


def _values(kind: str, values: list[Any]) -> Any:
    if kind == "String":
        raw = [v if isinstance(v, bytes) else v.encode() for v in values]
        return (c_char_p * max(len(values), 1))(*raw)
    return (_CTYPE[kind] * max(len(values), 1))(*values)


def _value_strategy(var: dict[str, Any]) -> st.SearchStrategy[Any]:
    kind, start = var["type"], var.get("start")
    if kind == "Real":
        weird = st.floats(allow_nan=True, allow_infinity=True, width=64)
        nominal = st.just(float(start)) if start is not None else st.just(0.0)
        return st.one_of(nominal, nominal, st.floats(-10, 10), weird)
    if kind == "Integer":
        nominal = st.just(int(start)) if start is not None else st.just(0)
        return st.one_of(nominal, nominal, st.integers(-3, 20), st.integers(-2**31, 2**31 - 1))
    if kind == "Boolean":
        return st.sampled_from([0, 1, 2])
    return st.text(max_size=12).filter(lambda s: "\x00" not in s)


class FmuMachine(RuleBasedStateMachine):
    """One sequence on one instance; the attributes are the host's view of the FMU."""

    def __init__(self) -> None:
        super().__init__()
        assert FMU is not None
        self.f = FMU
        self.f.new_sequence()
        self.c = self.f.create()
        self.mode = INSTANTIATED
        # FMU states this host holds, and addresses of states it freed, in the order of
        # the calls (not of the addresses, which change from run to run)
        self.live: dict[int, None] = {}
        self.freed: dict[int, None] = {}
        self.blobs: list[bytes] = []     # serialized states
        self.t = 0.0
        STATS["sequences"] += 1

    # -- the oracle ---------------------------------------------------------------------
    def check(self, label: str, status: int, illegal: bool) -> int:
        """Assert the properties for one call's status and log."""
        log = self.f.last_log
        STATS["calls"] += 1
        STATS["illegal" if illegal else "legal"] += 1
        STATS[f"status {status}"] += 1
        if not illegal and status == ERROR:
            STATS["legal refused"] += 1  # e.g. a parameter out of range: allowed
        CALLS[f"{label.split('(')[0].split('[')[0].split(' ')[0]} "
              f"{'illegal' if illegal else 'legal'} {status}"] += 1
        assert status != FATAL, (label, log)
        assert all(s != FATAL for s, _ in log), (label, log)
        assert not any("unusable" in m or "internal error" in m for _, m in log), (label, log)
        if status == ERROR:
            assert any(s == ERROR and m for s, m in log), (label, "fmi2Error without message")
        if illegal:
            assert status == ERROR, (label, status, log)
        return status

    def call(self, label: str, fn: str, *args: Any, illegal: bool = False) -> int:
        return self.check(label, self.f.call(label, fn, self.c, *args), illegal)

    # -- the state machine of FMI 2.0 co-simulation --------------------------------------
    @initialize(start=st.sampled_from([STEP, STEP, STEP, INIT, INSTANTIATED]))
    def start_in(self, start: str) -> None:
        """Most sequences start in step mode, after one step (random rules rarely get
        there alone)."""
        if start != INSTANTIATED:
            self.setup_experiment()
            self.enter_initialization()
        if start == STEP:
            self.exit_initialization()
            self.do_step(1, 1)

    @rule()
    def setup_experiment(self) -> None:
        self.call("fmi2SetupExperiment", "fmi2SetupExperiment", 0, 0.0, 0.0, 0, 0.0,
                  illegal=self.mode != INSTANTIATED)

    @rule()
    def enter_initialization(self) -> None:
        legal = self.mode == INSTANTIATED
        self.call("fmi2EnterInitializationMode", "fmi2EnterInitializationMode",
                  illegal=not legal)
        if legal:
            self.mode = INIT

    @rule()
    def exit_initialization(self) -> None:
        legal = self.mode == INIT
        self.call("fmi2ExitInitializationMode", "fmi2ExitInitializationMode", illegal=not legal)
        if legal:
            self.mode = STEP

    @rule(k=st.sampled_from([1, 1, 2, 5, 0, -1, math.nan, 0.37]), n=st.integers(1, 4))
    def do_step(self, k: float, n: int) -> None:
        """n steps of k times the default step (0.37: no whole number of Diagnoser samples,
        refused with a message; 0, -1, NaN: illegal)."""
        h = self.f.h * k
        bad_h = not (h > 0.0)
        for _ in range(n):
            status = self.call(f"fmi2DoStep({self.t}, {h})", "fmi2DoStep", self.t, h, 1,
                               illegal=self.mode != STEP or bad_h)
            if status > WARNING:
                break
            self.t += h

    @rule()
    def terminate(self) -> None:
        legal = self.mode in (INIT, STEP)
        self.call("fmi2Terminate", "fmi2Terminate", illegal=not legal)
        if legal:
            self.mode = TERMINATED

    @rule()
    def reset(self) -> None:
        self.call("fmi2Reset", "fmi2Reset")
        self.mode, self.t = INSTANTIATED, 0.0

    @rule(on=st.booleans())
    def debug_logging(self, on: bool) -> None:
        self.call(f"fmi2SetDebugLogging({on})", "fmi2SetDebugLogging", int(on), 0, None)

    # -- values ----------------------------------------------------------------------------
    def settable(self, var: dict[str, Any]) -> bool:
        """May a host set ``var`` now (FMI 2.0 co-simulation, as the shim enforces)?"""
        if self.mode == TERMINATED or var["variability"] == "constant":
            return False
        if self.mode == STEP:
            return var["causality"] == "input" or (
                var["causality"] == "parameter" and var["variability"] == "tunable")
        return True

    @rule(data=st.data(), set_=st.booleans())
    def get_or_set(self, data: st.DataObject, set_: bool) -> None:
        kind = data.draw(st.sampled_from(self.f.kinds))
        pool = [v for v in self.f.vars if v["type"] == kind]
        if set_:  # mostly variables that may be set now, sometimes any
            ok = [v for v in pool if self.settable(v)]
            pool = ok if data.draw(st.integers(0, 3)) and ok else pool
        chosen = data.draw(st.lists(st.sampled_from(pool), min_size=0, max_size=4))
        vrs = (c_uint * max(len(chosen), 1))(*[v["vr"] for v in chosen])
        label = f"fmi2{'Set' if set_ else 'Get'}{kind}{[v['name'] for v in chosen]}"
        if not set_:
            out = (_CTYPE[kind] * max(len(chosen), 1))()
            self.call(label, f"fmi2Get{kind}", vrs, len(chosen), out)
            return
        values = [data.draw(_value_strategy(v)) for v in chosen]
        illegal = self.mode == TERMINATED or not all(self.settable(v) for v in chosen)
        self.call(f"{label} = {values}", f"fmi2Set{kind}", vrs, len(chosen),
                  _values(kind, values), illegal=illegal)

    @rule(data=st.data(), set_=st.booleans())
    def wrong_type(self, data: st.DataObject, set_: bool) -> None:
        var = data.draw(st.sampled_from(self.f.vars))
        acc = data.draw(st.sampled_from([k for k in TYPES if k != var["type"]]))
        vrs = (c_uint * 1)(var["vr"])
        what = "Set" if set_ else "Get"
        values = _values(acc, [_SAMPLE[acc]]) if set_ else (_CTYPE[acc] * 1)()
        self.call(f"fmi2{what}{acc} on {var['type']} {var['name']}", f"fmi2{what}{acc}",
                  vrs, 1, values, illegal=True)

    @rule(kind=st.sampled_from(TYPES), set_=st.booleans(), offset=st.integers(0, 2**31))
    def unknown_reference(self, kind: str, set_: bool, offset: int) -> None:
        vr = (self.f.unknown + offset) % 2**32
        what = "Set" if set_ else "Get"
        values = _values(kind, [_SAMPLE[kind]]) if set_ else (_CTYPE[kind] * 1)()
        self.call(f"fmi2{what}{kind}[unknown {vr}]", f"fmi2{what}{kind}", (c_uint * 1)(vr), 1,
                  values, illegal=True)

    @rule(kind=st.sampled_from(TYPES), set_=st.booleans(), which=st.sampled_from(
        ["vr", "values", "both", "n=0"]))
    def null_arrays(self, kind: str, set_: bool, which: str) -> None:
        var = next((v for v in self.f.vars if v["type"] == kind), self.f.vars[0])
        n = 0 if which == "n=0" else 1
        vrs = None if which in ("vr", "both", "n=0") else (c_uint * 1)(var["vr"])
        values = None if which in ("values", "both", "n=0") else (
            _values(kind, [_SAMPLE[kind]]) if set_ else (_CTYPE[kind] * 1)())
        what = "Set" if set_ else "Get"
        illegal = n > 0 or (set_ and self.mode == TERMINATED)
        self.call(f"fmi2{what}{kind} NULL {which}", f"fmi2{what}{kind}", vrs, n, values,
                  illegal=illegal)

    # -- FMU states --------------------------------------------------------------------------
    def _take(self, address: int) -> None:
        self.live[address] = None
        self.freed.pop(address, None)  # the allocator may give a freed address again

    @staticmethod
    def _pick(data: st.DataObject, pool: list[Any], empty: Any = None) -> Any:
        """An element of ``pool`` (``empty`` if there is none), drawn the same way whatever
        the pool: which addresses the allocator gives again changes from run to run, and
        Hypothesis requires the same draws when it replays a sequence."""
        index = data.draw(st.integers(0, 1 << 20))
        return pool[index % len(pool)] if pool else empty

    @rule(data=st.data(), into=st.booleans())
    def get_state(self, data: st.DataObject, into: bool) -> None:
        target = self._pick(data, list(self.live))
        target = target if into else None
        state = c_void_p(target)
        if self.call(f"fmi2GetFMUstate(into {target})", "fmi2GetFMUstate",
                     byref(state)) <= WARNING:
            assert state.value, "fmi2GetFMUstate returned OK and no state"
            self._take(state.value)

    def _state(self, data: st.DataObject) -> tuple[int | None, bool]:
        """A live state (legal), or a NULL, freed or made-up one (illegal)."""
        kind = data.draw(st.sampled_from(["live", "live", "live", "freed", "null", "made-up"]))
        address = self._pick(data, list(self.live if kind == "live" else self.freed))
        if kind == "made-up" or (kind in ("live", "freed") and address is None):
            self.bogus = create_string_buffer(64)  # readable memory that is no state
            return addressof(self.bogus), True
        if kind == "null":
            return None, True
        return address, kind != "live"

    @rule(data=st.data())
    def set_state(self, data: st.DataObject) -> None:
        state, illegal = self._state(data)
        self.call(f"fmi2SetFMUstate({state})", "fmi2SetFMUstate", state, illegal=illegal)

    @rule(data=st.data())
    def free_state(self, data: st.DataObject) -> None:
        state, illegal = self._state(data)
        handle = c_void_p(state)
        status = self.call(f"fmi2FreeFMUstate({state})", "fmi2FreeFMUstate", byref(handle),
                           illegal=illegal and state is not None)  # *NULL: nothing to free
        if not illegal and status <= WARNING:
            self.live.pop(state, None)
            self.freed[state] = None

    @rule(data=st.data(), null=st.sampled_from(["", "", "", "size", "bytes", "short"]))
    def serialize(self, data: st.DataObject, null: str) -> None:
        state, illegal = self._state(data)
        size = c_size_t(0)
        tag = {"size": " NULL size", "bytes": " NULL bytes", "short": " short"}.get(null, "")
        status = self.call(f"fmi2SerializedFMUstateSize({state}){tag}",
                           "fmi2SerializedFMUstateSize", state,
                           None if null == "size" else byref(size),
                           illegal=illegal or null == "size")
        if status > WARNING or null == "size":
            return
        n = size.value - (1 if null == "short" else 0)
        buffer = create_string_buffer(max(n, 1))
        status = self.call(f"fmi2SerializeFMUstate({state}, {n}){tag}",
                           "fmi2SerializeFMUstate", state,
                           None if null == "bytes" else buffer, n,
                           illegal=null in ("bytes", "short"))
        if status <= WARNING:
            self.blobs = [*self.blobs[-3:], buffer.raw[:n]]

    @rule(data=st.data(), how=st.sampled_from(["as is", "as is", "truncated", "flipped",
                                                "garbage"]), into=st.booleans())
    def deserialize(self, data: st.DataObject, how: str, into: bool) -> None:
        blob = self._pick(data, self.blobs, b"")
        cut = data.draw(st.integers(0, 1 << 20))
        if how == "truncated" and blob:
            blob = blob[:cut % len(blob)]
        elif how == "flipped" and blob:
            blob = blob[:cut % len(blob)] + bytes([blob[cut % len(blob)] ^ 0x40]) + blob[
                cut % len(blob) + 1:]
        elif how == "garbage":
            blob = data.draw(st.binary(max_size=64))
        illegal = how != "as is" or not blob
        target = self._pick(data, list(self.live))
        target = target if into else None
        state = c_void_p(target)
        status = self.call(f"fmi2DeSerializeFMUstate({how}, {len(blob)} bytes, into {target})",
                           "fmi2DeSerializeFMUstate", blob, len(blob), byref(state),
                           illegal=illegal)
        if status <= WARNING:
            self._take(state.value)

    # -- the end of every sequence -----------------------------------------------------------
    def teardown(self) -> None:
        if self.mode in (INIT, STEP):
            status = self.call("fmi2Terminate (teardown)", "fmi2Terminate")
            assert status <= WARNING, ("fmi2Terminate after the sequence", status,
                                       self.f.last_log)
        for state in list(self.live)[: len(self.live) // 2]:  # the rest: FreeInstance's
            handle = c_void_p(state)
            status = self.call("fmi2FreeFMUstate (teardown)", "fmi2FreeFMUstate", byref(handle))
            assert status <= WARNING, ("fmi2FreeFMUstate after the sequence", self.f.last_log)
        self.f.trace.write("fmi2FreeInstance\n")
        self.f.dll.fmi2FreeInstance(self.c)
        del self.f.log[:]


def main(argv: list[str]) -> int:
    global FMU
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("fmu", type=Path)
    parser.add_argument("work", type=Path)
    parser.add_argument("--sequences", type=int, default=100)
    parser.add_argument("--steps", type=int, default=40, help="calls per sequence at most")
    parser.add_argument("--derandomize", action="store_true",
                        help="the same sequences at every run (the suite's); default: random")
    args = parser.parse_args(argv)
    args.work.mkdir(parents=True, exist_ok=True)
    FMU = FuzzHost(args.fmu, args.work)
    options = settings(max_examples=args.sequences, stateful_step_count=args.steps,
                       deadline=None, database=None, derandomize=args.derandomize,
                       suppress_health_check=list(HealthCheck), print_blob=True)
    failure = None
    try:
        run_state_machine_as_test(FmuMachine, settings=options)
    except Exception as exc:  # a property failed: Hypothesis printed the sequence
        failure = f"{type(exc).__name__}: {exc}"
        traceback.print_exc()
    print(json.dumps({"fmu": FMU.model, "failure": failure, **STATS,
                      "calls_by_kind": dict(sorted(CALLS.items()))}), flush=True)
    return 1 if failure else 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
