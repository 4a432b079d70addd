"""Detection-filter design, sampled-data filter, thresholds and alarms (docs/methods.md §4)."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.signal

from gyrodiag.df.filter import (
    DetectionFilter,
    ResidualEvaluator,
    ResidualThresholds,
    design_detection_filter,
    gaussian_k_sigma,
    observability_matrix,
    parity_space,
    zoh_discretise,
)
from gyrodiag.df.plant import PAPER_EIGENVALUES, PAPER_PRINTED_K, seed_aircraft

MODEL = seed_aircraft()
A, B, C = MODEL.A, MODEL.B, MODEL.C
F = np.eye(5)


@pytest.fixture(scope="module")
def gain() -> np.ndarray:
    return design_detection_filter(A, C, F, PAPER_EIGENVALUES)


# ------------------------------------------------------------------------ model


def test_seed_model_ranks_and_open_loop_eigenvalues():
    # docs/methods.md §4: ctrb rank 4 (v uncontrollable), obsv rank 5, unstable +1.46, +0.99.
    ctrb = np.hstack([np.linalg.matrix_power(A, k) @ B for k in range(5)])
    assert np.linalg.matrix_rank(ctrb) == 4
    assert np.linalg.matrix_rank(observability_matrix(A, C)) == 5
    eig = np.sort(np.linalg.eigvals(A).real)
    np.testing.assert_allclose(eig, [-5.4735, 0.0, 0.0, 0.99075, 1.45865], atol=1e-4)
    assert MODEL.output_names[MODEL.output_index("q")] == "q"
    assert MODEL.output_units[2] == "rad/s"
    with pytest.raises(ValueError, match="name"):
        MODEL.output_index("pitch")


def test_model_arrays_are_read_only():
    with pytest.raises(ValueError):
        MODEL.A[0, 0] = 1.0


# ----------------------------------------------------------------------- design


def test_designed_gain_places_eigenvalues_and_eigenvectors(gain):
    closed = A - gain @ C
    # F = I5: A - K C must be exactly diag(λ), i.e. each e_i an eigenvector.
    np.testing.assert_allclose(closed, np.diag(PAPER_EIGENVALUES), atol=1e-9)
    np.testing.assert_allclose(
        np.sort(np.linalg.eigvals(closed).real), np.sort(PAPER_EIGENVALUES), atol=1e-9
    )


def test_designed_gain_is_minimum_norm_and_free_part_is_parity(gain):
    w = parity_space(C)
    assert w.shape == (1, 6)
    # docs/methods.md §4: left null vector [0, 1, 0, -1, 1, 0] (α − θ + γ = 0).
    np.testing.assert_allclose(np.abs(w[0]), np.abs([0, 1, 0, -1, 1, 0]) / np.sqrt(3), atol=1e-12)
    # Min-norm: K has no component along the parity direction.
    np.testing.assert_allclose(gain @ w[0], 0.0, atol=1e-10)
    # Adding N = z wᵀ leaves A − K C unchanged but increases ‖K‖.
    other = gain + np.outer(np.arange(1.0, 6.0), w[0])
    np.testing.assert_allclose(A - other @ C, A - gain @ C, atol=1e-12)
    assert np.linalg.norm(other) > np.linalg.norm(gain)


def test_paper_printed_gain_is_unstable():
    eig = np.sort(np.linalg.eigvals(A - PAPER_PRINTED_K @ C).real)
    # Computed: {-5.7475, -5, -3.8820, -1, +2.4669}; methods §4 quotes -5.75, -5, -3.88, -1, +2.47.
    np.testing.assert_allclose(eig, [-5.7475, -5.0, -3.8820, -1.0, 2.4669], atol=1e-3)
    assert eig.max() > 2.0


def test_paper_printed_gain_also_fails_with_the_printed_minus_sign():
    # The paper's filter equation prints −K; even with that sign A + K C is unstable.
    assert np.linalg.eigvals(A + PAPER_PRINTED_K @ C).real.max() > 0.5


def test_design_general_directions():
    # Non-orthogonal directions: A − K C = F Λ F⁻¹ exactly.
    f = np.eye(5) + 0.3 * np.random.default_rng(1).normal(size=(5, 5))
    k = design_detection_filter(A, C, f, PAPER_EIGENVALUES)
    closed = A - k @ C
    np.testing.assert_allclose(closed @ f, f * PAPER_EIGENVALUES, atol=1e-9)


def test_design_partial_direction_set_leaves_free_modes_unstable():
    # Only the q direction: the minimum-norm K leaves the other 4 modes at 0 (not stable).
    with pytest.raises(ValueError, match="4 modes left free"):
        design_detection_filter(A, C, np.eye(5)[:, [2]], [-2.0])


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"A": np.zeros((5, 4))}, "A must be square"),
        ({"C": np.eye(6, 4)}, "C must have shape"),
        ({"fault_directions": np.eye(4)}, "fault_directions must have shape"),
        ({"eigenvalues": [-1.0, -2.0]}, "eigenvalues must have shape"),
        ({"C": np.eye(6, 5)[[5]], "fault_directions": np.eye(5)[:, :1],
          "eigenvalues": [-1.0]}, "observable"),
        ({"eigenvalues": [-1.0, -2.0, -2.0, -4.0, -5.0]}, "distinct"),
        ({"eigenvalues": [-1.0, -2.0, 0.5, -4.0, -5.0]}, "stable"),
        ({"eigenvalues": [-1.0, -2.0, 0.0, -4.0, -5.0]}, "stable"),
        ({"eigenvalues": np.array([-1, -2, -3 + 1j, -3 - 1j, -5])}, "real"),
        ({"eigenvalues": [-1.0, -2.0, np.nan, -4.0, -5.0]}, "eigenvalues must contain only"),
        ({"fault_directions": np.eye(5)[:, [0, 1, 1]], "eigenvalues": [-1.0, -2.0, -3.0]},
         "linearly independent"),
    ],
)
def test_design_rejects_impossible_specs(kwargs, match):
    args = {"A": A, "C": C, "fault_directions": F, "eigenvalues": PAPER_EIGENVALUES}
    args.update(kwargs)
    with pytest.raises(ValueError, match=match):
        design_detection_filter(**args)


def test_design_rejects_rank_cf_deficit():
    # Observable pair (v and h rows alone are not, so use q, θ, v, h: rank 4 in 5 states),
    # but 4 outputs cannot separate 5 fault directions: rank(C F) = 4 < r = 5.
    c_short = C[[0, 2, 3, 5]]
    assert np.linalg.matrix_rank(observability_matrix(A, c_short)) == 5
    with pytest.raises(ValueError, match=r"rank\(C F\)"):
        design_detection_filter(A, c_short, F, PAPER_EIGENVALUES)


# --------------------------------------------------------------- discretisation


def test_zoh_discretise_matches_cont2discrete():
    phi, gam = zoh_discretise(A, B, 0.01)
    ref = scipy.signal.cont2discrete((A, B, C, np.zeros((6, 2))), 0.01, method="zoh")
    np.testing.assert_allclose(phi, ref[0], atol=1e-12)
    np.testing.assert_allclose(gam, ref[1], atol=1e-12)


def _lsim_plant(t: np.ndarray, u: np.ndarray, x0: np.ndarray) -> np.ndarray:
    # scipy's lsim with interp=False holds u over each step (ZOH): independent of our expm.
    _, y, _ = scipy.signal.lsim((A, B, C, np.zeros((6, 2))), u, t, X0=x0, interp=False)
    return y


def test_noise_free_plant_gives_zero_residual(gain):
    rng = np.random.default_rng(3)
    dt = 0.01
    t = np.arange(0.0, 5.0, dt)
    u = np.column_stack([rng.normal(size=t.size), 0.05 * rng.normal(size=t.size)])
    x0 = np.array([2.0, 0.01, -0.02, 0.03, 10.0])
    y = _lsim_plant(t, u, x0)
    filt = DetectionFilter(A, B, C, gain, dt)
    filt.reset(x0)
    residuals = np.array([filt.update(u[k], y[k]) for k in range(t.size)])
    # The plant grows (unstable modes, h up to hundreds of metres); residual stays ~0.
    assert np.abs(y).max() > 10.0
    assert np.abs(residuals).max() < 1e-9


def test_initial_error_decays_with_designed_eigenvalues(gain):
    dt = 0.01
    t = np.arange(0.0, 3.0, dt)
    u = np.zeros((t.size, 2))
    y = np.zeros((t.size, 6))  # plant at rest in x = 0
    for i, lam in enumerate(PAPER_EIGENVALUES):
        filt = DetectionFilter(A, B, C, gain, dt)
        filt.reset(np.eye(5)[i])  # estimate error e(0) = −e_i
        residuals = np.array([filt.update(u[k], y[k]) for k in range(t.size)])
        # e_i is an eigenvector: γ(t) = −C e_i exp(λ_i t), exactly at the samples.
        expected = -np.outer(np.exp(lam * t), C[:, i])
        np.testing.assert_allclose(residuals, expected, atol=1e-12)


def test_discrete_error_dynamics_are_exact_exponential(gain):
    dt = 0.02
    filt = DetectionFilter(A, B, C, gain, dt)
    np.testing.assert_allclose(
        filt.closed_loop_matrix, np.diag(np.exp(PAPER_EIGENVALUES * dt)), atol=1e-12
    )
    assert filt.discretisation == "exact_error"
    assert filt.sample_period_s == dt


def test_literal_zoh_of_filter_leaves_order_dt_residual(gain):
    # Holding y over the step (plain ZOH of the filter) is not consistent with the
    # moving plant output: fault-free residual O(T). Halving T halves it.
    peaks = []
    for dt in (0.01, 0.005):
        t = np.arange(0.0, 3.0, dt)
        u = np.column_stack([np.zeros(t.size), 0.05 * np.sign(np.sin(2.0 * t))])
        x0 = np.array([0.0, 0.01, 0.0, 0.02, 0.0])
        y = _lsim_plant(t, u, x0)
        filt = DetectionFilter(A, B, C, gain, dt, discretisation="zoh")
        filt.reset(x0)
        res = np.array([filt.update(u[k], y[k]) for k in range(t.size)])
        peaks.append(np.abs(res[:, 2]).max())
    assert peaks[0] > 1e-4
    assert peaks[0] / peaks[1] == pytest.approx(2.0, rel=0.1)


# ------------------------------------------------------------- streaming contract


def _run(filt: DetectionFilter, u: np.ndarray, y: np.ndarray) -> np.ndarray:
    return np.array([filt.update(u[k], y[k]) for k in range(len(u))])


def _noisy_data(n: int = 300, seed: int = 5) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    return 0.01 * rng.normal(size=(n, 2)), 0.01 * rng.normal(size=(n, 6))


def test_state_round_trip_and_reset(gain):
    u, y = _noisy_data()
    filt = DetectionFilter(A, B, C, gain, 0.01)
    _run(filt, u[:100], y[:100])
    snap = filt.get_state()
    first = _run(filt, u[100:], y[100:])
    snap_copy = {k: np.copy(v) for k, v in snap.items()}
    snap["z"][0] = 99.0  # get_state must return a copy, not a view of the state
    assert filt.get_state()["z"][0] != 99.0
    filt.set_state(snap_copy)
    np.testing.assert_array_equal(_run(filt, u[100:], y[100:]), first)
    assert filt.get_state()["n_updates"] == 300
    filt.reset()
    fresh = DetectionFilter(A, B, C, gain, 0.01)
    np.testing.assert_array_equal(_run(filt, u, y), _run(fresh, u, y))


@pytest.mark.parametrize(
    ("u", "y", "name"),
    [
        ([np.nan, 0.0], np.zeros(6), "u"),
        ([0.0, 0.0], [0, 0, np.inf, 0, 0, 0], "y"),
        ([0.0], np.zeros(6), "u"),
        ([0.0, 0.0], np.zeros(5), "y"),
    ],
)
def test_bad_update_raises_naming_argument_and_keeps_state(gain, u, y, name):
    filt = DetectionFilter(A, B, C, gain, 0.01)
    filt.update([0.1, 0.2], np.arange(6.0))
    before = filt.get_state()
    with pytest.raises(ValueError, match=rf"^{name} must"):
        filt.update(u, y)
    after = filt.get_state()
    for key, val in before.items():
        np.testing.assert_array_equal(after[key], val)


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"sample_period_s": 0.0}, "sample_period_s"),
        ({"sample_period_s": float("nan")}, "sample_period_s"),
        ({"K": np.zeros((5, 5))}, "K must have shape"),
        ({"B": np.zeros((4, 2))}, "B must have shape"),
        ({"discretisation": "euler"}, "discretisation"),
    ],
)
def test_filter_constructor_rejects_bad_arguments(gain, kwargs, match):
    args = {"A": A, "B": B, "C": C, "K": gain, "sample_period_s": 0.01}
    args.update(kwargs)
    with pytest.raises(ValueError, match=match):
        DetectionFilter(**args)


def test_exact_error_needs_solvable_gain():
    # C without full column rank: L C = Φ − e^{(A−KC)T} generally has no solution.
    c_short = C[[0, 2, 3, 5]]
    k = np.full((5, 4), 0.5)
    with pytest.raises(ValueError, match="discretisation='zoh'"):
        DetectionFilter(A, B, c_short, k, 0.01)


def test_set_state_rejects_bad_state(gain):
    filt = DetectionFilter(A, B, C, gain, 0.01)
    with pytest.raises(ValueError, match="missing"):
        filt.set_state({"z": np.zeros(5)})
    good = filt.get_state()
    good["z"] = np.zeros(4)
    with pytest.raises(ValueError, match=r"state\['z'\]"):
        filt.set_state(good)


# ------------------------------------------------------------ thresholds, alarms


def test_thresholds_from_fault_free_statistics():
    rng = np.random.default_rng(11)
    data = rng.normal(loc=[0.0, 1.0], scale=[1.0, 0.01], size=(200_000, 2))
    thr = ResidualThresholds.from_fault_free(data, false_alarm_rate=1e-3)
    assert thr.k_sigma == pytest.approx(3.2905, abs=1e-4)  # two-sided Gaussian quantile
    np.testing.assert_allclose(thr.mean, [0.0, 1.0], atol=0.01)
    np.testing.assert_allclose(thr.std, [1.0, 0.01], rtol=0.01)
    # Fresh data: measured exceedance rate close to the design figure.
    fresh = rng.normal(loc=[0.0, 1.0], scale=[1.0, 0.01], size=(200_000, 2))
    rate = np.mean(np.abs(fresh - thr.mean) > thr.threshold, axis=0)
    np.testing.assert_allclose(rate, 1e-3, rtol=0.3)
    thr6 = ResidualThresholds.from_fault_free(data, k_sigma=6.0, burn_in=10)
    np.testing.assert_allclose(thr6.threshold, 6.0 * thr6.std)
    assert gaussian_k_sigma(0.05) == pytest.approx(1.95996, abs=1e-5)


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({}, "exactly one"),
        ({"k_sigma": 3.0, "false_alarm_rate": 0.01}, "exactly one"),
        ({"false_alarm_rate": 0.7}, "false_alarm_rate"),
        ({"k_sigma": -1.0}, "k_sigma"),
        ({"k_sigma": 3.0, "burn_in": 99}, "burn_in"),
    ],
)
def test_thresholds_reject_bad_arguments(kwargs, match):
    with pytest.raises(ValueError, match=match):
        ResidualThresholds.from_fault_free(np.random.default_rng(0).normal(size=(100, 2)),
                                           **kwargs)


def test_evaluator_persistence_k_of_n():
    thr = ResidualThresholds(mean=np.zeros(2), std=np.ones(2), threshold=np.ones(2), k_sigma=1.0)
    ev = ResidualEvaluator(thr, persistence_k=2, persistence_n=3)
    seq = [[2.0, 0.0], [0.0, 0.0], [2.0, 0.5], [0.0, -3.0], [0.0, 0.0], [0.0, 0.0]]
    alarms = []
    norms = []
    for r in seq:
        a, nrm = ev.update(r)
        alarms.append(a.copy())
        norms.append(nrm)
    # Channel 0 exceeds at samples 0 and 2: 2-of-3 met at sample 2 and still at 3.
    assert [a[0] for a in alarms] == [False, False, True, False, False, False]
    assert [a[1] for a in alarms] == [False] * 6
    np.testing.assert_allclose(norms[3], [0.0, -3.0])
    ev.reset()
    saved = ev.get_state()
    ev.update([5.0, 5.0])
    out1 = ev.update([5.0, 5.0])
    ev.set_state(saved)
    ev.update([5.0, 5.0])
    np.testing.assert_array_equal(ev.update([5.0, 5.0])[0], out1[0])
    with pytest.raises(ValueError, match="persistence_k"):
        ResidualEvaluator(thr, persistence_k=4, persistence_n=3)
    with pytest.raises(ValueError, match="residual"):
        ev.update([np.nan, 0.0])


def test_unchecked_paths_match_checked_ones_bit_for_bit(gain):
    # The isolator's bank validates a sample once and steps its observers and
    # evaluators unchecked: the unchecked path must be the same arithmetic.
    checked = DetectionFilter(A, B, C, gain, 0.01)
    unchecked = DetectionFilter(A, B, C, gain, 0.01)
    rng = np.random.default_rng(3)
    thr = ResidualThresholds(mean=np.full(6, 0.01), std=np.ones(6),
                             threshold=np.full(6, 0.05), k_sigma=3.0)
    ev_checked = ResidualEvaluator(thr, persistence_k=2, persistence_n=3)
    ev_unchecked = ResidualEvaluator(thr, persistence_k=2, persistence_n=3)
    for _ in range(200):
        u, y = rng.normal(size=2), rng.normal(scale=0.1, size=6)
        r1 = checked.update(u, y)
        r2 = unchecked.advance(u, y)
        np.testing.assert_array_equal(r1, r2)
        a1, n1 = ev_checked.update(r1)
        a2, n2 = ev_unchecked.advance(r2)
        np.testing.assert_array_equal(a1, a2)
        np.testing.assert_array_equal(n1, n2)
    np.testing.assert_array_equal(checked.get_state()["z"], unchecked.get_state()["z"])
    assert checked.get_state()["n_updates"] == unchecked.get_state()["n_updates"] == 200
    # the checked path still names a bad sample and leaves the state as it was
    before = checked.get_state()
    with pytest.raises(ValueError, match="y must contain only finite"):
        checked.update(np.zeros(2), [0, 0, np.nan, 0, 0, 0])
    np.testing.assert_array_equal(checked.get_state()["z"], before["z"])
