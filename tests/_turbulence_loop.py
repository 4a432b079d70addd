"""The seed aircraft loop in Dryden turbulence at library level (test and benchmark helper).

The Aircraft and PitchController FMUs' Python cores at 100 Hz, level flight, sensor noise
1 σ (v 0.05 m/s, α/ϑ/γ 1e-3 rad, q 1e-3 rad/s, h 0.2 m), u and y paired as a
Gauss-Seidel master delivers them to the Diagnoser (or, ``jacobi``, y one sample late).
"""

from __future__ import annotations

import sys
from collections.abc import Callable
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
for _sub in ("models/aircraft", "models/pitch_controller"):
    if str(ROOT / _sub) not in sys.path:
        sys.path.insert(0, str(ROOT / _sub))

from gd_aircraft_core import AircraftModel  # noqa: E402
from gd_aircraft_turbulence import DrydenGust  # noqa: E402
from gd_pitch_controller_design import PitchController, design_pitch_controller  # noqa: E402

T = 0.01
NOISE = np.array([0.05, 1e-3, 1e-3, 1e-3, 1e-3, 0.2])


def fly(duration_s: float, sigma: Callable[[float], float], seed: int,
        fault: Callable[[float, np.ndarray], np.ndarray] | None = None,
        jacobi: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """(u, y) rows per sample: σ_w(t) m/s, ``fault(t, y)`` on the sensors."""
    plane = AircraftModel(noise_std=NOISE, seed=seed, gust=DrydenGust(sigma(0.0)))
    law = PitchController(design_pitch_controller())
    n = round(duration_s / T)
    u, y = np.zeros((n, 2)), np.zeros((n, 6))
    meas = plane.measure()
    elevator = law.elevator(meas[1], meas[2], meas[3], 0.0)
    for k in range(n):
        t = k * T
        if sigma(t) != plane.gust.sigma_w:
            plane.set_gust(DrydenGust(sigma(t)))
        if fault is not None:
            meas = fault(t, meas)
        u[k], y[k] = (0.0, elevator), meas
        plane.step(T, u[k])
        elevator = law.update(T, meas[1], meas[2], meas[3], 0.0)
        meas = plane.measure()
    if jacobi:
        y = np.vstack([y[:1], y[:-1]])
    return u, y
