"""Figures of docs/dtg_case_rate.md: DTG θ in manoeuvres, with and without the case rate.

Runs the system chain without FMUs (tests/_system_chain.py: aircraft + LQR at 1 kHz, the
paper DTG as pitch gyro) for level flight and every manoeuvre kind, identifies θ of both
axes by batch least squares over 2–18 s (the paper's 50 Hz prefilter on every signal) and
prints, per manoeuvre, the change of θ against level flight for: no case rate (the
paper's regression), the case rate in the paper's scheme, the central scheme; the case
rate is the true pitch rate or a second gyro of the given noise.  Then the
errors-in-variables table: level flight and a 0.05 rad square wave against the second
gyro's noise.

    python benchmarks/system_case_rate.py [--duration 18]
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np
from scipy import signal

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))
sys.path.insert(0, str(ROOT / "fmu_src"))

from _system_chain import PitchCommand, run_chain  # noqa: E402

from gyrodiag.dtg.case_rate import dtg_case_rate_regression  # noqa: E402
from gyrodiag.dtg.model import dtg_regression  # noqa: E402

T = 1e-3
SOS = signal.butter(6, 50.0, fs=1.0 / T, output="sos")

CASES = {
    "level flight": {},
    "square 0.005 rad": {"command": PitchCommand(1, 0.005, period=8.0)},
    "square 0.05 rad": {"command": PitchCommand(1, 0.05, period=8.0)},
    "square 0.25 rad": {"command": PitchCommand(1, 0.25, period=8.0)},
    "doublets 0.1 rad": {"command": PitchCommand(3, 0.1, start=3.0, pulse=0.5, period=4.0)},
    "step 0.05 rad": {"command": PitchCommand(2, 0.05, start=3.0)},
    "sweep 0.05 rad 0.1-2 Hz": {"command": PitchCommand(4, 0.05, start=2.0, duration=16.0,
                                                        f0=0.1, f1=2.0)},
    "sweep 0.25 rad 0.1-2 Hz": {"command": PitchCommand(4, 0.25, start=2.0, duration=16.0,
                                                        f0=0.1, f1=2.0)},
    "off trim (θ0 0.1, q0 0.1)": {"x0": (0.0, 0.05, 0.1, 0.1, 0.0)},
    "turbulence σw 1.5 m/s": {"sigma_w": 1.5},
}


def theta(o: dict[str, np.ndarray], scheme: str | None, rate: np.ndarray) -> np.ndarray:
    rec = np.column_stack([o["Utx"], o["Uty"], o["Ux"], o["Uy"], np.zeros_like(rate), rate])
    f = signal.sosfilt(SOS, rec, axis=0)
    if scheme is None:
        px, yx, py, yy = dtg_regression(*f[:, :4].T)
    else:
        px, yx, py, yy = dtg_case_rate_regression(*f.T, T, 1e-3, scheme=scheme)
    keep = slice(2000, None)
    return np.array([np.linalg.lstsq(px[keep], yx[keep], rcond=None)[0],
                     np.linalg.lstsq(py[keep], yy[keep], rcond=None)[0]])


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--duration", type=float, default=18.0)
    ap.add_argument("--gyro-noise", type=float, default=2e-4,
                    help="second-gyro noise, rad/s per 1 kHz sample")
    a = ap.parse_args()
    t0 = time.perf_counter()
    runs = {name: run_chain(a.duration, **kw) for name, kw in CASES.items()}
    rng = np.random.default_rng(7)
    for o in runs.values():
        o["gyro2"] = o["q"] + a.gyro_noise * rng.standard_normal(o["q"].size)
    print(f"chain runs: {time.perf_counter() - t0:.0f} s wall")
    for label, scheme, rate in (("no case rate (paper regression)", None, "q"),
                                ("paper scheme, true q", "paper", "q"),
                                ("central scheme, true q", "central", "q"),
                                (f"central scheme, second gyro {a.gyro_noise:g} rad/s",
                                 "central", "gyro2")):
        ref = theta(runs["level flight"], scheme, runs["level flight"][rate])
        print(f"\n{label}: θ change against level flight, % (x axis | y axis)")
        for name, o in runs.items():
            d = (theta(o, scheme, o[rate]) / ref - 1.0) * 100.0
            print(f"  {name:26s} {' '.join(f'{v:+7.1f}' for v in d[0])} | "
                  f"{' '.join(f'{v:+7.1f}' for v in d[1])}")
    print("\nerrors in variables (central scheme): θ change against the true-q fit, %"
          " (x θ1..θ5 | y θ1..θ5)")
    for name in ("level flight", "square 0.05 rad"):
        o = runs[name]
        ref = theta(o, "central", o["q"])
        for sigma in (1e-4, 3e-4, 1e-3):
            noisy = o["q"] + sigma * np.random.default_rng(11).standard_normal(o["q"].size)
            d = (theta(o, "central", noisy) / ref - 1.0) * 100.0
            print(f"  {name:18s} σ {sigma:6.0e}  {' '.join(f'{v:+6.1f}' for v in d[0])} | "
                  f"{' '.join(f'{v:+6.1f}' for v in d[1])}")
    print(f"\ntotal {time.perf_counter() - t0:.0f} s wall")
    return 0


if __name__ == "__main__":
    sys.exit(main())
