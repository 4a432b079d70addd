"""The calibrated grey detector on the seed-001 HRG timeline with output noise, and its
false alarms on long fault-free HRG records.

Usage::

    .venv/bin/python benchmarks/bench_grey_noise.py [--seeds 1 40] [--noise 0 5 10 15 20]
        [--compare] [--faults 27 252 420] [--long-hours 0]
        [--long-noise 0 2.5 5 10 15 20] [--workers 2]

Library level (the HRG output model of models/hrg at 2 Hz, faults as in
scenarios/hrg_seed001_grey.toml: bias −0.2 V 27–47 s, stuck at 3 V 252–272 s, scale factor
× 1.05 from 420 s, flat from 825 s), per noise level (mV rms) and seed: the detection delay
of each fault, alarms outside the fault windows (+25 s, the scenario's rule) and on the
flat tail, for the calibrated sequential detector (improved model, residual order chosen
among 2, 1, 0 on the calibration window, CUSUM and lagged step test for 1e-3 false
alarms per hour in all). ``--compare`` adds the calibrated detector without the lagged
test and with the old suspicion level (3 σ_e) and the paper's fixed 0.05 V threshold.
``--faults`` moves the onsets (the scale fault is 5 % of the output there: 0.06 V near
350 s, 0.10 V at 420 s, up to 0.19 V).

``--long-hours H``: per noise level of ``--long-noise``, H hours of fault-free records of
the HRG model (1 h each, own noise seed, ω(t) the seed-001 wave 0.25 + 0.1 sin(2πt/500) +
0.04 sin(2πt/130 + 0.5) rad/s without its taper, started at a random phase, so the output
moves up to 0.03 V/s all the time): alarms per hour and the 95 % upper bound (Garwood).
Prints tables (no assertions).
"""

from __future__ import annotations

import argparse
import math
import sys
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))

from test_grey_calibrated import FAULTS, H, detector, fault_free_record, judge, timeline

from gyrodiag.grey import GreyFaultDetector, ImprovedGreyPredictor

KINDS = ("calibrated", "calibrated, no lagged test, suspicion 3", "paper 0.05 V")


def _make(kind: str) -> GreyFaultDetector:
    if kind == KINDS[0]:
        return detector()
    if kind == KINDS[1]:
        return detector(lag_max=0, suspicion_sigma=3.0)
    return GreyFaultDetector(ImprovedGreyPredictor(10), 0.05, H, 20.0)


def _timeline_run(args: tuple[str, float, int, tuple[float, float, float]]
                  ) -> tuple[list[float], bool, float]:
    kind, mv, seed, faults = args
    t, y = timeline(mv / 1000.0, seed, faults=faults)
    det = _make(kind)
    alarm = np.array([det.update(v, time_s=tk).alarm for v, tk in zip(y, t, strict=True)])
    d, outside, tail = judge(t, alarm, faults)
    ratio = det.sigma / (mv / 1000.0) if kind != KINDS[2] and mv else math.nan
    return d, bool(outside or tail), ratio


def _long_run(args: tuple[float, int]) -> int:
    """Alarm onsets in one fault-free hour."""
    mv, seed = args
    t, y = fault_free_record(mv / 1000.0, seed, 3600.0)
    det = detector()
    alarm = np.array([det.update(v, time_s=tk).alarm for v, tk in zip(y, t, strict=True)])
    return int(np.sum(alarm[1:] & ~alarm[:-1]) + alarm[0])


def garwood_upper(n: int, exposure: float, level: float = 0.95) -> float:
    """One-sided upper confidence bound of a Poisson rate (n events in ``exposure``)."""
    from scipy.stats import chi2

    return float(chi2.ppf(level, 2 * n + 2)) / 2.0 / exposure


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, nargs=2, default=[1, 40], metavar=("FIRST", "LAST"))
    ap.add_argument("--noise", type=float, nargs="*", default=[0.0, 5.0, 10.0, 15.0, 20.0])
    ap.add_argument("--compare", action="store_true")
    ap.add_argument("--faults", type=float, nargs=3, default=list(FAULTS),
                    metavar=("BIAS", "STUCK", "SCALE"),
                    help="fault onsets, s (default: the seed scenario's 27 252 420)")
    ap.add_argument("--long-hours", type=int, default=0)
    ap.add_argument("--long-noise", type=float, nargs="+",
                    default=[0.0, 2.5, 5.0, 10.0, 15.0, 20.0])
    ap.add_argument("--workers", type=int, default=2)
    args = ap.parse_args()
    seeds = range(args.seeds[0], args.seeds[1] + 1)
    kinds = KINDS if args.compare else KINDS[:1]
    with ProcessPoolExecutor(args.workers) as pool:
        if args.noise:
            print("noise mV | detector | bias ≤1.5 s | stuck ≤1.5 s | scale ≤1.5 s | "
                  "max delay bias/stuck/scale s | scale median s | runs with a false alarm "
                  "| sigma_e / noise")
        for mv in args.noise:
            for kind in kinds:
                res = list(pool.map(_timeline_run, [(kind, mv, s, tuple(args.faults))
                                                    for s in seeds]))
                dl = np.array([r[0] for r in res])
                n = len(dl)
                within = [int(np.sum(dl[:, i] <= 1.5)) for i in range(3)]
                worst = "/".join(f"{x:g}" for x in dl.max(axis=0))
                med = float(np.median(dl[:, 2]))
                false = sum(r[1] for r in res)
                ratio = [r[2] for r in res if math.isfinite(r[2])]
                sig = f"{np.mean(ratio):.2f}" if ratio else "–"
                print(f"{mv:8g} | {kind} | {within[0]}/{n} | {within[1]}/{n} | "
                      f"{within[2]}/{n} | {worst} | {med:.1f} | {false}/{n} | {sig}",
                      flush=True)
        if args.long_hours:
            print("\nfault-free HRG records, calibrated detector: noise mV | hours | alarms |"
                  " alarms per h | 95 % upper bound per h")
            total_n, total_h = 0, 0
            for mv in args.long_noise:
                counts = list(pool.map(_long_run, [(mv, 1000 + s)
                                                   for s in range(args.long_hours)]))
                n = sum(counts)
                total_n += n
                total_h += args.long_hours
                print(f"{mv:8g} | {args.long_hours} | {n} | {n / args.long_hours:.4f} | "
                      f"{garwood_upper(n, args.long_hours):.4f}", flush=True)
            print(f"     all | {total_h} | {total_n} | {total_n / total_h:.4f} | "
                  f"{garwood_upper(total_n, total_h):.4f}")


if __name__ == "__main__":
    main()
