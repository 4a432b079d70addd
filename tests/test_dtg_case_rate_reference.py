"""The case-rate reference of the pattern classifier refines θ0 with the fault-free blocks
and allows for θ0's remaining uncertainty (gyrodiag.dtg.reference, docs/dtg_case_rate.md
§8): known answers on the central-scheme difference equation and on constructed normal
matrices."""

from __future__ import annotations

import numpy as np
import pytest
from _dtg_sim import STABLE_ROTOR

from gyrodiag.dtg.case_rate import dtg_case_rate_regression, theta_central_from_physical
from gyrodiag.dtg.model import N_THETA
from gyrodiag.dtg.reference import (
    POWER_KAPPA,
    NominalReference,
    ReferenceLearner,
    RegressionModel,
    ResidualMonitor,
    ResidualThresholds,
    _refinement_start,
)

T = 1e-3
NB = 25
SHORT, LONG = 20, 80
KT = STABLE_ROTOR.KT
MODEL = RegressionModel("central", T, KT)
P = STABLE_ROTOR
THETA = theta_central_from_physical(P.J, P.c, P.k, P.L, P.lam, P.Ku, P.KT, T)
LEARN = 4000


def _record(n: int, seed: int, amplitude: float, dither: float = 1.0,
            noise: float = 1e-4) -> np.ndarray:
    """(Utx, Uty, Ux, Uy, ωx, ωy) generated exactly by the central scheme (θ of both axes
    = THETA) with white torquer voltages of std ``dither`` and, after the learning part, a
    square-wave pitch rate of ``amplitude`` rad/s (period 1 s); pick-off noise added
    afterwards."""
    rng = np.random.default_rng(seed)
    ux, uy = dither * rng.standard_normal(n), dither * rng.standard_normal(n)
    wx = np.zeros(n)
    k = np.arange(n)
    wy = np.where(k < LEARN, 0.0, amplitude * np.where((k - LEARN) % 1000 < 500, 1.0, -1.0))
    t1, t2, tl, tlam, t5 = THETA
    s = T / KT
    tx, ty = np.zeros(n), np.zeros(n)
    # the two lines share Utx(k), Uty(k) through θL: solve the 2×2 system per sample
    lhs = np.array([[1.0, tl], [-tl, 1.0]])
    for i in range(2, n):
        hx, hy = 0.5 * s * (wx[i] - wx[i - 1]), 0.5 * s * (wy[i] - wy[i - 1])
        rx = (-hx + t1 * tx[i - 1] - t2 * (tx[i - 2] + hx)
              - tl * (-ty[i - 2] + s * (wy[i] + wy[i - 1])) - tlam * ty[i - 1]
              + t5 * 0.5 * (ux[i] + ux[i - 1]))
        ry = (-hy + t1 * ty[i - 1] - t2 * (ty[i - 2] + hy)
              + tl * (-tx[i - 2] + s * (wx[i] + wx[i - 1])) + tlam * tx[i - 1]
              + t5 * 0.5 * (uy[i] + uy[i - 1]))
        tx[i], ty[i] = np.linalg.solve(lhs, [rx, ry])
    return np.column_stack([tx + noise * rng.standard_normal(n),
                            ty + noise * rng.standard_normal(n), ux, uy, wx, wy])


def _learn(rec: np.ndarray) -> tuple[ReferenceLearner, NominalReference]:
    learner = ReferenceLearner(NB, SHORT, LONG, ResidualThresholds(), NB * T, MODEL)
    learner.set_history(np.zeros((2, 6)))
    theta = np.tile(THETA, (NB, 2))
    for b in range(LEARN // NB):
        blk = rec[b * NB:(b + 1) * NB]
        learner.push_block(blk[:, :4], blk, theta, np.ones(NB, dtype=bool))
    return learner, learner.finish()


def _monitor(learner: ReferenceLearner, ref: NominalReference) -> ResidualMonitor:
    mon = ResidualMonitor(ref, NB, NB * T, SHORT, LONG, ResidualThresholds(), 20, MODEL)
    mon.prefill(*learner.reference_blocks(ref, LONG))
    return mon


def _feed(mon: ResidualMonitor, rec: np.ndarray, start: int, stop: int) -> np.ndarray:
    theta = np.tile(THETA, (NB, 2))
    alarms = []
    for b0 in range(start, stop, NB):
        blk = rec[b0:b0 + NB]
        alarms.append(mon.push_block(blk[:, :4], rec[b0 - 2:b0 + NB], theta,
                                     np.ones(NB, dtype=bool)))
    return np.array(alarms)


@pytest.fixture(scope="module")
def record() -> np.ndarray:
    # a weak torquer dither: the rest leaves directions of θ0 that a 2 rad/s square wave
    # excites poorly determined
    return _record(LEARN + 6000, seed=21, amplitude=2.0, dither=0.1)


def _frozen(learner: ReferenceLearner, ref: NominalReference) -> ResidualMonitor:
    """The monitor as before the refinement: a reference without its information."""
    old = ref.get_state()
    old.pop("information")
    old.pop("error_variance")
    mon = ResidualMonitor(NominalReference.from_state(old), NB, NB * T, SHORT, LONG,
                          ResidualThresholds(), 20, MODEL)
    mon.prefill(*learner.reference_blocks(ref, LONG))
    return mon


def test_refined_reference_is_the_least_squares_fit_of_all_accepted_data(record) -> None:
    """θ0 refined block by block (information form, no forgetting) equals the batch least
    squares over the learning rows and every accepted runtime row, per axis. On this
    exact plant the θ0 learned at rest alarms through the manoeuvre (level z ~9); refined
    (with the allowance for its uncertainty) the monitor is silent."""
    learner, ref = _learn(record)
    assert ref.information is not None and ref.error_variance is not None
    frozen = _frozen(learner, ref)
    assert _feed(frozen, record, LEARN, record.shape[0]).sum() > 200
    mon = _monitor(learner, ref)
    assert not _feed(mon, record, LEARN, record.shape[0]).any()
    phx, yx, phy, yy = dtg_case_rate_regression(*record.T, T, KT)
    # the learner's first two rows use its zero history: add them by hand
    hist = np.vstack([np.zeros((2, 6)), record[:2]])
    h = dtg_case_rate_regression(*hist.T, T, KT)
    refined = mon.theta_reference.reshape(2, N_THETA)
    for a, (ph, y, ph0, y0) in enumerate(((phx, yx, h[0], h[1]), (phy, yy, h[2], h[3]))):
        batch = np.linalg.lstsq(np.vstack([ph0, ph]), np.concatenate([y0, y]), rcond=None)[0]
        np.testing.assert_allclose(refined[a], batch, rtol=1e-6)
        # and it explains the manoeuvre as well as the rotor's own θ does
        run = slice(LEARN, None)
        e_ref = y[run] - ph[run] @ refined[a]
        e_true = y[run] - ph[run] @ THETA
        e_0 = y[run] - ph[run] @ ref.theta0[a * N_THETA:(a + 1) * N_THETA]
        assert e_ref.var() < 1.05 * e_true.var() < e_0.var()


def test_error_variance_is_the_residual_variance_when_white_and_grows_with_colour() -> None:
    """v = λmax(A⁻¹B): ≈ σ² for a white residual (E[B] = σ²A); with a block-constant part
    of variance τ² and a constant regressor, the constant direction's score variance is
    nb·σ² + nb²·τ² per block, so v ≈ σ² + nb·τ²."""
    rng = np.random.default_rng(3)
    nblk, sigma, tau = 800, 1.0, 0.2
    n = nblk * NB
    phi = np.column_stack([np.ones(n), rng.standard_normal((n, N_THETA - 1))])
    theta = np.arange(1.0, 2 * N_THETA + 1)

    def normal_matrices(e: np.ndarray) -> np.ndarray:
        zero = np.zeros_like(phi)
        zx = np.column_stack([phi, zero, phi @ theta[:N_THETA] + e])
        zy = np.column_stack([zero, phi, phi @ theta[N_THETA:] + e])
        zx, zy = zx.reshape(nblk, NB, -1), zy.reshape(nblk, NB, -1)
        return np.einsum("bki,bkj->bij", zx, zx) + np.einsum("bki,bkj->bij", zy, zy)

    white = sigma * rng.standard_normal(n)
    v_white = _refinement_start(normal_matrices(white), theta)["error_variance"]
    # λmax of 5 sample eigenvalues around σ², 800 blocks: a few % above
    np.testing.assert_allclose(v_white, sigma**2, rtol=0.2)
    coloured = white + np.repeat(tau * rng.standard_normal(nblk), NB)
    out = _refinement_start(normal_matrices(coloured), theta)
    np.testing.assert_allclose(out["error_variance"], sigma**2 + NB * tau**2, rtol=0.2)
    np.testing.assert_allclose(out["information"][0], phi.T @ phi)


def test_refinement_state_round_trip_and_mismatch(record) -> None:
    learner, ref = _learn(record)
    mon = _monitor(learner, ref)
    _feed(mon, record, LEARN, LEARN + 2500)
    state = mon.get_state()
    a = _feed(mon, record, LEARN + 2500, LEARN + 5000)
    other = ResidualMonitor(NominalReference.from_state(ref.get_state()), NB, NB * T, SHORT,
                            LONG, ResidualThresholds(), 20, MODEL)
    other.set_state(state)
    b = _feed(other, record, LEARN + 2500, LEARN + 5000)
    np.testing.assert_array_equal(a, b)
    np.testing.assert_array_equal(mon.statistics, other.statistics)
    np.testing.assert_array_equal(mon.theta_reference, other.theta_reference)
    # a reference without the refinement data (an older state): θ0 stays frozen
    frozen = _frozen(learner, ref)
    with pytest.raises(ValueError, match="refinement"):
        frozen.set_state(state)
    _feed(frozen, record, LEARN, LEARN + 500)
    np.testing.assert_array_equal(frozen.theta_reference, ref.theta0)



@pytest.fixture(scope="module")
def quiet_record() -> np.ndarray:
    # 10x less pick-off noise: a manoeuvre's θ0-uncertainty part is then comparable to
    # the residual's own variance, as on the system chain (1 V dither, 0.25 rad edges)
    return _record(LEARN + 6000, seed=21, amplitude=2.0, dither=0.1, noise=1e-5)


def _shifted_reference(ref: NominalReference, record: np.ndarray,
                       c: float) -> NominalReference:
    """``ref`` with the y axis's θ0 moved by c standard deviations of its covariance
    P = v·A⁻¹, in the direction the square wave's first edge block excites most (the top
    eigenvector of P½·S·P½, S that block's detrended regressor scatter)."""
    state = ref.get_state()
    P = state["error_variance"][1] * np.linalg.inv(state["information"][1])
    w, V = np.linalg.eigh(P)
    half = V @ np.diag(np.sqrt(np.maximum(w, 0.0))) @ V.T
    phy = MODEL.rows(record[LEARN - 2:LEARN + NB])[2]
    dev = phy - phy.mean(axis=0)
    k = np.arange(NB) - (NB - 1) / 2
    dev -= np.outer(k, (k @ dev) / (k @ k))
    u = np.linalg.eigh(half @ dev.T @ dev @ half)[1][:, -1]
    state["theta0"] = state["theta0"].copy()
    state["theta0"][N_THETA:] += c * half @ u
    return NominalReference.from_state(state)


@pytest.mark.parametrize(("c", "sigma", "alarm"), [
    (12.0, 1.0, True),   # the first rule alarms
    (12.0, 3.0, False),  # the default allows for it
    (30.0, 3.0, True),   # a gross error (a changed rotor) still alarms
])
def test_allowance_sigma_sets_the_theta0_error_the_variance_tests_allow(
        quiet_record, c: float, sigma: float, alarm: bool) -> None:
    """The reference's error is one draw per run; a manoeuvre edge exciting a direction
    where it is c standard deviations off raises the variance-type tests towards c²
    (ResidualThresholds.allowance_sigma): here the power CUSUM of the squared block
    means, as the square wave goes on (its edges excite that direction's block means
    too). The level test allows 6σ of the mean (z ≈ 3.4 at c = 12)."""
    learner, ref = _learn(quiet_record)
    shifted = _shifted_reference(ref, quiet_record, c)
    thresholds = ResidualThresholds(allowance_sigma=sigma)
    mon = ResidualMonitor(shifted, NB, NB * T, SHORT, LONG, thresholds, 20, MODEL)
    mon.prefill(*learner.reference_blocks(shifted, LONG))
    peak = np.zeros(8)
    alarms = []
    for b0 in range(LEARN, LEARN + 2000, NB):
        alarms.append(_feed(mon, quiet_record, b0, b0 + NB)[0])
        peak = np.maximum(peak, mon.statistics)
    assert bool(np.any(alarms)) is alarm
    assert peak[6:].max() >= 1.0 if alarm else peak[6:].max() < 0.5  # the power CUSUM
    if c < 20.0:
        assert peak[:2].max() < 0.8 * 6.0  # not the level test


def test_allowance_sigma_is_validated() -> None:
    for bad in (-1.0, float("nan"), float("inf")):
        with pytest.raises(ValueError, match="allowance_sigma"):
            ResidualThresholds(allowance_sigma=bad).validate()


def test_allowance_sigma_scales_the_variance_ratios_and_the_power_cusum(record) -> None:
    """Known answer: with the block allowance fixed at a = (a_mean x, y, a_within x, y),
    the same blocks give v/(var_ref + k²·(a_within + a_mean)) as the short and long
    variance ratios and (m − μ)²/(σ_b² + k²·a_mean) per block to the power CUSUM, and
    the level test its standard-deviation allowance whatever k is."""
    learner, ref = _learn(record)
    res = [4, 5]
    a = np.array([2.0, 3.0, 5.0, 7.0]) * ref.var_long[res].mean()
    mons = {}
    for k in (1.0, 3.0):
        mon = ResidualMonitor(ref, NB, NB * T, SHORT, LONG,
                              ResidualThresholds(allowance_sigma=k), 20, MODEL)
        mon.prefill(*learner.reference_blocks(ref, LONG))
        mon._allowance = lambda phis, use, a=a: a.copy()  # the allowance under test
        _feed(mon, record, LEARN, LEARN + (LONG + 5) * NB)
        mons[k] = mon
    one, three = mons[1.0].statistics, mons[3.0].statistics
    var_s, var_l = ref.var_short[res], ref.var_long[res]
    a_sum = a[2:] + a[:2]
    # the window variance v is the same data in both: v = ratio·(var + k²·a)
    np.testing.assert_allclose(one[2:4] * (var_s + a_sum), three[2:4] * (var_s + 9 * a_sum),
                               rtol=1e-12)
    np.testing.assert_allclose(one[4:6] * (var_l + a_sum), three[4:6] * (var_l + 9 * a_sum),
                               rtol=1e-12)
    np.testing.assert_array_equal(one[:2], three[:2])
    # the power CUSUM's per-block increment: (m − μ)²/(σ_b² + k²·a_mean), capped
    m = mons[3.0]._last(1)[0][0, res] - ref.mean[res]
    for k, mon in mons.items():
        q = np.minimum(m**2 / (ref.block_std[res] ** 2 + k * k * a[:2]), 10.0)
        before = mon._power.copy()
        mon._update_power(mons[3.0]._last(1)[0][0, res], a[:2])
        h = mon.thresholds.power
        np.testing.assert_allclose(mon._power, np.clip(before + q - POWER_KAPPA, 0.0, h),
                                   rtol=1e-12)


def test_allowance_sigma_scales_the_learning_guards_ratio() -> None:
    """The learning guard's segment check divides the segment's variance by
    var_ref + k²·(a_within + a_mean): a segment with ten times the reference variance and
    an allowance that makes its ratio 6 with k = 1 (over the threshold 4) is 1.4 with
    k = 3."""
    rng = np.random.default_rng(4)
    nref, k_seg = 40, 10
    ref_means = 1e-3 * rng.standard_normal((nref, 6))
    ref_vars = np.full((nref, 6), 1e-4)
    seg_means = np.zeros((k_seg, 6))
    seg_vars = np.full((k_seg, 6), 1e-3)
    from gyrodiag.dtg.reference import _window_reference_variance, window_moments
    res = [4, 5]
    v_ref = _window_reference_variance(ref_means[:, res], ref_vars[:, res], k_seg)
    v_seg = window_moments(seg_means[:, res], seg_vars[:, res])[1]
    # allowance per block such that v_seg/(v_ref + a) = 6 (> 4: fails at k = 1) and
    # v_seg/(v_ref + 9a) < 4 (passes at k = 3)
    a_tot = v_seg / 6.0 - v_ref
    assert np.all(a_tot > 0) and np.all(v_seg / (v_ref + 9 * a_tot) < 4.0)
    allow = np.zeros((k_seg, 4))
    allow[:, 2:] = a_tot  # within-block part only: the level test is untouched
    npar = 2 * N_THETA
    theta = np.ones(npar)
    M = np.eye(npar + 1)
    err_var = np.ones(2)
    verdict = {}
    for k in (1.0, 3.0):
        learner = ReferenceLearner(NB, SHORT, LONG, ResidualThresholds(allowance_sigma=k),
                                   NB * T, MODEL)
        verdict[k] = learner._segment_fails(ref_means, ref_vars, seg_means, seg_vars, theta,
                                            M, theta, M, allow, err_var)
    assert verdict == {1.0: True, 3.0: False}


def test_band_reference_refines_from_theta0_eta_only_with_quiet_blocks(record) -> None:
    """The ratio band's reference (DTGChannelConfig.band_sigma, docs/dtg_case_rate.md §10)
    starts at θ0_eta with θ0's covariance v·A⁻¹ and takes the same accepted rows as θref,
    but only from blocks marked band-quiet: with every block quiet,
    θband − θref = (A0 + R)⁻¹·A0·(θ0_eta − θ0) (same rows R, other start); with none, it
    stays at θ0_eta; it survives a state round trip."""
    learner, ref = _learn(record)
    assert ref.information is not None and ref.error_variance is not None
    eta0 = ref.theta0_eta.reshape(2, N_THETA)
    assert not np.allclose(eta0, ref.theta0.reshape(2, N_THETA))  # mean fast θ vs LS
    mon = _monitor(learner, ref)
    theta, var = mon.band_reference
    np.testing.assert_array_equal(theta, eta0)
    for a in range(2):
        np.testing.assert_allclose(
            var[a], ref.error_variance[a] * np.diag(np.linalg.inv(ref.information[a])))
    assert not _feed(mon, record, LEARN, LEARN + 3000).any()
    theta, var = mon.band_reference
    refined = mon.theta_reference.reshape(2, N_THETA)
    for a in range(2):
        A0, A = ref.information[a], mon._info[a]
        theta0 = ref.theta0[a * N_THETA:(a + 1) * N_THETA]
        expected = refined[a] + np.linalg.solve(A, A0 @ (eta0[a] - theta0))
        np.testing.assert_allclose(theta[a], expected, rtol=1e-7, atol=1e-12)
        np.testing.assert_allclose(var[a], ref.error_variance[a] * np.diag(np.linalg.inv(A)))
    # blocks that are not band-quiet refine θref only
    held = _monitor(learner, ref)
    thb = np.tile(THETA, (NB, 2))
    for b0 in range(LEARN, LEARN + 3000, NB):
        held.push_block(record[b0:b0 + NB, :4], record[b0 - 2:b0 + NB], thb,
                        np.ones(NB, dtype=bool), band_quiet=False)
    np.testing.assert_array_equal(held.band_reference[0], eta0)
    np.testing.assert_allclose(held.theta_reference, mon.theta_reference)
    # state round trip
    other = ResidualMonitor(NominalReference.from_state(ref.get_state()), NB, NB * T, SHORT,
                            LONG, ResidualThresholds(), 20, MODEL)
    other.set_state(mon.get_state())
    for x, y in zip(other.band_reference, mon.band_reference, strict=True):
        np.testing.assert_array_equal(x, y)


@pytest.mark.parametrize("kind", ["drift", "step"])
def test_growth_t_holds_a_drift_that_the_relative_growth_loses(kind):
    """A pick-off drift 10 s old: the long window (2 s) no longer starts at its onset, its
    relative growth has fallen under the library's learned 0.15 (a drift then read as a
    step), while its slope stays many standard errors from zero (DRIFT_HOLD_T = 4). A
    step of the same final size: slope within noise. Measured: drift growth 0.095,
    growth_t 35; step growth_t -0.11."""
    n = LEARN + 10_000
    rec = _record(n, seed=3, amplitude=0.0)
    k = np.arange(n)
    on = LEARN + 200
    ramp = np.where(k >= on, 0.1 * T * (k - on), 0.0)  # 0.1 per s: 1000 noise std per s
    rec[:, 0] += ramp if kind == "drift" else np.where(k >= on, ramp[-1], 0.0)
    learner, ref = _learn(rec)
    mon = _monitor(learner, ref)
    _feed(mon, rec, LEARN, n)
    stats = mon.window_statistics(LONG)
    if kind == "drift":
        assert stats.growth < 0.15, stats.growth
        assert stats.growth_t > 20.0, stats.growth_t
    else:
        assert abs(stats.growth_t) < 4.0, stats.growth_t
