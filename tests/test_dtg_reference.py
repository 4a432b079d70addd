"""Frozen reference of the DTG pattern classifier: moments, guarded learning, residual
tests with alarm memory (gyrodiag.dtg.reference)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from _dtg_sim import STABLE_ROTOR, simulate_difference_equation

from gyrodiag.common.estimators import batch_ls
from gyrodiag.dtg.model import dtg_regression, theta_from_physical
from gyrodiag.dtg.reference import (
    REFERENCE_STATUS,
    NominalPrior,
    ReferenceLearner,
    ResidualMonitor,
    ResidualThresholds,
    block_moments,
    regression_residuals,
    window_moments,
)

T = 1e-3
NB = 25          # samples per block (25 ms)
SHORT, LONG = 20, 80
THETA = theta_from_physical(STABLE_ROTOR, T)


def _record(n, seed, params=STABLE_ROTOR, noise=1e-4):
    rng = np.random.default_rng(seed)
    ux, uy = rng.standard_normal(n), rng.standard_normal(n)
    tx, ty = simulate_difference_equation(theta_from_physical(params, T), ux, uy)
    return np.column_stack([tx + noise * rng.standard_normal(n),
                            ty + noise * rng.standard_normal(n), ux, uy])


def _learn(rec, thresholds=None, prior=None, theta0=None):
    """Feed whole blocks (prefilter off: filtered = raw) and finish."""
    learner = ReferenceLearner(NB, SHORT, LONG, thresholds or ResidualThresholds(), NB * T)
    learner.set_history(np.zeros((2, 4)))
    theta = np.tile(THETA, (NB, 2))
    for b in range(rec.shape[0] // NB):
        blk = rec[b * NB:(b + 1) * NB]
        learner.push_block(blk, blk, theta, np.ones(NB, dtype=bool))
    return learner, learner.finish(theta0, prior)


def _monitor(learner, ref, clear_blocks=20):
    mon = ResidualMonitor(ref, NB, NB * T, SHORT, LONG, ResidualThresholds(), clear_blocks)
    mon.prefill(*learner.reference_blocks(ref, LONG))
    return mon


def _feed(mon, rec, prev):
    """Push whole blocks; ``prev`` holds the two samples before ``rec``. Returns the alarm
    after each block."""
    theta = np.tile(THETA, (NB, 2))
    alarms = []
    for b in range(rec.shape[0] // NB):
        blk = rec[b * NB:(b + 1) * NB]
        alarms.append(mon.push_block(blk, np.vstack([prev, blk]), theta,
                                     np.ones(NB, dtype=bool)))
        prev = blk[-2:]
    return np.array(alarms)


# --------------------------------------------------------------------------- moments
def test_block_moments_are_the_straight_line_fit_residuals():
    rng = np.random.default_rng(1)
    x = 0.3 + 0.02 * np.arange(25) + rng.standard_normal(25)
    mean, var = block_moments(x[:, None])
    fit = np.polyval(np.polyfit(np.arange(25), x, 1), np.arange(25))
    assert mean[0] == pytest.approx(x.mean(), abs=1e-14)
    assert var[0] == pytest.approx(np.mean((x - fit) ** 2), rel=1e-12)
    # a mask drops samples from both the line fit and the moments
    keep = np.ones(25, dtype=bool)
    keep[[3, 4, 17]] = False
    k = np.arange(25)[keep]
    fit = np.polyval(np.polyfit(k, x[keep], 1), k)
    _, var_m = block_moments(x[:, None], keep)
    assert var_m[0] == pytest.approx(np.mean((x[keep] - fit) ** 2), rel=1e-12)


def test_window_moments_remove_a_drift_across_blocks():
    means = (2.0 + 0.5 * np.arange(20))[:, None] * np.array([1.0, -1.0])
    variances = np.full((20, 2), 0.04)
    mean, var, slope = window_moments(means, variances)
    np.testing.assert_allclose(mean, [2.0 + 0.5 * 9.5, -(2.0 + 0.5 * 9.5)])
    np.testing.assert_allclose(var, [0.04, 0.04], atol=1e-12)  # the ramp is not noise
    np.testing.assert_allclose(slope, [0.5, -0.5])


def test_regression_residuals_vanish_for_the_true_theta():
    rec = _record(600, seed=2, noise=0.0)
    e = regression_residuals(rec, THETA)
    assert np.max(np.abs(e)) < 1e-12 * np.max(np.abs(rec[:, :2]))
    d = np.array([0.0, 0.0, 0.0, 0.0, 1e-3])   # a θ5 error shows as −Δθ5·U
    e2 = regression_residuals(rec, THETA + d)
    np.testing.assert_allclose(e2, -1e-3 * rec[2:, 2:], atol=1e-12)


# --------------------------------------------------------------------------- learning
def test_nominal_window_is_valid_and_fits_theta():
    rec = _record(4000, seed=3)
    _, ref = _learn(rec)
    assert ref.status == REFERENCE_STATUS["valid"] and ref.valid
    assert ref.change_segment == -1 and ref.segments_used == 8
    # θ0 is the least-squares fit of both axes over the window (batch LS to 1e-10;
    # pick-off noise in the regressors biases both alike, ~0.3 % here)
    phx, yx, phy, yy = dtg_regression(*np.vstack([np.zeros((2, 4)), rec]).T)
    ls = batch_ls(np.vstack([phx, phy]), np.concatenate([yx, yy]))
    np.testing.assert_allclose(ref.theta0, ls, rtol=1e-10)
    np.testing.assert_allclose(ref.theta0, THETA, rtol=1e-2)
    # the η reference is the mean fast-estimator θ of the blocks (here: the truth)
    np.testing.assert_allclose(ref.theta0_eta, THETA, rtol=1e-12)
    # residual spread: the 1e-4 V pick-off noise through (1 - θ1 z⁻¹ + θ2 z⁻²) and the
    # cross terms: sqrt(1 + θ1² + θ2² + θ3² + θ4²)·1e-4 per axis
    expected = 1e-4 * np.sqrt(1 + THETA[0] ** 2 + THETA[1] ** 2 + THETA[2] ** 2 + THETA[3] ** 2)
    assert np.sqrt(ref.var_short[4:]) == pytest.approx([expected] * 2, rel=0.1)


@pytest.mark.parametrize(("what", "at"), [("step", 2600), ("noise", 1100), ("gain", 3100)])
def test_a_fault_inside_the_window_ends_the_usable_data(what, at):
    """A 0.5 V torquer step, 1 mV of pick-off noise or the torquer gain falling to 70 % part-way
    through the window: the reference is fitted on the segments before it."""
    rec = _record(4000, seed=4)
    if what == "step":
        rec[at:, 2] += 0.5
    elif what == "noise":
        rec[at:, 1] += 1e-3 * np.random.default_rng(5).standard_normal(4000 - at)
    else:
        weak = dataclasses.replace(STABLE_ROTOR, Ku=0.7 * STABLE_ROTOR.Ku)
        tail = _record(4000, seed=6, params=weak)
        rec[at:] = tail[at:]
    _, ref = _learn(rec)
    assert ref.status == REFERENCE_STATUS["change_in_window"] and not ref.valid
    segment = at // 500  # 8 segments of 0.5 s
    assert ref.change_segment in (segment, segment + 1)
    assert ref.segments_used == ref.change_segment
    np.testing.assert_allclose(ref.theta0, THETA, rtol=1e-2)


def test_a_learned_reference_outside_the_prior_is_replaced_by_the_prior():
    refs = [_learn(_record(4000, seed=s))[1] for s in (7, 17, 27, 37)]
    ref = refs[0]
    prior = NominalPrior(theta0=np.mean([r.theta0 for r in refs], axis=0),
                         theta0_std=np.std([r.theta0 for r in refs], axis=0),
                         mean=ref.mean.copy(), block_std=ref.block_std.copy(),
                         var_short=ref.var_short.copy(), var_long=ref.var_long.copy())
    _, same = _learn(_record(4000, seed=8), prior=prior)
    assert same.status == REFERENCE_STATUS["valid"]
    # a gyro whose torquer gain is 80 % from the start: nothing changes inside the
    # window, only the prior can tell
    weak = dataclasses.replace(STABLE_ROTOR, Ku=0.8 * STABLE_ROTOR.Ku)
    _, ref_w = _learn(_record(4000, seed=9, params=weak), prior=prior)
    assert ref_w.status == REFERENCE_STATUS["prior_mismatch"]
    np.testing.assert_array_equal(ref_w.theta0, prior.theta0)
    np.testing.assert_array_equal(ref_w.var_short, prior.var_short)


def test_learner_state_round_trip():
    rec = _record(2000, seed=10)
    learner = ReferenceLearner(NB, SHORT, LONG, ResidualThresholds(), NB * T)
    theta = np.tile(THETA, (NB, 2))
    for b in range(40):
        blk = rec[b * NB:(b + 1) * NB]
        learner.push_block(blk, blk, theta, np.ones(NB, dtype=bool))
    other = ReferenceLearner(NB, SHORT, LONG, ResidualThresholds(), NB * T)
    other.set_state(learner.get_state())
    a, b = learner.finish(), other.finish()
    np.testing.assert_array_equal(a.theta0, b.theta0)
    np.testing.assert_array_equal(a.var_long, b.var_long)


# --------------------------------------------------------------------------- monitor
def test_persistent_fault_keeps_the_alarm_and_an_intermittent_one_clears():
    """Alarm memory: a 0.5 V torquer-voltage step held for 70 s keeps the alarm at every block;
    noise for 2 s raises it, and it clears within the long window plus the clear time
    (2 s + 0.5 s) after the noise stops."""
    rec = _record(4000 + 75000, seed=11)
    learner, ref = _learn(rec[:4000])
    mon = _monitor(learner, ref, clear_blocks=20)
    quiet = _feed(mon, rec[4000:9000], rec[3998:4000])
    assert not quiet.any()
    faulty = rec[9000:79000].copy()
    faulty[:, 2] += 0.5
    alarms = _feed(mon, faulty, rec[8998:9000])
    assert alarms[1:].all(), np.flatnonzero(~alarms)[:5]   # held for 70 s
    assert mon.blocks_in_alarm >= 2799

    rec2 = _record(4000 + 12000, seed=12)
    learner2, ref2 = _learn(rec2[:4000])
    mon2 = _monitor(learner2, ref2)
    run = rec2[4000:].copy()
    noise = np.random.default_rng(13).standard_normal(2000)
    run[3000:5000, 1] += 2e-3 * noise
    alarms2 = _feed(mon2, run, rec2[3998:4000])
    t_block = (np.arange(alarms2.size) + 1) * NB * T  # end of each block, s
    assert not alarms2[t_block < 3.0].any()
    assert alarms2[(t_block > 3.1) & (t_block < 5.0)].all()
    cleared = t_block[(t_block > 5.0) & ~alarms2][0] - 5.0
    assert 0.5 <= cleared <= 2.5 + NB * T, cleared
    assert not alarms2[t_block > 5.0 + cleared].any()


def test_monitor_state_round_trip_and_reference_state():
    rec = _record(4000 + 3000, seed=14)
    learner, ref = _learn(rec[:4000])
    mon = _monitor(learner, ref)
    _feed(mon, rec[4000:5500], rec[3998:4000])
    state = mon.get_state()
    a = _feed(mon, rec[5500:7000], rec[5498:5500])
    other = ResidualMonitor(type(ref).from_state(ref.get_state()), NB, NB * T, SHORT, LONG,
                            ResidualThresholds(), 20)
    other.set_state(state)
    b = _feed(other, rec[5500:7000], rec[5498:5500])
    np.testing.assert_array_equal(a, b)
    np.testing.assert_array_equal(mon.statistics, other.statistics)


@pytest.mark.parametrize(("kwargs", "name"), [
    ({"level": 0.0}, "level_threshold"), ({"variance": 1.0}, "var_threshold"),
    ({"long_variance": float("nan")}, "long_var_threshold"),
    ({"theta_spread": -1.0}, "theta_spread_threshold"),
])
def test_bad_thresholds_name_the_threshold(kwargs, name):
    with pytest.raises(ValueError, match=name):
        ResidualThresholds(**kwargs).validate()


def test_a_levels_only_prior_replaces_only_an_offset_reference_of_the_same_bench():
    """A library learned on the user's bench replaces any mismatching reference; the
    shipped one (levels_only) only one whose θ0 (within 30 %) and noise match its bench
    and whose levels do not: another rotor, dither or noise level stands."""
    from dataclasses import replace

    from gyrodiag.dtg.reference import NominalPrior, NominalReference, ReferenceLearner

    theta = np.array([2.0, 1.0, -0.03, -0.03, 2e-4])
    stats = dict(mean=np.zeros(6), block_std=np.full(6, 0.01), var_short=np.ones(6),
                 var_long=np.ones(6))
    full = NominalPrior(theta0=theta, theta0_std=np.full(5, 1e-4), **stats)
    shipped = replace(full, levels_only=True)
    same = NominalReference(theta0=theta, theta0_eta=theta, **stats)
    offset = replace(same, mean=np.array([0, 0.3, 0, 0, 0, 0]),
                     theta0=theta * [1, 1, 1.2, 1.2, 1])          # θ3, θ4 moved 20 %
    noisier = replace(same, var_short=np.full(6, 4.0))            # another dither level
    rotor = replace(offset, theta0=theta * [1, 1, 2.0, 2.0, 1])  # another rotor
    replaces = ReferenceLearner._prior_replaces
    assert [replaces(r, full) for r in (same, offset, noisier, rotor)] == [
        False, True, True, True]
    assert [replaces(r, shipped) for r in (same, offset, noisier, rotor)] == [
        False, True, False, False]
    assert NominalPrior.from_dict(shipped.to_dict()).to_dict() == shipped.to_dict()
    assert shipped.to_dict()["levels_only"] and "levels_only" not in full.to_dict()
    with pytest.raises(ValueError, match="levels_only must be true or false"):
        NominalPrior.from_dict({**full.to_dict(), "levels_only": "yes"})
