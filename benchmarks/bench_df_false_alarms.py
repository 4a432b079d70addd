"""Long-run false-alarm rate of the sequential detection filter at library level.

Usage::

    nice -n 10 .venv/bin/python benchmarks/bench_df_false_alarms.py [--hours 2000]
        [--parallel 1000] [--calibrations 10] [--rate 1e-3] [--period 0.01]

The residual of an observer whose model is exact depends on the sensor noise only
(gyrodiag.df.residual), so the detection path of the Diagnoser's default decision
(main detection filter, whitening, scales, CUSUM charts with their cap and release) is
run on white sensor noise, ``--parallel`` runs at a time (gyrodiag.df.sequential_diagnosis.
simulate_fault_free), for the seed aircraft (noise 1 σ: v 0.05 m/s, α/ϑ/γ 1e-3 rad,
q 1e-3 rad/s, h 0.2 m).

Two figures:

* the model as designed (noise known): ``--hours`` of fault-free operation;
* as the FMU runs it: ``--calibrations`` diagnosers, each from its own 6 s calibration
  window of the closed loop (noise estimated from the residual, scales widened to their
  95 % bound, initial state fitted), each simulated for ``--hours / --calibrations``
  hours with the *true* noise, so that the estimation error of a short window is in the
  figure.

Prints the alarms, the simulated hours, the rate and its 95 % Garwood upper bound per
hour (no assertions). Minutes of CPU for 2000 h at 100 Hz.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))

from _aircraft_loop import NOISE_STD, simulate

from gyrodiag.df.channel import DFChannel, DFChannelConfig
from gyrodiag.df.filter import design_detection_filter
from gyrodiag.df.plant import seed_aircraft
from gyrodiag.df.sequential_diagnosis import (
    SequentialDiagnoser,
    SequentialSettings,
    simulate_fault_free,
)


def _line(label: str, r: dict, seconds: float) -> str:
    return (f"{label:<34} {r['alarms']:>5} alarms in {r['hours']:8.1f} h: "
            f"{100 * r['rate_per_h']:.3f} per 100 h (95 % upper "
            f"{100 * r['upper95_per_h']:.3f}), design {100 * r['design_per_h']:.3f}; "
            f"{seconds:.0f} s")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--hours", type=float, default=2000.0)
    ap.add_argument("--parallel", type=int, default=1000)
    ap.add_argument("--calibrations", type=int, default=10)
    ap.add_argument("--rate", type=float, default=1e-3, help="design false alarms per hour")
    ap.add_argument("--period", type=float, default=0.01, help="sample period, s")
    args = ap.parse_args()
    m = seed_aircraft()
    k = design_detection_filter(m.A, m.C, np.eye(5), -np.arange(1.0, 6.0))
    settings = SequentialSettings(false_alarms_per_h=args.rate, max_faults=1)

    t0 = time.perf_counter()
    diag = SequentialDiagnoser(m.A, m.B, m.C, k, args.period, NOISE_STD**2, settings)
    r = simulate_fault_free(diag, args.hours, n_parallel=args.parallel, seed=1)
    print(_line("noise known (the model as designed)", r, time.perf_counter() - t0))
    print(f"  thresholds: mean CUSUM h = {diag.h_mean:.3f} σ (k = {settings.cusum_k}), "
          f"variance CUSUM h = {diag.h_variance:.3f}; per-chart ARL {diag.chart_arl:.3g}")

    if args.calibrations and abs(args.period - 0.01) < 1e-12:
        t0 = time.perf_counter()
        total = {"alarms": 0, "hours": 0.0}
        per = args.hours / args.calibrations
        for j in range(args.calibrations):
            _, u, y = simulate(8.5, 500 + j)
            ch = DFChannel(DFChannelConfig(sample_period_s=0.01, calibrate_s=8.0,
                                           burn_in_s=2.0, false_alarms_per_h=args.rate,
                                           max_faults=1))
            for uk, yk in zip(u, y, strict=True):
                ch.update(uk, yk)
            engine = ch.engine
            assert isinstance(engine, SequentialDiagnoser)
            got = simulate_fault_free(engine, per, n_parallel=args.parallel, seed=1000 + j,
                                      sensor_std=NOISE_STD)
            total["alarms"] += got["alarms"]
            total["hours"] += got["hours"]
            est = ch.noise_std / NOISE_STD
            print(f"  calibration {j}: noise estimate / true {np.round(est, 3)}, "
                  f"{got['alarms']} alarms in {got['hours']:.0f} h")
        from scipy.stats import chi2

        n, h = total["alarms"], total["hours"]
        print(_line("noise learned on 6 s windows", {
            "alarms": n, "hours": h, "rate_per_h": n / h,
            "upper95_per_h": chi2.ppf(0.975, 2 * (n + 1)) / 2 / h,
            "design_per_h": args.rate}, time.perf_counter() - t0))


if __name__ == "__main__":
    main()
