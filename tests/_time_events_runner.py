"""Time events seen by two masters, in a fresh process (tests/test_time_events.py).

``python _time_events_runner.py FMU_DIR OUT.npz CASE``

Each CASE runs one FMU twice through fmpy's FMU2Slave: once with the communication
points t = t0 + k·h, once with t += h (a master that accumulates time, a few ulps early
or late after many steps), and saves the recorded outputs after every step
(``exact_*``, ``accum_*``) and both masters' times (``t_exact``, ``t_accum``).

* ``fault_injector``: channel 1 STEP, channel 2 BIAS window, channel 3 INTERMITTENT,
  starting at t0 + 10 s; t0 = 0 (t += 0.01 reaches 9.999999999999831).
* ``fault_injector_late``: the same from t0 = 1e5 s (t += h drifts by 5e-9 s).
* ``pitch_controller``: a doublet from t0 + 10 s (pulses of 1 s), t0 = 1e5 s.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from conftest import FmuSlave

H = 0.01
N_STEPS = 1600
EVENT_AFTER = 10.0

#: case -> (FMU, t0, parameters, time parameters relative to t0, outputs recorded)
CASES = {
    "fault_injector": ("FaultInjector", 0.0, {
        "fault_type_1": 6, "magnitude_1": 1.0,                       # STEP
        "fault_type_2": 1, "magnitude_2": 1.0,                       # BIAS window
        "fault_type_3": 10, "magnitude_3": 1.0, "period_3": 1.0, "duty_3": 0.5,
    }, {"t_start_1": EVENT_AFTER, "t_start_2": EVENT_AFTER, "t_end_2": EVENT_AFTER + 3.0,
        "t_start_3": EVENT_AFTER},
        ("fault_active_1", "fault_active_2", "fault_active_3", "out_1", "out_2", "out_3")),
    "pitch_controller": ("PitchController", 1.0e5, {
        "command_source": 3, "cmd_amplitude": 0.1, "cmd_pulse_s": 1.0, "cmd_period": 0.0,
    }, {"cmd_start_s": EVENT_AFTER}, ("cmd_active", "theta_cmd")),
}
CASES["fault_injector_late"] = ("FaultInjector", 1.0e5, *CASES["fault_injector"][2:])


def run(fmu_dir: Path, case: str) -> dict[str, np.ndarray]:
    name, t0, params, times_rel, outputs = CASES[case]
    params = {**params, **{k: t0 + v for k, v in times_rel.items()}}
    result: dict[str, np.ndarray] = {}
    for master in ("exact", "accum"):
        slave = FmuSlave(fmu_dir / f"{name}.fmu", f"{name}_{master}", params, start_time=t0)
        t = t0
        times, rows = [], []
        for k in range(N_STEPS):
            if master == "exact":
                t = t0 + k * H
            times.append(t)
            slave.fmu.doStep(currentCommunicationPoint=t, communicationStepSize=H)
            rows.append([float(slave.get(o)) for o in outputs])
            if master == "accum":
                t += H
        slave.close()
        result[f"t_{master}"] = np.array(times)
        data = np.array(rows)
        for j, o in enumerate(outputs):
            result[f"{master}_{o}"] = data[:, j]
    result["event_time"] = np.array(t0 + EVENT_AFTER)
    return result


if __name__ == "__main__":
    out = run(Path(sys.argv[1]), sys.argv[3])
    np.savez(sys.argv[2], **out)
