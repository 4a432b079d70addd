import dataclasses

import numpy as np
import pytest
from _dtg_sim import STABLE_ROTOR, simulate_difference_equation

from gyrodiag.dtg.channel import DTGChannel, DTGChannelConfig
from gyrodiag.dtg.decision import UNKNOWN_CODE, median_feature
from gyrodiag.dtg.model import theta_from_physical

T = 1e-3


def _record(params, n, seed, noise=0.0):
    rng = np.random.default_rng(seed)
    ux, uy = rng.standard_normal(n), rng.standard_normal(n)
    tx, ty = simulate_difference_equation(theta_from_physical(params, T), ux, uy)
    tx = tx + noise * rng.standard_normal(n)
    ty = ty + noise * rng.standard_normal(n)
    return np.column_stack([tx, ty, ux, uy])


def _faulty_record(n_nominal, n_fault, seed):
    """Nominal rotor, then the torquer gain Ku drops to 30 % (θ5 × 0.3)."""
    broken = dataclasses.replace(STABLE_ROTOR, Ku=0.3 * STABLE_ROTOR.Ku)
    a = _record(STABLE_ROTOR, n_nominal, seed)
    b = _record(broken, n_fault, seed + 1)
    return np.vstack([a, b])


def _run(ch, rec):
    return [ch.update(*row) for row in rec]


def test_learns_theta0_then_detects_and_classifies_a_torquer_fault():
    cfg = DTGChannelConfig(
        sample_period_s=T, prefilter_enabled=False, estimator="forgetting", forgetting=0.99,
        p0=1e8, learn_start_s=0.5, learn_end_s=2.0, classifier="paper",
        signatures={"torquer_gain": [0, 0, 0, 0, -1], "pickoff_loss": [-3, -1, 1, 1, 2]},
    )
    ch = DTGChannel(cfg)
    outs = _run(ch, _faulty_record(3000, 2000, seed=1))
    truth = theta_from_physical(STABLE_ROTOR, T)
    np.testing.assert_allclose(ch.theta0, truth, rtol=1e-6)  # noise-free: exact
    assert outs[1999].learning and not outs[2001].learning
    assert not any(o.alarm for o in outs[2001:3000])
    first = ch.last_output.first_alarm_time_s
    # the fault starts at 3.0 s; with forgetting 0.99 θ5 passes η = 0.5 within ~100 samples
    assert 3.0 <= first < 3.2
    assert outs[-1].alarm and outs[-1].fault_code == 1
    np.testing.assert_allclose(outs[-1].eta[:, 4], 0.3, rtol=1e-3)
    np.testing.assert_array_equal(outs[-1].feature, [0, 0, 0, 0, -1])
    phys = outs[2500].physical
    np.testing.assert_allclose(
        phys, [STABLE_ROTOR.c, STABLE_ROTOR.k, STABLE_ROTOR.L, STABLE_ROTOR.lam,
               STABLE_ROTOR.Ku / STABLE_ROTOR.KT], rtol=1e-4)


@pytest.mark.parametrize("kind", ["batch", "rls", "forgetting"])
def test_given_theta0_no_alarm_on_nominal_data(kind):
    truth = theta_from_physical(STABLE_ROTOR, T)
    ch = DTGChannel(DTGChannelConfig(
        sample_period_s=T, estimator=kind, window=200, p0=1e8, theta0=list(truth),
        persistence_k=1, persistence_n=1))
    outs = _run(ch, _record(STABLE_ROTOR, 3000, seed=2, noise=1e-4))
    assert not outs[-1].learning
    assert not any(o.alarm for o in outs[1000:]), "false alarm on nominal data"
    np.testing.assert_allclose(outs[-1].theta.mean(axis=0)[:4], truth[:4], rtol=2e-2)


def test_unclassified_alarm_has_unknown_code():
    # the paper band set explicitly (left automatic, a bench has the physical test
    # instead, which learns its own reference over 1-5 s)
    ch = DTGChannel(DTGChannelConfig(
        sample_period_s=T, prefilter_enabled=False, p0=1e8, low=0.5, high=1.5,
        theta0=list(theta_from_physical(STABLE_ROTOR, T))))
    outs = _run(ch, _faulty_record(500, 1000, seed=3))
    assert outs[-1].alarm and outs[-1].fault_code == UNKNOWN_CODE


def test_no_excitation_while_learning_leaves_no_reference_and_no_alarm():
    """Zero inputs (a host's default start values): θ stays 0, so θ0 would have zero
    entries. The channel keeps no reference and never alarms, instead of failing every
    sample from the end of learning on; a state round trip keeps that."""
    cfg = DTGChannelConfig(sample_period_s=T, learn_start_s=0.1, learn_end_s=0.3, p0=1e8)
    ch = DTGChannel(cfg)
    outs = _run(ch, np.zeros((299, 4)))
    assert outs[-1].learning and not ch.reference_failed
    outs += _run(ch, np.zeros((3, 4)))
    assert ch.reference_failed and ch.theta0 is None
    assert not outs[-1].learning and not outs[-1].alarm
    # excitation afterwards does not start a late reference: the window is over
    outs += _run(ch, _record(STABLE_ROTOR, 500, seed=9))
    assert ch.theta0 is None and not any(o.alarm for o in outs)
    again = DTGChannel(cfg)
    again.set_state(ch.get_state())
    assert again.reference_failed


def test_nan_sample_is_skipped_and_state_round_trip_is_exact():
    cfg = DTGChannelConfig(sample_period_s=T, learn_start_s=0.2, learn_end_s=0.5, p0=1e8)
    rec = _record(STABLE_ROTOR, 1500, seed=4, noise=1e-4)
    ch = DTGChannel(cfg)
    _run(ch, rec[:600])
    before = ch.get_state()
    out = ch.update(np.nan, 0.0, 0.0, 0.0)
    assert not out.valid
    after = ch.get_state()
    np.testing.assert_array_equal(after["estimators"][0]["theta"],
                                  before["estimators"][0]["theta"])
    assert after["n_samples"] == before["n_samples"]
    ref = _run(ch, rec[600:])
    ch.set_state(before)
    again = _run(ch, rec[600:])
    for a, b in zip(ref, again, strict=True):
        np.testing.assert_array_equal(a.theta, b.theta)
        assert a.alarm == b.alarm and a.fault_code == b.fault_code
    ch.reset()
    fresh = DTGChannel(cfg)
    for a, b in zip(_run(ch, rec[:700]), _run(fresh, rec[:700]), strict=True):
        np.testing.assert_array_equal(a.theta, b.theta)


def test_windowed_classification_is_the_median_of_the_per_sample_features():
    """Ku falls to 35 % (log10 0.35 = -0.46, near a decade boundary): with noise the
    per-sample feature flickers between [0,0,0,0,0] and [0,0,0,0,-1]; the channel
    classifies the median of the alarm samples of the last window instead, exactly the
    signature-learning rule, and flickers an order of magnitude less."""
    broken = dataclasses.replace(STABLE_ROTOR, Ku=0.35 * STABLE_ROTOR.Ku)
    rec = np.vstack([_record(STABLE_ROTOR, 1000, 5, noise=1e-3),
                     _record(broken, 2000, 6, noise=1e-3)])
    window = 50  # s = 0.05: 51 samples, both ends
    outs = {}
    for w in (0.0, window * T):
        ch = DTGChannel(DTGChannelConfig(
            sample_period_s=T, prefilter_enabled=False, p0=1e8, forgetting=0.99,
            theta0=list(theta_from_physical(STABLE_ROTOR, T)), classify_window_s=w,
            classifier="paper",
            signatures={"torquer_weak": [0, 0, 0, 0, -1], "near_nominal": [0, 0, 0, 0, 0]}))
        outs[w] = _run(ch, rec)
    single, smooth = outs[0.0], outs[window * T]
    feats = np.array([o.feature for o in single])
    alarm = np.array([o.alarm for o in single])
    assert alarm[1300:].all()
    for k in range(1300, len(rec), 7):
        lo = max(0, k - window)
        expected = median_feature(feats[lo:k + 1][alarm[lo:k + 1]])
        np.testing.assert_array_equal(smooth[k].feature, expected, err_msg=f"sample {k}")
        assert smooth[k].fault_code == (1 if expected[4] == -1 else 2)
    flips = [np.count_nonzero(np.diff([o.fault_code for o in outs[w][1300:]])) for w in outs]
    assert flips[0] > 50 and flips[1] < flips[0] / 5, flips
    # the ring buffer is part of the state: a restored channel classifies identically
    ch = DTGChannel(DTGChannelConfig(
        sample_period_s=T, prefilter_enabled=False, p0=1e8, forgetting=0.99,
        theta0=list(theta_from_physical(STABLE_ROTOR, T)), classify_window_s=window * T,
        classifier="paper",
        signatures={"torquer_weak": [0, 0, 0, 0, -1], "near_nominal": [0, 0, 0, 0, 0]}))
    _run(ch, rec[:1500])
    state = ch.get_state()
    ref = _run(ch, rec[1500:1600])
    ch.set_state(state)
    again = _run(ch, rec[1500:1600])
    assert [o.fault_code for o in again] == [o.fault_code for o in ref]
    for a, b in zip(again, ref, strict=True):
        np.testing.assert_array_equal(a.feature, b.feature)
    with pytest.raises(ValueError, match="classify_window_s"):
        DTGChannel(DTGChannelConfig(
            sample_period_s=T, prefilter_enabled=False, p0=1e8, classify_window_s=0.2,
            classifier="paper",
            theta0=list(theta_from_physical(STABLE_ROTOR, T)))).set_state(state)


@pytest.mark.parametrize(
    ("changes", "name"),
    [
        ({"sample_period_s": 0.0}, "sample_period_s"),
        ({"prefilter_cutoff_hz": 600.0}, "cutoff_hz"),
        ({"estimator": "kalman"}, "estimator"),
        ({"window": 3}, "window"),
        ({"forgetting": 1.5}, "forgetting"),
        ({"theta0": [1.0, 0.0, 1.0, 1.0, 1.0]}, "theta0"),
        ({"learn_start_s": 2.0, "learn_end_s": 1.0}, "learn_end_s"),
        ({"low": 2.0}, "low"),
        ({"signatures": {"a": [0, 0, 0]}, "classifier": "paper"}, "signatures"),
        ({"signatures": {"a": [0, 0, 0, 0, 0]}}, "signatures"),
        ({"classifier": "nearest"}, "classifier"),
        ({"long_window_s": 0.2}, "long_window_s"),
        ({"var_threshold": 1.0}, "var_threshold"),
        ({"learn_start_s": 1.0, "learn_end_s": 1.03}, "learn_end_s"),
        ({"classify_window_s": -0.1}, "classify_window_s"),
    ],
)
def test_invalid_settings_name_the_setting(changes, name):
    with pytest.raises((ValueError, TypeError), match=name):
        DTGChannel(DTGChannelConfig(**changes))


def test_pattern_alarm_clears_after_an_intermittent_fault_and_the_estimator_rolls_back():
    """A noise burst on Utx 4-6 s (pattern classifier): the residual tests alarm at once and
    clear within the long window + clear time (2.5 s) + the prefilter's memory (0.095 s)
    + block alignment (2 × 25 ms) after it; the fast estimators are then rolled back to
    their state from before the burst, so the ratio band does not keep the alarm while
    they would forget the burst (its data raise their information ~100-fold)."""
    rec = _record(STABLE_ROTOR, 10000, seed=21, noise=1e-4)
    scale = np.std(rec[:, 0])
    rec[4000:6000, 0] += 10 * scale * np.random.default_rng(22).standard_normal(2000)
    ch = DTGChannel(DTGChannelConfig(sample_period_s=T, p0=1e8, learn_start_s=0.5,
                                     learn_end_s=3.0))
    outs = _run(ch, rec)
    t = np.arange(len(rec)) * T
    alarm = np.array([o.alarm for o in outs])
    residual = np.array([o.diagnosis.residual_alarm for o in outs])
    assert not alarm[t < 4.0].any()
    assert alarm[(t >= 4.05) & (t < 6.0)].all()
    cleared = t[(t > 6.0) & ~alarm][0] - 6.0
    assert 2.0 < cleared <= 2.5 + 0.095 + 0.05, cleared
    assert not alarm[t > 6.0 + cleared].any()
    # the ratio band alone may alarm within the block that detects the burst (before the
    # block's tests run), never after the burst
    band_only = alarm & ~residual
    assert not band_only[t > 4.1].any(), t[band_only]
    # during the burst the estimators absorb it; after the clearing they are back at
    # their estimates from before the burst (half a test window before the alarm)
    k_clear = int(np.argmax((t > 6.0) & ~alarm))
    assert np.any(np.abs(outs[5900].eta - 1.0) > 0.5)
    np.testing.assert_allclose(outs[k_clear].theta, outs[3500].theta, rtol=0.05, atol=1e-6)
    # the hold and the snapshots are part of the state
    ch2 = DTGChannel(ch.config)
    _run(ch2, rec[:5000])
    state = ch2.get_state()
    ref = _run(ch2, rec[5000:7000])
    ch2.set_state(state)
    again = _run(ch2, rec[5000:7000])
    for a, b in zip(ref, again, strict=True):
        np.testing.assert_array_equal(a.theta, b.theta)
        assert a.alarm == b.alarm
