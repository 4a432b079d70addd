"""Linear model of the DTG rate read-out: case rate → omega_read through the rebalance loop.

At steady state the read-out is exact (Ku·Ux = L·ωy), but the loop takes its time: for
the paper set the read-out of a pitch-rate sine has gain 0.74 at 1 Hz and an 83 ms lag
at 0.1 Hz.  This module builds the exact sampled model of that path (rotor and
controller as ``gd_dtg_sim`` steps them, noise-free and fault-free) for a detection
filter that must model its q sensor (gyrodiag.df.sensor_dynamics), and writes it in the
JSON format the Diagnoser reads (``df.sensor_dynamics_file``)::

    python models/dtg/gd_dtg_readout.py --set 1 --axis y --sensor 3 --step 0.001 --out FILE

Alignment (what ``DTGSimulator.advance`` does): over a communication step of n controller
ticks the case rate ω(k) is held; the read-out published at its end is the mean over the
step of Ku·U/L, U being computed at each tick from the pick-offs before the tick's
interval.  So ``read(k) = C x(k) + D ω(k)`` and ``x(k+1) = A x(k) + B ω(k)``; D = 0 for
n = 1.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path

import numpy as np
from gd_dtg_core import (
    DTGParameterSet,
    controller_matrices,
    rotor_coefficients,
    rotor_state_space,
    zoh_discretize,
)


def tick_model(p: DTGParameterSet, axis: str = "y") -> tuple[np.ndarray, ...]:
    """Per-tick closed loop from the case rate of ``axis`` to its read-out.

    Returns
    -------
    Phi, G, H : ndarray
        State [rotor (4), controller x-axis, controller y-axis]; x⁺ = Phi x + G ω and the
        read-out over the coming tick is H x (rad/s per rad/s).
    """
    if axis not in ("x", "y"):
        raise ValueError(f"axis must be 'x' or 'y', got {axis!r}")
    r = rotor_coefficients(p)
    A, B = rotor_state_space(r)
    Tc = p.controller_sample_time
    Ad, Bd = zoh_discretize(A, B, Tc)
    Ac, Bc, Cc, Dc = controller_matrices(p)
    nc = Ac.shape[0]
    c, s = math.cos(p.loop_rotation), math.sin(p.loop_rotation)
    R = np.array([[c, -s], [s, c]])
    n = 4 + 2 * nc
    pick = np.zeros((2, n))
    pick[0, 0] = pick[1, 1] = 1.0 / r.KT
    E = -R @ pick  # controller input e = E x (pick-offs at the tick, noise-free)
    Cu = np.zeros((2, n))  # torquer voltages U = Cu x
    for a in range(2):
        Cu[a, 4 + a * nc:4 + (a + 1) * nc] = Cc
        Cu[a] += Dc * E[a]
    Phi = np.zeros((n, n))
    Phi[:4, :4] = Ad[:, :4]
    Phi[:4] += Bd[:, 2:] @ Cu
    for a in range(2):
        rows = slice(4 + a * nc, 4 + (a + 1) * nc)
        Phi[rows, rows] = Ac
        Phi[rows] += np.outer(Bc, E[a])
    col = 1 if axis == "y" else 0
    G = Bd[:, col].copy()
    G = np.concatenate([G, np.zeros(2 * nc)])
    gain = p.Ku / r.L  # the electronics' nominal scale
    # omega_y_read = Ku·Ux/L, omega_x_read = −Ku·Uy/L
    H = gain * Cu[0] if axis == "y" else -gain * Cu[1]
    return Phi, G, H


def rate_readout_model(p: DTGParameterSet, axis: str = "y", ticks_per_step: int = 1
                       ) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
    """Discrete (A, B, C, D) of the read-out at a communication step of n ticks."""
    if isinstance(ticks_per_step, bool) or not isinstance(ticks_per_step, int) \
            or ticks_per_step < 1:
        raise ValueError(f"ticks_per_step must be an integer >= 1, got {ticks_per_step!r}")
    Phi, G, H = tick_model(p, axis)
    n = ticks_per_step
    size = Phi.shape[0]
    A = np.eye(size)
    B = np.zeros(size)
    C = np.zeros(size)
    D = 0.0
    for _ in range(n):  # tick i: read H x_i, then x_{i+1} = Phi x_i + G ω
        C += H @ A / n
        D += float(H @ B) / n
        A = Phi @ A
        B = Phi @ B + G
    return A, B, C, D


def readout_dict(p: DTGParameterSet, axis: str, sensor: int, step_s: float) -> dict:
    """The Diagnoser's sensor-dynamics JSON (``{"sensor", "discrete": {...}}``)."""
    ratio = step_s / p.controller_sample_time
    n = round(ratio)
    if n < 1 or abs(ratio - n) > 1e-9 * ratio:
        raise ValueError(f"step {step_s} s is not a whole number of controller ticks "
                         f"({p.controller_sample_time} s)")
    A, B, C, D = rate_readout_model(p, axis, n)
    return {"sensor": int(sensor),
            "description": f"DTG {p.name} set, omega_{axis}_read from the case rate "
                           f"omega_{axis} (rebalance loop, {n} tick(s) per step)",
            "discrete": {"sample_period_s": float(step_s), "A": A.tolist(), "B": B.tolist(),
                         "C": C.tolist(), "D": D}}


def main(argv: list[str] | None = None) -> int:
    from gd_dtg_sets import PARAMETER_SETS, parameter_set

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--set", type=int, default=1, choices=sorted(PARAMETER_SETS))
    ap.add_argument("--axis", choices=("x", "y"), default="y")
    ap.add_argument("--sensor", type=int, default=3, help="1-based index in the filter's y")
    ap.add_argument("--step", type=float, default=1e-3, help="communication step, s")
    ap.add_argument("--out", type=Path, required=True)
    a = ap.parse_args(argv)
    data = readout_dict(parameter_set(a.set), a.axis, a.sensor, a.step)
    a.out.parent.mkdir(parents=True, exist_ok=True)
    a.out.write_text(json.dumps(data, indent=1) + "\n", encoding="utf-8")
    print(f"wrote {a.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
