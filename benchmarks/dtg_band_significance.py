"""Figures of docs/dtg_case_rate.md §10: the DTG ratio band with and without significance.

Runs the system chain without FMUs (tests/_system_chain.py: aircraft + LQR at 1 kHz, the
paper DTG as pitch gyro, second gyro 2e-4 rad/s as the case rate) and the DTG channel of
the system scenarios (pattern classifier, case rate, fine band 0.93/1.07 held 100 of 200
samples) for each ``--sigmas`` value of ``band_sigma`` (0: the band alone). Prints

* fault-free runs (calm level flight, level flight at the DTG's pick-off noise times
  ``--noise-factor``, a 0.05 rad square wave): the fraction of time in alarm after
  10 s and the first alarm;
* physical faults at 20 s (spin 0.95 / 0.9, torquer gain 0.9 / 1.1) in calm level
  flight, level turbulence (σ_w 0.77 m/s) and a 0.05 rad square wave: the detection
  delay (s), and whether anything alarmed before the fault.

No assertions (the tests of tests/test_system_diagnosis.py hold the known answers).

    python benchmarks/dtg_band_significance.py [--sigmas 0,3,5] [--nominal-s 120]
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))
sys.path.insert(0, str(ROOT / "fmu_src"))

from _system_chain import PitchCommand, run_chain  # noqa: E402

from gyrodiag.dtg.channel import DTGChannel, DTGChannelConfig  # noqa: E402

T = 1e-3
GYRO2_STD = 2e-4
CHANNEL = dict(classifier="pattern", case_rate="central", forgetting=0.9998,
               learn_start_s=2.0, learn_end_s=10.0, low=0.93, high=1.07,
               persistence_k=100, persistence_n=200)
FAULTS = {"spin 0.95": {"spin_fraction": 0.95}, "spin 0.9": {"spin_fraction": 0.9},
          "torquer 0.9": {"torquer_scale": 0.9}, "torquer 1.1": {"torquer_scale": 1.1}}


def _inputs(seed: int, duration_s: float, **kw) -> np.ndarray:
    o = run_chain(duration_s, seed=seed, dtg_seed=seed + 3, **kw)
    gyro2 = o["q"] + GYRO2_STD * np.random.default_rng(seed + 7).standard_normal(o["q"].size)
    return np.column_stack([o["Utx"], o["Uty"], o["Ux"], o["Uy"], np.zeros_like(gyro2),
                            gyro2])


def _alarms(rows: np.ndarray, sigma: float) -> np.ndarray:
    ch = DTGChannel(DTGChannelConfig(**CHANNEL, band_sigma=sigma))
    return np.array([ch.update(*r).alarm for r in rows])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--sigmas", default="0,3,5", help="band_sigma values, comma-separated")
    ap.add_argument("--nominal-s", type=float, default=120.0, help="fault-free run length, s")
    ap.add_argument("--noise-factor", type=float, default=3.0,
                    help="pick-off noise of the noisy fault-free case / the DTG's 1e-3 V")
    ap.add_argument("--seed", type=int, default=2)
    args = ap.parse_args()
    sigmas = [float(s) for s in args.sigmas.split(",")]
    square = {"command": PitchCommand(1, 0.05, start=12.0, period=8.0)}
    t0 = time.perf_counter()

    print(f"fault-free, {args.nominal_s:g} s: time in alarm after 10 s, first alarm (s)")
    nominal = {"calm level": {},
               f"calm level, pick-off noise x{args.noise_factor:g}":
                   {"dtg_noise_std": 1e-3 * args.noise_factor},
               "square 0.05 rad": square}
    for name, kw in nominal.items():
        rows = _inputs(args.seed, args.nominal_s, **kw)
        cells = []
        for s in sigmas:
            a = _alarms(rows, s)[round(10.0 / T):]
            first = np.flatnonzero(a)
            cells.append(f"sigma {s:g}: {a.mean():6.2%} "
                         f"{(first[0] * T + 10.0) if first.size else '-':>8}")
        print(f"  {name:<34} " + " | ".join(cells), flush=True)

    print("faults at 20 s, runs of 32 s: detection delay (s); '!' alarm before the fault")
    flights = {"calm level": {}, "level, sigma_w 0.77 m/s": {"sigma_w": 0.77},
               "square 0.05 rad": square}
    k0 = round(20.0 / T) - 1
    for flight, kw in flights.items():
        for fault, values in FAULTS.items():
            rows = _inputs(args.seed, 32.0, faults=(20.0, values), **kw)
            cells = []
            for s in sigmas:
                a = _alarms(rows, s)
                after = np.flatnonzero(a[k0:])
                delay = f"{after[0] * T:.3f}" if after.size else "missed"
                cells.append(f"sigma {s:g}: {delay:>7}{'!' if a[:k0].any() else ' '}")
            print(f"  {flight + ', ' + fault:<34} " + " | ".join(cells), flush=True)
    print(f"({time.perf_counter() - t0:.0f} s)")


if __name__ == "__main__":
    main()
