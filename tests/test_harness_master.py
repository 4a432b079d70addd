"""Co-simulation master (gyrodiag_harness.cosim.master) on the real FMUs.

All FMU work happens in ONE fresh process (this file run as a script through the
``run_fmu_script`` fixture, docs/methods.md §6.11): it runs every case below and saves the arrays;
the tests compare them with hand-written fmpy loops and with the documented timing of
the FMUs (FaultInjector: ``out(t+h) = F(in, t)``, RAMP fault ``u + m (t - t_start)``).
"""

from __future__ import annotations

import math
import sys
import traceback
from pathlib import Path

import numpy as np
import pytest

DATA = Path(__file__).resolve().parent / "data" / "scenarios"
H = 0.01


# ---------------------------------------------------------------------------------------
# scenarios (plain dicts, validated by gyrodiag_harness.cosim.scenario.parse_scenario in the runner)
# ---------------------------------------------------------------------------------------
def chain_scenario(coupling: str) -> dict:
    """HRG → FaultInjector a → FaultInjector b, a bias on each injector."""
    return {
        "name": f"chain_{coupling}", "duration_s": 1.0, "step_s": H, "coupling": coupling,
        "fmus": {
            "hrg": {"fmu": "HRG", "parameters": {"profile": 0, "noise_std": 0.01, "seed": 4,
                                                 "bias": 0.7}},
            "a": {"fmu": "FaultInjector"},
            "b": {"fmu": "FaultInjector"},
        },
        "connections": [{"from": "hrg.voltage", "to": "a.in_1"},
                        {"from": "a.out_1", "to": "b.in_1"}],
        "faults": [
            {"name": "bias_a", "injector": "a", "channel": 1, "type": "bias", "start_s": 0.5,
             "magnitude": 0.5},
            {"name": "bias_b", "injector": "b", "channel": 1, "type": "bias", "start_s": 0.25,
             "end_s": 0.75, "magnitude": 0.125},
        ],
        "record": {"variables": ["hrg.voltage", "a.in_1", "a.out_1", "b.in_1", "b.out_1"]},
    }


def multirate_scenario() -> dict:
    """Injector ``slow`` (step_ratio 2) with a RAMP of slope 1 on channel 1 (its output is
    then the sample time of its step) and the HRG voltage on channel 2; a Diagnoser
    (grey channel only) with step_ratio 2 that refuses any step but 2 * step_s."""
    return {
        "name": "multirate", "duration_s": 0.2, "step_s": H,
        "fmus": {
            "hrg": {"fmu": "HRG", "parameters": {"noise_std": 0.01, "seed": 2}},
            "slow": {"fmu": "FaultInjector", "step_ratio": 2},
            "fast": {"fmu": "FaultInjector"},
            "diag": {"fmu": "Diagnoser", "step_ratio": 2,
                     "parameters": {"sample_period_s": 2 * H, "dtg.enabled": False,
                                    "df.enabled": False}},
        },
        "connections": [{"from": "hrg.voltage", "to": "slow.in_2"},
                        {"from": "hrg.voltage", "to": "diag.grey.y"}],
        "faults": [
            {"name": "ramp_slow", "injector": "slow", "channel": 1, "type": "ramp",
             "start_s": 0.0, "magnitude": 1.0},
            {"name": "ramp_fast", "injector": "fast", "channel": 1, "type": "ramp",
             "start_s": 0.0, "magnitude": 1.0},
        ],
        "record": {"variables": ["hrg.voltage", "slow.out_1", "slow.out_2", "fast.out_1",
                                 "diag.grey.prediction"], "decimation": 1},
    }


def decimation_scenario() -> dict:
    sc = chain_scenario("gauss-seidel")
    sc["name"] = "decimated"
    sc["duration_s"] = 0.1
    sc["faults"] = []
    sc["record"] = {"variables": ["hrg.voltage", "b.out_1"], "decimation": 3}
    return sc


def physical_fault_scenario() -> dict:
    """throttle_trim (tunable) of a PitchController set to 0.3 in [0.05, 0.1) s."""
    return {
        "name": "physical", "duration_s": 0.2, "step_s": H,
        "fmus": {"ctl": {"fmu": "PitchController", "parameters": {"throttle_trim": 0.1}}},
        "faults": [{"name": "trim", "set": "ctl.throttle_trim", "value": 0.3, "start_s": 0.05,
                    "end_s": 0.1}],
        "record": {"variables": ["ctl.throttle"]},
    }


def error_mid_run_scenario() -> dict:
    """An invalid command_source (tunable) at t = 0.05 s: the next doStep fails."""
    return {
        "name": "error_mid_run", "duration_s": 0.2, "step_s": H,
        "fmus": {"ctl": {"fmu": "PitchController", "parameters": {"command_source": 1}}},
        "faults": [{"name": "bad_source", "set": "ctl.command_source", "value": 5,
                    "start_s": 0.05}],
        "record": {"variables": ["ctl.theta_cmd", "ctl.elevator"]},
    }


def manoeuvre_scenario() -> dict:
    """Aircraft off trim (ϑ0 = 0.05 rad) and a PitchController flying a doublet from 0.1 s."""
    return {
        "name": "manoeuvre", "duration_s": 0.4, "step_s": H,
        "fmus": {"ac": {"fmu": "Aircraft"}, "ctl": {"fmu": "PitchController"}},
        "manoeuvres": [
            {"name": "doublet", "kind": "doublet", "instance": "ctl", "start_s": 0.1,
             "duration_s": 0.2, "amplitude_rad": 0.02, "pulse_s": 0.05},
            {"name": "start", "kind": "off_trim", "instance": "ac", "duration_s": 0.3,
             "theta0_rad": 0.05},
        ],
        "record": {"variables": ["ctl.theta_cmd", "ctl.cmd_active", "ac.x_theta"]},
    }


def wrong_step_scenario() -> dict:
    """Diagnoser sampled at 0.02 s but stepped every 0.01 s: a sample every other step."""
    return {
        "name": "wrong_step", "duration_s": 0.4, "step_s": H,
        "fmus": {"diag": {"fmu": "Diagnoser",
                          "parameters": {"sample_period_s": 2 * H, "dtg.enabled": False,
                                         "df.enabled": False}}},
        "record": {"variables": ["diag.grey.prediction_valid"]},
    }


# ---------------------------------------------------------------------------------------
# the runner process
# ---------------------------------------------------------------------------------------
def _hand_loop(fmu_dir: Path, scenario) -> dict[str, np.ndarray]:
    """Aircraft ↔ PitchController written directly against fmpy, Gauss-Seidel with the
    aircraft first: aircraft steps with the controller's outputs at t, the controller
    with the aircraft's outputs at t + h."""
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from conftest import FmuSlave

    ac = FmuSlave.__new__(FmuSlave)
    ctl = FmuSlave.__new__(FmuSlave)
    # the same lifecycle as FmuSlave.__init__, but leaving initialisation in order
    from fmpy import extract, read_model_description
    from fmpy.fmi2 import FMU2Slave

    for slave, name in ((ac, "aircraft"), (ctl, "controller")):
        unzipdir = extract(str(fmu_dir / f"{scenario.fmus[name].fmu}.fmu"))
        slave.md = read_model_description(unzipdir)
        slave.vars = {v.name: v for v in slave.md.modelVariables}
        slave.fmu = FMU2Slave(guid=slave.md.guid, unzipDirectory=unzipdir,
                              modelIdentifier=slave.md.coSimulation.modelIdentifier,
                              instanceName=name)
        slave.fmu.instantiate()
        slave.fmu.setupExperiment(startTime=0.0)
        for p, v in scenario.fmus[name].parameters.items():
            slave.set(p, v)
        slave.fmu.enterInitializationMode()
        slave.time = 0.0
    ac.fmu.exitInitializationMode()
    sensors = {"alpha_meas": "y_alpha", "q_meas": "y_q", "theta_meas": "y_theta"}

    def feed_controller() -> None:
        for inp, out in sensors.items():
            ctl.set(inp, ac.get(out))

    def feed_aircraft() -> None:
        ac.set("elevator", ctl.get("elevator"))
        ac.set("throttle", ctl.get("throttle"))

    feed_controller()
    ctl.fmu.exitInitializationMode()
    names = scenario.record.variables
    rows = []

    def record() -> None:
        rows.append([(ac if q.startswith("aircraft.") else ctl).get(q.split(".", 1)[1])
                     for q in names])

    record()
    for k in range(scenario.n_steps):
        t = k * scenario.step_s
        feed_aircraft()
        ac.fmu.doStep(currentCommunicationPoint=t, communicationStepSize=scenario.step_s)
        feed_controller()
        ctl.fmu.doStep(currentCommunicationPoint=t, communicationStepSize=scenario.step_s)
        record()
    ac.close()
    ctl.close()
    table = np.array(rows, dtype=float)
    return {q: table[:, j] for j, q in enumerate(names)}


def _save_result(out: dict, prefix: str, result) -> None:
    out[f"{prefix}/time"] = result.time
    for name, values in result.signals.items():
        out[f"{prefix}/{name}"] = values
    out[f"{prefix}/error"] = np.array("" if result.error is None else result.error)


def _runner(fmu_dir: Path, out_path: Path) -> None:
    root = Path(__file__).resolve().parents[1]
    sys.path.insert(0, str(root))
    from gyrodiag_harness.cosim.master import plan_coupling, run_scenario
    from gyrodiag_harness.cosim.results import RunResult
    from gyrodiag_harness.cosim.scenario import load_scenario, parse_scenario

    out: dict[str, np.ndarray] = {}

    def case(prefix: str, fn) -> None:
        try:
            fn()
        except Exception:
            out[f"{prefix}/crash"] = np.array(traceback.format_exc())

    def closed_loop() -> None:
        s = load_scenario(DATA / "aircraft_pitch.toml")
        out["pitch/order"] = np.array(plan_coupling(s).order)
        _save_result(out, "pitch", run_scenario(s, fmu_dir=fmu_dir, progress=False))
        for name, values in _hand_loop(fmu_dir, s).items():
            out[f"hand/{name}"] = values

    def injector_loop() -> None:
        r = run_scenario(load_scenario(DATA / "closed_loop.toml"), fmu_dir=fmu_dir,
                         progress=False)
        _save_result(out, "inj", r)
        w = r.fault("q_bias")
        out["inj/window"] = np.array([w.start_s, w.end_s])
        out["inj/window_target"] = np.array(w.target)

    def chains() -> None:
        for coupling in ("gauss-seidel", "jacobi"):
            r = run_scenario(parse_scenario(chain_scenario(coupling), source="chain"),
                             fmu_dir=fmu_dir, progress=False)
            _save_result(out, coupling, r)

    def others() -> None:
        for prefix, sc in (("multirate", multirate_scenario()),
                           ("decimated", decimation_scenario()),
                           ("physical", physical_fault_scenario()),
                           ("manoeuvre", manoeuvre_scenario()),
                           ("wrong_step", wrong_step_scenario())):
            case(prefix, lambda sc=sc, prefix=prefix: _save_result(
                out, prefix, run_scenario(parse_scenario(sc, source=prefix), fmu_dir=fmu_dir,
                                          progress=False)))

    def error_mid_run() -> None:
        saved = out_path.parent / "error_run"
        r = run_scenario(parse_scenario(error_mid_run_scenario(), source="err"),
                         fmu_dir=fmu_dir, progress=False, out_dir=saved)
        _save_result(out, "err", r)
        _save_result(out, "err_loaded", RunResult.load(saved))

    for prefix, fn in (("pitch", closed_loop), ("inj", injector_loop), ("chain", chains),
                       ("other", others), ("err", error_mid_run)):
        case(prefix, fn)
    np.savez(out_path, **out)


if __name__ == "__main__":
    import os

    _runner(Path(sys.argv[1]), Path(sys.argv[2]))
    # skip interpreter shutdown with pythonfmu loaded: it has aborted now and then after
    # the results were saved (see harness/__main__.py)
    sys.stdout.flush()
    os._exit(0)


# ---------------------------------------------------------------------------------------
# tests
# ---------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def runs(run_fmu_script) -> dict[str, np.ndarray]:
    return run_fmu_script(Path(__file__))


def _get(runs: dict, prefix: str) -> dict[str, np.ndarray]:
    crash = runs.get(f"{prefix}/crash")
    if crash is not None:
        pytest.fail(f"case {prefix} crashed in the runner:\n{crash}")
    return {k[len(prefix) + 1:]: v for k, v in runs.items() if k.startswith(prefix + "/")}


def test_closed_loop_reproduces_hand_written_fmpy_loop(runs):
    pitch, hand = _get(runs, "pitch"), _get(runs, "hand")
    assert _get(runs, "pitch")["order"].tolist() == ["aircraft", "controller"]
    assert str(pitch["error"]) == ""
    np.testing.assert_array_equal(pitch["time"], np.arange(201) * H)
    for name, values in hand.items():
        np.testing.assert_array_equal(pitch[name], values, err_msg=name)
    # the loop is really closed: the controller tracks the ±0.1 rad square wave
    assert np.ptp(pitch["aircraft.x_theta"]) > 0.05
    assert set(np.round(pitch["controller.theta_cmd"], 12)) == {0.1, -0.1}


def test_injector_fault_applied_at_scheduled_time(runs):
    r = _get(runs, "inj")
    assert str(r["error"]) == ""
    t, y, out = r["time"], r["aircraft.y_q"], r["injector.out_3"]
    active = r["injector.fault_active_3"]
    # Gauss-Seidel, injector after the aircraft: out(t_k+1) = y(t_k+1) + 0.1 once the
    # injector's step start t_k >= 1.0 s, i.e. from row 101 (t = 1.01 s) on
    k0 = 101
    np.testing.assert_array_equal(out[:k0], y[:k0])
    np.testing.assert_allclose(out[k0:] - y[k0:], 0.1, rtol=0, atol=1e-12)
    np.testing.assert_array_equal(active, (np.arange(len(t)) >= k0).astype(float))
    assert t[k0] == pytest.approx(1.01)
    np.testing.assert_array_equal(r["window"], [1.0, math.inf])
    assert str(r["window_target"]) == "injector.out_3"


def _lag(v: np.ndarray, out: np.ndarray, rows: slice) -> int:
    """Samples d such that out[k] == v[k - d] exactly for every k in ``rows``."""
    lags = [d for d in range(4) if np.array_equal(out[rows], v[rows.start - d:rows.stop - d])]
    assert len(lags) == 1, lags
    return lags[0]


def _first_change(values: np.ndarray) -> int:
    return int(np.flatnonzero(np.abs(values) > 1e-9)[0])


def test_gauss_seidel_and_jacobi_latency_differ_by_one_step_per_boundary(runs):
    gs, jac = _get(runs, "gauss-seidel"), _get(runs, "jacobi")
    assert str(gs["error"]) == "" and str(jac["error"]) == ""
    before_faults = slice(5, 25)  # both biases start at t >= 0.25 s
    lags = {}
    for name, r in (("gs", gs), ("jac", jac)):
        v = r["hrg.voltage"]
        lags[name] = (_lag(v, r["a.out_1"], before_faults), _lag(v, r["b.out_1"], before_faults))
    assert lags["gs"] == (0, 0)      # no latency along the connection order
    assert lags["jac"] == (1, 2)     # one step per FMU boundary
    # the bias of injector a (t_start 0.5 s) seen at b's output: one more row with Jacobi
    for r, lag_b, row in ((gs, 0, 51), (jac, 2, 52)):
        v, b = r["hrg.voltage"], r["b.out_1"]
        # remove the signal and b's own bias window (b steps at t_k, output at t_k+1)
        expected_b_bias = np.where((r["time"] - H >= 0.25 - 1e-12)
                                   & (r["time"] - H < 0.75 - 1e-12), 0.125, 0.0)
        residual = b[3:] - v[3 - lag_b:len(v) - lag_b] - expected_b_bias[3:]
        assert _first_change(residual) + 3 == row
        np.testing.assert_allclose(residual[row - 3:], 0.5, atol=1e-12)
    # the inputs at row 0 already carry the initial outputs (propagated before step 1)
    for r in (gs, jac):
        assert r["hrg.voltage"][0] != 0.0
        assert r["a.in_1"][0] == r["hrg.voltage"][0] == r["a.out_1"][0] == r["b.out_1"][0]


def test_multi_rate_instance_steps_every_other_base_step_with_twice_the_step(runs):
    r = _get(runs, "multirate")
    assert str(r["error"]) == "", str(r["error"])  # the Diagnoser accepted h = 2 * step_s
    t = r["time"]
    np.testing.assert_array_equal(t, np.arange(21) * H)
    j = np.arange(1, 21)
    # RAMP slope 1 from 0 s: out = the start time of the injector's latest step
    np.testing.assert_allclose(r["fast.out_1"][1:], (j - 1) * H, atol=1e-15)
    np.testing.assert_allclose(r["slow.out_1"][1:], 2 * H * ((j - 1) // 2), atol=1e-15)
    # channel 2 holds the HRG voltage taken when the slow injector stepped
    v, slow2 = r["hrg.voltage"], r["slow.out_2"]
    np.testing.assert_array_equal(slow2[1::2], v[1::2])
    np.testing.assert_array_equal(slow2[2::2], v[1::2])
    # the Diagnoser's prediction only changes at its own steps (odd rows)
    pred = r["diag.grey.prediction"]
    np.testing.assert_array_equal(pred[2::2], pred[1::2])


def test_decimation_records_every_third_step_and_the_last(runs):
    r = _get(runs, "decimated")
    np.testing.assert_allclose(r["time"], [0.0, 0.03, 0.06, 0.09, 0.1], atol=1e-15)
    gs = _get(runs, "gauss-seidel")
    # same seed and wiring as the chain run: identical samples at the recorded rows
    np.testing.assert_array_equal(r["hrg.voltage"], gs["hrg.voltage"][[0, 3, 6, 9, 10]])


def test_physical_fault_sets_and_restores_a_tunable_parameter(runs):
    r = _get(runs, "physical")
    assert str(r["error"]) == ""
    # throttle(t_k+1) = throttle_trim at the step start t_k; fault window [0.05, 0.1)
    t_start_of_step = r["time"][1:] - H
    expected = np.where((t_start_of_step > 0.05 - 1e-9) & (t_start_of_step < 0.1 - 1e-9),
                        0.3, 0.1)
    np.testing.assert_array_equal(r["ctl.throttle"][1:], expected)
    assert r["ctl.throttle"][0] == 0.1


def test_manoeuvres_become_start_values(runs):
    """The doublet is flown from its start (command published one step later), the
    aircraft starts at ϑ0; the windows are not faults."""
    t = runs["manoeuvre/time"]
    cmd = runs["manoeuvre/ctl.theta_cmd"]
    active = runs["manoeuvre/ctl.cmd_active"]
    # row k holds the command the controller used for its step [t_{k-1}, t_k]
    t_cmd = t - H
    expected = np.where((t_cmd >= 0.1 - 1e-9) & (t_cmd < 0.15 - 1e-9), 0.02,
                        np.where((t_cmd >= 0.15 - 1e-9) & (t_cmd < 0.2 - 1e-9), -0.02, 0.0))
    np.testing.assert_array_equal(cmd[1:], expected[1:])
    assert active[1:].tolist() == ((t_cmd[1:] >= 0.1 - 1e-9) & (t_cmd[1:] < 0.3 - 1e-9)).tolist()
    assert runs["manoeuvre/ac.x_theta"][0] == 0.05


def test_fmu_error_mid_run_stops_with_log_and_keeps_rows(runs):
    r, loaded = _get(runs, "err"), _get(runs, "err_loaded")
    error = str(r["error"])
    assert error.startswith("instance ctl: doStep at t=0.05 returned ERROR")
    assert "command_source must be 0..4" in error      # the FMU's own log line
    np.testing.assert_allclose(r["time"], np.arange(6) * H, atol=1e-15)
    assert np.all(np.abs(r["ctl.theta_cmd"][1:]) == 0.25)       # rows before the error kept
    # saved although the run failed: time and the ±0.25 command exactly, the elevator
    # (no expectation reads it) rounded to 13 significant bits (record.precision compact)
    assert str(loaded["error"]) == error
    for key in ("time", "ctl.theta_cmd"):
        np.testing.assert_array_equal(loaded[key], r[key])
    np.testing.assert_allclose(loaded["ctl.elevator"], r["ctl.elevator"], rtol=2.0**-13,
                               atol=0)


def test_a_step_shorter_than_the_sample_period_holds_the_outputs_between_samples(runs):
    """Sampled at 2H, stepped at H: the first prediction is checked on sample k = 10
    (the window of 10 full), taken at t = 20 H and recorded after its step, 21 H; a
    sample every step would give 11 H."""
    r = _get(runs, "wrong_step")
    assert not str(r.get("error", "")), r["error"]
    np.testing.assert_allclose(r["time"], np.arange(41) * H, atol=1e-12)
    valid = r["diag.grey.prediction_valid"].astype(bool)
    first = int(np.argmax(valid))
    assert valid[first:].all() and r["time"][first] == pytest.approx(21 * H), first


