"""Known answers of the DTG paper's decision table (docs/methods.md §2)."""

import numpy as np
import pytest

from gyrodiag.dtg.decision import (
    UNKNOWN_CODE,
    SignatureClassifier,
    ThresholdDecision,
    WindowedMedianFeature,
    feature_vector,
    median_feature,
    parameter_ratios,
    signature_distance,
)

THETA_NOM = [1.9951, 0.9959, -0.0288, -0.0303, 0.0002]
THETA_F = {
    "f1_step": [1.0055, 0.0058, -0.8660, -0.8881, 0.0032],
    "f2_noise": [0.3394, -0.3240, 1.2404, 0.9521, 0.0320],
    "f3_signal_loss": [-0.0040, 0.0604, -0.2406, -0.3054, 0.0081],
    "f4_drift": [1.9946, 0.9955, -0.0195, -0.0198, 0.00002],
}
C_PRINTED = {
    "f1_step": [0, -2, 1, 1, 1],
    "f2_noise": [-1, 0, 2, 1, 2],
    "f3_signal_loss": [-3, -1, 1, 1, 2],
    "f4_drift": [0, 0, 0, 0, 1],  # the paper's print; the formula gives [0,0,0,0,-1]
}


@pytest.mark.parametrize("fault", ["f1_step", "f2_noise", "f3_signal_loss"])
def test_feature_vectors_match_the_paper(fault):
    eta = parameter_ratios(THETA_F[fault], THETA_NOM)
    np.testing.assert_array_equal(feature_vector(eta), C_PRINTED[fault])


def test_paper_eta_values():
    eta = {f: parameter_ratios(t, THETA_NOM) for f, t in THETA_F.items()}
    # the paper prints η_f1 = [0.5, 0.0058, 30, 30, 15], η_f3 = [0.002, 0.06, 8.36, 10, 37.4]
    np.testing.assert_allclose(eta["f1_step"], [0.504, 0.00582, 30.07, 29.31, 16.0], rtol=2e-3)
    np.testing.assert_allclose(eta["f3_signal_loss"][:4], [0.002, 0.0606, 8.354, 10.08],
                               rtol=3e-3)


def test_f4_drift_printed_ratios_are_reciprocals():
    """The paper prints η_f4 = [1.00, 1.00, 1.47, 1.5, 10.35]; the formula gives the
    reciprocals of the last three: [1.00, 1.00, 0.68, 0.65, 0.10], C_f4 = [0,0,0,0,−1]."""
    eta = parameter_ratios(THETA_F["f4_drift"], THETA_NOM)
    np.testing.assert_allclose(eta, [0.99975, 0.99960, 0.67708, 0.65347, 0.1], rtol=1e-4)
    np.testing.assert_allclose(1 / eta[2:4], [1.477, 1.530], rtol=2e-3)
    np.testing.assert_array_equal(feature_vector(eta), [0, 0, 0, 0, -1])


def test_all_four_paper_faults_alarm_and_nominal_does_not():
    for theta in THETA_F.values():
        dec = ThresholdDecision(THETA_NOM)
        assert dec.update(theta).alarm
    dec = ThresholdDecision(THETA_NOM)
    out = dec.update(THETA_NOM)
    assert not out.alarm and not out.violation
    np.testing.assert_array_equal(out.eta, np.ones(5))


def test_which_parameters_leave_the_band():
    out = ThresholdDecision(THETA_NOM).update(THETA_F["f1_step"])
    # η_f1 = [0.504, 0.0058, 30, 29, 16]: θ1 stays just inside the 0.5 limit
    np.testing.assert_array_equal(out.out_of_band, [False, True, True, True, True])
    out4 = ThresholdDecision(THETA_NOM).update(THETA_F["f4_drift"])
    np.testing.assert_array_equal(out4.out_of_band, [False, False, False, False, True])
    masked = ThresholdDecision(THETA_NOM, monitored=[True, True, True, True, False])
    # without θ5, drift f4 (η3 = 0.68, η4 = 0.65) stays inside the band
    assert not masked.update(THETA_F["f4_drift"]).alarm


def test_eq7_distances_with_printed_vectors():
    clf = SignatureClassifier(C_PRINTED)
    d = clf.pairwise_distances()
    names = list(C_PRINTED)
    got = {(a, b): d[i, j] for i, a in enumerate(names) for j, b in enumerate(names)}
    # matches the paper: d(f1,f3) = d(f1,f2) = d(f2,f4) = 1, d(f3,f4) = 1.4
    assert got["f1_step", "f3_signal_loss"] == pytest.approx(1.0)
    assert got["f1_step", "f2_noise"] == pytest.approx(1.0)
    assert got["f2_noise", "f4_drift"] == pytest.approx(1.0)
    assert got["f3_signal_loss", "f4_drift"] == pytest.approx(1.4)
    # the paper prints 0.9 for these two; eq. 7 on its own vectors gives 0.8
    assert got["f1_step", "f4_drift"] == pytest.approx(0.8)
    assert got["f2_noise", "f3_signal_loss"] == pytest.approx(0.8)
    np.testing.assert_allclose(np.diag(d), 0.0)


def test_classifier_recovers_each_fault_from_its_theta():
    computed = {
        f: feature_vector(parameter_ratios(t, THETA_NOM)) for f, t in THETA_F.items()
    }
    clf = SignatureClassifier(computed)
    for code, (fault, theta) in enumerate(THETA_F.items(), start=1):
        res = clf.classify(feature_vector(parameter_ratios(theta, THETA_NOM)))
        assert res.label == fault and res.code == code and res.distance == 0.0


def test_classifier_unknown_beyond_max_distance():
    clf = SignatureClassifier(C_PRINTED, max_distance=0.5)
    res = clf.classify([5, 5, 5, 5, 5])
    assert res.label == "unknown" and res.code == UNKNOWN_CODE
    assert res.distance == pytest.approx(min(res.distances.values()))
    near = clf.classify([0, -2, 1, 1, 2])  # one step from f1
    assert near.label == "f1_step" and near.distance == pytest.approx(0.2)


def test_persistence_k_of_n_and_latching():
    bad, good = THETA_F["f1_step"], THETA_NOM
    dec = ThresholdDecision(THETA_NOM, persistence_k=2, persistence_n=3)
    alarms = [dec.update(t).alarm for t in [bad, good, good, bad, good, bad, good, good]]
    assert alarms == [False, False, False, False, False, True, False, False]
    latched = ThresholdDecision(THETA_NOM, latch=True)
    outs = [latched.update(t) for t in [good, bad, good, good]]
    assert [o.alarm for o in outs] == [False, True, True, True]
    assert outs[-1].first_alarm_sample == 1
    saved = latched.get_state()
    latched.reset()
    assert not latched.update(good).alarm
    latched.set_state(saved)
    assert latched.update(good).alarm


def test_feature_of_vanished_parameter_is_finite():
    c = feature_vector(parameter_ratios([0.0, 1.0, 1.0, 1.0, 1.0], [1.0] * 5))
    assert c[0] == -12


@pytest.mark.parametrize(
    ("call", "name"),
    [
        (lambda: ThresholdDecision([1.0, 0.0]), "theta0"),
        (lambda: ThresholdDecision([1.0], low=1.2), "low"),
        (lambda: ThresholdDecision([1.0], persistence_k=3, persistence_n=2), "persistence_k"),
        (lambda: ThresholdDecision([1.0, 1.0], monitored=[False, False]), "monitored"),
        (lambda: SignatureClassifier({}), "signatures"),
        (lambda: SignatureClassifier({"a": [1, 2], "b": [1]}), "signatures\\['b'\\]"),
        (lambda: signature_distance([1, 2], [1]), "c_b"),
        (lambda: parameter_ratios([1.0, np.nan], [1.0, 1.0]), "theta"),
    ],
)
def test_bad_arguments_name_the_argument(call, name):
    with pytest.raises((ValueError, TypeError), match=name):
        call()


def test_median_feature_rounds_half_away_from_zero():
    from gyrodiag.dtg.decision import median_feature

    np.testing.assert_array_equal(
        median_feature([[0, -2, 1], [0, -3, 1], [1, -3, 2]]), [0, -3, 1])
    # even counts: the mean of the middle pair, .5 rounded away from zero
    np.testing.assert_array_equal(median_feature([[-1, 1, 0], [-2, 2, 0]]), [-2, 2, 0])
    np.testing.assert_array_equal(median_feature([0, -1, 3]), [0, -1, 3])
    with pytest.raises(ValueError, match="features"):
        median_feature(np.zeros((0, 5)))
    with pytest.raises(ValueError, match="features"):
        median_feature([[0, np.nan]])


def test_windowed_median_feature_equals_the_batch_median_at_every_sample():
    from gyrodiag.dtg.decision import WindowedMedianFeature, median_feature

    rng = np.random.default_rng(7)
    feats = rng.integers(-4, 3, size=(400, 5))
    flags = rng.random(400) < 0.6
    w = WindowedMedianFeature(5, 9)
    for k in range(400):
        w.update(feats[k], bool(flags[k]))
        lo = max(0, k - 8)
        rows = feats[lo:k + 1][flags[lo:k + 1]]
        if rows.size == 0:
            assert w.median() is None and w.n_flagged == 0
        else:
            np.testing.assert_array_equal(w.median(), median_feature(rows), err_msg=str(k))
        if k == 200:
            state = w.get_state()
    # restore mid-record: the counts are rebuilt from the window
    w2 = WindowedMedianFeature(5, 9)
    w2.set_state(state)
    for k in range(201, 400):
        w2.update(feats[k], bool(flags[k]))
    np.testing.assert_array_equal(w2.median(), w.median())
    with pytest.raises(ValueError, match="shapes"):
        WindowedMedianFeature(5, 10).set_state(state)
    with pytest.raises(ValueError, match="pos"):
        w2.set_state({**state, "pos": 9})
    with pytest.raises(ValueError, match="window"):
        WindowedMedianFeature(5, 0)
    with pytest.raises(ValueError, match="features"):
        median_feature([])


def test_feature_floats_equals_feature_vector_on_every_decade_and_edge():
    """The channel's plain-float features are the checked function's, including η = 0
    (the floor), exact decades and half decades (rounding half away from zero)."""
    from gyrodiag.dtg.decision import feature_floats

    rng = np.random.default_rng(3)
    cases = [10.0 ** rng.uniform(-14, 14, 5) for _ in range(2000)]
    cases += [np.array([0.0, 1.0, 10.0, 1e-3, 10 ** 2.5]),
              np.array([10 ** -2.5, 10 ** 0.5, 10 ** -0.5, 1e-12, 1e-13])]
    for eta in cases:
        assert feature_floats(eta.tolist()) == tuple(feature_vector(eta).tolist()), eta
    assert feature_floats([0.0, 1e3, 10 ** -0.6, 10 ** 0.6, 1.0]) == (-12, 3, -1, 1, 0)


def test_windowed_median_feature_matches_median_of_flagged_window():
    """Streaming median over a sliding window = median_feature of the flagged rows of
    the same window, through wrap-around and a state round trip."""
    rng = np.random.default_rng(5)
    w = WindowedMedianFeature(5, 7)
    rows, flags = [], []
    for k in range(200):
        f = rng.integers(-3, 4, 5)
        flag = bool(rng.random() < 0.6)
        w.update(f, flag)
        rows.append(f)
        flags.append(flag)
        window = [r for r, g in zip(rows[-7:], flags[-7:], strict=True) if g]
        got = w.median()
        if not window:
            assert got is None
        else:
            np.testing.assert_array_equal(got, median_feature(window), err_msg=f"k={k}")
        if k == 100:
            twin = WindowedMedianFeature(5, 7)
            twin.set_state(w.get_state())
            w = twin


@pytest.mark.parametrize("monitored", [None, [True, True, True, True, False],
                                       [False, False, True, False, False]])
@pytest.mark.parametrize(("k", "n", "latch"), [(1, 1, False), (3, 5, False), (2, 4, True)])
def test_unchecked_step_equals_checked_update(monitored, k, n, latch):
    """The channel's hot path (plain floats) gives the η, alarms and state of the checked
    update on ratios inside, outside and at the band's edges."""
    rng = np.random.default_rng(11)
    a = ThresholdDecision(THETA_NOM, 0.5, 1.5, k, n, latch, monitored)
    b = ThresholdDecision(THETA_NOM, 0.5, 1.5, k, n, latch, monitored)
    nominal = np.array(THETA_NOM)
    for j in range(400):
        ratio = rng.choice([0.5, 1.5, 1.0, 0.2, 3.0, 0.9]) if j % 7 == 0 else \
            rng.uniform(0.3, 1.8, 5)
        theta = nominal * ratio * rng.choice([-1.0, 1.0], 5)
        checked = a.update(theta)
        eta, alarm = b.step(theta.tolist())
        np.testing.assert_array_equal(eta, checked.eta)
        assert alarm == checked.alarm, j
    assert a.get_state()["first_alarm"] == b.get_state()["first_alarm"]


def test_confirm_gates_band_violations_and_sees_only_out_of_band_samples():
    """``step(theta, confirm)``: an out-of-band sample counts only when confirm says so
    (the DTG channel's significance test); confirm is not asked inside the band."""
    bad, good = THETA_F["f1_step"], THETA_NOM
    asked: list[list[float]] = []

    def deny(eta: list[float]) -> bool:
        asked.append(eta)
        return False

    dec = ThresholdDecision(THETA_NOM, persistence_k=2, persistence_n=3)
    assert [dec.step(t, deny)[1] for t in [bad, bad, good, bad]] == [False] * 4
    assert len(asked) == 3
    np.testing.assert_allclose(asked[0], parameter_ratios(bad, THETA_NOM))
    assert dec.out_of_band(asked[0]) == [1, 2, 3, 4]  # η1 = 0.504 stays inside 0.5/1.5
    dec.reset()
    assert [dec.step(t, lambda eta: True)[1] for t in [bad, bad, good]] == [False, True, True]


def test_set_theta0_moves_the_band_and_validates():
    dec = ThresholdDecision(THETA_NOM, low=0.9, high=1.1)
    shifted = [1.2 * v for v in THETA_NOM]
    assert dec.step(shifted)[1]
    dec.set_theta0(shifted)
    eta, alarm = dec.step(shifted)
    np.testing.assert_allclose(eta, 1.0)
    assert not alarm
    with pytest.raises(ValueError, match="theta0"):
        dec.set_theta0([1.0, 0.0, 1.0, 1.0, 1.0])
    with pytest.raises(ValueError, match="theta0"):
        dec.set_theta0([1.0, 2.0])
    np.testing.assert_allclose(dec.theta0, shifted)
