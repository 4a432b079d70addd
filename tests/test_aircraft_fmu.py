"""Aircraft.fmu and PitchController.fmu acceptance tests (fmpy, fresh process).

* open-loop outputs equal an independent solve_ivp simulation of docs/methods.md §4 to 1e−6,
  with a step-size change mid-run (the ZOH matrices are recomputed);
* sensor noise is the documented seeded sequence; FMU state round trip is exact;
* the LQR gains equal python-control's, margins as documented;
* Aircraft + PitchController with a 0.25 rad square-wave command stay bounded for 120 s
  and ϑ follows the command;
* turbulence: the FMU equals the model core (gd_aircraft_core) to 1e−12 with the same
  seed, inputs and a mid-run intensity change; its state round trip is exact;
* every PitchController command shape equals gd_pitch_commands at the step start, with
  its window flag.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
A = np.array([[0, 0, 0, 0, 0], [0, 0, -1.5122, 1, 0], [0, -7.9101, -3.0241, 0, 0],
              [0, 0, 1, 0, 0], [0, -272.24, 0, 272.24, 0]], dtype=float)
B = np.array([[0, 0], [0, -0.2779], [0, -26.3821], [0, 0], [0, 0]], dtype=float)
C = np.vstack([np.eye(5)[:4], [0, -1, 0, 1, 0], np.eye(5)[4]])
STATES = ["x_v", "x_alpha", "x_q", "x_theta", "x_h"]
SENSORS = ["y_v", "y_alpha", "y_q", "y_theta", "y_gamma", "y_h"]
X0 = {"x0_v": 1.0, "x0_alpha": 0.01, "x0_q": -0.02, "x0_theta": 0.03, "x0_h": 5.0}
NOISE = {"noise_std_v": 0.1, "noise_std_alpha": 0.002, "noise_std_q": 0.003,
         "noise_std_theta": 0.004, "noise_std_gamma": 0.005, "noise_std_h": 0.5}
STEPS = [0.01] * 200 + [0.02] * 100 + [0.005] * 100  # 4.5 s, three step sizes
H_CL, T_CL, PERIOD = 0.01, 120.0, 20.0


def inputs(t: float) -> tuple[float, float]:
    """Known throttle / elevator record (rad) of the open-loop test."""
    return 0.3, 0.01 * np.sin(2.0 * t) + (0.005 if t >= 1.0 else 0.0)


# ---------------------------------------------------------------------------------------
# scenario process
# ---------------------------------------------------------------------------------------

def _open_loop(fmu: Path, FmuSlave, params: dict, steps: list[float], name: str) -> dict:
    s = FmuSlave(fmu, name, params)
    t, u, x, y = [s.time], [], [s.get_many(STATES)], [s.get_many(SENSORS)]
    for h in steps:
        thr, elev = inputs(s.time)
        s.set("throttle", thr)
        s.set("elevator", elev)
        s.step(h)
        t.append(s.time)
        u.append([thr, elev])
        x.append(s.get_many(STATES))
        y.append(s.get_many(SENSORS))
    s.close()
    return {"t": np.array(t), "u": np.array(u), "x": np.array(x), "y": np.array(y)}


def _state_round_trip(fmu: Path, FmuSlave) -> dict:
    s = FmuSlave(fmu, "ac_state", {**X0, **NOISE, "seed": 3})

    def advance(n: int) -> list[list[float]]:
        rows = []
        for _ in range(n):
            s.set("elevator", inputs(s.time)[1])
            s.step(0.01)
            rows.append(s.get_many(SENSORS + STATES))
        return rows

    advance(50)
    t_saved = s.time
    state = s.fmu.getFMUstate()
    first = advance(50)
    s.fmu.setFMUstate(state)
    s.time = t_saved
    second = advance(50)
    s.fmu.setFMUstate(s.fmu.deSerializeFMUstate(s.fmu.serializeFMUstate(state)))
    s.time = t_saved
    third = advance(50)
    s.close()
    return {"first": np.array(first), "second": np.array(second), "third": np.array(third)}


def _closed_loop(fmu_dir: Path, FmuSlave) -> dict:
    ac = FmuSlave(fmu_dir / "Aircraft.fmu", "ac_cl", {"seed": 1, "noise_std_alpha": 1e-3,
                                                      "noise_std_q": 1e-3,
                                                      "noise_std_theta": 1e-3})
    pc = FmuSlave(fmu_dir / "PitchController.fmu", "pc_cl",
                  {"command_source": 1, "cmd_amplitude": 0.25, "cmd_period": PERIOD})
    gains = [pc.get(k) for k in ("k_alpha", "k_q", "k_theta", "k_int")]
    rows = []
    for _ in range(round(T_CL / H_CL)):
        alpha, q, theta = ac.get_many(["y_alpha", "y_q", "y_theta"])
        pc.set("alpha_meas", alpha)
        pc.set("q_meas", q)
        pc.set("theta_meas", theta)
        ac.set("elevator", pc.get("elevator"))
        ac.set("throttle", pc.get("throttle"))
        t = ac.time
        ac.step(H_CL)
        pc.step(H_CL)
        rows.append([t, *ac.get_many(STATES), pc.get("theta_cmd"), pc.get("elevator")])
    ac.close()
    pc.close()
    return {"rows": np.array(rows), "gains": np.array(gains)}


TURB = {"turbulence_sigma_w": 1.5, "turbulence_scale_length": 60.0,
        "turbulence_wingspan": 8.0, "seed": 9, "noise_std_q": 1e-3, "noise_std_alpha": 1e-4}
TURB_STEPS = [0.01] * 150 + [0.005] * 100  # 2 s; intensity 0.5 m/s from step 100


def _turbulence(fmu: Path, FmuSlave) -> dict:
    sys.path.insert(0, str(ROOT / "models" / "aircraft"))
    from gd_aircraft_core import AircraftModel
    from gd_aircraft_turbulence import DrydenGust

    s = FmuSlave(fmu, "ac_turb", TURB)
    noise = [0.0, 1e-4, 1e-3, 0.0, 0.0, 0.0]
    ref = AircraftModel(noise_std=noise, seed=9, gust=DrydenGust(1.5, 60.0, wingspan=8.0))
    ref_y = ref.measure()
    rows, ref_rows = [], []
    saved = None
    for k, h in enumerate(TURB_STEPS):
        if k == 100:
            s.set("turbulence_sigma_w", 0.5)
            ref.set_gust(DrydenGust(0.5, 60.0, wingspan=8.0))
        if k == 120:
            saved = (s.fmu.serializeFMUstate(s.fmu.getFMUstate()), s.time)
        elev = inputs(s.time)[1]
        s.set("elevator", elev)
        s.step(h)
        ref.step(h, np.array([0.0, elev]))
        ref_y = ref.measure()
        rows.append(s.get_many(STATES + SENSORS + ["gust_alpha", "gust_q"]))
        ref_rows.append([*ref.x, *ref_y, *ref.gust_output])
    s.fmu.setFMUstate(s.fmu.deSerializeFMUstate(saved[0]))
    s.time = saved[1]
    again = []
    for h in TURB_STEPS[120:]:
        s.set("elevator", inputs(s.time)[1])
        s.step(h)
        again.append(s.get_many(STATES + SENSORS + ["gust_alpha", "gust_q"]))
    s.close()
    return {"fmu": np.array(rows), "ref": np.array(ref_rows), "again": np.array(again)}


COMMANDS = [  # (command_source, parameters)
    (1, {"cmd_amplitude": 0.05, "cmd_period": 2.0, "cmd_start_s": 1.0, "cmd_duration_s": 4.0}),
    (2, {"cmd_amplitude": -0.01, "cmd_start_s": 0.5, "cmd_duration_s": 0.0}),
    (3, {"cmd_amplitude": 0.2, "cmd_start_s": 1.0, "cmd_pulse_s": 0.5, "cmd_period": 3.0,
         "cmd_duration_s": 5.0}),
    (4, {"cmd_amplitude": 0.1, "cmd_start_s": 0.5, "cmd_duration_s": 5.0, "cmd_f0_hz": 0.1,
         "cmd_f1_hz": 2.0}),
]


def _commands(fmu: Path, FmuSlave) -> dict:
    res = {}
    for source, params in COMMANDS:
        s = FmuSlave(fmu, f"pc_cmd{source}", {"command_source": source, **params})
        rows = []
        for _ in range(700):
            t = s.time
            s.step(0.01)
            rows.append([t, s.get("theta_cmd"), s.get("cmd_active")])
        s.close()
        res[f"cmd{source}"] = np.array(rows)
    return res


def _scenarios(fmu_dir: Path, out: Path) -> None:
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from conftest import FmuSlave

    fmu = fmu_dir / "Aircraft.fmu"
    res = {}
    for tag, params in [("clean", X0), ("noisy", {**X0, **NOISE, "seed": 42}),
                        ("noisy_same", {**X0, **NOISE, "seed": 42}),
                        ("noisy_other", {**X0, **NOISE, "seed": 43})]:
        for k, v in _open_loop(fmu, FmuSlave, params, STEPS, f"ac_{tag}").items():
            res[f"{tag}_{k}"] = v
    for k, v in _state_round_trip(fmu, FmuSlave).items():
        res[f"state_{k}"] = v
    for k, v in _closed_loop(fmu_dir, FmuSlave).items():
        res[f"cl_{k}"] = v
    for k, v in _turbulence(fmu, FmuSlave).items():
        res[f"turb_{k}"] = v
    res.update(_commands(fmu_dir / "PitchController.fmu", FmuSlave))
    np.savez(out, **res)


# ---------------------------------------------------------------------------------------
# tests
# ---------------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def rec(run_fmu_script) -> dict[str, np.ndarray]:
    return run_fmu_script(Path(__file__).resolve())


def _reference(t: np.ndarray, u: np.ndarray, x0: np.ndarray) -> np.ndarray:
    """Independent reference: adaptive Runge–Kutta (DOP853) per held-input interval."""
    from scipy.integrate import solve_ivp

    xs = [x0]
    x = x0.copy()
    for k in range(len(u)):
        sol = solve_ivp(lambda _t, z, uk=u[k]: A @ z + B @ uk, (t[k], t[k + 1]), x,
                        method="DOP853", rtol=1e-12, atol=1e-12)
        x = sol.y[:, -1]
        xs.append(x)
    return np.array(xs)


def test_open_loop_matches_independent_reference(rec):
    t, u, x, y = rec["clean_t"], rec["clean_u"], rec["clean_x"], rec["clean_y"]
    x0 = np.array([X0[f"x0_{n[2:]}"] for n in STATES])
    np.testing.assert_array_equal(x[0], x0)
    x_ref = _reference(t, u, x0)
    y_ref = x_ref @ C.T
    scale_x = np.abs(x_ref).max(axis=0)
    scale_y = np.abs(y_ref).max(axis=0)
    rel_x = np.abs(x - x_ref).max(axis=0) / np.where(scale_x > 0, scale_x, 1.0)
    rel_y = np.abs(y - y_ref).max(axis=0) / np.where(scale_y > 0, scale_y, 1.0)
    assert rel_x.max() < 1e-6, rel_x
    assert rel_y.max() < 1e-6, rel_y
    # the run is dynamic (unstable open loop grows) and v stays constant (v' = 0)
    assert np.abs(x_ref[:, 4]).max() > 10 * abs(X0["x0_h"])
    assert np.all(x[:, 0] == X0["x0_v"])


def test_sensor_noise_is_the_seeded_sequence(rec):
    x, y = rec["noisy_x"], rec["noisy_y"]
    std = np.array(list(NOISE.values()))
    draws = np.random.default_rng(42).standard_normal((len(y), 6))
    np.testing.assert_allclose(y - x @ C.T, std * draws, rtol=0, atol=1e-9)
    # noise does not feed back into the plant
    np.testing.assert_array_equal(rec["noisy_x"], rec["clean_x"])
    np.testing.assert_array_equal(rec["noisy_y"], rec["noisy_same_y"])
    assert np.all(rec["noisy_y"][:, 0] != rec["noisy_other_y"][:, 0])


def test_fmu_state_round_trip_is_exact(rec):
    np.testing.assert_array_equal(rec["state_first"], rec["state_second"])
    np.testing.assert_array_equal(rec["state_first"], rec["state_third"])


def test_plant_and_library_matrices_are_one_aircraft():
    """The Aircraft FMU's core and the library's detection-filter model are written
    apart (the FMU ships without gyrodiag): they must be the same seed aircraft."""
    sys.path.insert(0, str(ROOT / "models" / "aircraft"))
    import gd_aircraft_core as core

    from gyrodiag.df.plant import seed_aircraft

    lib = seed_aircraft()
    for name in ("A", "B", "C"):
        np.testing.assert_array_equal(getattr(core, name), getattr(lib, name), err_msg=name)
    assert core.STATE_NAMES == lib.state_names and core.OUTPUT_NAMES == lib.output_names
    assert core.INPUT_NAMES == lib.input_names
    # paper data (docs/methods.md §4): the pitch-moment row and the elevator column
    np.testing.assert_array_equal(lib.A[2, 1:3], [-7.9101, -3.0241])
    np.testing.assert_array_equal(lib.B[1:3, 1], [-0.2779, -26.3821])


def _design_module():
    sys.path.insert(0, str(ROOT / "models" / "pitch_controller"))
    import gd_pitch_controller_design as design

    return design


def test_controller_gains_and_margins_match_python_control(rec):
    import control

    design = _design_module()
    d = design.design_pitch_controller()
    k_ctrl, _, poles = control.lqr(d.a_aug, d.b_aug, np.diag([1.0, 1.0, 10.0, 1e-3]), 100.0)
    np.testing.assert_allclose(rec["cl_gains"], np.ravel(k_ctrl), rtol=1e-8)
    np.testing.assert_allclose(d.k, np.ravel(k_ctrl), rtol=1e-8)
    assert np.all(np.real(poles) < 0)
    m = design.loop_margins(d)
    assert m["phase_margin_deg"] == pytest.approx(65.0, abs=0.1)
    assert m["w_gain_crossover"] == pytest.approx(5.29, abs=0.01)
    assert m["gain_margin"] == pytest.approx(0.447, abs=0.001)
    assert m["delay_margin_s"] > 0.2
    # trim: A z + B δ = 0 at ϑ = 1
    a3 = d.a_aug[:3, :3]
    b3 = d.b_aug[:3, 0]
    np.testing.assert_allclose(a3 @ d.n_x + b3 * d.n_u, 0.0, atol=1e-12)
    assert d.n_x[2] == pytest.approx(1.0)


def test_closed_loop_bounded_and_tracks_square_wave(rec):
    rows = rec["cl_rows"]
    t, x, cmd = rows[:, 0], rows[:, 1:6], rows[:, 6]  # t: step start, x: state at t + h
    assert np.all(np.isfinite(rows))
    # bounded: pitch states within a few rad, altitude swing bounded and not growing
    assert np.abs(x[:, 1:4]).max() < 6.0
    per = round(PERIOD / H_CL)
    h_swing = [np.ptp(x[i * per:(i + 1) * per, 4]) for i in range(len(t) // per)]
    assert max(h_swing) < 2.0e4
    assert h_swing[-1] < 1.2 * h_swing[1]
    assert np.abs(x[-per:, 1:4]).max() < 1.05 * np.abs(x[per:2 * per, 1:4]).max()
    # ϑ follows the command: within 0.03 rad over the last second of every half period
    half = per // 2
    for start in range(0, len(t), half):
        seg = slice(start + half - int(1.0 / H_CL), start + half)
        err = np.abs(x[seg, 3] - cmd[seg])
        assert err.max() < 0.03, (t[seg][0], err.max())  # measured ≤ 0.0193 rad
    # the command really is the ±0.25 rad square wave of period PERIOD (switching instants
    # judged with the command's 1 ns tolerance: t accumulates h in floating point)
    expected = np.where(((t + 1e-9) % PERIOD) < PERIOD / 2, 0.25, -0.25)
    np.testing.assert_array_equal(cmd, expected)


def test_turbulence_fmu_equals_model_core(rec):
    fmu, ref = rec["turb_fmu"], rec["turb_ref"]
    np.testing.assert_allclose(fmu, ref, rtol=1e-12, atol=1e-12)
    gust = fmu[:, -2:]
    assert np.abs(gust[:100]).max() > 1e-3  # turbulence on, q and alpha moved by it
    assert np.abs(fmu[:, 2]).max() > 1e-3


def test_turbulence_fmu_state_round_trip(rec):
    np.testing.assert_array_equal(rec["turb_fmu"][120:], rec["turb_again"])


def test_command_shapes_match_the_model_library(rec):
    sys.path.insert(0, str(ROOT / "models" / "pitch_controller"))
    from gd_pitch_commands import PitchCommand

    names = {"cmd_amplitude": "amplitude", "cmd_period": "period", "cmd_start_s": "start",
             "cmd_duration_s": "duration", "cmd_pulse_s": "pulse", "cmd_f0_hz": "f0",
             "cmd_f1_hz": "f1"}
    for source, params in COMMANDS:
        rows = rec[f"cmd{source}"]
        shape = PitchCommand(source, **{names[k]: v for k, v in params.items()})
        np.testing.assert_array_equal(rows[:, 1], [shape.value(t) for t in rows[:, 0]])
        np.testing.assert_array_equal(rows[:, 2], [shape.active(t) for t in rows[:, 0]])
        assert np.abs(rows[:, 1]).max() > 0.5 * abs(params["cmd_amplitude"])


if __name__ == "__main__":
    _scenarios(Path(sys.argv[1]), Path(sys.argv[2]))
