"""The detection filter's gust model (gyrodiag.df.gust, docs/methods.md §4.6), library level.

* the library's Dryden filter is the Aircraft FMU's (same state space; α_g std σ_w/V);
* the residual model with the gust predicts the detection filter's residual variance in
  turbulence (Monte Carlo on the aircraft model, closed loop);
* the whitened residual is white in turbulence of the design intensity, and coloured
  without the gust model;
* sensor noise is recovered in turbulence (the gust no longer counts as noise);
* onsets and cessations of turbulence up to the design intensity raise no alarm, and a
  5σ q bias in moderate turbulence is detected, isolated to q and typed bias.
"""

from __future__ import annotations

import numpy as np
import pytest
from _turbulence_loop import NOISE, T, fly
from gd_aircraft_turbulence import DrydenGust  # on the path via _turbulence_loop

from gyrodiag.df.channel import DFChannel, DFChannelConfig
from gyrodiag.df.filter import DetectionFilter, design_detection_filter
from gyrodiag.df.gust import GustModel, seed_gust_input
from gyrodiag.df.plant import seed_aircraft
from gyrodiag.df.residual import ResidualModel, estimate_sensor_variances
from gyrodiag.df.sequential_diagnosis import (
    SequentialDiagnoser,
    _gust_disturbance,
)

PLANT = seed_aircraft()
A, B, C = np.array(PLANT.A), np.array(PLANT.B), np.array(PLANT.C)
K = design_detection_filter(A, C, np.eye(5), -np.arange(1.0, 6.0))


def residuals(u: np.ndarray, y: np.ndarray) -> np.ndarray:
    f = DetectionFilter(A, B, C, K, T)
    return np.array([f.update(u[k], y[k]).copy() for k in range(len(u))])


def residual_model(gust: GustModel | None) -> ResidualModel:
    f = DetectionFilter(A, B, C, K, T)
    return ResidualModel(f.closed_loop_matrix, f.discrete_gain, C,
                         _gust_disturbance(gust, A, T, np.eye(5)))


# --------------------------------------------------------------------------- model


def test_library_gust_filter_is_the_aircraft_fmus() -> None:
    for sigma, length, span in ((0.77, 50.0, 10.0), (2.3, 120.0, 14.0)):
        plant = DrydenGust(sigma, scale_length=length, wingspan=span).state_space()
        ours = GustModel(sigma, scale_length=length, wingspan=span).filter()
        for a, b in zip(plant, ours, strict=True):
            np.testing.assert_allclose(b, a, rtol=1e-12, atol=1e-15)
    # the gust angle of attack has the Dryden variance σ_w² / V² exactly
    g = GustModel(1.5)
    assert g.output_std()[0] == pytest.approx(1.5 / g.airspeed, rel=1e-9)


def test_seed_gust_input_is_the_aircraft_models() -> None:
    from gd_aircraft_core import E_GUST  # _turbulence_loop put models/aircraft on the path

    np.testing.assert_array_equal(seed_gust_input(A), E_GUST)
    with pytest.raises(ValueError, match="A must be square"):
        seed_gust_input(np.zeros((2, 2)))
    with pytest.raises(ValueError, match="sigma_w"):
        GustModel(0.0)


def test_residual_model_predicts_the_residual_variance_in_turbulence() -> None:
    u, y = fly(120.0, lambda t: 1.5, seed=3)
    measured = residuals(u, y)[500:].var(axis=0)
    model = residual_model(GustModel(1.5))
    predicted = np.diag(model.residual_covariance(NOISE**2))
    # α, q, γ: the gust is 10–40 times the sensor noise there; the model explains it
    np.testing.assert_allclose(measured[1:5], predicted[1:5], rtol=0.3)
    calm = np.diag(residual_model(None).residual_covariance(NOISE**2))
    assert measured[2] > 10.0 * calm[2]


# ----------------------------------------------------------------------- whiteness


def _whitened(gust: GustModel | None, sigma: float, seed: int) -> np.ndarray:
    """Standardised innovations of the main generator (true noise variances) over a
    90 s level flight in turbulence σ_w = ``sigma``, after 10 s."""
    u, y = fly(90.0, lambda t: sigma, seed=seed)
    d = SequentialDiagnoser(A, B, C, K, T, NOISE**2, gust=gust)
    return np.array([_z(d, u[k], y[k]) for k in range(len(u))])[1000:]


def _z(d: SequentialDiagnoser, u: np.ndarray, y: np.ndarray) -> np.ndarray:
    z, _ = d.main.update(np.concatenate([u, y]))
    return z


def _lag_corr(z: np.ndarray, lag: int) -> np.ndarray:
    c = z - z.mean(axis=0)
    return (c[lag:] * c[:-lag]).mean(axis=0) / c.var(axis=0)


def test_whitened_residual_is_white_in_turbulence_of_the_design_intensity() -> None:
    z = _whitened(GustModel(1.5), 1.5, seed=4)
    channels = [1, 2, 3, 4]  # α, q, ϑ, γ: the channels the gust reaches
    np.testing.assert_allclose(z[:, channels].var(axis=0), 1.0, rtol=0.15)
    for lag in (1, 2, 5, 10):
        assert np.abs(_lag_corr(z[:, channels], lag)).max() < 0.06, lag
    # without the gust model the same residual is far from white
    z0 = _whitened(None, 1.5, seed=4)
    assert _lag_corr(z0[:, [2]], 1)[0] > 0.5
    assert z0[:, 2].var() > 10.0


# ----------------------------------------------------------------------- noise


def test_sensor_noise_is_recovered_in_turbulence() -> None:
    u, y = fly(10.0, lambda t: 1.5, seed=4)
    r = residuals(u, y)[200:]
    got = np.sqrt(estimate_sensor_variances(r, residual_model(GustModel(2.3))))
    np.testing.assert_allclose(got[1:5], NOISE[1:5], rtol=0.25)
    # the calm model takes the gust for noise: q several times its true noise
    calm = np.sqrt(estimate_sensor_variances(r, residual_model(None)))
    assert calm[2] > 3.0 * NOISE[2]


# ------------------------------------------------------------------ channel level


def _run(u: np.ndarray, y: np.ndarray, gust: GustModel | None
         ) -> tuple[np.ndarray, list]:
    ch = DFChannel(DFChannelConfig(sample_period_s=T, decision="sequential", gust=gust))
    outs = [ch.update(u[k], y[k]) for k in range(len(u))]
    return np.array([o.detected for o in outs]), outs


def test_entering_and_leaving_turbulence_is_not_a_fault() -> None:
    sigma = lambda t: 1.5 if 30.0 <= t < 70.0 else 0.0  # noqa: E731
    u, y = fly(100.0, sigma, seed=7)
    detected, _ = _run(u, y, GustModel(2.3))
    assert not detected.any()
    # the calm model, calibrated in calm air, alarms at the onset
    detected0, _ = _run(u, y, None)
    assert detected0[round(30.0 / T):].any()


def test_q_bias_of_5_sigma_in_moderate_turbulence_is_isolated_and_typed() -> None:
    def bias(t: float, y: np.ndarray) -> np.ndarray:
        y = y.copy()
        if t >= 40.0 - 1e-9:
            y[2] += 5e-3
        return y

    u, y = fly(50.0, lambda t: 1.5, seed=5, fault=bias)
    detected, outs = _run(u, y, GustModel(2.3))
    k0 = round(40.0 / T)
    assert not detected[:k0].any()
    first = int(np.flatnonzero(detected[k0:])[0]) * T
    assert first < 2.0
    end = outs[-1]
    assert end.isolated_sensor == 3
    assert end.fault_type == 1
    assert end.magnitude == pytest.approx(5e-3, rel=0.2)


# -------------------------------------------------------------- decoupled analysis


def test_decoupled_isolability_analytic_cases() -> None:
    from gyrodiag.df.decoupling import decoupled_isolability

    # a disturbance along sensor 1's own state: it can imitate that sensor's bias exactly
    a = -np.eye(3)
    rep = decoupled_isolability(a, np.eye(3), np.array([[1.0], [0.0], [0.0]]),
                                ("s1", "s2", "s3"))
    np.testing.assert_allclose(rep.visibility[:, 0], 0.0, atol=1e-12)
    np.testing.assert_allclose(rep.visibility[:, 1:], 1.0, atol=1e-12)
    assert rep.isolable_from("s1") == ()
    assert rep.isolable_from("s2") == ("s3",)
    # the seed gust never reaches the airspeed: v stays fully visible; rank 2
    seed = decoupled_isolability(A, C, seed_gust_input(A), PLANT.output_names)
    np.testing.assert_allclose(seed.visibility[:, 0], 1.0, atol=1e-12)
    assert list(seed.disturbance_rank) == [2, 2, 2]
    assert "h" not in seed.isolable_from("q")
    with pytest.raises(ValueError, match="frequencies"):
        decoupled_isolability(A, C, seed_gust_input(A), PLANT.output_names, frequencies=[0.0])


def test_harness_isolability_report_shows_the_decoupled_table() -> None:
    import json

    from gyrodiag_harness.verification.isolability import render, seed_isolability_report

    report = seed_isolability_report()
    data = json.loads(render(report, "json"))
    names = [s["name"] for s in data["gust_decoupled"]["sensors"]]
    assert names == list(PLANT.output_names)
    assert "With the disturbance decoupled" in render(report, "text")
