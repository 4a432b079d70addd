"""Bad FMU states against every FMU, in a fresh process (docs/methods.md §6.11, §6.14).

``python _state_runner.py FMU_DIR OUT.json`` runs, for every FMU of the project: N steps,
get and serialise the state S, M more steps (the reference R1); restore S and run M
steps (R2); restore S, then feed the instance every kind of bad state below, then run M
steps (R3). It records the status and log of every bad call. R3 = R1 shows that no bad
state changed the instance.

Serialized states are framed by the status shim (fmu_src/shim): ``GDFMUST1``, u32 GUID
length, GUID, u64 payload length, u64 FNV-1a 64 of GUID and payload, payload. The
"forged" cases build valid frames around bad payloads, so that the Python side's checks
are reached too.
"""

from __future__ import annotations

import json
import struct
import sys
from ctypes import c_void_p
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _fmu_calls import Instance

N_STEPS, M_STEPS = 40, 30
#: Parameters per FMU (steps of 10 ms for the Diagnoser, short learning windows so that
#: the state holds learned references and calibrated thresholds).
SETUP: dict[str, tuple[dict[str, Any], float | None]] = {
    "Aircraft": ({"noise_std_q": 1e-3, "seed": 3}, None),
    "DTG": ({"noise_std": 1e-3, "dither_std": 0.5, "seed": 4}, None),
    "FaultInjector": ({"fault_type_1": 1, "t_start_1": 0.1, "magnitude_1": 0.5,
                       "fault_type_2": 8, "noise_std_2": 0.1}, None),
    "HRG": ({"noise_std": 1e-3, "profile": 2, "rate_const": 0.1}, None),
    "PitchController": ({"command_source": 1, "cmd_period": 0.5}, None),
    "Diagnoser": ({"sample_period_s": 0.01, "dtg.learn_start_s": 0.05, "dtg.learn_end_s": 0.2,
                   "df.calibrate_s": 0.3, "df.burn_in_s": 0.05, "grey.window": 6,
                   "grey.decision": 0,
                   "dtg.prefilter_cutoff_hz": 20.0}, 0.01),
}
MAGIC = b"GDFMUST1"


def fnv1a64(data: bytes, h: int = 0xCBF29CE484222325) -> int:
    for byte in data:
        h = ((h ^ byte) * 0x100000001B3) & 0xFFFFFFFFFFFFFFFF
    return h


def frame(guid: str, payload: bytes) -> bytes:
    g = guid.encode()
    return (MAGIC + struct.pack("<I", len(g)) + g + struct.pack("<Q", len(payload))
            + struct.pack("<Q", fnv1a64(payload, fnv1a64(g))) + payload)


def unframe(data: bytes) -> tuple[str, bytes]:
    (n,) = struct.unpack("<I", data[8:12])
    return data[12:12 + n].decode(), data[12 + n + 16:]


def flip(data: bytes, index: int) -> bytes:
    return data[:index] + bytes([data[index] ^ 0x5A]) + data[index + 1:]


def bad_bytes(inst: Instance, good: bytes, foreign: bytes) -> dict[str, bytes]:
    guid, payload = unframe(good)
    state = json.loads(payload)
    header = len(good) - len(payload)
    missing = json.loads(payload)
    first = next(iter(missing["payload"]))
    if inst.md.modelName == "Diagnoser":  # FacadeBase: values + internal
        del missing["payload"]["values"]["__dict__"][0]
    else:
        del missing["payload"][first]
    cases = {
        "empty": b"",
        "truncated_header": good[:10],
        "truncated_half": good[:len(good) // 2],
        "truncated_last_byte": good[:-1],
        "trailing_byte": good + b"x",
        "flipped_payload": flip(good, header + len(payload) // 2),
        "flipped_checksum": flip(good, header - 3),
        "flipped_guid": flip(good, 14),
        "garbage": np.random.default_rng(5).integers(0, 256, len(good), np.uint8).tobytes(),
        "raw_json": payload,
        "foreign_fmu": foreign,
        "forged_other_model": frame(guid, unframe(foreign)[1]),
        "forged_bad_json": frame(guid, payload[: len(payload) // 3]),
        "forged_missing_variable": frame(guid, json.dumps(missing).encode()),
        "forged_other_format": frame(guid, json.dumps({**state, "format": "x/9"}).encode()),
    }
    if inst.md.modelName == "Diagnoser":
        # passes every check up front, fails inside the channel restore: rolled back
        broken = json.loads(payload)
        internal = broken["payload"]["internal"]["__dict__"]
        for pair in internal:
            if pair[0] == "df":
                pair[1]["__dict__"] = [kv for kv in pair[1]["__dict__"] if kv[0] != "monitor"]
        cases["forged_broken_channel_state"] = frame(guid, json.dumps(broken).encode())
    return cases


def run(fmu_dir: Path) -> dict[str, Any]:
    names = list(SETUP)
    insts = {}
    for name in names:
        params, step = SETUP[name]
        inst = Instance(fmu_dir / f"{name}.fmu", f"{name}_a", params, step)
        assert inst.init_status == 0, inst.messages()
        inst.step(N_STEPS)
        insts[name] = inst
    saved = {name: inst.fmu.getFMUstate() for name, inst in insts.items()}
    serial = {name: inst.fmu.serializeFMUstate(saved[name]) for name, inst in insts.items()}
    out: dict[str, Any] = {}
    for i, name in enumerate(names):
        inst = insts[name]
        other = names[(i + 1) % len(names)]
        res: dict[str, Any] = {"columns": [v.name for v in inst.outputs],
                               "guid": inst.md.guid, "size": len(serial[name])}
        res["R1"] = inst.step(M_STEPS).tolist()
        inst.fmu.setFMUstate(saved[name])
        inst.k = N_STEPS
        res["R2"] = inst.step(M_STEPS).tolist()
        inst.fmu.setFMUstate(saved[name])
        inst.k = N_STEPS
        calls: dict[str, dict[str, Any]] = {}
        for case, data in bad_bytes(inst, serial[name], serial[other]).items():
            mark = len(inst.log)
            state = None

            def deserialize(data: bytes = data, inst: Instance = inst) -> None:
                nonlocal state
                state = inst.fmu.deSerializeFMUstate(data)

            entry = {"deserialize": inst.call(deserialize)}
            entry["deserialize_log"] = inst.messages(mark)
            if entry["deserialize"] == 0:
                mark = len(inst.log)
                entry["set"] = inst.call(inst.fmu.setFMUstate, state)
                entry["set_log"] = inst.messages(mark)
                inst.fmu.freeFMUstate(state)
            calls[case] = entry
        # in-memory states that are not this FMU's
        foreign = insts[other].fmu.getFMUstate()
        stale = inst.fmu.getFMUstate()
        stale_copy = c_void_p(stale.value)
        inst.fmu.freeFMUstate(stale)
        for case, pointer in (("pointer_of_other_fmu", foreign), ("freed_pointer", stale_copy),
                              ("null_pointer", c_void_p())):
            mark = len(inst.log)
            calls[case] = {"set": inst.call(inst.fmu.setFMUstate, pointer),
                           "set_log": inst.messages(mark)}
        insts[other].fmu.freeFMUstate(foreign)
        res["calls"] = calls
        res["R3"] = inst.step(M_STEPS).tolist()
        out[name] = res
    for name, inst in insts.items():
        inst.fmu.freeFMUstate(saved[name])
        inst.close()
    return out


if __name__ == "__main__":
    result = run(Path(sys.argv[1]))
    Path(sys.argv[2]).write_text(json.dumps(result), encoding="utf-8")
