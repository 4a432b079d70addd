"""Test-only system chain without FMUs: aircraft (models/aircraft) with the LQR pitch
controller (models/pitch_controller) and the DTG (models/dtg) as its pitch-rate gyro, at
1 kHz, in the order of the harness's Gauss-Seidel master for the system scenarios: the
aircraft steps with the elevator of the previous step, the DTG with the new pitch rate
held over the step, the controller reads the DTG's read-out."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
for _sub in ("models/aircraft", "models/pitch_controller", "models/dtg"):
    if str(ROOT / _sub) not in sys.path:
        sys.path.insert(0, str(ROOT / _sub))

from gd_aircraft_core import AircraftModel  # noqa: E402
from gd_aircraft_turbulence import DrydenGust  # noqa: E402
from gd_dtg_sets import parameter_set  # noqa: E402
from gd_dtg_sim import DTGSimulator  # noqa: E402
from gd_pitch_commands import PitchCommand  # noqa: E402
from gd_pitch_controller_design import PitchController, design_pitch_controller  # noqa: E402

SIGNALS = ("t", "Utx", "Uty", "Ux", "Uy", "q", "q_read", "y_v", "y_alpha", "y_q", "y_theta",
           "y_gamma", "y_h", "elevator")


def run_chain(duration_s: float, *, command: PitchCommand | None = None,
              x0=(0.0, 0.0, 0.0, 0.0, 0.0), sigma_w: float = 0.0, seed: int = 2,
              dtg_seed: int = 5, noise=(0.05, 1e-4, 2e-4, 1e-4, 1e-3, 0.2),
              spin: tuple[float, float] | None = None, step_s: float = 1e-3,
              faults: tuple[float, dict[str, float]] | None = None,
              dtg_noise_std: float = 1e-3) -> dict[str, np.ndarray]:
    """Run the chain; row k holds the samples at t = (k+1)·step_s.

    ``spin`` = (t, fraction) slows the spin motor at t; ``faults`` = (t, {name: value})
    sets any of the DTG simulator's fault parameters at t (``torquer_scale``, ...).
    ``elevator[k]`` is the command computed from row k's sensors: it acts over the next
    step (what a detection filter must pair with row k's outputs). ``y_q`` is the
    aircraft's own rate sensor (a second gyro), ``q_read`` the DTG read-out.
    """
    ac = AircraftModel(x0=x0, noise_std=noise, seed=seed, gust=DrydenGust(sigma_w))
    law = PitchController(design_pitch_controller())
    dtg = DTGSimulator(parameter_set(1), noise_std=dtg_noise_std, dither_std=1.0,
                       seed=dtg_seed)
    cmd = command or PitchCommand(0)
    n = round(duration_s / step_s)
    out = {k: np.empty(n) for k in SIGNALS}
    y = ac.measure()
    elev = law.elevator(y[1], dtg.rate_readout[1], y[3], cmd.value(0.0))
    for k in range(n):
        t = (k + 1) * step_s
        if spin is not None and abs(k * step_s - spin[0]) < 0.5 * step_s:
            dtg.set_faults(spin_fraction=spin[1])
        if faults is not None and abs(k * step_s - faults[0]) < 0.5 * step_s:
            dtg.set_faults(**faults[1])
        ac.step(step_s, np.array([0.0, elev]))
        y = ac.measure()
        dtg.advance(t, 0.0, float(ac.x[2]))
        q_read = dtg.rate_readout[1]
        elev = law.update(step_s, y[1], q_read, y[3], cmd.value(k * step_s))
        row = (t, *dtg.pickoff, *dtg.torquer_mean, ac.x[2], q_read, *y, elev)
        for key, value in zip(SIGNALS, row, strict=True):
            out[key][k] = value
    return out
