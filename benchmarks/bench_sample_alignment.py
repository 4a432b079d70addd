"""Per-sample cost of the sample-alignment options of the DTG and detection-filter channels.

Usage::

    .venv/bin/python benchmarks/bench_sample_alignment.py [--seconds 14] [--repeat 3]

Runs the library system chain (tests/_system_chain.py: aircraft + LQR + paper DTG at 1 kHz,
0.1 rad doublets from 10 s in σ_w 1.5 m/s turbulence) once, then times, in this process
(CPU time, best of ``--repeat``), each channel on the same record:

* DTG channel (case rate, ratio band, pattern-free): aligned (d = 0), the fixed delay
  d = 1 on a record whose case rate is one sample ahead, and the opt-in aligner
  (``case_rate_align_max`` = 2) on that record, with its chosen delay and switches;
* detection filter (paper rule): no skew, and ``sensor_delay_samples[2]`` = 1 on a record
  whose q is one sample late.

Prints µs per sample and the ratio to the aligned run; no assertions.
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

from gyrodiag.df.channel import DFChannel, DFChannelConfig  # noqa: E402
from gyrodiag.dtg.channel import DTGChannel, DTGChannelConfig  # noqa: E402

T = 1e-3
DTG = dict(classifier="paper", forgetting=0.9998, learn_start_s=2.0, learn_end_s=10.0,
           low=0.93, high=1.07, persistence_k=100, persistence_n=200, case_rate="central")


def _best(fn, repeat: int) -> tuple[float, object]:
    best, result = float("inf"), None
    for _ in range(repeat):
        t0 = time.process_time()
        result = fn()
        best = min(best, time.process_time() - t0)
    return best, result


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=14.0, help="simulated time, s")
    ap.add_argument("--repeat", type=int, default=3, help="timed runs per case (best)")
    args = ap.parse_args()
    o = run_chain(args.seconds, command=PitchCommand(3, 0.1, start=10.0, pulse=0.5,
                                                     period=5.0), sigma_w=1.5)
    n = o["y_q"].size
    ahead = np.clip(np.arange(n) + 1, 0, n - 1)
    dtg = {0: np.column_stack([o["Utx"], o["Uty"], o["Ux"], o["Uy"], np.zeros(n), o["y_q"]])}
    dtg[1] = dtg[0].copy()
    dtg[1][:, 5] = o["y_q"][ahead]

    def run_dtg(rows: np.ndarray, **kw) -> DTGChannel:
        ch = DTGChannel(DTGChannelConfig(**{**DTG, **kw}))
        for r in rows.tolist():
            ch.update(*r)
        return ch

    print(f"{n} samples at 1 kHz, best of {args.repeat} (CPU time)")
    base, _ = _best(lambda: run_dtg(dtg[0]), args.repeat)
    print(f"DTG channel, aligned:            {1e6 * base / n:7.1f} µs/sample")
    t, ch = _best(lambda: run_dtg(dtg[1], case_rate_delay_samples=1), args.repeat)
    print(f"DTG channel, fixed d = 1:        {1e6 * t / n:7.1f} µs/sample ({t / base:.2f}×)")
    t, ch = _best(lambda: run_dtg(dtg[1], case_rate_align_max=2), args.repeat)
    print(f"DTG channel, aligner (max 2):    {1e6 * t / n:7.1f} µs/sample ({t / base:.2f}×), "
          f"delay {ch.case_rate_delay}, {ch.case_rate_switches} switch(es)")

    u = np.column_stack([np.zeros(n), o["elevator"]])
    y = np.column_stack([o["y_v"], o["y_alpha"], o["y_q"], o["y_theta"], o["y_gamma"],
                         o["y_h"]])
    late = y.copy()
    late[1:, 2] = y[:-1, 2]
    cfg = dict(sample_period_s=T, decision="paper", calibrate_s=8.0, burn_in_s=2.0,
               align_auto=False)

    def run_df(yy: np.ndarray, **kw) -> DFChannel:
        ch = DFChannel(DFChannelConfig(**cfg, **kw))
        for a, b in zip(u.tolist(), yy.tolist(), strict=True):
            ch.update_floats(a, b)
        return ch

    base, _ = _best(lambda: run_df(y), args.repeat)
    print(f"detection filter, no skew:       {1e6 * base / n:7.1f} µs/sample")
    t, _ = _best(lambda: run_df(late, sensor_delay_samples=[0, 0, 1, 0, 0, 0]), args.repeat)
    print(f"detection filter, q one late:    {1e6 * t / n:7.1f} µs/sample ({t / base:.2f}×)")


if __name__ == "__main__":
    main()
