"""How small a noise on a DTG torquer read-out (Ux, Uy) can be seen, and how fast.

Usage::

    .venv/bin/python benchmarks/dtg_torquer_noise_floor.py [--seeds 8] [--learn-s 4]

The torquer voltage of the seed DTG chain is the rebalance controller's output plus a
white dither (1 V per 1 ms tick, scenarios/dtg_pattern_*.toml). The rotor model weighs
Ux by θ5 ≈ 2e−4, so noise added to the *read-out* of Ux leaves the regression residuals
almost untouched: what it changes is the variance of Ux itself, by the ratio
r = 1 + σn² / var(Ux). This script simulates the plant (models/dtg, paper set, loop on,
1 V dither, 1 mV pick-off noise) and prints, per noise level σn:

* r, from the simulated var(Ux);
* the relative standard error of var(Ux) learned over the reference window (``--learn-s``,
  the Diagnoser's learning window 1-5 s), measured over seeds: a variance test cannot
  flag a change below a few of these;
* the same ratio for the channel's real witness, the x-axis regression residual (the
  channel's 6th-order 50 Hz prefilter, θ fitted by least squares on the learning window
  of the fault-free record, the noise added to Ux before the prefilter as the
  FaultInjector does);
* the Kullback-Leibler divergence per sample of N(0, r·v) from N(0, v),
  KL = (r − 1 − ln r) / 2, and the expected delay of the optimal sequential test at an
  in-control run length of 10 h at 1 kHz, h / KL with h = ln(ARL0) (Lorden's bound, a
  lower bound on any detector's delay at that false-alarm rate, even with var(Ux)
  known exactly).

Prints a table, no assertions (figures in docs/notes.md, DTG).
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "models" / "dtg"))

from gd_dtg_sets import paper_set  # noqa: E402
from gd_dtg_sim import DTGSimulator  # noqa: E402

from gyrodiag.common.prefilter import ButterworthPrefilter  # noqa: E402
from gyrodiag.dtg.reference import regression_residuals  # noqa: E402

T = 1e-3


def chain_record(seed: int, seconds: float) -> np.ndarray:
    """[Utx, Uty, Ux, Uy] of the seed chain's DTG at 1 kHz (V), after a 1 s settling."""
    sim = DTGSimulator(paper_set(), rebalance=True, noise_std=1e-3, dither_std=1.0,
                       seed=seed)
    n = round((seconds + 1.0) / T)
    rec = np.empty((n, 4))
    for k in range(n):
        sim.advance((k + 1) * T, 0.0, 0.0)
        rec[k, :2] = sim.pickoff
        rec[k, 2:] = sim.torquer_mean
    return rec[round(1.0 / T):]


def x_residual_variance(rec: np.ndarray, learn: int, noise_v: float, seed: int) -> float:
    """Variance of the x regression residual after the learning window, with white noise
    of ``noise_v`` (V) on the Ux read-out, θ from the fault-free learning window."""
    def filtered(r: np.ndarray) -> np.ndarray:
        f = ButterworthPrefilter(6, 50.0, 1.0 / T, 4)
        return np.array([f.step(row.tolist()) for row in r])

    clean = filtered(rec)
    tx, ty = clean[2:learn, 0], clean[2:learn, 1]
    phi = np.column_stack([clean[1:learn - 1, 0], -clean[:learn - 2, 0], -ty,
                           clean[1:learn - 1, 1], clean[2:learn, 2]])
    theta = np.linalg.lstsq(phi, tx, rcond=None)[0]
    faulty = rec.copy()
    faulty[learn:, 2] += noise_v * np.random.default_rng(seed + 99).standard_normal(
        rec.shape[0] - learn)
    e = regression_residuals(filtered(faulty)[learn - 2:], theta)[:, 0]
    return float(np.var(e[50:]))  # past the prefilter's transient at the onset


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=8)
    ap.add_argument("--learn-s", type=float, default=4.0)
    ap.add_argument("--noise", type=float, nargs="+", default=[0.1, 0.3, 0.4, 0.5, 1.0])
    args = ap.parse_args()
    learn = round(args.learn_s / T)
    learned, total, res = [], [], {sn: [] for sn in [0.0, *args.noise]}
    for seed in range(args.seeds):
        rec = chain_record(seed, 2 * args.learn_s)
        ux = rec[:, 2]
        learned.append(float(np.var(ux[:learn])))
        total.append(float(np.var(ux)))
        for sn in res:
            res[sn].append(x_residual_variance(rec, learn, sn, seed))
    v = float(np.mean(total))
    rel_se = float(np.std(learned, ddof=1) / np.mean(learned))
    arl0 = 10 * 3600 / T
    h = math.log(arl0)
    v_res = np.array(res[0.0])
    print(f"var(Ux) = {v:.4f} V^2 (std {math.sqrt(v):.3f} V) over {args.seeds} seeds; "
          f"learned over {args.learn_s:g} s: relative standard error {100 * rel_se:.1f} %")
    print(f"optimal sequential test at ARL0 = 10 h ({arl0:.2g} samples): h = ln ARL0 = "
          f"{h:.1f}; delays are Lorden's lower bound h/KL for white samples")
    print("noise V | Ux: ratio r | (r-1)/learned s.e. | min. delay s | x residual: ratio r"
          " (seed range) | min. delay s")
    for sn in args.noise:
        r = 1.0 + sn * sn / v
        kl = 0.5 * (r - 1.0 - math.log(r))
        ratios = np.array(res[sn]) / v_res
        rr = float(np.mean(ratios))
        kl_res = 0.5 * (rr - 1.0 - math.log(rr))
        print(f"{sn:7g} | {r:11.3f} | {(r - 1.0) / rel_se:18.1f} | {h / kl * T:12.2f} | "
              f"{rr:7.3f} ({ratios.min():.3f}-{ratios.max():.3f}) | "
              f"{h / kl_res * T:12.2f}")


if __name__ == "__main__":
    main()
