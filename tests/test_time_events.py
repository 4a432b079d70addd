"""Time events do not depend on how the master computes its communication points.

Issue 32 item 4, docs/fmu.md "Time events". A master that adds h each step (t += h)
reaches 9.999999999999831 instead of 10 after 1000 steps of 0.01 s. Every time event of
the FMUs is compared within half a communication step, so both masters see each event
at the same step index.

The plants (Aircraft, DTG, HRG) have no time event: they use the step size only (the HRG's
rate profile is a continuous function of time, the DTG checks the host's time against its
own within half a step).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

RUNNER = Path(__file__).resolve().parent / "_time_events_runner.py"
EVENT_STEP = 1000  # t0 + 10 s with h = 0.01 s


def _first(x: np.ndarray) -> int | None:
    on = np.flatnonzero(x)
    return int(on[0]) if on.size else None


def _check_same_steps(res: dict[str, np.ndarray], flags: list[str], values: list[str]) -> None:
    event = float(res["event_time"])
    # the accumulating master really is early at the event (else the test proves nothing)
    assert res["t_exact"][EVENT_STEP] == event
    assert res["t_accum"][EVENT_STEP] < event
    for name in flags:
        exact, accum = res[f"exact_{name}"], res[f"accum_{name}"]
        assert _first(exact) == EVENT_STEP, name
        assert _first(accum) == EVENT_STEP, (name, _first(accum))
        np.testing.assert_array_equal(accum, exact, err_msg=name)
    for name in values:
        np.testing.assert_array_equal(res[f"accum_{name}"], res[f"exact_{name}"],
                                      err_msg=name)


@pytest.mark.parametrize("case", ["fault_injector", "fault_injector_late"])
def test_fault_injector_events_fire_at_the_same_step_for_both_masters(run_fmu_script, case):
    """STEP latch, BIAS window start and end (t_end = t_start + 3 s) and the edges of an
    INTERMITTENT fault (period 1 s, duty 0.5): the same steps for t = t0 + k·h and t += h."""
    res = run_fmu_script(RUNNER, case)
    _check_same_steps(res, ["fault_active_1", "fault_active_2", "fault_active_3"],
                      ["out_1", "out_2", "out_3"])
    window = res["exact_fault_active_2"]
    assert _first(window[EVENT_STEP:] == 0) == 300  # the window closes at t_end, 3 s later
    edges = np.flatnonzero(np.diff(res["exact_fault_active_3"][EVENT_STEP:]))
    assert edges[:4].tolist() == [49, 99, 149, 199]  # on 0.5 s, off 0.5 s


def test_pitch_controller_manoeuvre_fires_at_the_same_step_for_both_masters(run_fmu_script):
    """A doublet (pulses of 1 s) from t0 + 10 s with t0 = 1e5 s: start, sign change and
    end at the same steps for both masters (the accumulating one is 5e-9 s early)."""
    res = run_fmu_script(RUNNER, "pitch_controller")
    assert float(res["event_time"]) - res["t_accum"][EVENT_STEP] > 1e-9
    _check_same_steps(res, ["cmd_active"], ["theta_cmd"])
    cmd = res["exact_theta_cmd"]
    assert cmd[EVENT_STEP - 1] == 0.0 and cmd[EVENT_STEP] == pytest.approx(0.1)
    assert cmd[EVENT_STEP + 100] == pytest.approx(-0.1) and cmd[EVENT_STEP + 200] == 0.0
