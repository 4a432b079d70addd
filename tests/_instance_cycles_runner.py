"""Instantiate and free one FMU many times in one process; print the memory per cycle.

``python _instance_cycles_runner.py FMU_PATH WORK_DIR [--cycles N] [--warmup W]
[--steps S] [--forget-state]``

The host of issue 37 (optimisers, test benches, campaign workers): the binary is loaded
once (fmpy's ``FMU2Slave``), then each cycle is fmi2Instantiate, fmi2SetupExperiment,
initialisation, S doSteps, fmi2GetFMUstate, its serialization and fmi2FreeFMUstate
(with ``--forget-state`` one more FMU state, left for fmi2FreeInstance to free),
fmi2Terminate and fmi2FreeInstance. After W cycles the resident set size
(``/proc/self/statm``), the number of objects the garbage collector tracks and the
length of ``sys.path`` are read, and again after N more cycles; the last line is one
JSON object::

    {"fmu": NAME, "cycles": N, "warmup": W, "steps": S, "forget_state": bool,
     "rss0_kb": ..., "rss1_kb": ..., "kb_per_cycle": ..., "objects_per_cycle": ...,
     "s_per_cycle": ..., "sys_path": [before, after]}

Used only in processes that run FMUs (never imports ``gyrodiag``, docs/methods.md §6.3).
"""

from __future__ import annotations

import argparse
import gc
import json
import os
import sys
import time
import xml.etree.ElementTree as ET
import zipfile
from ctypes import byref, c_size_t, create_string_buffer
from pathlib import Path

#: Start values a cycle sets before initialisation (FMUs whose defaults refuse
#: initialisation: the Diagnoser's default prefilter cutoff needs 1 kHz samples).
START_VALUES: dict[str, dict[str, float]] = {"Diagnoser": {"sample_period_s": 0.001}}


def rss_kb() -> float:
    """Resident set size of this process now (kB)."""
    with open("/proc/self/statm") as f:
        return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 1024.0


class Cycler:
    """One FMU's binary, loaded once, and the cycle of issue 37."""

    def __init__(self, fmu: Path, work: Path, steps: int, forget_state: bool) -> None:
        from fmpy.fmi2 import FMU2Slave

        unzip = work / fmu.stem
        with zipfile.ZipFile(fmu) as zf:
            zf.extractall(unzip)
        root = ET.parse(unzip / "modelDescription.xml").getroot()
        self.name = root.get("modelName")
        default = root.find("DefaultExperiment")
        self.h = float(default.get("stepSize")) if default is not None and default.get(
            "stepSize") else 0.01
        vrs = {sv.get("name"): int(sv.get("valueReference"))
               for sv in root.iter("ScalarVariable")}
        self.start = {vrs[k]: v for k, v in START_VALUES.get(self.name, {}).items()}
        if self.name == "Diagnoser":
            self.h = 0.016
        self.steps = steps
        self.forget_state = forget_state
        self.fmu = FMU2Slave(guid=root.get("guid"), unzipDirectory=str(unzip),
                             modelIdentifier=root.find("CoSimulation").get("modelIdentifier"),
                             instanceName="cycle")

    def cycle(self) -> None:
        f = self.fmu
        f.instantiate(loggingOn=False)
        f.setupExperiment(startTime=0.0)
        if self.start:
            f.setReal(list(self.start), list(self.start.values()))
        f.enterInitializationMode()
        f.exitInitializationMode()
        t = 0.0
        for _ in range(self.steps):
            f.doStep(t, self.h)
            t += self.h
        state = f.getFMUstate()
        size = c_size_t()
        f.fmi2SerializedFMUstateSize(f.component, state, byref(size))
        buffer = create_string_buffer(size.value)
        f.fmi2SerializeFMUstate(f.component, state, buffer, size)
        f.freeFMUstate(state)
        if self.forget_state:
            f.getFMUstate()   # left for fmi2FreeInstance (hosts forget states)
        f.terminate()
        f.freeInstance()


def main(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("fmu", type=Path)
    parser.add_argument("work", type=Path)
    parser.add_argument("--cycles", type=int, default=1000)
    parser.add_argument("--warmup", type=int, default=100)
    parser.add_argument("--steps", type=int, default=10)
    parser.add_argument("--forget-state", action="store_true")
    args = parser.parse_args(argv)
    c = Cycler(args.fmu, args.work, args.steps, args.forget_state)
    for _ in range(args.warmup):
        c.cycle()
    gc.collect()
    path0, objects0, rss0 = len(sys.path), len(gc.get_objects()), rss_kb()
    t0 = time.perf_counter()
    for _ in range(args.cycles):
        c.cycle()
    seconds = time.perf_counter() - t0
    gc.collect()
    rss1, n = rss_kb(), max(args.cycles, 1)
    print(json.dumps({"fmu": c.name, "cycles": args.cycles, "warmup": args.warmup,
                      "steps": args.steps, "forget_state": args.forget_state,
                      "rss0_kb": rss0, "rss1_kb": rss1, "kb_per_cycle": (rss1 - rss0) / n,
                      "objects_per_cycle": (len(gc.get_objects()) - objects0 - 1) / n,
                      "s_per_cycle": seconds / n, "sys_path": [path0, len(sys.path)]}),
          flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
