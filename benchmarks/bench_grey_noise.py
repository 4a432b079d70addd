"""The calibrated grey detector on the seed-001 HRG timeline with output noise.

Usage::

    .venv/bin/python benchmarks/bench_grey_noise.py [--seeds 12] [--noise 0 5 10 20]

Library level (the HRG output model of models/hrg at 2 Hz, faults as in
scenarios/hrg_seed001_grey.toml: bias −0.2 V 27–47 s, stuck at 3 V 252–272 s, scale factor
× 1.05 from 420 s, flat from 825 s), per noise level (mV rms) and seed: the detection delay
of each fault, alarms outside the fault windows (+25 s, the scenario's rule) and on the
flat tail, for the calibrated sequential detector (improved model, residual order chosen
among 2, 1, 0 on the calibration window, CUSUM for 1e-3 false alarms per hour) and for the
paper's fixed 0.05 V threshold. Prints a table (no assertions).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))

from test_grey_calibrated import H, detector, judge, timeline

from gyrodiag.grey import GreyFaultDetector, ImprovedGreyPredictor


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=12)
    ap.add_argument("--noise", type=float, nargs="+", default=[0.0, 5.0, 10.0, 20.0])
    args = ap.parse_args()
    print("noise mV | detector | bias ≤1.5 s | stuck ≤1.5 s | scale ≤1.5 s | scale median s |"
          " runs with a false alarm | sigma_e / noise")
    for mv in args.noise:
        for kind in ("calibrated", "paper 0.05 V"):
            delays, false, ratio = [], 0, []
            for seed in range(1, args.seeds + 1):
                t, y = timeline(mv / 1000.0, seed)
                det = (detector() if kind == "calibrated" else
                       GreyFaultDetector(ImprovedGreyPredictor(10), 0.05, H, 20.0))
                alarm = np.array([det.update(v, time_s=tk).alarm
                                  for v, tk in zip(y, t, strict=True)])
                d, outside, tail = judge(t, alarm)
                delays.append(d)
                false += outside or tail
                if kind == "calibrated" and mv:
                    ratio.append(det.sigma / (mv / 1000.0))
            dl = np.array(delays)
            n = len(dl)
            within = [int(np.sum(dl[:, i] <= 1.5)) for i in range(3)]
            med = float(np.median(dl[:, 2]))
            sig = f"{np.mean(ratio):.2f}" if ratio else "–"
            print(f"{mv:8g} | {kind} | {within[0]}/{n} | {within[1]}/{n} | {within[2]}/{n} | "
                  f"{med:.1f} | {false}/{n} | {sig}")


if __name__ == "__main__":
    main()
