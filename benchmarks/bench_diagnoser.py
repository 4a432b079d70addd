"""Cost of a Diagnoser.fmu step per channel, as ratios to cheap FMUs, compiled and fallback.

Usage::

    .venv/bin/python benchmarks/bench_diagnoser.py [--steps 3000] [--warmup 1500] [--no-chain]
    .venv/bin/python benchmarks/bench_diagnoser.py --states-only [--steps 3000] [--fmu-dir DIR]

Measures, in one run, through fmpy, on the same input records at 1 kHz, in one fresh
process per Diagnoser configuration (docs/methods.md §6.11) in which three FMUs are stepped in
turn, step by step, so that their ratios do not depend on the load of a shared machine:

* the host step of a trivial pythonfmu FMU (one Real output set in do_step, built here in
  a temporary directory with pythonfmu's builder): the floor of any pythonfmu step;
* the host step of FaultInjector.fmu (set its inputs, doStep), the near-trivial FMU of
  the project that the targets are stated against;
* the host step of Diagnoser.fmu (set the channel's inputs, doStep) for the DTG, grey and
  detection-filter channels alone and all together, with the default install (compiled
  kernels) and with the plain-Python fallback (``GYRODIAG_KERNELS=python``);
* the Diagnoser's fmi2Instantiate and its initialisation (channels built) per channel;
* the library channels called directly (no FMI) with both kernel sets;
* the real-time factor of the DTG 1 kHz chain, the seed scenario ``dtg_nominal``
  (DTG → FaultInjector → two Diagnoser DTG channels, 60 s) through the harness, as
  simulated time over the process's CPU time (and over wall time, which a loaded machine
  inflates).

* nominal against in alarm (issue 35), default install, per channel and all together:
  a nominal Diagnoser (the records above) and one in alarm (every Real input the channel
  has gets sin(7 t) plus 1e-3 white noise: the DF calibrates on it over 0.5 s and detects,
  the DTG learns its reference over 0.2-0.8 s and is in alarm from about 1 s on; what each
  channel says is printed) stepped in turn with FaultInjector.fmu after a 1 s warm-up: the
  host step's median, p99 and maximum (wall time, and the thread's CPU time, which a
  shared machine's preemptions do not inflate), and the cost of reading every output after a step,
  as one fmi2GetReal/Integer/Boolean call per type (fmpy, and the same calls through ctypes
  with the arrays built once, as a C host makes them) and as one call per variable.

Prints figures only (no assertions); medians of per-step times. The detection filter
calibrates over the warm-up (0.5 s), so the timed steps are steady-state monitoring.
Targets (issue 14): all-channel step ≤ 4× the FaultInjector step (default install),
≤ 12× (fallback); DTG chain real-time factor ≥ 10; instantiate ≤ 0.4 s.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
H = 1e-3
IN_NAMES = (
    ["dtg.Utx", "dtg.Uty", "dtg.Ux", "dtg.Uy", "grey.y", "df.u[1]", "df.u[2]"]
    + [f"df.y[{i}]" for i in range(1, 7)]
)
BASE_PARAMS = {"sample_period_s": H, "df.calibrate_s": 0.5, "df.burn_in_s": 0.1,
               "dtg.learn_start_s": 0.2, "dtg.learn_end_s": 0.8, "dtg.p0": 1e8,
               "grey.window": 10, "grey.decision": 0, "grey.threshold": 0.05}
#: channel configuration → (enabled channels, input columns of IN_NAMES)
CONFIGS = {
    "DTG": (("dtg",), list(range(0, 4))),
    "grey": (("grey",), [4]),
    "DF": (("df",), list(range(5, 13))),
    "all": (("dtg", "grey", "df"), list(range(13))),
}

#: every Real input of the Diagnoser per channel configuration, for the in-alarm state
ALARM_INPUTS = {
    "DTG": ["dtg.Utx", "dtg.Uty", "dtg.Ux", "dtg.Uy", "dtg.case_rate_x", "dtg.case_rate_y"],
    "grey": ["grey.y"],
    "DF": ["df.u[1]", "df.u[2]"] + [f"df.y[{i}]" for i in range(1, 7)],
}
ALARM_INPUTS["all"] = ALARM_INPUTS["DTG"] + ALARM_INPUTS["grey"] + ALARM_INPUTS["DF"]
#: warm-up of the nominal/in-alarm comparison: the DTG reference ends at 0.8 s
STATE_WARMUP = 1000
#: outputs that tell whether the instance in alarm is
ALARM_FLAGS = ("dtg.alarm", "dtg.learning", "df.detected", "df.calibrating", "grey.alarm",
               "any_alarm")

TRIVIAL_SCRIPT = '''
from pythonfmu import Fmi2Causality, Fmi2Slave, Real


class GdBenchTrivial(Fmi2Slave):
    """One Real output, set to the step's start time."""

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        self.y = 0.0
        self.register_variable(Real("y", causality=Fmi2Causality.output))

    def do_step(self, current_time, step_size):
        self.y = current_time
        return True
'''


# ------------------------------------------------------------------ input records
def make_records(n: int, seed: int = 1) -> np.ndarray:
    """Columns IN_NAMES at 1 kHz: DTG rotor run, slow grey signal, closed-loop aircraft."""
    import scipy.linalg
    import scipy.signal

    from gyrodiag.demo import NOMINAL
    from gyrodiag.demo import simulate as simulate_dtg
    from gyrodiag.df.plant import seed_aircraft

    rng = np.random.default_rng(seed)
    rec = np.zeros((n, len(IN_NAMES)))
    rec[:, 0:4] = simulate_dtg(NOMINAL, n, seed, noise_v=1e-4)
    t = np.arange(n) * H
    rec[:, 4] = 2.0 + 0.3 * np.sin(2 * np.pi * 0.5 * t) + 1e-3 * rng.standard_normal(n)
    # the seed aircraft is open-loop unstable: LQR elevator feedback on (alpha, q, theta)
    # (v and h are not controllable by it and stay marginal), white excitation
    model = seed_aircraft()
    a_sub, b_sub = model.A[1:4, 1:4], model.B[1:4, 1:2]
    riccati = scipy.linalg.solve_continuous_are(a_sub, b_sub, np.eye(3), np.eye(1))
    gain = np.zeros((2, 5))
    gain[1, 1:4] = (b_sub.T @ riccati)[0]
    phi, gamma, *_ = scipy.signal.cont2discrete(
        (model.A, model.B, model.C, np.zeros((6, 2))), H, method="zoh")
    noise = np.array([0.05, 1e-3, 1e-3, 1e-3, 1e-3, 0.2])
    x = np.zeros(5)
    for k in range(n):
        u = -gain @ x + np.array([0.0, 0.02]) * rng.standard_normal(2)
        rec[k, 5:7] = u
        rec[k, 7:13] = model.C @ x + noise * rng.standard_normal(6)
        x = phi @ x + gamma @ u
    return rec


# ------------------------------------------------------------------ FMU measurement
class _Instance:
    """One FMU instance through fmpy with the inputs it is fed (host step = set + doStep)."""

    def __init__(self, fmu: str, spec: dict, n: int) -> None:
        from fmpy import extract, read_model_description
        from fmpy.fmi2 import FMU2Slave

        unzipdir = extract(fmu)
        md = read_model_description(unzipdir)
        vr = {v.name: v.valueReference for v in md.modelVariables}
        types = {v.name: v.type for v in md.modelVariables}
        self.slave = slave = FMU2Slave(
            guid=md.guid, unzipDirectory=unzipdir,
            modelIdentifier=md.coSimulation.modelIdentifier, instanceName="bench")
        t0, c0 = time.perf_counter(), time.process_time()
        slave.instantiate()
        self.instantiate_s = time.perf_counter() - t0
        self.instantiate_cpu_s = time.process_time() - c0
        slave.setupExperiment(startTime=0.0)
        for name, value in spec.get("params", {}).items():
            setter = {"Real": slave.setReal, "Integer": slave.setInteger,
                      "Boolean": slave.setBoolean}[types[name]]
            setter([vr[name]], [value])
        t0, c0 = time.perf_counter(), time.process_time()
        slave.enterInitializationMode()
        slave.exitInitializationMode()
        self.initialise_s = time.perf_counter() - t0
        self.initialise_cpu_s = time.process_time() - c0
        in_names = spec.get("inputs")
        if in_names is None:  # every Real input (the FaultInjector)
            in_names = [v.name for v in md.modelVariables
                        if v.causality == "input" and v.type == "Real"]
        self.in_vr = [vr[name] for name in in_names]
        if "records" in spec:
            self.rows = np.load(spec["records"])[:n, spec["columns"]].tolist()
        else:
            self.rows = np.random.default_rng(0).standard_normal(
                (n, len(self.in_vr))).tolist()
        outputs = [v for v in md.modelVariables if v.causality == "output"]
        getters = {"Real": slave.getReal, "Integer": slave.getInteger,
                   "Boolean": slave.getBoolean}
        self.reads = [(getters[kind], refs) for kind in ("Real", "Integer", "Boolean")
                      if (refs := [v.valueReference for v in outputs if v.type == kind])]
        self.n_inputs, self.n_outputs = len(self.in_vr), len(outputs)
        self.vr = vr

    def step(self, k: int) -> tuple[float, float]:
        """(host step, host step + reading every output) in seconds."""
        slave = self.slave
        t0 = time.perf_counter()
        if self.in_vr:
            slave.setReal(self.in_vr, self.rows[k])
        slave.doStep(currentCommunicationPoint=k * H, communicationStepSize=H)
        t1 = time.perf_counter()
        for getter, refs in self.reads:
            getter(refs)
        return t1 - t0, time.perf_counter() - t0

    def close(self) -> None:
        self.slave.terminate()
        self.slave.fmi2FreeInstance(self.slave.component)


def measure_fmus(specs: dict[str, dict], warmup: int, steps: int) -> dict:
    """Runs in a fresh process: the FMUs of ``specs`` stepped in turn, step by step.

    Interleaving makes the ratios robust to the load of a shared machine: each step of
    the Diagnoser is compared with the FaultInjector and trivial steps taken around it.
    """
    n = warmup + steps
    instances = {name: _Instance(spec["fmu"], spec, n) for name, spec in specs.items()}
    times = {name: np.empty((n, 2)) for name in specs}
    for k in range(n):
        for name, inst in instances.items():
            times[name][k] = inst.step(k)
    accel = sys.modules.get("gyrodiag.common._accel")
    out: dict = {"accelerated": None if accel is None else bool(accel.ACCELERATED)}
    timed = slice(warmup, None)
    for name, inst in instances.items():
        out[name] = {"step_us": 1e6 * float(np.median(times[name][timed, 0])),
                     "whole_us": 1e6 * float(np.median(times[name][timed, 1])),
                     "instantiate_s": inst.instantiate_s, "initialise_s": inst.initialise_s,
                     "instantiate_cpu_s": inst.instantiate_cpu_s,
                     "initialise_cpu_s": inst.initialise_cpu_s,
                     "n_inputs": inst.n_inputs, "n_outputs": inst.n_outputs}
    base = times["diag"][timed, 0]
    for ref in ("injector", "trivial"):
        if ref in times:
            out[f"ratio_{ref}"] = float(np.median(base / times[ref][timed, 0]))
    for inst in instances.values():
        inst.close()
    return out


# ------------------------------------------------------------------ nominal and in alarm
def make_alarm_records(n: int, n_inputs: int, seed: int = 2) -> np.ndarray:
    """Every column sin(7 t) + 1e-3 white noise at 1 kHz: the DF and DTG channels alarm."""
    t = np.arange(n) * H
    noise = 1e-3 * np.random.default_rng(seed).standard_normal((n, n_inputs))
    return np.sin(7.0 * t)[:, None] + noise


class _Reader:
    """Reads every output of an instance: per type through fmpy, per type through ctypes
    with the arrays built once (as a C host does), and one fmpy call per variable."""

    KINDS = ("Real", "Integer", "Boolean")

    def __init__(self, inst: _Instance, md_outputs: list) -> None:
        from fmpy.fmi2 import fmi2Boolean, fmi2Integer, fmi2Real, fmi2ValueReference

        slave = inst.slave
        self.fmpy = {"Real": slave.getReal, "Integer": slave.getInteger,
                     "Boolean": slave.getBoolean}
        raw = {"Real": (slave.fmi2GetReal, fmi2Real),
               "Integer": (slave.fmi2GetInteger, fmi2Integer),
               "Boolean": (slave.fmi2GetBoolean, fmi2Boolean)}
        self.refs = {k: [v.valueReference for v in md_outputs if v.type == k]
                     for k in self.KINDS}
        self.raw = {}
        for kind, (call, ctype) in raw.items():
            refs = self.refs[kind]
            self.raw[kind] = (call, slave.component, (fmi2ValueReference * len(refs))(*refs),
                              len(refs), (ctype * len(refs))())

    def per_type(self, how: str) -> list[float]:
        """Seconds of each type's call, in KINDS order (the first includes any output
        copying the FMU defers to the first read after a step)."""
        perf = time.perf_counter
        times = []
        for kind in self.KINDS:
            if how == "fmpy":
                get, refs = self.fmpy[kind], self.refs[kind]
                t0 = perf()
                get(refs)
            else:
                call, comp, vrs, n, out = self.raw[kind]
                t0 = perf()
                if call(comp, vrs, n, out) != 0:
                    raise RuntimeError(f"fmi2Get{kind} failed")
            times.append(perf() - t0)
        return times

    def per_variable(self) -> float:
        """Seconds for every output read by one fmpy call of its own."""
        perf = time.perf_counter
        t0 = perf()
        for kind in self.KINDS:
            get = self.fmpy[kind]
            for ref in self.refs[kind]:
                get([ref])
        return perf() - t0


def _stats(x: np.ndarray) -> dict:
    us = 1e6 * x
    return {"median": float(np.median(us)), "p99": float(np.percentile(us, 99)),
            "max": float(us.max())}


def measure_states(specs: dict[str, dict], warmup: int, steps: int) -> dict:
    """Runs in a fresh process: nominal and in-alarm Diagnosers and the FaultInjector
    stepped in turn; after each Diagnoser step its outputs are read, alternately per type
    (fmpy and ctypes, in turn) and per variable, so that each read pays the output copy."""
    from fmpy import read_model_description

    n = warmup + steps
    instances = {name: _Instance(spec["fmu"], spec, n) for name, spec in specs.items()}
    diag_names = [name for name in specs if name != "injector"]
    readers = {}
    for name in diag_names:
        md = read_model_description(specs[name]["fmu"])
        readers[name] = _Reader(instances[name],
                                [v for v in md.modelVariables if v.causality == "output"])
    step = {name: np.empty(n) for name in specs}
    cpu = {name: np.empty(n) for name in specs}
    reads: dict[str, dict[str, list]] = {
        name: {"fmpy": [], "ctypes": [], "per_variable": []} for name in diag_names}
    flags_at: dict[str, dict] = {}
    perf, thread_time = time.perf_counter, time.thread_time
    for k in range(n):
        for name, inst in instances.items():
            slave = inst.slave
            c0 = thread_time()
            t0 = perf()
            if inst.in_vr:
                slave.setReal(inst.in_vr, inst.rows[k])
            slave.doStep(currentCommunicationPoint=k * H, communicationStepSize=H)
            step[name][k] = perf() - t0
            cpu[name][k] = thread_time() - c0
            if name not in readers or k < warmup:
                continue
            how = ("fmpy", "ctypes", "per_variable")[k % 3]
            r = readers[name]
            reads[name][how].append(r.per_variable() if how == "per_variable"
                                    else r.per_type(how))
        if k in (warmup, n - 1):
            for name in diag_names:
                inst = instances[name]
                flags = {f: bool(inst.slave.getBoolean([inst.vr[f]])[0]) for f in ALARM_FLAGS}
                flags["fault_code"] = inst.slave.getInteger([inst.vr["fault_code"]])[0]
                flags_at.setdefault(name, {})["start" if k == warmup else "end"] = flags
    timed = slice(warmup, None)
    inj = step["injector"][timed]
    inj_cpu = cpu["injector"][timed]
    out: dict = {"injector": _stats(inj), "injector_cpu": _stats(inj_cpu)}
    for name in diag_names:
        d = step[name][timed]
        res = {"step": _stats(d), "ratio_median": float(np.median(d / inj)),
               "cpu": _stats(cpu[name][timed]),
               "flags": flags_at[name]}
        for how in ("fmpy", "ctypes"):
            per = 1e6 * np.array(reads[name][how])
            res[f"read_{how}"] = {kind: float(np.median(per[:, i]))
                                  for i, kind in enumerate(_Reader.KINDS)}
            res[f"read_{how}"]["total"] = float(np.median(per.sum(axis=1)))
            res[f"read_{how}"]["total_p99"] = float(np.percentile(per.sum(axis=1), 99))
        res["read_per_variable"] = float(np.median(1e6 * np.array(reads[name]["per_variable"])))
        res["n_outputs"] = {kind: len(readers[name].refs[kind]) for kind in _Reader.KINDS}
        out[name] = res
    for inst in instances.values():
        inst.close()
    return out


def run_states(fmu_dir: Path, tmp: Path, steps: int) -> dict[str, dict]:
    """measure_states per channel configuration, one fresh process each."""
    nominal = np.load(tmp / "records.npy")
    n = STATE_WARMUP + steps
    results = {}
    for config, (channels, columns) in CONFIGS.items():
        params = dict(BASE_PARAMS)
        for ch in ("dtg", "grey", "df"):
            params[f"{ch}.enabled"] = ch in channels
        names = ALARM_INPUTS[config]
        np.save(tmp / f"alarm_{config}.npy", make_alarm_records(n, len(names)))
        np.save(tmp / f"nominal_{config}.npy", nominal[:n])
        diag = str(fmu_dir / "Diagnoser.fmu")
        specs = {
            "nominal": {"fmu": diag, "params": params, "columns": columns,
                        "records": str(tmp / f"nominal_{config}.npy"),
                        "inputs": [IN_NAMES[c] for c in columns]},
            "alarm": {"fmu": diag, "params": params, "columns": list(range(len(names))),
                      "records": str(tmp / f"alarm_{config}.npy"), "inputs": names},
            "injector": {"fmu": str(fmu_dir / "FaultInjector.fmu")},
        }
        results[config] = run_measurement(specs, STATE_WARMUP, steps, states=True)
    return results


def print_states(results: dict[str, dict], steps: int) -> None:
    first = results["all"]
    inj = first["injector"]
    print(f"\nNominal and in alarm (issue 35), default install, {steps} timed steps after "
          f"{STATE_WARMUP} warm-up steps; per process (one per row): Diagnoser nominal, "
          "Diagnoser in alarm and FaultInjector.fmu stepped in turn")
    print(f"  e.g. FaultInjector host step median {inj['median']:.1f} µs, p99 "
          f"{inj['p99']:.1f}, max {inj['max']:.1f}")
    print("  what the in-alarm instance says at the first timed step / at the end:")
    for config, r in results.items():
        f = r["alarm"]["flags"]
        print(f"    {config:5s} " + "  ".join(
            f"{key} {f['start'][key]!s}/{f['end'][key]!s}" for key in f["start"]))
    print("\n  host step µs (wall; CPU time of the thread in brackets):")
    print(f"    {'channels':8s} {'state':7s} {'median':>8s} {'p99':>17s} {'max':>19s} "
          f"{'/ FaultInj':>11s} {'p99 CPU/FI med':>15s} {'FI med':>7s}")
    for config, r in results.items():
        fi = r["injector"]["median"]
        for state in ("nominal", "alarm"):
            s, c = r[state]["step"], r[state]["cpu"]
            print(f"    {config:8s} {state:7s} {s['median']:8.1f} {s['p99']:8.1f} "
                  f"({c['p99']:7.1f}) {s['max']:9.1f} ({c['max']:7.1f}) "
                  f"{r[state]['ratio_median']:10.2f}x {c['p99'] / fi:14.1f}x {fi:7.1f}")
    print("\n  reading every output after a step, µs (medians; the first call, Real, "
          "includes the outputs' copy):")
    kinds = first["alarm"]["n_outputs"]
    print(f"    {'channels':8s} {'state':7s} {'host':7s} "
          + " ".join(f"{k + f' ({n})':>14s}" for k, n in kinds.items())
          + f" {'total':>8s} {'total p99':>10s} {'/ FI step':>10s} {'per variable':>13s}")
    for config, r in results.items():
        fi = r["injector"]["median"]
        for state in ("nominal", "alarm"):
            d = r[state]
            for how in ("fmpy", "ctypes"):
                rd = d[f"read_{how}"]
                per_var = f"{d['read_per_variable']:13.1f}" if how == "fmpy" else ""
                print(f"    {config:8s} {state:7s} {how:7s} "
                      + " ".join(f"{rd[k]:14.1f}" for k in kinds)
                      + f" {rd['total']:8.1f} {rd['total_p99']:10.1f} "
                      f"{rd['total'] / fi:9.1f}x {per_var}")


def run_measurement(specs: dict[str, dict], warmup: int, steps: int,
                    fallback: bool = False, states: bool = False) -> dict:
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "result.json"
        spec_file = Path(tmp) / "spec.json"
        spec_file.write_text(json.dumps(specs))
        cmd = [sys.executable, __file__, "--_measure", str(out), str(spec_file),
               "--warmup", str(warmup), "--steps", str(steps)]
        if states:
            cmd.append("--_states")
        env = dict(os.environ)
        env.pop("GYRODIAG_KERNELS", None)
        if fallback:
            env["GYRODIAG_KERNELS"] = "python"
        subprocess.run(cmd, check=True, cwd=ROOT, env=env, timeout=3600)
        return json.loads(out.read_text())


def build_trivial(tmp: Path) -> Path:
    """Build the one-output FMU with pythonfmu's builder, in a fresh process (§6.4)."""
    (tmp / "gd_bench_trivial.py").write_text(TRIVIAL_SCRIPT, encoding="utf-8")
    code = ("from pythonfmu import FmuBuilder; "
            "FmuBuilder.build_FMU('gd_bench_trivial.py', dest='.')")
    subprocess.run([sys.executable, "-c", code], check=True, cwd=tmp, capture_output=True,
                   timeout=3600)
    return tmp / "GdBenchTrivial.fmu"


def built_fmus(names: list[str]) -> Path:
    """build/fmus with these FMUs, rebuilt first if older than their sources."""
    out = ROOT / "build" / "fmus"
    sys.path.insert(0, str(ROOT))
    import build_fmu

    if build_fmu.stale_fmus(out, names):
        subprocess.run([sys.executable, str(ROOT / "build_fmu.py"), "--out", str(out),
                        *names], check=True, cwd=ROOT, capture_output=True, timeout=3600)
    return out


# ------------------------------------------------------------------ library measurement
def measure_library(rec: np.ndarray, warmup: int, kernels: str) -> dict:
    """Per-step times of the three channels called directly, same settings as BASE_PARAMS."""
    from gyrodiag.common import _accel

    previous = _accel.use(kernels)
    try:
        from gyrodiag.df.channel import DFChannel, DFChannelConfig
        from gyrodiag.dtg.channel import DTGChannel, DTGChannelConfig
        from gyrodiag.grey import GreyFaultDetector, ImprovedGreyPredictor

        dtg = DTGChannel(DTGChannelConfig(sample_period_s=H, learn_start_s=0.2,
                                          learn_end_s=0.8, p0=1e8))
        grey = GreyFaultDetector(ImprovedGreyPredictor(10, a_min=1e-6), 0.05, H, 20.0)
        df = DFChannel(DFChannelConfig(sample_period_s=H, calibrate_s=0.5, burn_in_s=0.1))
    finally:
        _accel.kernels = previous
        _accel.ACCELERATED = previous is not _accel._pykernels
    times = np.empty((len(rec), 3))
    rows = rec.tolist()
    perf = time.perf_counter
    for k, row in enumerate(rows):
        t0 = perf()
        dtg.update(row[0], row[1], row[2], row[3])
        t1 = perf()
        grey.update(row[4], time_s=k * H)
        t2 = perf()
        df_out = df.update(row[5:7], row[7:13])
        t3 = perf()
        times[k] = (t1 - t0, t2 - t1, t3 - t2)
    if df_out.calibrating:
        raise RuntimeError("the detection filter is still calibrating: raise --warmup")
    med = 1e6 * np.median(times[warmup:], axis=0)
    return {"DTG": float(med[0]), "grey": float(med[1]), "DF": float(med[2]),
            "all": 1e6 * float(np.median(times[warmup:].sum(axis=1)))}


# ------------------------------------------------------------------ DTG chain
_CHAIN_RUNNER = """
import json, os, sys, time
from gyrodiag_harness import load_scenario, run_scenario
s = load_scenario(sys.argv[1])
t0, c0 = time.perf_counter(), time.process_time()
r = run_scenario(s, fmu_dir=sys.argv[2], progress=False)
print(json.dumps({"sim_s": s.duration_s, "wall_s": time.perf_counter() - t0,
                  "cpu_s": time.process_time() - c0, "error": r.error}))
sys.stdout.flush()
os._exit(0)
"""


def measure_chain(fmu_dir: Path, fallback: bool) -> dict:
    env = dict(os.environ)
    env.pop("GYRODIAG_KERNELS", None)
    if fallback:
        env["GYRODIAG_KERNELS"] = "python"
    proc = subprocess.run([sys.executable, "-c", _CHAIN_RUNNER,
                           str(ROOT / "scenarios" / "dtg_nominal.toml"), str(fmu_dir)],
                          cwd=ROOT, capture_output=True, text=True, env=env, timeout=3600)
    lines = [ln for ln in proc.stdout.splitlines() if ln.startswith("{")]
    if proc.returncode != 0 or not lines:
        raise RuntimeError(f"dtg_nominal failed ({proc.returncode}):\n{proc.stderr[-2000:]}")
    return json.loads(lines[-1])


# ------------------------------------------------------------------ main
def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=3000, help="timed steps")
    parser.add_argument("--warmup", type=int, default=1500, help="untimed steps first")
    parser.add_argument("--no-chain", action="store_true",
                        help="skip the DTG chain (dtg_nominal, 60 s simulated)")
    parser.add_argument("--fmu-dir", type=Path, default=None,
                        help="take the FMUs from here as they are (default: build/fmus, "
                             "rebuilt first if older than their sources)")
    parser.add_argument("--states-only", action="store_true",
                        help="only the nominal / in-alarm comparison and the output reads")
    parser.add_argument("--_measure", nargs=2, dest="measure", help=argparse.SUPPRESS)
    parser.add_argument("--_states", action="store_true", dest="states",
                        help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.measure:
        out, spec = map(Path, args.measure)
        measure = measure_states if args.states else measure_fmus
        res = measure(json.loads(spec.read_text()), args.warmup, args.steps)
        out.write_text(json.dumps(res))
        return 0

    sys.path.insert(0, str(ROOT / "fmu_src"))
    n = max(args.warmup, STATE_WARMUP) + args.steps
    rec = make_records(n)
    fmu_dir = args.fmu_dir or built_fmus(["Diagnoser", "FaultInjector", "DTG"])
    results: dict[tuple[str, str], dict] = {}
    with tempfile.TemporaryDirectory() as tmp_name:
        tmp = Path(tmp_name)
        np.save(tmp / "records.npy", rec)
        states = run_states(fmu_dir, tmp, args.steps)
        if args.states_only:
            print_states(states, args.steps)
            return 0
        trivial = str(build_trivial(tmp))
        for kernels in ("default", "fallback"):
            for config, (channels, columns) in CONFIGS.items():
                params = dict(BASE_PARAMS)
                for ch in ("dtg", "grey", "df"):
                    params[f"{ch}.enabled"] = ch in channels
                # the Diagnoser first: its instantiation is the process's first
                specs = {
                    "diag": {"fmu": str(fmu_dir / "Diagnoser.fmu"), "params": params,
                             "records": str(tmp / "records.npy"), "columns": columns,
                             "inputs": [IN_NAMES[c] for c in columns]},
                    "trivial": {"fmu": trivial},
                    "injector": {"fmu": str(fmu_dir / "FaultInjector.fmu")},
                }
                results[(kernels, config)] = run_measurement(
                    specs, args.warmup, args.steps, fallback=kernels == "fallback")
    library = {"default": measure_library(rec, args.warmup, "c" if _compiled() else "python"),
               "fallback": measure_library(rec, args.warmup, "python")}

    first = results[("default", "all")]
    print(f"Diagnoser.fmu at 1 kHz, {args.steps} timed steps after {args.warmup} warm-up "
          "steps. Per process (one per row): a trivial pythonfmu FMU, FaultInjector.fmu and "
          "Diagnoser.fmu stepped in turn; host step = set inputs + doStep; ratios are "
          "medians of the per-step ratios (robust to the machine's load)")
    print(f"  e.g. trivial pythonfmu FMU doStep {first['trivial']['step_us']:.1f} µs, "
          f"FaultInjector ({first['injector']['n_inputs']} inputs + doStep) "
          f"{first['injector']['step_us']:.1f} µs")
    for kernels in ("default", "fallback"):
        label = ("default install (compiled kernels)" if kernels == "default"
                 else "plain-Python fallback (GYRODIAG_KERNELS=python)")
        acc = results[(kernels, "all")]["accelerated"]
        print(f"\n  Diagnoser, {label}; compiled kernels in use in the FMU: {acc}")
        print(f"    {'channels':8s} {'step µs':>9s} {'/ FaultInj':>11s} {'/ trivial':>10s} "
              f"{'FI µs':>7s} {'library µs':>11s} {'+outputs µs':>12s}")
        for config in CONFIGS:
            r = results[(kernels, config)]
            d = r["diag"]
            print(f"    {config:8s} {d['step_us']:9.1f} {r['ratio_injector']:10.2f}x "
                  f"{r['ratio_trivial']:9.1f}x {r['injector']['step_us']:7.1f} "
                  f"{library[kernels][config]:11.1f} {d['whole_us']:12.1f}")
    target = {"default": 4.0, "fallback": 12.0}
    verdicts = []
    for k in ("default", "fallback"):
        ratio = results[(k, "all")]["ratio_injector"]
        verdicts.append(f"{k} {ratio:.2f}x ({'met' if ratio <= target[k] else 'NOT met'})")
    print("\n  targets: all channels <= 4x FaultInjector (default), <= 12x (fallback): "
          + ", ".join(verdicts))
    print("\n  Diagnoser instantiate / initialise, fmpy host, default install, first "
          "instance in the process (s; CPU time of the process, wall in brackets):")
    for config in CONFIGS:
        d = results[("default", config)]["diag"]
        print(f"    {config:8s} instantiate {d['instantiate_cpu_s']:6.3f} "
              f"({d['instantiate_s']:6.3f})   initialise (channels built) "
              f"{d['initialise_cpu_s']:6.3f} ({d['initialise_s']:6.3f})")
    if not args.no_chain:
        print("\n  DTG 1 kHz chain, seed scenario dtg_nominal (DTG -> FaultInjector -> 2 "
              "Diagnoser DTG channels, 60 s) through the harness, fresh process:")
        for kernels in ("default", "fallback"):
            c = measure_chain(fmu_dir, kernels == "fallback")
            err = "" if c["error"] is None else f"  (run error: {c['error']})"
            print(f"    {kernels:8s} CPU {c['cpu_s']:6.2f} s, wall {c['wall_s']:6.2f} s: "
                  f"real-time factor {c['sim_s'] / c['cpu_s']:6.2f} on CPU time "
                  f"({c['sim_s'] / c['wall_s']:.2f} on wall time){err}")
    print_states(states, args.steps)
    return 0


def _compiled() -> bool:
    from gyrodiag.common import _accel

    try:
        _accel.use("c")
    except ImportError:
        return False
    return True


if __name__ == "__main__":
    sys.exit(main())
