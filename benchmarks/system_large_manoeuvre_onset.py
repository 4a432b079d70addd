"""DTG channel false alarms at the onset of a large fault-free manoeuvre (system chain).

Usage::

    nice -n 5 .venv/bin/python benchmarks/system_large_manoeuvre_onset.py
        [--seeds 51-70] [--amplitude 0.25] [--kind step] [--duration 15] [--workers 2]
        [--turbulence 0] [--patterns FILE]

Found 2026-11-26 (issue 12, outside the campaign's manoeuvres): the system scenario
``system_nominal_step_small`` with its 0.005 rad step at 12 s replaced by a larger one,
in level flight without turbulence, one run per DTG seed (``dtg.seed``; the aircraft's
seed stays 2), the detection filter off (it does not feed the DTG channel). A 0.25 rad
step makes the DTG channel's residual test alarm 50 ms after the edge in some seeds (the
x residual's 2 s variance ratio over 2: the reference θ0 learned in level flight is off
in a direction the edge excites by more than its allowance), and an alarm stops the
reference refinement, so it can last to the end of the run.

Prints, per seed, the first alarm time and the fraction of the run after the onset in
alarm, then the count of seeds with an alarm. No assertions; the FMUs come from
``build/fmus`` (built first if stale) or ``$GYRODIAG_FMU_DIR``; the DTG pattern library
from ``--patterns`` (e.g. ``results/latest/dtg_patterns.json`` of ``harness all``), else it
is learned first from ``scenarios/training/patterns`` (~2 min).
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from harness.cosim.batch import run_all  # noqa: E402
from harness.cosim.scenario import load_scenario  # noqa: E402

BASE = ROOT / "scenarios" / "system_nominal_step_small.toml"


def _seeds(text: str) -> list[int]:
    out: list[int] = []
    for part in text.split(","):
        lo, _, hi = part.partition("-")
        out.extend(range(int(lo), int(hi or lo) + 1))
    return out


def _scenario_text(seed: int, kind: str, amplitude: float, duration: float,
                   turbulence: float, patterns: Path) -> str:
    text = BASE.read_text(encoding="utf-8")
    replacements = {
        "duration_s = 32.0": f"duration_s = {duration!r}",
        "seed = 5, noise_std": f"seed = {seed}, noise_std",
        '"df.enabled" = true': '"df.enabled" = false',
        "${out}/dtg_patterns.json": str(patterns.resolve()),
        'kind = "step"': f'kind = "{kind}"',
        "amplitude_rad = 0.005": f"amplitude_rad = {amplitude!r}"
        + ("\nperiod_s = 8.0" if kind == "square_wave" else ""),
        'name = "system_nominal_step_small"': f'name = "large_onset_{seed}"',
    }
    for old, new in replacements.items():
        if old not in text:
            raise SystemExit(f"{BASE.name} changed: {old!r} not found; update this script")
        text = text.replace(old, new, 1)
    if turbulence > 0:
        text = text.replace("seed = 2 }", f"seed = 2, turbulence_sigma_w = {turbulence!r} }}", 1)
    # judge nothing: the run's alarm signal is read here
    return text[:text.index("[[expect]]")] if "[[expect]]" in text else text


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", default="51-70", help="DTG seeds, e.g. 51-70 or 5,7")
    parser.add_argument("--amplitude", type=float, default=0.25, help="rad")
    parser.add_argument("--kind", default="step", choices=["step", "square_wave"])
    parser.add_argument("--duration", type=float, default=15.0, help="run length, s")
    parser.add_argument("--turbulence", type=float, default=0.0, help="sigma_w, m/s")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--patterns", type=Path, default=None,
                        help="DTG pattern library .json (default: learned first)")
    args = parser.parse_args(argv)
    fmu_dir = Path(os.environ.get("GYRODIAG_FMU_DIR", ROOT / "build" / "fmus"))
    subprocess.run([sys.executable, str(ROOT / "build_fmu.py"), "--out", str(fmu_dir)],
                   check=True, capture_output=True)
    with tempfile.TemporaryDirectory(prefix="gyrodiag-onset-") as tmp:
        out = Path(tmp)
        patterns = args.patterns
        if patterns is None:
            patterns = out / "dtg_patterns.json"
            subprocess.run([sys.executable, "-m", "harness", "learn-signatures",
                            str(ROOT / "scenarios" / "training" / "patterns"), "--out",
                            str(patterns), "--fmu-dir", str(fmu_dir), "--no-progress",
                            "--workers", str(args.workers)],
                           check=True, capture_output=True, cwd=ROOT)
        elif not patterns.is_file():
            parser.error(f"--patterns: no such file {patterns}")
        seeds = _seeds(args.seeds)
        scenarios = []
        for seed in seeds:
            path = out / f"large_onset_{seed}.toml"
            path.write_text(_scenario_text(seed, args.kind, args.amplitude, args.duration,
                                           args.turbulence, patterns), encoding="utf-8")
            scenarios.append(load_scenario(path))
        results = run_all(scenarios, out / "runs", fmu_dir, progress=False,
                          workers=args.workers)
        alarmed = 0
        print(f"{args.kind} {args.amplitude:g} rad at 12 s, turbulence {args.turbulence:g} "
              f"m/s, DTG seeds {args.seeds}")
        for seed, res in zip(seeds, results, strict=True):
            if res.error is not None:
                print(f"dtg.seed {seed}: ERROR {res.error.splitlines()[0]}")
                continue
            t = np.asarray(res.time)
            alarm = np.asarray(res.signals["diag.dtg.alarm"]) > 0.5
            after = t >= 12.0
            first = t[alarm][0] if alarm.any() else None
            alarmed += first is not None
            print(f"dtg.seed {seed}: first alarm "
                  f"{'-' if first is None else f'{first:.3f} s'}, "
                  f"{alarm[after].mean():.0%} of the run after 12 s in alarm")
        print(f"{alarmed} of {len(seeds)} seeds alarmed")
    return 0


if __name__ == "__main__":
    sys.exit(main())
