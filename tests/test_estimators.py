import numpy as np
import pytest

from gyrodiag.common.estimators import RLS, ForgettingRLS, SlidingWindowLS, batch_ls

THETA_A = np.array([1.96, 0.96, -0.0288, -0.0288, 0.00096])


def _regression(n, theta, noise, seed):
    rng = np.random.default_rng(seed)
    phi = rng.standard_normal((n, theta.size))
    y = phi @ theta + noise * rng.standard_normal(n)
    return phi, y


def _run(est, phi, y):
    return np.array([est.update(p, v).copy() for p, v in zip(phi, y, strict=True)])


def test_batch_ls_matches_normal_equation_solution_on_well_conditioned_data():
    phi, y = _regression(500, THETA_A, 0.01, seed=1)
    ref = np.linalg.solve(phi.T @ phi, phi.T @ y)
    np.testing.assert_allclose(batch_ls(phi, y), ref, rtol=1e-10)


def test_batch_ls_rejects_rank_deficient_record():
    phi = np.zeros((50, 5))
    phi[:, 0] = 1.0
    with pytest.raises(ValueError, match="rank 1 < n_params 5"):
        batch_ls(phi, np.ones(50))


@pytest.mark.parametrize("cls", [RLS, ForgettingRLS])
def test_rls_without_forgetting_equals_batch_ls(cls):
    phi, y = _regression(2000, THETA_A, 0.05, seed=2)
    kwargs = {"forgetting": 1.0} if cls is ForgettingRLS else {}
    est = cls(5, p0=1e10, **kwargs)
    _run(est, phi, y)
    np.testing.assert_allclose(est.theta, batch_ls(phi, y), rtol=1e-6)
    # and at an intermediate sample, against the batch solution of the prefix
    est.reset()
    _run(est, phi[:300], y[:300])
    np.testing.assert_allclose(est.theta, batch_ls(phi[:300], y[:300]), rtol=1e-6)


def test_forgetting_rls_tracks_a_step_change_within_a_few_hundred_samples():
    theta_b = THETA_A * np.array([0.5, 1.0, 3.0, 3.0, 1.0])
    phi1, y1 = _regression(2000, THETA_A, 1e-3, seed=3)
    phi2, y2 = _regression(2000, theta_b, 1e-3, seed=4)
    est = ForgettingRLS(5, forgetting=0.99, p0=1e6)
    _run(est, phi1, y1)
    traj = _run(est, phi2, y2)
    err = np.linalg.norm(traj - theta_b, axis=1) / np.linalg.norm(theta_b)
    settled = int(np.argmax(err < 0.02))
    assert err[settled] < 0.02
    # The old data's weight decays as 0.99**n, so the error of the old θ decays alike:
    # n_theory = ln(0.02 / err0) / ln(0.99) samples to get within 2 %.
    err0 = np.linalg.norm(THETA_A - theta_b) / np.linalg.norm(theta_b)
    n_theory = np.log(0.02 / err0) / np.log(0.99)
    assert settled < 1.3 * n_theory, f"took {settled} samples, theory {n_theory:.0f}"
    assert settled < 500, f"took {settled} samples to track within 2 %"
    assert np.all(err[settled + 100 :] < 0.02), "did not stay on the new θ"
    # plain RLS, with memory of all 2000 old samples, is still far off after 300
    plain = RLS(5, p0=1e6)
    _run(plain, phi1, y1)
    traj_plain = _run(plain, phi2[:300], y2[:300])
    assert np.linalg.norm(traj_plain[-1] - theta_b) / np.linalg.norm(theta_b) > 0.2


def test_no_covariance_windup_over_a_million_quiet_samples():
    est = ForgettingRLS(5, forgetting=0.99, p0=1e4)
    phi, y = _regression(200, THETA_A, 1e-3, seed=5)
    _run(est, phi, y)
    theta_before = est.theta.copy()
    zero = np.zeros(5)
    max_trace_seen = 0.0
    for k in range(1_000_000):
        est.update(zero, 0.0)
        if k % 10_000 == 0:
            max_trace_seen = max(max_trace_seen, float(np.trace(est.P)))
    P = est.P
    assert np.all(np.isfinite(P))
    assert np.trace(P) <= est.max_trace * (1 + 1e-9)
    assert max_trace_seen <= est.max_trace * (1 + 1e-9)
    assert np.min(np.linalg.eigvalsh(P)) > 0.0
    np.testing.assert_array_equal(est.theta, theta_before)  # no data, no change
    # unbounded forgetting would have grown P by 0.99**-1e6 (overflow): the bound is
    # what keeps it finite; excitation afterwards re-identifies θ
    _run(est, *_regression(300, THETA_A, 1e-3, seed=6))
    np.testing.assert_allclose(est.theta, THETA_A, rtol=1e-2, atol=5e-4)


def test_sliding_window_ls_equals_batch_ls_of_the_last_window():
    phi, y = _regression(1000, THETA_A, 0.05, seed=7)
    est = SlidingWindowLS(5, window=200)
    traj = _run(est, phi, y)
    for k in (9, 199, 200, 517, 999):
        lo = max(0, k + 1 - 200)
        np.testing.assert_allclose(traj[k], batch_ls(phi[lo : k + 1], y[lo : k + 1]), rtol=1e-9)
    assert est.well_posed


def test_sliding_window_holds_theta0_until_full_rank():
    est = SlidingWindowLS(3, window=10, theta0=[1.0, 2.0, 3.0])
    est.update([1.0, 0.0, 0.0], 5.0)
    np.testing.assert_array_equal(est.theta, [1.0, 2.0, 3.0])
    est.update([1.0, 0.0, 0.0], 5.0)
    est.update([2.0, 0.0, 0.0], 10.0)  # three rows, rank 1
    assert not est.well_posed
    np.testing.assert_array_equal(est.theta, [1.0, 2.0, 3.0])


def test_convergence_flag_uses_the_paper_criterion():
    phi, y = _regression(600, THETA_A, 0.0, seed=8)
    est = RLS(5, p0=1e8)
    traj = _run(est, phi, y)
    assert est.converged
    k = est.converged_at
    assert k is not None
    step = np.max(np.abs(np.diff(traj, axis=0)), axis=1)
    assert step[k - 2] < 1e-5  # update number k moved θ by < 1e−5
    assert np.all(step[: k - 2] >= 1e-5)


@pytest.mark.parametrize(
    "make",
    [
        lambda: RLS(5, p0=1e6),
        lambda: ForgettingRLS(5, forgetting=0.98, p0=1e3),
        lambda: SlidingWindowLS(5, window=50),
    ],
)
def test_state_round_trip_reset_and_nan_rejection(make):
    phi, y = _regression(300, THETA_A, 0.01, seed=9)
    est = make()
    _run(est, phi[:150], y[:150])
    saved = est.get_state()
    first = _run(est, phi[150:], y[150:])
    est.set_state(saved)
    np.testing.assert_array_equal(_run(est, phi[150:], y[150:]), first)
    before = est.get_state()
    with pytest.raises(ValueError, match="phi must contain only finite"):
        est.update([np.nan, 0, 0, 0, 0], 1.0)
    with pytest.raises(ValueError, match="y must contain only finite"):
        est.update(np.ones(5), np.inf)
    after = est.get_state()
    for key, value in before.items():
        np.testing.assert_array_equal(after[key], value)
    est.reset()
    fresh = make()
    np.testing.assert_array_equal(_run(est, phi, y), _run(fresh, phi, y))


@pytest.mark.parametrize(
    ("factory", "name"),
    [
        (lambda: RLS(0), "n_params"),
        (lambda: RLS(5, p0=-1.0), "p0"),
        (lambda: RLS(5, theta0=[1.0, 2.0]), "theta0"),
        (lambda: ForgettingRLS(5, forgetting=1.2), "forgetting"),
        (lambda: ForgettingRLS(5, forgetting=0.0), "forgetting"),
        (lambda: ForgettingRLS(5, p0=10.0, max_trace=1.0), "max_trace"),
        (lambda: SlidingWindowLS(5, window=3), "window"),
        (lambda: RLS(5, convergence_tol=0.0), "convergence_tol"),
    ],
)
def test_bad_arguments_name_the_argument(factory, name):
    with pytest.raises((ValueError, TypeError), match=name):
        factory()
