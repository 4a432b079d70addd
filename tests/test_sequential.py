"""Sequential tests (gyrodiag.common.cusum) and the residual model (gyrodiag.df.residual):
known answers for CUSUM run lengths, the shipped threshold table, the chart bank, and
the whitening of the detection filter's coloured residual (docs/methods.md §4)."""

import math

import numpy as np
import pytest
import scipy.linalg

from gyrodiag.common.cusum import (
    TABLE_K,
    TABLE_LOG10_ARL,
    TABLE_RATIO,
    CusumBank,
    arl_for_rate,
    mean_cusum_arl,
    mean_cusum_threshold,
    variance_cusum_arl,
    variance_cusum_increment,
    variance_cusum_threshold,
)
from gyrodiag.df.filter import DetectionFilter, design_detection_filter
from gyrodiag.df.plant import seed_aircraft
from gyrodiag.df.residual import ResidualModel, estimate_sensor_variances

NOISE_STD = np.array([0.05, 1e-3, 1e-3, 1e-3, 1e-3, 0.2])
T = 0.01


# ------------------------------------------------------------------ run lengths

@pytest.mark.parametrize(("h", "two_sided"), [(4.0, 168.0), (5.0, 465.0)])
def test_mean_cusum_arl_matches_the_published_table(h, two_sided):
    """Two-sided CUSUM, k = 0.5: in-control ARL 168 at h = 4 and 465 at h = 5
    (Montgomery, Introduction to SQC, table 9.3); the two sides together alarm twice as
    often as one."""
    assert mean_cusum_arl(h, 0.5) / 2.0 == pytest.approx(two_sided, rel=3e-3)


def test_mean_cusum_arl_out_of_control_known_answer():
    # same table: a shift of 1 σ is detected after 8.38 samples on average at h = 4
    assert mean_cusum_arl(4.0, 0.5, shift=1.0) == pytest.approx(8.38, rel=0.01)


def _simulated_arl(increment, h, runs, rng):
    s = np.zeros(runs)
    length = np.zeros(runs)
    alive = np.ones(runs, dtype=bool)
    t = 0
    while alive.any():
        t += 1
        s[alive] = np.maximum(0.0, s[alive] + increment(rng.standard_normal(alive.sum())))
        hit = alive & (s > h)
        length[hit] = t
        alive &= ~hit
    return length.mean(), length.std() / math.sqrt(runs)


def test_variance_cusum_arl_agrees_with_simulation():
    a, c = variance_cusum_increment(4.0)
    assert (a, c) == pytest.approx((0.375, math.log(2.0)))
    rng = np.random.default_rng(5)
    mean, se = _simulated_arl(lambda z: a * z * z - c, 3.0, 20000, rng)
    assert abs(variance_cusum_arl(3.0, 4.0) - mean) < 4.0 * se
    # and a variance that is 4 times larger is seen within a few samples
    assert variance_cusum_arl(3.0, 4.0, true_variance=4.0) < 10.0


def test_thresholds_invert_the_run_length():
    h = mean_cusum_threshold(1e6, 0.5, exact=True)
    assert mean_cusum_arl(h, 0.5) == pytest.approx(1e6, rel=1e-4)
    hv = variance_cusum_threshold(1e6, 4.0, exact=True)
    assert variance_cusum_arl(hv, 4.0) == pytest.approx(1e6, rel=1e-4)


@pytest.mark.parametrize(("k", "log_arl"), [(0.5, 9.8), (0.37, 6.1), (1.23, 11.9)])
def test_shipped_mean_table_gives_the_chain_threshold(k, log_arl):
    """Off-grid points: interpolated h gives an ARL within 0.5 % of the target."""
    h = mean_cusum_threshold(10.0**log_arl, k)
    assert math.log(mean_cusum_arl(h, k)) == pytest.approx(log_arl * math.log(10), abs=5e-3)


@pytest.mark.parametrize(("ratio", "log_arl"), [(4.0, 10.3), (2.7, 7.4)])
def test_shipped_variance_table_gives_the_chain_threshold(ratio, log_arl):
    h = variance_cusum_threshold(10.0**log_arl, ratio)
    assert math.log(variance_cusum_arl(h, ratio)) == pytest.approx(
        log_arl * math.log(10), abs=0.06)  # the χ² chain itself is good to ~3 %


def test_table_grid_covers_the_fmu_parameter_ranges():
    assert TABLE_K[0] <= 0.1 and TABLE_K[-1] >= 2.0
    assert TABLE_RATIO[0] <= 1.5 and TABLE_RATIO[-1] >= 100.0
    # 1 kHz, six sensors, three charts each, 1e-5 false alarms per hour
    assert math.log10(arl_for_rate(1e-5, 1e-3, 18)) <= TABLE_LOG10_ARL[-1]


def test_arl_for_rate_is_a_union_bound():
    assert arl_for_rate(1.0, 0.01, 18) == pytest.approx(18 * 360000)


# ------------------------------------------------------------------ the charts

def _bank():
    return CusumBank(2, 0.5, 5.0, 4.0, 5.0, release=0.5)


def test_bank_alarms_on_a_shift_and_clears_after_it():
    bank = _bank()
    z = np.array([0.0, 0.0])
    assert not any(bank.update(z) for _ in range(50))
    shifted = np.array([2.0, 0.0])
    steps = next(k for k in range(1, 20) if bank.update(shifted))
    # S⁺ grows by 1.5 per sample: threshold 5 after 4 samples
    assert steps == 4 and bank.alarms.tolist() == [True, False]
    assert bank.statistic()[0] == 1.0  # capped at the threshold
    # back to zero: S⁺ falls by k = 0.5 per sample, clears below 2.5 after 6 samples
    clears = next(k for k in range(1, 30) if not bank.update(z))
    assert clears == 6


def test_bank_variance_chart_sees_a_larger_noise():
    bank = CusumBank(1, 0.5, 1e9, 4.0, 10.0)
    rng = np.random.default_rng(1)
    assert not any(bank.update(rng.standard_normal(1)) for _ in range(200))
    hit = next(k for k in range(1, 500) if bank.update(3.0 * rng.standard_normal(1)))
    assert hit < 100


def test_bank_started_in_alarm_clears_when_nothing_is_there():
    bank = _bank()
    bank.start_in_alarm()
    assert bank.any_alarm
    zeros = np.zeros(2)
    # the mean charts fall by k = 0.5 per sample from 5: below 2.5 (release) after 6
    # samples; the variance chart by ln 2, below after 4
    assert [bank.update(zeros) for _ in range(6)] == [True] * 5 + [False]


def test_bank_state_round_trip_and_bad_state():
    bank = _bank()
    rng = np.random.default_rng(2)
    for _ in range(30):
        bank.update(rng.standard_normal(2) + 1.5)
    state = bank.get_state()
    other = _bank()
    other.set_state(state)
    z = rng.standard_normal((20, 2))
    assert [bank.update(x) for x in z] == [other.update(x) for x in z]
    np.testing.assert_array_equal(bank.statistic(), other.statistic())
    with pytest.raises(ValueError, match="outside"):
        other.set_state({**state, "s": np.full(6, 99.0)})


@pytest.mark.parametrize(("kwargs", "name"), [
    ({"k": 0.0}, "k"), ({"h_mean": -1.0}, "h_mean"), ({"variance_ratio": 1.0},
                                                      "variance_ratio"),
    ({"release": 1.0}, "release"), ({"n_channels": 0}, "n_channels"),
])
def test_bank_rejects_bad_settings(kwargs, name):
    args = {"n_channels": 2, "k": 0.5, "h_mean": 5.0, "variance_ratio": 4.0,
            "h_variance": 5.0, **kwargs}
    with pytest.raises(ValueError, match=name):
        CusumBank(**args)


# ------------------------------------------------------------------ residual model

@pytest.fixture(scope="module")
def main_model():
    m = seed_aircraft()
    k = design_detection_filter(m.A, m.C, np.eye(5), -np.arange(1.0, 6.0))
    f = DetectionFilter(m.A, m.B, m.C, k, T)
    return ResidualModel(f.closed_loop_matrix, f.discrete_gain, m.C)


def test_residual_is_coloured_as_design_says(main_model):
    """docs/methods.md §4: the q residual is 1.03 σ with autocorrelation ≈ 0.06 at lags 1–5;
    its long-run variance (spectral density at 0) is what a CUSUM integrates: 5.3 times
    the variance on q, and 0 on v and h (a constant offset of them is a state)."""
    var = NOISE_STD**2
    cov = main_model.residual_covariance(var)
    std = np.sqrt(np.diag(cov))
    assert std[2] / NOISE_STD[2] == pytest.approx(1.034, abs=2e-3)
    for lag in range(1, 6):
        rho = main_model.autocovariance(var, lag)[2, 2] / cov[2, 2]
        assert 0.05 < rho < 0.065
    dc = main_model.dc_gain()
    long_run = np.diag(dc @ np.diag(var) @ dc.T) / np.diag(cov)
    assert long_run[2] == pytest.approx(5.27, abs=0.05)
    assert long_run[0] == pytest.approx(0.0, abs=1e-12)
    assert long_run[5] < 0.06


def _simulate_residual(model, std, n, rng):
    e = np.zeros(model.n)
    out = np.empty((n, model.m))
    for k in range(n):
        v = std * rng.standard_normal(model.m)
        out[k] = model.C @ e + v
        e = model.F @ e - model.L @ v
    return out


def test_whitening_makes_the_residual_white(main_model):
    var = NOISE_STD**2
    w = main_model.whitening(var, regularisation=0.01)
    assert np.max(np.abs(np.linalg.eigvals(w.closed_loop))) < 1.0
    # analytic: innovations of the regularised model are white with covariance S;
    # check on a simulated record of the real (unregularised) residual
    rng = np.random.default_rng(3)
    r = _simulate_residual(main_model, NOISE_STD, 60000, rng)
    e = np.zeros(main_model.n)
    eps = np.empty_like(r)
    for k in range(r.shape[0]):
        eps[k] = r[k] - w.C @ e
        e = w.F @ e + w.K @ eps[k]
    z = eps[2000:] / w.scale
    n = z.shape[0]
    for lag in range(1, 6):
        rho = np.mean(z[lag:] * z[:-lag], axis=0) / np.mean(z * z, axis=0)
        assert np.all(np.abs(rho) < 4.0 / math.sqrt(n)), (lag, rho)
    # regularisation: the real residual comes out at or below unit variance
    assert np.all(z.var(axis=0) < 1.0 + 5.0 * math.sqrt(2.0 / n))
    assert np.all(z.var(axis=0) > 0.9)


def test_sensor_variances_are_recovered_from_residuals(main_model):
    rng = np.random.default_rng(4)
    r = _simulate_residual(main_model, NOISE_STD, 40000, rng)[500:]
    got = np.sqrt(estimate_sensor_variances(r, main_model))
    np.testing.assert_allclose(got, NOISE_STD, rtol=0.03)


def test_sensor_variances_of_a_window_without_noise(main_model):
    # all-zero inputs (fmpy simulate with defaults) made the weights 1/tiny and the
    # weighted map inf: nnls failed with "array must not contain infs or NaNs"
    assert np.array_equal(estimate_sensor_variances(np.zeros((200, main_model.m)),
                                                    main_model), np.zeros(main_model.m))
    rng = np.random.default_rng(5)
    r = _simulate_residual(main_model, NOISE_STD, 20000, rng)[500:]
    r[:, 0] = 0.0  # one channel noise-free, the others as before
    got = estimate_sensor_variances(r, main_model)
    assert np.all(np.isfinite(got)) and np.all(got >= 0.0)
    assert np.all(got[1:] > 0.0)


def test_variance_map_is_linear_and_matches_lyapunov(main_model):
    var = NOISE_STD**2
    direct = np.diag(main_model.residual_covariance(var))
    np.testing.assert_allclose(main_model.variance_map() @ var, direct, rtol=1e-10)
    p = scipy.linalg.solve_discrete_lyapunov(
        main_model.F, main_model.L @ np.diag(var) @ main_model.L.T)
    np.testing.assert_allclose(main_model.state_covariance(var), p, rtol=1e-12)


def test_residual_model_rejects_an_unstable_filter():
    with pytest.raises(ValueError, match="F must be stable"):
        ResidualModel(np.array([[1.0]]), np.ones((1, 1)), np.ones((1, 1)))
