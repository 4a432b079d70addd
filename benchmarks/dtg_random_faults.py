"""DTG bench at the Diagnoser's defaults: faults drawn at random, named at the end.

Usage::

    nice -n 10 .venv/bin/python benchmarks/dtg_random_faults.py [--workers 2]
        [--signal-runs 100] [--physical-runs 40] [--master-seed 34]
        [--out campaigns/results/dtg_random_faults]

The seed bench (paper set, rebalance loop, 1 mV pick-off noise, 1 V dither, 1 kHz) and
the DTG channel as the Diagnoser runs it by default (shipped pattern library, automatic
bench settings). Every run draws its bench seed and its onset (6–12 s, judged 12 s
after it) from the master seed, and then:

* signal faults: a step (±0.05–1 V, log-uniform), a drift (±0.02–2 V/s), noise
  (0.05–0.5 V) or a loss on one of Utx, Uty, Ux, Uy;
* physical faults: a spin slow-down or a torquer scale change of ±2–15 % (uniform);
* pairs: steps of ±0.1–1 V on two signals at the same instant, or the second 2–5 s
  after the first.

With ``--nominal-runs N --nominal-s S``, N fault-free runs of S seconds (bench seeds
drawn too) count the alarms (rising edges) after the learning window.

Right = the class named at the end of the run (a pair: both signals named). Writes
``summary.json`` (with every run) and ``summary.md`` under ``--out`` with the commit and
the hash of the library sources, and prints the tables. Figures only, no assertions.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from collections import defaultdict
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from typing import Any

import numpy as np
from _provenance import library_provenance

ROOT = Path(__file__).resolve().parents[1]
for _sub in ("fmu_src", "models/dtg"):
    sys.path.insert(0, str(ROOT / _sub))

from gd_dtg_sets import paper_set  # noqa: E402
from gd_dtg_sim import DTGSimulator  # noqa: E402

from gyrodiag.dtg import DTGChannel, DTGChannelConfig, default_library  # noqa: E402

T = 1e-3
SIGNALS = ("utx", "uty", "ux", "uy")
SIGNAL_KINDS = ("step", "drift", "noise", "loss")


def bench(seconds: float, seed: int, onset: float | None = None,
          **fault: float) -> np.ndarray:
    """[Utx, Uty, Ux, Uy] (V) at 1 kHz; ``fault`` (plant parameters) from ``onset``."""
    sim = DTGSimulator(paper_set(), rebalance=True, noise_std=1e-3, dither_std=1.0,
                       seed=seed)
    n = round(seconds / T)
    k_on = None if onset is None else round(onset / T)
    rec = np.empty((n, 4))
    for k in range(n):
        if k == k_on:
            sim.set_faults(**fault)
        sim.advance((k + 1) * T, 0.0, 0.0)
        rec[k, :2] = sim.pickoff
        rec[k, 2:] = sim.torquer_mean
    return rec


def plan(args: argparse.Namespace) -> list[dict[str, Any]]:
    """The drawn runs: signal faults, then physical faults and pairs."""
    rng = np.random.default_rng(args.master_seed)
    jobs = []
    for _ in range(args.signal_runs):
        kind, sig = SIGNAL_KINDS[int(rng.integers(4))], int(rng.integers(4))
        sign = float(rng.choice([-1.0, 1.0]))
        size = {"step": sign * 10 ** rng.uniform(np.log10(0.05), 0.0),
                "drift": sign * 10 ** rng.uniform(np.log10(0.02), np.log10(2.0)),
                "noise": 10 ** rng.uniform(np.log10(0.05), np.log10(0.5)),
                "loss": 0.0}[kind]
        jobs.append({"family": "signal", "kind": kind, "signal": SIGNALS[sig],
                     "size": round(size, 4), "seed": int(rng.integers(1000, 9999)),
                     "onset": round(float(rng.uniform(6.0, 12.0)), 3)})
    for _ in range(args.physical_runs):
        kind = ("spin", "torquer", "pair", "sequential")[int(rng.integers(4))]
        job: dict[str, Any] = {"family": "physical" if kind in ("spin", "torquer") else "pair",
                               "kind": kind, "seed": int(rng.integers(1000, 9999)),
                               "onset": round(float(rng.uniform(6.0, 12.0)), 3)}
        if kind in ("spin", "torquer"):
            pct = float(rng.uniform(2.0, 15.0))
            sign = 1.0 if kind == "torquer" and rng.random() < 0.5 else -1.0
            job["ratio"] = round(1.0 + sign * pct / 100.0, 4)
        else:
            a, b = (int(v) for v in rng.choice(4, 2, replace=False))
            sa, sb = (float(rng.choice([-1.0, 1.0]) * 10 ** rng.uniform(-1.0, 0.0))
                      for _ in range(2))
            job.update(a=SIGNALS[a], sa=round(sa, 3), b=SIGNALS[b], sb=round(sb, 3),
                       second=job["onset"] + (0.0 if kind == "pair"
                                              else round(float(rng.uniform(2.0, 5.0)), 2)))
        jobs.append(job)
    return jobs


def nominal_run(job: dict[str, Any]) -> dict[str, Any]:
    """A fault-free run: the alarms' rising edges and the classes they named."""
    seconds = job["seconds"]
    rec = bench(seconds, job["seed"])
    ch = DTGChannel(DTGChannelConfig(patterns=default_library()))
    was, alarms, names = False, 0, []
    for row in rec:
        o = ch.update(*row)
        if o.alarm and not was:
            alarms += 1
            names.append(o.diagnosis.class_name)
        was = o.alarm
    return {**job, "alarms": alarms, "names": names}


def run(job: dict[str, Any]) -> dict[str, Any]:
    """One drawn run through the channel; what it named and when."""
    onset, seconds = job["onset"], job["onset"] + 12.0
    t = (np.arange(round(seconds / T)) + 1) * T
    after = t > onset
    if job["kind"] in ("spin", "torquer"):
        name = "spin_fraction" if job["kind"] == "spin" else "torquer_scale"
        rec = bench(seconds, job["seed"], onset, **{name: job["ratio"]})
        want = {job["kind"]}
    else:
        rec = bench(seconds, job["seed"])
        if job["family"] == "pair":
            a, b = SIGNALS.index(job["a"]), SIGNALS.index(job["b"])
            rec[after, a] += job["sa"]
            rec[t > job["second"], b] += job["sb"]
            want = {f"{job['a']}_step+{job['b']}_step", f"{job['b']}_step+{job['a']}_step"}
        else:
            s = SIGNALS.index(job["signal"])
            noise = np.random.default_rng(job["seed"] + 1).standard_normal(int(after.sum()))
            rec[after, s] = {"step": rec[after, s] + job["size"],
                             "drift": rec[after, s] + job["size"] * (t[after] - onset),
                             "noise": rec[after, s] + job["size"] * noise,
                             "loss": 0.0 * rec[after, s]}[job["kind"]]
            want = {f"{job['signal']}_{job['kind']}"}
    ch = DTGChannel(DTGChannelConfig(patterns=default_library()))
    first, before, names = None, False, []
    for k, row in enumerate(rec):
        o = ch.update(*row)
        if o.alarm and not after[k]:
            before = True
        if o.alarm and after[k] and first is None:
            first = float(t[k] - onset)
        if first is not None:
            names.append(o.diagnosis.class_name if o.alarm else "")
    end = names[-1] if names else ""
    tail = names[3000:]
    return {**job, "delay_s": None if first is None else round(first, 3),
            "alarm_before_onset": before, "end": end, "right": end in want,
            "right_share_after_3s": round(float(np.mean([n in want for n in tail])), 3)
            if tail else 0.0,
            "ratio_estimate": (float(ch.diagnosis.ratio) if job["kind"] in ("spin", "torquer")
                               else None)}


def summarise(runs: list[dict[str, Any]]) -> dict[str, Any]:
    cells: dict[str, dict[str, Any]] = defaultdict(lambda: {"runs": 0, "right": 0,
                                                            "detected": 0, "delays": []})
    for r in runs:
        key = (f"{r['kind']} on {r['signal']}" if r["family"] == "signal"
               else r["kind"])
        c = cells[key]
        c["runs"] += 1
        c["right"] += int(r["right"])
        if r["delay_s"] is not None:
            c["detected"] += 1
            c["delays"].append(r["delay_s"])
    out = {k: {"runs": c["runs"], "right": c["right"], "detected": c["detected"],
               "median_delay_s": float(np.median(c["delays"])) if c["delays"] else None}
           for k, c in sorted(cells.items())}
    return {"cells": out, "runs": len(runs), "right": sum(r["right"] for r in runs),
            "alarms_before_onset": sum(r["alarm_before_onset"] for r in runs),
            "wrong": [{k: r[k] for k in r if k not in ("family",)}
                      for r in runs if not r["right"]]}


def markdown(summary: dict[str, Any], meta: dict[str, Any]) -> str:
    lines = ["# DTG bench at the defaults: drawn faults (library level)", "",
             f"Commit {meta['commit']} (dirty: {meta['dirty']}), library sources sha256 "
             f"{meta['library_sha256'][:16]}…, master seed {meta['master_seed']}; "
             f"command: `{meta['command']}`.", "",
             f"{summary['right']} of {summary['runs']} named right at the end; alarms "
             f"before the onset: {summary['alarms_before_onset']}.", "",
             f"Fault-free: {summary['nominal']['runs']} runs, "
             f"{summary['nominal']['hours']:.2f} h, {summary['nominal']['alarms']} alarms.",
             "",
             "| fault | runs | detected | right at the end | median delay (s) |",
             "|---|---|---|---|---|"]
    for key, c in summary["cells"].items():
        delay = "–" if c["median_delay_s"] is None else f"{c['median_delay_s']:.3f}"
        lines.append(f"| {key} | {c['runs']} | {c['detected']} | {c['right']} | {delay} |")
    if summary["wrong"]:
        lines += ["", "Not right at the end:", ""]
        lines += [f"- {json.dumps(w)}" for w in summary["wrong"]]
    return "\n".join(lines) + "\n"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--signal-runs", type=int, default=100)
    ap.add_argument("--physical-runs", type=int, default=40)
    ap.add_argument("--nominal-runs", type=int, default=0)
    ap.add_argument("--nominal-s", type=float, default=1800.0)
    ap.add_argument("--master-seed", type=int, default=34)
    ap.add_argument("--out", type=Path, default=ROOT / "campaigns" / "results" /
                    "dtg_random_faults")
    args = ap.parse_args()
    jobs = plan(args)
    origin = library_provenance(ROOT)  # the code the runs use, taken before they start
    start = time.perf_counter()
    nominal_rng = np.random.default_rng([args.master_seed, 1])
    nominal_jobs = [{"seed": int(nominal_rng.integers(10000, 99999)),
                     "seconds": args.nominal_s} for _ in range(args.nominal_runs)]
    with ProcessPoolExecutor(args.workers) as pool:
        nominal = list(pool.map(nominal_run, nominal_jobs))
        runs = list(pool.map(run, jobs))
    summary = summarise(runs)
    summary["nominal"] = {"runs": len(nominal),
                          "hours": round(sum(j["seconds"] for j in nominal) / 3600.0, 3),
                          "alarms": sum(r["alarms"] for r in nominal)}
    meta = {**origin, "master_seed": args.master_seed,
            "wall_s": round(time.perf_counter() - start, 1),
            "command": "benchmarks/dtg_random_faults.py " + " ".join(sys.argv[1:])}
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "summary.json").write_text(json.dumps(
        {"meta": meta, "summary": summary, "runs": runs, "nominal_runs": nominal},
        indent=1) + "\n",
        encoding="utf-8")
    text = markdown(summary, meta)
    (args.out / "summary.md").write_text(text, encoding="utf-8")
    print(text)
    print(f"wall {meta['wall_s']} s")


if __name__ == "__main__":
    main()
