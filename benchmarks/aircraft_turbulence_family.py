"""Aircraft loop in turbulence at library level: false alarms, detection, isolation.

Usage::

    nice -n 10 .venv/bin/python benchmarks/aircraft_turbulence_family.py [--workers 2]
        [--nominal-runs 18] [--nominal-s 600] [--fault-seeds 4] [--master-seed 3311]
        [--out campaigns/results/aircraft_turbulence]

The seed loop (the Aircraft and PitchController FMUs' Python cores, 100 Hz, sensor noise
1 σ: v 0.05 m/s, α/ϑ/γ 1e-3 rad, q 1e-3 rad/s, h 0.2 m; level flight) in Dryden
turbulence, with the detection-filter channel at the Diagnoser's defaults (sequential
rule with its gust model, 10 s calibration). Conditions are drawn, not gridded: each run
draws its seed, its fault onset (30–40 s) and, for the onset/cessation conditions, the
time turbulence starts or stops, from the master seed.

* nominal: calm, light 0.77, moderate 1.5, severe 2.3 m/s, calm → moderate, calm →
  severe, moderate → calm, light → moderate; ``--nominal-runs`` runs of ``--nominal-s``
  each; an alarm is a rising edge of ``detected``;
* faults on α, q, ϑ: biases 2–50 σ, gains, stuck, noise, ramps, in calm, light, moderate
  and severe air, Gauss-Seidel and Jacobi pairing (y one sample after its u); judged 6 s
  after the onset (detection), isolated sensor and type at the end (12 s after).

Writes ``summary.json`` and ``summary.md`` (with the commit and the hash of the library
sources) under ``--out``, and prints the tables. Library level: the FMUs' own runs are
the seed scenarios ``scenarios/aircraft_turbulence_*``.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from typing import Any

import numpy as np
from _provenance import library_provenance

ROOT = Path(__file__).resolve().parents[1]
for _sub in ("fmu_src", "tests"):
    sys.path.insert(0, str(ROOT / _sub))

from _turbulence_loop import NOISE, T, fly  # noqa: E402

from gyrodiag.df.channel import DFChannel, DFChannelConfig  # noqa: E402

SENSORS = {2: "alpha", 3: "q", 4: "theta"}  # 1-based, as df.isolated_sensor
LEVELS = {"calm": 0.0, "light": 0.77, "moderate": 1.5, "severe": 2.3}
#: nominal conditions: (before, after) intensities; a change happens at a drawn time
NOMINAL = {"calm": ("calm", "calm"), "light": ("light", "light"),
           "moderate": ("moderate", "moderate"), "severe": ("severe", "severe"),
           "calm->moderate": ("calm", "moderate"), "calm->severe": ("calm", "severe"),
           "moderate->calm": ("moderate", "calm"), "light->moderate": ("light", "moderate")}
FAULTS = ([("bias", s) for s in (2.0, 5.0, 10.0, 20.0, 50.0)]
          + [("gain", 1.2), ("gain", 1.5), ("stuck", 0.0), ("noise", 3.0), ("ramp", 2e-3)])
TYPE_CODE = {"bias": 1, "gain": 2, "stuck": 3, "noise": 5, "ramp": 6}


def sensor_fault(kind: str, size: float, sensor: int, onset: float, rng_seed: int) -> Any:
    i = sensor - 1
    rng = np.random.default_rng(rng_seed)
    held: list[float] = []

    def apply(t: float, y: np.ndarray) -> np.ndarray:
        if t < onset - 1e-9:
            return y
        y = y.copy()
        if kind == "bias":
            y[i] += size * NOISE[i]
        elif kind == "gain":
            y[i] *= size
        elif kind == "stuck":
            if not held:
                held.append(float(y[i]))
            y[i] = held[0]
        elif kind == "noise":
            y[i] += size * NOISE[i] * rng.standard_normal()
        elif kind == "ramp":
            y[i] += size * (t - onset)
        return y

    return apply


def run_channel(u: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, Any]:
    ch = DFChannel(DFChannelConfig(sample_period_s=T))
    detected = np.zeros(len(u), dtype=bool)
    out = None
    for k in range(len(u)):
        out = ch.update(u[k], y[k])
        detected[k] = out.detected
    return detected, out


def nominal_run(job: dict[str, Any]) -> dict[str, Any]:
    before, after = (LEVELS[x] for x in NOMINAL[job["condition"]])
    change = job["change_s"]
    u, y = fly(job["duration_s"], lambda t: before if t < change else after, job["seed"])
    detected, _ = run_channel(u, y)
    k0 = round(12.0 / T)  # after the calibration window
    alarms = int(np.count_nonzero(np.diff(detected[k0:].astype(int)) > 0)
                 + int(detected[k0]))
    return {**job, "alarms": alarms, "alarm_fraction": float(detected[k0:].mean())}


def fault_run(job: dict[str, Any]) -> dict[str, Any]:
    sigma = LEVELS[job["condition"]]
    onset = job["onset_s"]
    f = sensor_fault(job["type"], job["size"], job["sensor"], onset, job["seed"] + 17)
    u, y = fly(onset + 12.0, lambda t: sigma, job["seed"], f, job["coupling"] == "jacobi")
    detected, out = run_channel(u, y)
    k0 = round(onset / T)
    before = bool(detected[round(12.0 / T):k0].any())
    hit = np.flatnonzero(detected[k0:])
    delay = float(hit[0] * T) if hit.size else None
    iso = int(out.isolated_sensor)
    wrong = (iso > 0 and iso != job["sensor"]) or (
        iso == -2 and not out.isolated_mask & (1 << (job["sensor"] - 1)))
    return {**job, "false_alarm_before": before, "delay_s": delay,
            "detected_6s": delay is not None and delay <= 6.0,
            "isolated": iso, "right_sensor": iso == job["sensor"], "wrong_sensor": bool(wrong),
            "typed": int(out.fault_type),
            "right_type": int(out.fault_type) == TYPE_CODE[job["type"]]}


def plan(args: argparse.Namespace) -> tuple[list[dict[str, Any]], list[dict[str, Any]]]:
    rng = np.random.default_rng(args.master_seed)
    nominal = []
    for cond in NOMINAL:
        runs = args.nominal_runs if cond != "calm" else max(2, args.nominal_runs // 4)
        for _ in range(runs):
            nominal.append({"condition": cond, "seed": int(rng.integers(1, 2**31)),
                            "duration_s": args.nominal_s,
                            "change_s": float(rng.uniform(30.0, args.nominal_s - 60.0))})
    faults = []
    for cond in LEVELS:
        for kind, size in FAULTS:
            for sensor in SENSORS:
                for coupling in ("gauss-seidel", "jacobi"):
                    for _ in range(args.fault_seeds // 2 or 1):
                        faults.append({"condition": cond, "type": kind, "size": size,
                                       "sensor": sensor, "coupling": coupling,
                                       "seed": int(rng.integers(1, 2**31)),
                                       "onset_s": float(rng.uniform(30.0, 40.0))})
    return nominal, faults


def summarise(nominal: list[dict[str, Any]], faults: list[dict[str, Any]]) -> dict[str, Any]:
    by_cond: dict[str, dict[str, float]] = {}
    for r in nominal:
        row = by_cond.setdefault(r["condition"], {"runs": 0, "hours": 0.0, "alarms": 0})
        row["runs"] += 1
        row["hours"] += (r["duration_s"] - 12.0) / 3600.0
        row["alarms"] += r["alarms"]
    cells: dict[str, dict[str, Any]] = {}
    for r in faults:
        key = f"{r['condition']}|{r['type']} {r['size']:g}"
        c = cells.setdefault(key, {"runs": 0, "detected_6s": 0, "right_sensor": 0,
                                   "wrong_sensor": 0, "right_type": 0, "delays": []})
        c["runs"] += 1
        c["detected_6s"] += r["detected_6s"]
        c["right_sensor"] += r["right_sensor"]
        c["wrong_sensor"] += r["wrong_sensor"]
        c["right_type"] += r["right_type"]
        if r["delay_s"] is not None:
            c["delays"].append(r["delay_s"])
    for c in cells.values():
        d = c.pop("delays")
        c["median_delay_s"] = float(np.median(d)) if d else None
    turb_hours = sum(v["hours"] for k, v in by_cond.items() if k != "calm")
    return {"nominal": by_cond, "turbulence_hours": turb_hours,
            "turbulence_alarms": sum(v["alarms"] for k, v in by_cond.items() if k != "calm"),
            "faults": cells}


def markdown(summary: dict[str, Any], meta: dict[str, Any]) -> str:
    lines = ["# Aircraft loop in turbulence (library level)", "",
             f"Commit {meta['commit']} (dirty: {meta['dirty']}), library sources sha256 "
             f"{meta['library_sha256'][:16]}…, master seed {meta['master_seed']}; "
             f"command: `{meta['command']}`.", "",
             "## Fault-free", "", "| condition | runs | hours | alarms |", "|---|---|---|---|"]
    for cond, r in summary["nominal"].items():
        lines.append(f"| {cond} | {r['runs']} | {r['hours']:.2f} | {r['alarms']} |")
    lines += ["", f"Turbulence hours (onsets and cessations included): "
              f"{summary['turbulence_hours']:.1f}, alarms {summary['turbulence_alarms']}.",
              "", "## Faults on α, q, ϑ (both couplings)", "",
              "| air | fault | runs | detected ≤ 6 s | right sensor | wrong sensor "
              "| right type | median delay (s) |",
              "|---|---|---|---|---|---|---|---|"]
    for key, c in summary["faults"].items():
        air, fault = key.split("|")
        delay = "–" if c["median_delay_s"] is None else f"{c['median_delay_s']:.2f}"
        lines.append(f"| {air} | {fault} | {c['runs']} | {c['detected_6s']} | "
                     f"{c['right_sensor']} | {c['wrong_sensor']} | {c['right_type']} | {delay} |")
    return "\n".join(lines) + "\n"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--nominal-runs", type=int, default=18)
    ap.add_argument("--nominal-s", type=float, default=600.0)
    ap.add_argument("--fault-seeds", type=int, default=4)
    ap.add_argument("--master-seed", type=int, default=3311)
    ap.add_argument("--out", type=Path, default=ROOT / "campaigns" / "results" /
                    "aircraft_turbulence")
    args = ap.parse_args()
    nominal_jobs, fault_jobs = plan(args)
    origin = library_provenance(ROOT)  # the code the runs use, taken before they start
    start = time.perf_counter()
    with ProcessPoolExecutor(args.workers) as pool:
        faults = list(pool.map(fault_run, fault_jobs, chunksize=4))
        nominal = list(pool.map(nominal_run, nominal_jobs))
    summary = summarise(nominal, faults)
    meta = {**origin, "master_seed": args.master_seed,
            "wall_s": round(time.perf_counter() - start, 1),
            "command": "benchmarks/aircraft_turbulence_family.py " + " ".join(sys.argv[1:])}
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "summary.json").write_text(json.dumps(
        {"meta": meta, "summary": summary, "nominal_runs": nominal, "fault_runs": faults},
        indent=1) + "\n", encoding="utf-8")
    text = markdown(summary, meta)
    (args.out / "summary.md").write_text(text, encoding="utf-8")
    print(text)
    print(f"wall {meta['wall_s']} s")


if __name__ == "__main__":
    main()
