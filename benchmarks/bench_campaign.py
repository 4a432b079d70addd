"""Campaign throughput with 1 and 2 workers, and the parallel efficiency, in one run.

::

    .venv/bin/python benchmarks/bench_campaign.py [--runs 8] [--duration 4] [--dask]

Runs the same campaign (``--runs`` aircraft runs of the smoke campaign's kind:
campaigns/smoke.toml's class, q bias 0.1 rad/s at 3 s, one seed each, ``--duration`` s
at 100 Hz) twice into fresh temporary folders, with 1 and with 2 workers (process pool,
or a dask LocalCluster with ``--dask``), and prints runs per minute and the parallel
efficiency ``throughput(2) / (2 * throughput(1))``, after one untimed warm-up run.
Each run is a fresh process, so the figures include process start-up and FMU loading
(about 1.5 s per run).
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from gyrodiag_harness.campaigns.campaign import CampaignSpec, load_campaign, run_campaign  # noqa: E402


def spec_for(runs: int, duration_s: float) -> tuple[CampaignSpec, Path]:
    smoke, base = load_campaign(ROOT / "campaigns" / "smoke.toml")
    data = smoke.model_dump(by_alias=True)
    data.update(name="bench", sweeps=[{
        "class": "aircraft", "type": "bias", "magnitudes": [0.1], "onsets_s": [3.0],
        "channels": [3], "seeds": runs, "duration_s": duration_s}], nominal=[])
    return CampaignSpec.model_validate(data), base


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--runs", type=int, default=8)
    ap.add_argument("--duration", type=float, default=4.0, help="simulated s per run")
    ap.add_argument("--dask", action="store_true", help="dask LocalCluster, not the pool")
    args = ap.parse_args()
    spec, base = spec_for(args.runs, args.duration)
    print(f"campaign: {args.runs} aircraft runs of {args.duration:g} s at 100 Hz, "
          f"{'dask LocalCluster' if args.dask else 'process pool'}, {os.cpu_count()} CPUs")
    # one untimed run first: the first process start reads every file from disk
    warm, _ = spec_for(1, args.duration)
    with tempfile.TemporaryDirectory(prefix="gd-bench-campaign-") as tmp:
        run_campaign(warm, base, Path(tmp), workers=1, progress=False)
    throughput = {}
    for workers in (1, 2):
        with tempfile.TemporaryDirectory(prefix="gd-bench-campaign-") as tmp:
            t0 = time.perf_counter()
            out = run_campaign(spec, base, Path(tmp), workers=workers,
                               dask="local" if args.dask else None, progress=False)
            wall = time.perf_counter() - t0
        if out.failed:
            raise SystemExit(f"{len(out.failed)} runs failed: "
                             f"{[r.get('error') for r in out.records if r['status'] != 'ok']}")
        per_run = sum(r["wall_s"] for r in out.records) / len(out.records)
        throughput[workers] = 60.0 * out.n_executed / wall
        print(f"{workers} worker(s): {out.n_executed} runs in {wall:.1f} s = "
              f"{throughput[workers]:.1f} runs/min (mean {per_run:.2f} s per run incl. "
              f"process start)")
    eff = throughput[2] / (2 * throughput[1])
    print(f"speed-up {throughput[2] / throughput[1]:.2f}, parallel efficiency {eff:.0%}")


if __name__ == "__main__":
    main()
