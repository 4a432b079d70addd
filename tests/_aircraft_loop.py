"""Closed-loop seed aircraft at library level with any set of sensor faults (test helper).

The plant, noise and LQR pitch controller of ``test_isolation_closed_loop`` (ZOH at
100 Hz, ±0.25 rad square-wave pitch command, period 8 s), with the controller reading
the possibly faulty α, q and ϑ sensors (the realistic case) and faults given as
``Fault`` entries. Fault models follow the FaultInjector's formulas.
"""

from __future__ import annotations

from dataclasses import dataclass

import control
import numpy as np
import scipy.signal

from gyrodiag.df.plant import seed_aircraft

MODEL = seed_aircraft()
A, B, C = MODEL.A, MODEL.B, MODEL.C
DT = 0.01
NOISE_STD = np.array([0.05, 1e-3, 1e-3, 1e-3, 1e-3, 0.2])


@dataclass(frozen=True)
class Fault:
    """Sensor ``sensor`` (0-based) from ``start_s`` to ``end_s``.

    kind: "bias" (+value), "gain" (value·y), "stuck" (held at the onset sample),
    "fail" (0), "ramp" (+value·(t − start)), "noise" (+value·N(0, 1)),
    "intermittent" (+value while ((t − start) mod period) < duty·period).
    """

    sensor: int
    kind: str
    value: float = 0.0
    start_s: float = 10.0
    end_s: float = 1e9
    period_s: float = 1.0
    duty: float = 0.5


def _controller_gain() -> np.ndarray:
    a_i = np.zeros((4, 4))
    a_i[:3, :3] = A[1:4, 1:4]
    a_i[3, 2] = 1.0
    b_i = np.zeros((4, 1))
    b_i[:3, 0] = B[1:4, 1]
    gain, _, _ = control.lqr(a_i, b_i, np.diag([1.0, 1.0, 10.0, 10.0]), np.eye(1))
    return np.asarray(gain)[0]


CONTROLLER = _controller_gain()
PHI, GAMMA, *_ = scipy.signal.cont2discrete((A, B, C, np.zeros((6, 2))), DT, method="zoh")


def simulate(duration_s: float, seed: int, faults: tuple[Fault, ...] = (),
             input_delay: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Return t, u, y (rows per sample). ``input_delay`` d > 0 returns u shifted so that
    row k holds the input of sample k + d (as a Jacobi master with one FMU between the
    sensors and the Diagnoser delivers it: y one sample late relative to u)."""
    rng = np.random.default_rng(seed)
    fault_rng = np.random.default_rng(seed + 7919)
    n = round(duration_s / DT) + max(input_delay, 0)
    t = np.arange(n) * DT
    x = np.zeros(5)
    integ = 0.0
    u_log, y_log = np.zeros((n, 2)), np.zeros((n, 6))
    held: dict[int, float] = {}
    for k in range(n):
        y = C @ x + NOISE_STD * rng.standard_normal(6)
        for f in faults:
            if not f.start_s <= t[k] < f.end_s:
                continue
            i = f.sensor
            if f.kind == "bias":
                y[i] += f.value
            elif f.kind == "gain":
                y[i] *= f.value
            elif f.kind == "stuck":
                held.setdefault(id(f), y[i])
                y[i] = held[id(f)]
            elif f.kind == "fail":
                y[i] = 0.0
            elif f.kind == "ramp":
                y[i] += f.value * (t[k] - f.start_s)
            elif f.kind == "noise":
                y[i] += f.value * fault_rng.standard_normal()
            elif f.kind == "intermittent":
                if ((t[k] - f.start_s) % f.period_s) < f.duty * f.period_s:
                    y[i] += f.value
            else:
                raise ValueError(f"unknown fault kind {f.kind!r}")
        u = np.array([0.0, -CONTROLLER @ np.append(y[[1, 2, 3]], integ)])
        cmd = 0.25 if (t[k] % 8.0) < 4.0 else -0.25
        integ += DT * (y[3] - cmd)
        u_log[k], y_log[k] = u, y
        x = PHI @ x + GAMMA @ u
    if input_delay > 0:
        d = input_delay
        return t[:n - d], u_log[d:], y_log[:n - d]
    return t, u_log, y_log
