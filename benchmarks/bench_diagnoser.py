"""Cost of one Diagnoser.fmu doStep with all channels on at 1 kHz, and what it is made of.

Usage::

    .venv/bin/python benchmarks/bench_diagnoser.py [--steps 5000] [--warmup 1500]

Measures, in one run, on the same input records:

* Diagnoser.fmu doStep (DTG + grey + detection filter, sample period 1 ms), through
  fmpy, in a fresh process (DESIGN §6.11); also the whole host step (set the 13 inputs,
  doStep, read the 60 outputs);
* a trivial pythonfmu FMU (one Real output set in do_step), built here in a temporary
  directory with pythonfmu's builder, in its own fresh process: the floor of any
  pythonfmu FMU step;
* the library channels called directly (DTGChannel, GreyFaultDetector, DFChannel) in
  this process: the floor of the diagnosis itself.

Prints figures only (no assertions). The detection filter calibrates over the warm-up
(0.5 s) so that the timed steps are steady-state monitoring steps, fault-free.
"""

from __future__ import annotations

import argparse
import json
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
PARAMS = {"sample_period_s": H, "df.calibrate_s": 0.5, "df.burn_in_s": 0.1,
          "dtg.learn_start_s": 0.2, "dtg.learn_end_s": 0.8, "dtg.p0": 1e8,
          "grey.window": 10, "grey.threshold": 0.05}

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

    from gyrodiag.aircraft import seed_aircraft
    from gyrodiag.demo import NOMINAL
    from gyrodiag.demo import simulate as simulate_dtg

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
def measure_fmu(fmu: Path, records: Path | None, warmup: int, steps: int) -> dict:
    """Runs in a fresh process: per-step times of doStep (and of the whole host step)."""
    from fmpy import extract, read_model_description
    from fmpy.fmi2 import FMU2Slave

    unzipdir = extract(str(fmu))
    md = read_model_description(unzipdir)
    vr = {v.name: v.valueReference for v in md.modelVariables}
    types = {v.name: v.type for v in md.modelVariables}
    slave = FMU2Slave(guid=md.guid, unzipDirectory=unzipdir,
                      modelIdentifier=md.coSimulation.modelIdentifier, instanceName="bench")
    slave.instantiate()
    slave.setupExperiment(startTime=0.0)
    if records is not None:
        for name, value in PARAMS.items():
            if types[name] == "Real":
                slave.setReal([vr[name]], [float(value)])
            else:
                slave.setInteger([vr[name]], [int(value)])
    slave.enterInitializationMode()
    slave.exitInitializationMode()
    rec = np.load(records) if records is not None else None
    in_vr = [vr[n] for n in IN_NAMES] if rec is not None else []
    outputs = [v for v in md.modelVariables if v.causality == "output"]
    out_real = [v.valueReference for v in outputs if v.type == "Real"]
    out_int = [v.valueReference for v in outputs if v.type == "Integer"]
    out_bool = [v.valueReference for v in outputs if v.type == "Boolean"]
    do_step = np.empty(warmup + steps)
    whole = np.empty(warmup + steps)
    for k in range(warmup + steps):
        t0 = time.perf_counter()
        if rec is not None:
            slave.setReal(in_vr, rec[k].tolist())
        t1 = time.perf_counter()
        slave.doStep(currentCommunicationPoint=k * H, communicationStepSize=H)
        t2 = time.perf_counter()
        slave.getReal(out_real)
        if out_int:
            slave.getInteger(out_int)
        if out_bool:
            slave.getBoolean(out_bool)
        t3 = time.perf_counter()
        do_step[k], whole[k] = t2 - t1, t3 - t0
    slave.terminate()
    slave.fmi2FreeInstance(slave.component)
    timed = slice(warmup, None)
    return {"do_step_us": 1e6 * float(np.median(do_step[timed])),
            "do_step_mean_us": 1e6 * float(np.mean(do_step[timed])),
            "whole_step_us": 1e6 * float(np.median(whole[timed])),
            "n_outputs": len(outputs)}


def run_measurement(fmu: Path, records: Path | None, warmup: int, steps: int) -> dict:
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "result.json"
        cmd = [sys.executable, __file__, "--_measure", str(fmu), str(out),
               "--warmup", str(warmup), "--steps", str(steps)]
        if records is not None:
            cmd += ["--records", str(records)]
        subprocess.run(cmd, check=True, cwd=ROOT)
        return json.loads(out.read_text())


def build_trivial(tmp: Path) -> Path:
    """Build the one-output FMU with pythonfmu's builder, in a fresh process (§6.4)."""
    (tmp / "gd_bench_trivial.py").write_text(TRIVIAL_SCRIPT, encoding="utf-8")
    code = ("from pythonfmu import FmuBuilder; "
            "FmuBuilder.build_FMU('gd_bench_trivial.py', dest='.')")
    subprocess.run([sys.executable, "-c", code], check=True, cwd=tmp, capture_output=True)
    return tmp / "GdBenchTrivial.fmu"


def diagnoser_fmu() -> Path:
    """build/fmus/Diagnoser.fmu, rebuilt first if older than its sources."""
    out = ROOT / "build" / "fmus"
    sys.path.insert(0, str(ROOT))
    import build_fmu

    if build_fmu.stale_fmus(out, ["Diagnoser"]):
        subprocess.run([sys.executable, str(ROOT / "build_fmu.py"), "--out", str(out),
                        "Diagnoser"], check=True, cwd=ROOT, capture_output=True)
    return out / "Diagnoser.fmu"


# ------------------------------------------------------------------ library measurement
def measure_library(rec: np.ndarray, warmup: int) -> dict:
    """Per-step times of the three channels called directly, same settings as PARAMS."""
    from gyrodiag.df_channel import DFChannel, DFChannelConfig
    from gyrodiag.dtg_channel import DTGChannel, DTGChannelConfig
    from gyrodiag.grey import GreyFaultDetector, ImprovedGreyPredictor

    dtg = DTGChannel(DTGChannelConfig(sample_period_s=H, learn_start_s=0.2, learn_end_s=0.8,
                                      p0=1e8))
    grey = GreyFaultDetector(ImprovedGreyPredictor(10, a_min=1e-6), 0.05, H, 20.0)
    df = DFChannel(DFChannelConfig(sample_period_s=H, calibrate_s=0.5, burn_in_s=0.1))
    times = np.empty((len(rec), 3))
    for k, row in enumerate(rec):
        t0 = time.perf_counter()
        dtg.update(row[0], row[1], row[2], row[3])
        t1 = time.perf_counter()
        grey.update(float(row[4]), time_s=k * H)
        t2 = time.perf_counter()
        df_out = df.update(row[5:7], row[7:13])
        t3 = time.perf_counter()
        times[k] = (t1 - t0, t2 - t1, t3 - t2)
    med = 1e6 * np.median(times[warmup:], axis=0)
    total = 1e6 * float(np.median(times[warmup:].sum(axis=1)))
    if df_out.calibrating:
        raise RuntimeError("the detection filter is still calibrating: raise --warmup")
    return {"dtg_us": float(med[0]), "grey_us": float(med[1]), "df_us": float(med[2]),
            "total_us": total}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=5000, help="timed steps")
    parser.add_argument("--warmup", type=int, default=1500, help="untimed steps first")
    parser.add_argument("--records", type=Path, help=argparse.SUPPRESS)
    parser.add_argument("--_measure", nargs=2, dest="measure", help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.measure:
        fmu, out = map(Path, args.measure)
        res = measure_fmu(fmu, args.records, args.warmup, args.steps)
        out.write_text(json.dumps(res))
        return 0

    sys.path.insert(0, str(ROOT / "fmu_src"))
    n = args.warmup + args.steps
    rec = make_records(n)
    with tempfile.TemporaryDirectory() as tmp_name:
        tmp = Path(tmp_name)
        np.save(tmp / "records.npy", rec)
        trivial = run_measurement(build_trivial(tmp), None, args.warmup, args.steps)
        diag = run_measurement(diagnoser_fmu(), tmp / "records.npy", args.warmup, args.steps)
    lib = measure_library(rec, args.warmup)

    d, tr = diag["do_step_us"], trivial["do_step_us"]
    print(f"Diagnoser.fmu, all channels at 1 kHz: {args.steps} timed steps after "
          f"{args.warmup} warm-up steps (medians, µs per step)")
    print(f"  trivial pythonfmu FMU doStep        {tr:9.1f}")
    print(f"  library channels, direct calls      {lib['total_us']:9.1f}   "
          f"(DTG {lib['dtg_us']:.1f}, grey {lib['grey_us']:.1f}, DF {lib['df_us']:.1f})")
    print(f"  Diagnoser.fmu doStep                {d:9.1f}   (mean {diag['do_step_mean_us']:.1f})")
    print(f"  Diagnoser.fmu whole host step       {diag['whole_step_us']:9.1f}   "
          f"(set 13 inputs, doStep, get {diag['n_outputs']} outputs)")
    print(f"  doStep / trivial FMU doStep         {d / tr:9.1f} x")
    print(f"  doStep / library direct             {d / lib['total_us']:9.2f} x   "
          f"(facade + FMI overhead {d - lib['total_us']:.1f} µs)")
    print(f"  real-time budget used at 1 kHz      {d / 1e3:9.1%}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
