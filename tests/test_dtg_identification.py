"""Identification of the DTG regression: exact on data of the model itself, and the
honest discretisation bias on the continuous rotor sampled at 1 kHz."""

import numpy as np
import pytest
from _dtg_sim import STABLE_ROTOR, simulate_continuous, simulate_difference_equation
from scipy import signal

from gyrodiag.common.estimators import RLS, batch_ls
from gyrodiag.common.prefilter import ButterworthPrefilter
from gyrodiag.dtg.model import (
    DTGParameters,
    DTGRegressor,
    dtg_regression,
    physical_from_theta,
    theta_from_physical,
)

T = 1e-3
THETA_NOM_PAPER = np.array([1.9951, 0.9959, -0.0288, -0.0303, 0.0002])


def _inputs(n, seed):
    rng = np.random.default_rng(seed)
    return rng.standard_normal(n), rng.standard_normal(n)


def _fmt(values):
    return "[" + ", ".join(f"{v:.1e}" for v in values) + "]"


def _stacked(tx, ty, ux, uy):
    px, yx, py, yy = dtg_regression(tx, ty, ux, uy)
    return np.vstack([px, py]), np.concatenate([yx, yy])


def test_theta_physical_round_trip():
    th = theta_from_physical(STABLE_ROTOR, T)
    r = physical_from_theta(th, T)
    p = STABLE_ROTOR
    want = [p.c / p.J, p.k / p.J, p.L / p.J, p.lam / p.J, p.Ku / (p.KT * p.J)]
    np.testing.assert_allclose(r.as_array(), want, rtol=1e-9)


def test_paper_theta_nom_inverts_to_plausible_rotor():
    r = physical_from_theta(THETA_NOM_PAPER, T)
    # (θ1 − 2θ2)/(θ2 T) etc., by hand from the printed θ_nom
    assert r.c_over_J == pytest.approx((1.9951 - 2 * 0.9959) / (0.9959 * T), rel=1e-12)
    assert r.k_over_J == pytest.approx((1 - 1.9951 + 0.9959) / (0.9959 * T**2), rel=1e-12)
    assert r.L_over_J == pytest.approx(-0.0303 / (0.9959 * T), rel=1e-12)
    assert r.c_over_J > 0 and r.k_over_J > 0  # damped, spring-like: a physical rotor


@pytest.mark.parametrize("axis", ["x", "y", "both"])
def test_batch_ls_recovers_theta_exactly_from_difference_equation(axis):
    theta = theta_from_physical(STABLE_ROTOR, T)
    ux, uy = _inputs(3000, seed=10)
    tx, ty = simulate_difference_equation(theta, ux, uy)
    px, yx, py, yy = dtg_regression(tx, ty, ux, uy)
    phi, y = {"x": (px, yx), "y": (py, yy), "both": _stacked(tx, ty, ux, uy)}[axis]
    est = batch_ls(phi, y)
    np.testing.assert_allclose(est, theta, rtol=1e-6)
    ratios = physical_from_theta(est, T).as_array()
    p = STABLE_ROTOR
    np.testing.assert_allclose(
        ratios, [p.c, p.k, p.L, p.lam, p.Ku / p.KT], rtol=1e-4
    )  # the inversion amplifies θ errors by up to 1/T²


def test_rls_recovers_theta_and_physical_parameters():
    theta = theta_from_physical(STABLE_ROTOR, T)
    ux, uy = _inputs(4000, seed=11)
    tx, ty = simulate_difference_equation(theta, ux, uy)
    reg = DTGRegressor()
    est = RLS(5, p0=1e10)
    for k in range(len(ux)):
        rows = reg.update(tx[k], ty[k], ux[k], uy[k])
        if rows is not None:
            est.update(rows[0], rows[1])
            est.update(rows[2], rows[3])
    np.testing.assert_allclose(est.theta, theta, rtol=1e-6)
    assert est.converged
    assert est.converged_at is not None and est.converged_at < 1000


def test_streaming_regressor_equals_batch_regression():
    ux, uy = _inputs(50, seed=12)
    tx, ty = _inputs(50, seed=13)
    px, yx, py, yy = dtg_regression(tx, ty, ux, uy)
    reg = DTGRegressor()
    rows = [reg.update(tx[k], ty[k], ux[k], uy[k]) for k in range(50)]
    assert rows[0] is None and rows[1] is None
    np.testing.assert_array_equal(np.array([r[0] for r in rows[2:]]), px)
    np.testing.assert_array_equal(np.array([r[1] for r in rows[2:]]), yx)
    np.testing.assert_array_equal(np.array([r[2] for r in rows[2:]]), py)
    np.testing.assert_array_equal(np.array([r[3] for r in rows[2:]]), yy)


def test_common_prefilter_keeps_the_regression_exact():
    """docs/methods.md §2: filtering all four signals with one LTI filter keeps θ exact."""
    theta = theta_from_physical(STABLE_ROTOR, T)
    ux, uy = _inputs(6000, seed=14)
    tx, ty = simulate_difference_equation(theta, ux, uy)
    filt = ButterworthPrefilter(6, 50.0, 1000.0, n_channels=4)
    f = np.array([filt.update(s) for s in np.column_stack([tx, ty, ux, uy])])
    phi, y = _stacked(*f.T)
    np.testing.assert_allclose(batch_ls(phi, y), theta, rtol=1e-6)


def test_common_bandpass_prefilter_keeps_the_regression_exact():
    """The optional high-pass is one more LTI filter on all four signals: θ stays exact."""
    theta = theta_from_physical(STABLE_ROTOR, T)
    ux, uy = _inputs(6000, seed=16)
    tx, ty = simulate_difference_equation(theta, ux, uy)
    filt = ButterworthPrefilter(6, 50.0, 1000.0, n_channels=4, highpass_hz=5.0)
    f = np.array([filt.update(s) for s in np.column_stack([tx, ty, ux, uy])])
    phi, y = _stacked(*f.T)
    np.testing.assert_allclose(batch_ls(phi, y), theta, rtol=1e-6)


def test_continuous_rotor_at_1khz_shows_the_discretisation_bias():
    """Backward differences are not the exact discretisation of the rotor: report it.

    Measured (seed 15, 20 000 samples, excitation low-passed at 50 Hz): relative bias of
    θ = [2.4e−3, 4.8e−3, 1.6e−3, 9.7e−4, 6.9e−3]; of the physical ratios
    [c/J, k/J, L/J, λ/J, Ku/(KT·J)] = [0.13, 2.8e−3, 3.8e−3, 0.37, 1.2e−2]: c/J and λ/J
    are small differences (θ1 − 2θ2, θ3 − θ4) of biased numbers. The θ ratios η stay far
    inside the 0.5/1.5 decision band.
    """
    p = STABLE_ROTOR
    # Band-limited excitation: the paper's signals have no content above 50 Hz.
    sos = signal.butter(4, 50.0, fs=1.0 / T, output="sos")
    ux, uy = (signal.sosfilt(sos, u) for u in _inputs(20000, seed=15))
    tx, ty = simulate_continuous(p, ux, uy, T)
    phi, y = _stacked(tx, ty, ux, uy)
    est = batch_ls(phi, y)
    truth = theta_from_physical(p, T)
    rel = np.abs(est - truth) / np.abs(truth)
    phys = physical_from_theta(est, T).as_array()
    phys_true = physical_from_theta(truth, T).as_array()
    rel_phys = np.abs(phys - phys_true) / np.abs(phys_true)
    msg = (
        f"θ identified {np.array2string(est, precision=6)} vs θ(physical) "
        f"{np.array2string(truth, precision=6)}; relative bias of θ "
        f"{_fmt(rel)}, of physical ratios "
        f"{_fmt(rel_phys)}"
    )
    print(msg)
    assert np.all(rel < 1e-2), msg
    assert np.max(rel) > 1e-4, "continuous data cannot fit the backward-difference model"
    assert rel_phys[1] < 0.02 and rel_phys[2] < 0.02 and rel_phys[4] < 0.02, msg
    assert rel_phys[0] > 0.05 and rel_phys[3] > 0.05, "c/J, λ/J should carry the bias"


def test_physical_parameters_validation():
    with pytest.raises(ValueError, match="J must be > 0"):
        DTGParameters(J=0.0, c=1, k=1, L=1, lam=1, Ku=1, KT=1)
    with pytest.raises(ValueError, match="sample_period_s"):
        theta_from_physical(STABLE_ROTOR, 0.0)
    with pytest.raises(ValueError, match=r"theta\[1\]"):
        physical_from_theta([2.0, 0.0, 0.0, 0.0, 0.0], T)
    with pytest.raises(ValueError, match="Uty must have shape"):
        dtg_regression(np.zeros(10), np.zeros(9), np.zeros(10), np.zeros(10))
