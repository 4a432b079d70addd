"""Model level (no FMU): Dryden turbulence of the aircraft and the pitch-command family.

* the shaping filter's state space has the analytic Dryden responses H_w/V and H_q;
  stationary variances are σ_w²/V² (closed form) and ∫|H_q|² dω/2π (quadrature);
* Van Loan's one-step noise covariance composes over steps (Qd(2h) = Φ Qd(h) Φᵀ + Qd(h));
* long closed-loop runs reproduce the stationary gust std at two step sizes;
* σ_w = 0 is bit for bit the plain ZOH aircraft, and turbulence never changes the sensor
  noise; state save/restore is exact;
* every command shape has its documented values, sweep frequency and validation errors.
"""

from __future__ import annotations

import math
import sys
from pathlib import Path

import numpy as np
import pytest
from scipy.integrate import quad

ROOT = Path(__file__).resolve().parents[1]
for sub in ("models/aircraft", "models/pitch_controller"):
    if str(ROOT / sub) not in sys.path:
        sys.path.insert(0, str(ROOT / sub))

import gd_aircraft_core as core  # noqa: E402
import gd_pitch_commands as cmds  # noqa: E402
from gd_aircraft_turbulence import DrydenGust, psd_factor, van_loan  # noqa: E402
from gd_pitch_controller_design import PitchController, design_pitch_controller  # noqa: E402


def _closed_loop(model: core.AircraftModel, h: float, n: int) -> np.ndarray:
    """Pitch-hold loop around ``model`` (true states fed back); returns gust outputs."""
    law = PitchController(design_pitch_controller())
    out = np.empty((n, 2))
    for k in range(n):
        _, alpha, q, theta, _ = model.x
        model.step(h, np.array([0.0, law.update(h, alpha, q, theta, 0.0)]))
        out[k] = model.gust_output
    return out


# ------------------------------------------------------------------------- turbulence

def test_shaping_filter_is_the_dryden_spectrum() -> None:
    gust = DrydenGust(1.5, scale_length=80.0, wingspan=12.0)
    ag, bg, cg = gust.state_space()
    omega = np.logspace(-3, 3, 61)
    ss = np.array([cg @ np.linalg.solve(1j * w * np.eye(3) - ag, bg) for w in omega])[..., 0].T
    ref = gust.frequency_response(omega)
    np.testing.assert_allclose(ss, ref, rtol=1e-10, atol=0)
    # the MIL-F-8785C vertical spectrum, one-sided in rad/s: σ² L/(πV) (1+3τ²ω²)/(1+τ²ω²)²,
    # equals |H_w|²/π for unit-intensity white noise (two-sided density 1)
    tw = gust.tau_w
    mil = 1.5**2 * tw / math.pi * (1 + 3 * (tw * omega) ** 2) / (1 + (tw * omega) ** 2) ** 2
    np.testing.assert_allclose(np.abs(ref[0] * gust.airspeed) ** 2 / math.pi, mil, rtol=1e-12)


def test_stationary_variances() -> None:
    gust = DrydenGust(2.0)
    std = gust.output_std()
    assert std[0] == pytest.approx(2.0 / gust.airspeed, rel=1e-12)
    # q_g: quadrature of |H_q|² over ω (two-sided / 2π)
    var_q = 2 * quad(lambda w: abs(gust.frequency_response(np.array([w]))[1, 0]) ** 2,
                     0, np.inf, limit=400)[0] / (2 * math.pi)
    assert std[1] == pytest.approx(math.sqrt(var_q), rel=1e-8)
    assert np.all(DrydenGust(0.0).output_std() == 0.0)


def test_van_loan_covariance_composes_over_steps() -> None:
    ag, bg, _ = DrydenGust(1.0).state_space()
    phi1, q1 = van_loan(ag, bg, 0.01)
    phi2, q2 = van_loan(ag, bg, 0.02)
    np.testing.assert_allclose(phi1 @ phi1, phi2, rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(phi1 @ q1 @ phi1.T + q1, q2, rtol=1e-9, atol=1e-18)
    s = psd_factor(q1)
    np.testing.assert_allclose(s @ s.T, q1, rtol=1e-9, atol=1e-20)


@pytest.mark.parametrize("h,n", [(0.01, 100_000), (0.002, 250_000)])
def test_simulated_gusts_have_the_stationary_std(h: float, n: int) -> None:
    gust = DrydenGust(1.5)
    model = core.AircraftModel(seed=11, gust=gust)
    out = _closed_loop(model, h, n)
    # 1000 s (500 s) with a 0.18 s correlation time: the std is known to ~2 % (1σ)
    np.testing.assert_allclose(out.std(axis=0), gust.output_std(), rtol=0.08)
    assert abs(out[:, 0].mean()) < 0.1 * gust.output_std()[0]


def test_no_turbulence_is_the_plain_zoh_model_bit_for_bit() -> None:
    rng = np.random.default_rng(0)
    u = np.column_stack([np.zeros(300), 0.01 * rng.standard_normal(300)])
    model = core.AircraftModel(x0=[1.0, 0.01, -0.02, 0.03, 5.0], seed=4)
    ad, bd = core.zoh_discretise(core.A, core.B, 0.01)
    x = model.x.copy()
    for uk in u:
        model.step(0.01, uk)
        x = ad @ x + bd @ uk
        assert np.array_equal(model.x, x)
    assert np.all(model.gust_output == 0.0)


def test_turbulence_moves_the_aircraft_not_the_sensor_noise() -> None:
    calm = core.AircraftModel(noise_std=[0.1, 1e-3, 1e-3, 1e-3, 1e-3, 0.5], seed=7)
    rough = core.AircraftModel(noise_std=[0.1, 1e-3, 1e-3, 1e-3, 1e-3, 0.5], seed=7,
                               gust=DrydenGust(1.5))
    for _ in range(200):
        for m in (calm, rough):
            m.step(0.01, np.zeros(2))
        n_calm = calm.measure() - core.C @ calm.x
        n_rough = rough.measure() - core.C @ rough.x
        np.testing.assert_allclose(n_calm, n_rough, rtol=0, atol=1e-12)
    assert np.abs(rough.x[1:3]).max() > 1e-4 and np.all(calm.x == 0.0)


def test_state_round_trip_with_turbulence_and_intensity_change() -> None:
    model = core.AircraftModel(noise_std=[0.0, 1e-3, 1e-3, 1e-3, 1e-3, 0.0], seed=5,
                               gust=DrydenGust(0.8))

    def run(n: int, change_at: int = -1) -> np.ndarray:
        rows = []
        for k in range(n):
            if k == change_at:
                model.set_gust(DrydenGust(2.0))
            model.step(0.005, np.array([0.0, 0.001]))
            rows.append(np.concatenate([model.x, model.gust_output, model.measure()]))
        return np.array(rows)

    run(40)
    saved = model.get_state()
    first = run(60, change_at=30)
    assert model.gust.sigma_w == 2.0
    model.set_state(saved)
    assert model.gust.sigma_w == 0.8
    second = run(60, change_at=30)
    np.testing.assert_array_equal(first, second)


def test_turbulence_parameters_are_validated() -> None:
    for kwargs, name in [({"sigma_w": -1.0}, "sigma_w"),
                         ({"scale_length": 0.0}, "scale_length"),
                         ({"airspeed": float("nan")}, "airspeed"),
                         ({"wingspan": -2.0}, "wingspan")]:
        with pytest.raises(ValueError, match=name):
            DrydenGust(**kwargs)


# ------------------------------------------------------------------------ manoeuvres

def test_square_wave_step_and_window() -> None:
    sq = cmds.PitchCommand(cmds.COMMAND_SQUARE_WAVE, 0.05, start=28.0, duration=16.0, period=8.0)
    assert [sq.value(t) for t in (27.99, 28.0, 31.99, 32.0, 43.99, 44.0)] == \
        [0.0, 0.05, 0.05, -0.05, -0.05, 0.0]
    assert not sq.active(27.9) and sq.active(30.0) and not sq.active(44.0)
    # defaults: the historical internal square wave, from t = 0 and for ever
    legacy = cmds.PitchCommand()
    assert [legacy.value(t) for t in (0.0, 9.99, 10.0, 1e4 + 1)] == [0.25, 0.25, -0.25, 0.25]
    step = cmds.PitchCommand(cmds.COMMAND_STEP, -0.2, start=1.0, duration=2.0)
    assert [step.value(t) for t in (0.5, 1.0, 2.99, 3.0)] == [0.0, -0.2, -0.2, 0.0]
    assert cmds.PitchCommand(cmds.COMMAND_INPUT).value(5.0) == 0.0


def test_doublet_once_and_repeated() -> None:
    once = cmds.PitchCommand(cmds.COMMAND_DOUBLET, 0.1, start=2.0, pulse=0.5, period=0.0)
    assert [once.value(t) for t in (1.9, 2.0, 2.49, 2.5, 2.99, 3.0, 50.0)] == \
        [0.0, 0.1, 0.1, -0.1, -0.1, 0.0, 0.0]
    rep = cmds.PitchCommand(cmds.COMMAND_DOUBLET, 0.1, start=2.0, pulse=0.5, period=4.0,
                            duration=12.0)
    t = np.arange(2.0, 14.0, 1e-3)
    v = np.array([rep.value(ti) for ti in t])
    assert v.sum() * 1e-3 == pytest.approx(0.0, abs=2e-4)  # zero mean: no net attitude
    assert rep.value(6.2) == 0.1 and rep.value(6.7) == -0.1 and rep.value(7.5) == 0.0
    assert rep.value(14.2) == 0.0


def test_sine_sweep_frequency_and_ends() -> None:
    sw = cmds.PitchCommand(cmds.COMMAND_SINE_SWEEP, 0.02, start=5.0, duration=40.0, f0=0.1,
                           f1=2.0)
    assert sw.value(5.0) == 0.0 and sw.value(45.0) == 0.0 and sw.value(4.0) == 0.0
    for tau in (0.0, 10.0, 20.0, 39.0):
        dphi = (sw.sweep_phase(tau + 1e-6) - sw.sweep_phase(tau - 1e-6)) / 2e-6
        assert dphi / (2 * math.pi) == pytest.approx(sw.sweep_frequency(tau), rel=1e-6)
    assert sw.sweep_frequency(0.0) == pytest.approx(0.1)
    assert sw.sweep_frequency(40.0) == pytest.approx(2.0)
    assert sw.sweep_frequency(20.0) == pytest.approx(math.sqrt(0.2))  # geometric middle
    t = np.arange(5.0, 45.0, 1e-3)
    assert max(abs(sw.value(ti)) for ti in t) == pytest.approx(0.02, rel=1e-4)
    flat = cmds.PitchCommand(cmds.COMMAND_SINE_SWEEP, 1.0, duration=10.0, f0=0.5, f1=0.5)
    assert flat.value(0.5) == pytest.approx(1.0)


@pytest.mark.parametrize("kwargs,name", [
    ({"kind": 7}, "kind"),
    ({"kind": cmds.COMMAND_SQUARE_WAVE, "period": 0.0}, "period"),
    ({"kind": cmds.COMMAND_DOUBLET, "pulse": 0.0}, "pulse"),
    ({"kind": cmds.COMMAND_DOUBLET, "pulse": 1.0, "period": 1.5}, "period"),
    ({"kind": cmds.COMMAND_SINE_SWEEP, "duration": 0.0}, "duration"),
    ({"kind": cmds.COMMAND_SINE_SWEEP, "duration": 5.0, "f0": 0.0}, "f0"),
    ({"kind": cmds.COMMAND_STEP, "duration": -1.0}, "duration"),
    ({"kind": cmds.COMMAND_STEP, "amplitude": float("inf")}, "amplitude"),
])
def test_command_validation_names_the_parameter(kwargs: dict, name: str) -> None:
    with pytest.raises(ValueError, match=name):
        cmds.PitchCommand(**kwargs)
