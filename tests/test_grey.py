"""Tests of gyrodiag.grey: GM(1,1), classic/improved grey predictors, grey fault detector."""

from __future__ import annotations

import math
from dataclasses import astuple

import numpy as np
import pytest

from gyrodiag.grey import (
    ClassicGreyPredictor,
    GreyFaultDetector,
    ImprovedGreyPredictor,
    gm11_fit,
    gm11_fitted_values,
    gm11_optimal_initial_value,
    gm11_predict_classic,
    gm11_predict_next,
    gm11_predict_optimized,
    positive_shift,
    prediction_errors_percent,
)

# ----------------------------------------------------------------------------- helpers


def one_step_predictions(predictor, y: np.ndarray) -> np.ndarray:
    """p[k] = prediction of y[k] made after y[0..k-1] (NaN where none)."""
    p = np.full(y.size, np.nan)
    for k in range(y.size - 1):
        p[k + 1] = predictor.update(y[k])
    return p


def mean_abs_error(y: np.ndarray, p: np.ndarray) -> float:
    return float(np.nanmean(np.abs(y - p)))


def gm11_classic_bias(q: float, m: int) -> float:
    """Exact relative error of the classic GM(1,1) prediction of x0(k) = c·q^k.

    With s = ln q the fit is a = −2·tanh(s/2) exactly, so e^{−a} = q·e^{δ} with
    δ = 2·tanh(s/2) − s, and x̂0(m+1)/x0(m+1) = e^{(m−1)δ}·(q·e^{δ} − 1)/(q − 1).
    """
    s = math.log(q)
    delta = 2.0 * math.tanh(0.5 * s) - s
    return math.exp((m - 1) * delta) * (q * math.exp(delta) - 1.0) / (q - 1.0) - 1.0


def run_detector(detector: GreyFaultDetector, y: np.ndarray) -> list:
    return [detector.update(float(v)) for v in y]


def assert_same_outputs(a: list, b: list) -> None:
    """Detector outputs equal field by field, NaN equal to NaN."""
    assert len(a) == len(b)
    for oa, ob in zip(a, b, strict=True):
        np.testing.assert_array_equal(np.array(astuple(oa)), np.array(astuple(ob)))


def alarm_intervals(t: np.ndarray, alarm: np.ndarray) -> list[tuple[float, float]]:
    edges = np.flatnonzero(np.diff(np.r_[0, alarm.astype(int), 0]))
    return [(float(t[edges[i]]), float(t[edges[i + 1] - 1])) for i in range(0, edges.size, 2)]


# ------------------------------------------------------------------ GM(1,1) known answers


@pytest.mark.parametrize("q", [1.1, 0.8, 1.5])
@pytest.mark.parametrize("c", [2.0, 0.3])
@pytest.mark.parametrize("m", [5, 12])
def test_gm11_fit_is_exact_on_geometric_sequence(q: float, c: float, m: int) -> None:
    # x0(k) = c·q^k, k = 1..m. x1(k) = c·q·(q^k − 1)/(q − 1), so
    # z1(k) = c·q/(q−1)·(q^{k−1}(q+1)/2 − 1). x0(k) + a·z1(k) = b for all k requires the
    # q^k terms to cancel, a = −2(q−1)/(q+1), and leaves b = −a·c·q/(q−1) = 2cq/(q+1).
    k = np.arange(1, m + 1)
    x0 = c * q**k
    a, b = gm11_fit(x0)
    a_exact = -2.0 * (q - 1.0) / (q + 1.0)
    b_exact = 2.0 * c * q / (q + 1.0)
    assert a == pytest.approx(a_exact, rel=1e-12)
    assert b == pytest.approx(b_exact, rel=1e-12)


def test_classic_prediction_of_slow_exponential_is_exact_to_1e9() -> None:
    # Classic GM(1,1) is not exact on exponentials: its a is the Padé value −2·tanh(s/2),
    # not −s, and the one-step prediction carries a relative bias ≈ −s²/12 − (m−1)s³/12
    # (gm11_classic_bias gives it exactly). For s = ln q = 1e−4 that bias is < 1e−9.
    c, m, s = 2.0, 10, 1e-4
    q = math.exp(s)
    bias = gm11_classic_bias(q, m)
    leading = s**2 / 12 + (m - 1) * abs(s) ** 3 / 12
    assert abs(bias) < 1e-9
    assert abs(bias) == pytest.approx(leading, rel=1e-2)
    x0 = c * q ** np.arange(1, m + 1)
    truth = c * q ** (m + 1)
    rel_err = gm11_predict_classic(x0) / truth - 1.0
    assert abs(rel_err) < 1e-9
    # the only error left is the analytic bias (rounding here is ~1e−13)
    assert rel_err == pytest.approx(bias, abs=1e-11)


@pytest.mark.parametrize("q", [1.05, 0.93])
def test_classic_prediction_bias_on_fast_exponential_matches_analysis(q: float) -> None:
    c, m = 1.5, 8
    x0 = c * q ** np.arange(1, m + 1)
    rel_err = gm11_predict_classic(x0) / (c * q ** (m + 1)) - 1.0
    bias = gm11_classic_bias(q, m)
    assert abs(bias) > 1e-4  # visibly not exact
    assert rel_err == pytest.approx(bias, rel=1e-8)


def test_optimized_prediction_of_slow_exponential() -> None:
    c, m, s = 2.0, 10, 1e-4
    q = math.exp(s)
    x0 = c * q ** np.arange(1, m + 1)
    rel_err = gm11_predict_optimized(x0) / (c * q ** (m + 1)) - 1.0
    assert abs(rel_err) < 1e-9


def test_optimal_initial_value_recovers_known_c_and_is_the_minimum() -> None:
    # Build x1 from the time response itself for given (a, b, C0): the least-squares C
    # over the window must be C0 exactly, and any other C must cost more.
    a, b, c0, m = -0.07, 1.3, 2.2, 9
    k = np.arange(1, m + 1)
    x1 = (c0 - b / a) * np.exp(-a * (k - 1)) + b / a
    x0 = np.diff(x1, prepend=0.0)
    c_star = gm11_optimal_initial_value(x0, a, b)
    assert c_star == pytest.approx(c0, rel=1e-12)

    # On data that do not follow the law, C* still minimises Σ(x̂1 − x1)².
    rng = np.random.default_rng(7)
    noisy = x0 + 0.05 * rng.standard_normal(m)
    c_star = gm11_optimal_initial_value(noisy, a, b)

    def cost(c: float) -> float:
        x1_hat = np.cumsum(gm11_fitted_values(a, b, c, m))
        return float(np.sum((x1_hat - np.cumsum(noisy)) ** 2))

    for dc in (1e-3, -1e-3, 0.1, -0.1):
        assert cost(c_star + dc) > cost(c_star)


def test_fitted_values_reproduce_time_response() -> None:
    a, b, c, m = 0.12, 0.8, 1.7, 6
    k = np.arange(1, m + 1)
    x1_hat = (c - b / a) * np.exp(-a * (k - 1)) + b / a
    np.testing.assert_allclose(
        gm11_fitted_values(a, b, c, m), np.diff(x1_hat, prepend=0.0), rtol=1e-12
    )


@pytest.mark.parametrize("a", [0.3, -0.2, 1e-3, -4e-2])
def test_careful_and_textbook_evaluation_agree_for_moderate_a(a: float) -> None:
    b, c, m = 1.1, 0.9, 7
    careful = gm11_predict_next(a, b, c, m)
    textbook = gm11_predict_next(a, b, c, m, evaluation="textbook")
    assert careful == pytest.approx(textbook, rel=1e-10)


def test_careful_evaluation_has_the_a_to_zero_limit() -> None:
    # lim_{a→0} x̂0(m+1) = b (the exponential degenerates to a constant level b)
    b, c, m = 2.5, 3.0, 10
    assert gm11_predict_next(0.0, b, c, m) == b
    assert gm11_predict_next(1e-17, b, c, m) == pytest.approx(b, rel=1e-15)
    assert math.isnan(gm11_predict_next(0.0, b, c, m, evaluation="textbook"))


@pytest.mark.parametrize(
    ("x0", "match"),
    [
        (np.ones((3, 3)), "x0 must be 1-D"),
        (np.ones(3), "x0 must have at least 4"),
        (np.array([1.0, 2.0, np.nan, 3.0]), "x0 must contain only finite"),
        (np.array([1.0, 2.0, 0.0, 3.0]), "x0 must be strictly positive"),
        (np.array([1.0, -2.0, 1.0, 3.0]), "x0 must be strictly positive"),
    ],
)
def test_gm11_fit_rejects_bad_windows(x0: np.ndarray, match: str) -> None:
    with pytest.raises(ValueError, match=match):
        gm11_fit(x0)


# ------------------------------------------------------------------ constant window


@pytest.mark.parametrize("level", [1.0, 2.5, -3.7, 1000.0])
@pytest.mark.parametrize("m", [5, 10, 20])
def test_constant_window_textbook_collapses_careful_and_improved_do_not(
    level: float, m: int
) -> None:
    textbook = ClassicGreyPredictor(m, evaluation="textbook")
    careful = ClassicGreyPredictor(m)
    improved = ImprovedGreyPredictor(m)
    for _ in range(m):
        p_text = textbook.update(level)
        p_care = careful.update(level)
        p_impr = improved.update(level)
    # the textbook model keeps the orthogonal factorisation, which leaves |a| at rounding
    # level, not exactly zero; the careful model's centred normal equations give 0
    assert 0.0 < abs(textbook.last_a) < 1e-14
    assert abs(careful.last_a) < 1e-14
    # textbook (1 − e^{a})(C − b/a): e^{a} rounds to 1 (or 1 ± ulp) -> 0 or garbage
    assert not math.isfinite(p_text) or abs(p_text / level - 1.0) > 1e-3
    # the same GM(1,1) evaluated without the cancellation is exact to rounding
    assert p_care == pytest.approx(level, rel=1e-12)
    assert p_impr == pytest.approx(level, rel=1e-9)
    assert improved.last_used_fallback


def test_zero_window_is_predicted_as_zero() -> None:
    improved = ImprovedGreyPredictor(6)
    for _ in range(6):
        p = improved.update(0.0)
    assert abs(p) < 1e-12


# ------------------------------------------------------------------ predictor accuracy


def test_improved_beats_classic_on_ramp_with_small_noise() -> None:
    n, slope = 400, 0.01
    rng = np.random.default_rng(3)
    y = 0.5 + slope * np.arange(n) + 0.02 * slope * rng.standard_normal(n)
    e_improved = mean_abs_error(y, one_step_predictions(ImprovedGreyPredictor(10), y))
    e_classic = mean_abs_error(y, one_step_predictions(ClassicGreyPredictor(10), y))
    e_ordinary = mean_abs_error(y, one_step_predictions(ClassicGreyPredictor(None), y))
    assert e_improved < 0.5 * e_classic
    assert e_improved < 0.1 * e_ordinary


def test_noise_dominated_ramp_favours_the_moving_classic_but_not_the_ordinary() -> None:
    # Documented limitation: the quadratic residual extrapolation amplifies white
    # noise. With noise σ equal to the per-sample ramp increment the moving-window
    # classic GM (a near-linear trend fit) is better; the paper's "ordinary" GM over
    # the whole record is still worse than the improved one.
    n, slope = 400, 0.01
    rng = np.random.default_rng(3)
    y = 0.5 + slope * np.arange(n) + slope * rng.standard_normal(n)
    e_improved = mean_abs_error(y, one_step_predictions(ImprovedGreyPredictor(10), y))
    e_classic = mean_abs_error(y, one_step_predictions(ClassicGreyPredictor(10), y))
    e_ordinary = mean_abs_error(y, one_step_predictions(ClassicGreyPredictor(None), y))
    assert e_classic < e_improved < e_ordinary


@pytest.mark.parametrize("start", [-5.0, 0.3])
def test_improved_predicts_negative_and_zero_crossing_ramps(start: float) -> None:
    slope, m = -0.01, 10
    y = start + slope * np.arange(200)
    p = one_step_predictions(ImprovedGreyPredictor(m), y)
    assert np.all(np.isnan(p[:m])) and np.all(np.isfinite(p[m:]))
    # a ramp is not an exponential: after the quadratic residual correction a fixed
    # bias of 1.2e-3 of the per-sample increment is left (m = 10, default level ratio)
    assert np.max(np.abs(y[m:] - p[m:])) < 2e-3 * abs(slope)


@pytest.mark.parametrize("predictor_cls", [ImprovedGreyPredictor, ClassicGreyPredictor])
def test_predictions_are_equivariant_under_offset_and_scale(predictor_cls) -> None:
    t = np.arange(150) * 0.1
    rng = np.random.default_rng(11)
    y = np.sin(0.7 * t) + 0.05 * rng.standard_normal(t.size)
    scale, offset = 3.0, -7.0
    p = one_step_predictions(predictor_cls(12), y)
    p_affine = one_step_predictions(predictor_cls(12), scale * y + offset)
    np.testing.assert_allclose(p_affine[12:], scale * p[12:] + offset, rtol=0, atol=1e-10)


def test_positive_shift_puts_minimum_at_level_ratio_times_range() -> None:
    w = np.array([-3.0, -1.0, -2.0, -2.5])
    shift = positive_shift(w, level_ratio=2.0)
    assert (w + shift).min() == pytest.approx(2.0 * 2.0)
    assert positive_shift(np.full(5, 4.0)) == 0.0  # positive constant left as is
    assert positive_shift(np.full(5, -4.0)) == 8.0
    with pytest.raises(ValueError, match="level_ratio"):
        positive_shift(w, level_ratio=0.0)


# ------------------------------------------------------------------ predictor streaming


@pytest.mark.parametrize(
    "make",
    [
        lambda: ImprovedGreyPredictor(8),
        lambda: ClassicGreyPredictor(8),
        lambda: ClassicGreyPredictor(None),
    ],
)
def test_predictor_state_round_trip_and_reset(make) -> None:
    y = 2.0 + np.sin(0.3 * np.arange(60))
    a = make()
    for v in y[:30]:
        a.update(v)
    state = a.get_state()
    b = make()
    b.set_state(state)
    state["samples"][:] = 0.0  # the saved copy must not alias the predictor
    out_a = [a.update(v) for v in y[30:]]
    out_b = [b.update(v) for v in y[30:]]
    assert out_a == out_b
    a.reset()
    fresh = make()
    assert [a.update(v) for v in y] == [fresh.update(v) for v in y]


def test_predictor_rejects_non_finite_sample_and_bad_state() -> None:
    p = ImprovedGreyPredictor(5)
    with pytest.raises(ValueError, match="y must be finite"):
        p.update(math.nan)
    with pytest.raises(ValueError, match="state\\['samples'\\]"):
        p.set_state({"samples": np.ones(6), "prediction": 0.0, "a": 0.0, "fallback": 0})
    with pytest.raises(ValueError, match="missing"):
        p.set_state({"samples": np.ones(3)})


@pytest.mark.parametrize(
    ("make", "match"),
    [
        (lambda: ImprovedGreyPredictor(3), "window"),
        (lambda: ImprovedGreyPredictor(None), "window"),
        (lambda: ImprovedGreyPredictor(4, residual_order=3), "window must be >= residual_order"),
        (lambda: ImprovedGreyPredictor(8, residual_order=-1), "residual_order"),
        (lambda: ImprovedGreyPredictor(8, a_min=-1.0), "a_min"),
        (lambda: ImprovedGreyPredictor(8, level_ratio=0.0), "level_ratio"),
        (lambda: ClassicGreyPredictor(2), "window"),
        (lambda: ClassicGreyPredictor(8, evaluation="exact"), "evaluation"),
        (lambda: ClassicGreyPredictor(8.5), "window"),
    ],
)
def test_predictor_rejects_bad_arguments(make, match: str) -> None:
    with pytest.raises((ValueError, TypeError), match=match):
        make()


# ------------------------------------------------------------------ detector

T_S = 0.5  # sample period of the detector scenarios, s


def bias_scenario() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Smooth HRG-like output with a −0.2 V bias from 27 s to 47 s (paper's first fault)."""
    t = np.arange(0.0, 120.0, T_S)
    base = 3.0 - 2.0 * np.exp(-t / 30.0) + 0.1 * np.sin(2.0 * np.pi * t / 40.0)
    fault = (t >= 27.0) & (t < 47.0)
    return t, base - 0.2 * fault, fault


def test_detector_alarm_spans_bias_fault_thanks_to_substitution() -> None:
    t, y, fault = bias_scenario()
    det = GreyFaultDetector(ImprovedGreyPredictor(10), threshold=0.05, sample_period_s=T_S)
    out = run_detector(det, y)
    alarm = np.array([o.alarm for o in out])
    # onset at the first faulty sample, alarm on every faulty sample and nowhere else
    assert alarm_intervals(t, alarm) == [(27.0, 46.5)]
    assert out[int(27.0 / T_S)].alarm_onset_time_s == 27.0
    assert np.all(np.isnan([o.alarm_onset_time_s for o in out if not o.alarm]))
    # without substitution the same predictor absorbs the step: a short pulse only
    plain = ImprovedGreyPredictor(10)
    p = one_step_predictions(plain, y)
    raw_alarm = np.abs(y - p) > 0.05
    assert raw_alarm[fault].sum() < 0.5 * fault.sum()


def test_detector_clears_after_clear_after_s_and_reseeds() -> None:
    t, y, _ = bias_scenario()
    det = GreyFaultDetector(
        ImprovedGreyPredictor(10), threshold=0.05, sample_period_s=T_S, clear_after_s=5.0
    )
    out = run_detector(det, y)
    alarm = np.array([o.alarm for o in out])
    cleared_at = [o.time_s for o in out if o.cleared]
    # alarm 27 s, cleared at 32 s; the predictor re-seeded on the biased signal then
    # sees the bias disappear at 47 s as a new step: alarm again, cleared at 52 s.
    assert cleared_at == [32.0, 52.0]
    assert alarm_intervals(t, alarm) == [(27.0, 31.5), (47.0, 51.5)]
    reseeded = out[int(32.0 / T_S) + 1]
    assert not reseeded.alarm and abs(reseeded.error) < 0.05


def test_detector_does_not_alarm_during_warm_up() -> None:
    det = GreyFaultDetector(ImprovedGreyPredictor(6), threshold=1e-3, sample_period_s=1.0)
    out = run_detector(det, np.array([1.0, 50.0, -3.0, 8.0, 2.0, 7.0]))
    assert not any(o.alarm for o in out)
    assert all(math.isnan(o.prediction) for o in out)
    assert math.isfinite(det.pending_prediction)


def flat_tail_scenario() -> tuple[np.ndarray, np.ndarray]:
    """Exponential approach that becomes exactly constant (HRG output after 825 s)."""
    t = np.arange(0.0, 200.0, T_S)
    return t, np.where(t < 60.0, 3.0 - 2.0 * np.exp(-t / 10.0), 3.0)


def test_flat_tail_false_alarms_only_with_textbook_classic() -> None:
    t, y = flat_tail_scenario()
    threshold = 0.05  # a quarter of the paper's 0.2 V bias fault

    def alarms(predictor) -> np.ndarray:
        det = GreyFaultDetector(predictor, threshold, T_S, clear_after_s=20.0)
        return np.array([o.alarm for o in run_detector(det, y)])

    textbook = alarms(ClassicGreyPredictor(10, evaluation="textbook"))
    # the paper's result: false alarms once the whole window is constant (60 s + 9·T)
    assert textbook[t >= 70.0].any()
    assert not textbook[t < 60.0].any()
    assert not alarms(ImprovedGreyPredictor(10)).any()
    # the careful evaluation of the same classic model does not collapse
    assert not alarms(ClassicGreyPredictor(10)).any()


def test_improved_error_is_far_below_classic_on_the_smooth_scenario() -> None:
    _, y = flat_tail_scenario()
    e_improved = mean_abs_error(y, one_step_predictions(ImprovedGreyPredictor(10), y))
    e_classic = mean_abs_error(y, one_step_predictions(ClassicGreyPredictor(10), y))
    assert e_improved < 0.2 * e_classic


def test_detector_skips_non_finite_sample_without_touching_state() -> None:
    _, y, _ = bias_scenario()
    make = lambda: GreyFaultDetector(  # noqa: E731
        ImprovedGreyPredictor(10), threshold=0.05, sample_period_s=T_S, clear_after_s=20.0
    )
    det, ref = make(), make()
    k_nan = 60  # inside the alarm (30 s), where substitution state matters
    out, out_ref = [], []
    for k, v in enumerate(y):
        if k == k_nan:
            before = det.get_state()
            for bad in (math.nan, math.inf, -math.inf):
                o = det.update(bad)
                assert not o.valid and math.isnan(o.error)
                assert o.alarm == det.alarm and o.prediction == det.pending_prediction
            after = det.get_state()
            assert before.keys() == after.keys()
            for key in before:
                np.testing.assert_array_equal(before[key], after[key])
        out.append(det.update(float(v)))
        out_ref.append(ref.update(float(v)))
    assert_same_outputs(out, out_ref)


def test_detector_state_round_trip_gives_identical_outputs() -> None:
    _, y, _ = bias_scenario()
    make = lambda: GreyFaultDetector(  # noqa: E731
        ImprovedGreyPredictor(10), threshold=0.05, sample_period_s=T_S, clear_after_s=5.0
    )
    det = make()
    k_save = 58  # 29 s: in alarm, with substituted samples in the window
    run_detector(det, y[:k_save])
    assert det.alarm
    state = det.get_state()
    tail = run_detector(det, y[k_save:])
    other = make()
    other.set_state(state)
    assert_same_outputs(run_detector(other, y[k_save:]), tail)


def test_detector_reset_equals_fresh_instance() -> None:
    _, y, _ = bias_scenario()
    make = lambda: GreyFaultDetector(  # noqa: E731
        ImprovedGreyPredictor(10), threshold=0.05, sample_period_s=T_S, clear_after_s=5.0
    )
    det = make()
    run_detector(det, y[:80])
    det.reset()
    assert_same_outputs(run_detector(det, y), run_detector(make(), y))


def test_detector_uses_host_time_when_given() -> None:
    _, y, _ = bias_scenario()
    det = GreyFaultDetector(ImprovedGreyPredictor(10), 0.05, T_S)
    out = [det.update(float(v), time_s=100.0 + k * T_S) for k, v in enumerate(y)]
    onsets = {o.alarm_onset_time_s for o in out if o.alarm}
    assert onsets == {127.0}


def manoeuvre_output(noise_v: float) -> np.ndarray:
    """HRG-like output at 100 Hz through a fast pitch manoeuvre (the co-simulation case).

    2.5 V + 0.3 V slow sine, plus 10 V/(rad/s) times a ±0.1 rad/s square pitch-rate
    doublet at 2–4 s, through the 10 Hz first-order read-out (exact ZOH recursion),
    plus seeded white noise. The doublet's corners are far outside what a 0.1 s
    window predicts, so the detector false-alarms at 2.01 s.
    """
    t = np.arange(0.0, 25.0, MANOEUVRE_H)
    rate = 0.1 * (((t >= 2.0) & (t < 3.0)).astype(float) - ((t >= 3.0) & (t < 4.0)))
    u = 2.5 + 0.3 * np.sin(2.0 * np.pi * t / 50.0) + 10.0 * rate
    decay = math.exp(-2.0 * math.pi * 10.0 * MANOEUVRE_H)
    v = np.empty_like(u)
    v[0] = u[0]
    for k in range(1, u.size):
        v[k] = u[k - 1] + decay * (v[k - 1] - u[k - 1])
    return v + noise_v * np.random.default_rng(5).standard_normal(t.size)


MANOEUVRE_H = 0.01  # s


def longest_run(flags: np.ndarray) -> int:
    edges = np.flatnonzero(np.diff(np.r_[0, flags.astype(int), 0]))
    return int(np.max(edges[1::2] - edges[::2])) if edges.size else 0


@pytest.mark.parametrize("noise_v", [0.0, 0.002])
@pytest.mark.parametrize("predictor_cls", [ImprovedGreyPredictor, ClassicGreyPredictor])
def test_substituted_prediction_stays_bounded_through_a_long_false_alarm(
    predictor_cls, noise_v: float
) -> None:
    # Without the bound the self-fed extrapolation reached 2.6e7–6.2e8 V on these four
    # cases (co-simulation: 3.3e9 V); with it the largest |prediction| is 2.80–2.86 V.
    m = 10
    y = manoeuvre_output(noise_v)
    det = GreyFaultDetector(predictor_cls(m), 0.05, MANOEUVRE_H, clear_after_s=20.0)
    out = run_detector(det, y)
    alarm = np.array([o.alarm for o in out])
    p = np.array([o.prediction for o in out])
    k_onset = round(2.01 / MANOEUVRE_H)
    assert alarm[k_onset] and not alarm[:k_onset].any()
    assert longest_run(alarm) > 10 * m  # the window has been all-substituted for long
    span = float(y.max() - y.min())
    finite = p[np.isfinite(p)]
    assert finite.size == y.size - m
    assert np.all((finite >= y.min() - span) & (finite <= y.max() + span))
    # the reported error is against the bounded prediction
    errors = np.array([o.error for o in out])
    np.testing.assert_array_equal(errors[m:], y[m:] - p[m:])


def test_constant_history_gives_a_held_substitute_equal_to_the_level() -> None:
    # Fault-free history exactly constant: the envelope has zero span, so any
    # substitute that is not the level itself is clipped to it and held there.
    level, m = 1.25, 6
    y = np.r_[np.full(20, level), np.linspace(1.5, 4.0, 30)]  # a ramp far off the level
    det = GreyFaultDetector(ImprovedGreyPredictor(m), 0.05, 1.0)
    out = run_detector(det, y)
    assert all(o.alarm for o in out[20:])
    assert [o.prediction for o in out[21:]] == [level] * 29
    assert det.envelope == (level, level)


def test_detector_state_round_trip_while_holding_a_clipped_substitute() -> None:
    y = manoeuvre_output(0.002)
    make = lambda: GreyFaultDetector(  # noqa: E731
        ImprovedGreyPredictor(10), 0.05, MANOEUVRE_H, clear_after_s=20.0
    )
    det = make()
    k_save = round(10.0 / MANOEUVRE_H)
    run_detector(det, y[:k_save])
    state = det.get_state()
    assert det.alarm and math.isfinite(state["hold"])
    tail = run_detector(det, y[k_save:])
    other = make()
    other.set_state(state)
    assert_same_outputs(run_detector(other, y[k_save:]), tail)


SEED_H = 0.1  # s


def seed_like_hrg_timeline() -> tuple[np.ndarray, np.ndarray]:
    """Seed-001 scenario at 10 Hz (docs/methods.md §3), noise-free, 0–1000 s.

    10 V/(rad/s) times the HRG model's seed-001 rate profile (two slow sines about
    0.25 rad/s, tapered to exactly constant from 825 s), then bias −0.2 V in 27–47 s,
    stuck at 3 V in 252–272 s, scale factor 1.05 from 420 s.
    """
    t = np.arange(0.0, 1000.0, SEED_H)
    wave = 0.10 * np.sin(2.0 * np.pi * t / 500.0) + 0.04 * np.sin(2.0 * np.pi * t / 130.0 + 0.5)
    taper = np.clip((t - 725.0) / 100.0, 0.0, 1.0)
    weight = 0.5 * (1.0 + np.cos(np.pi * taper))
    y = 10.0 * (0.25 + np.where(t >= 825.0, 0.0, weight * wave))
    y = np.where((t >= 27.0) & (t < 47.0), y - 0.2, y)
    y = np.where((t >= 252.0) & (t < 272.0), 3.0, y)
    y = np.where(t >= 420.0, 1.05 * y, y)
    return t, y


def test_seed_timeline_alarms_last_the_fault_with_bounded_substitutes() -> None:
    t, y = seed_like_hrg_timeline()
    det = GreyFaultDetector(ImprovedGreyPredictor(10), 0.05, SEED_H, clear_after_s=20.0)
    out = run_detector(det, y)
    alarm = np.array([o.alarm for o in out])
    p = np.array([o.prediction for o in out])
    # Same intervals as the unbounded detector: the bias and the stuck output alarm for
    # their whole duration, the permanent scale fault until cleared 20 s after onset.
    # The stuck fault ends exactly when its alarm is cleared (272 s), so the re-seeded
    # window holds the stuck value and the return to the true signal is a new step
    # (alarm 272.2–292.1 s). Nothing after 440 s, in particular not on the flat tail.
    intervals = [(round(a, 6), round(b, 6)) for a, b in alarm_intervals(t, alarm)]
    assert intervals == [(27.0, 46.9), (252.0, 271.9), (272.2, 292.1), (420.0, 439.9)]
    assert [round(o.time_s, 6) for o in out if o.cleared] == [272.0, 292.2, 440.0]
    # The unbounded detector's substitute reached −1184 V after the stuck fault. Bounded,
    # it is clipped at 272.6 s to the fault-free envelope so far (2.42–3.85 V) minus its
    # span, 0.995 V, and held there: below the signal's range (1.15–3.94 V) but within
    # that range widened by its span on each side.
    span = float(y.max() - y.min())
    assert y.min() - span <= np.nanmin(p) and np.nanmax(p) <= y.max() + span
    fault_free = y[(t < 272.15) & ~alarm]
    lo, hi = float(fault_free.min()), float(fault_free.max())
    assert (lo, hi) == (pytest.approx(2.4227, abs=1e-4), pytest.approx(3.8505, abs=1e-4))
    assert np.all(p[(t >= 272.7) & (t < 292.2)] == lo - (hi - lo))


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"envelope_margin": -0.5}, "envelope_margin"),
        ({"threshold": 0.0}, "threshold"),
        ({"threshold": math.nan}, "threshold"),
        ({"sample_period_s": -1.0}, "sample_period_s"),
        ({"clear_after_s": -1.0}, "clear_after_s"),
        ({"clear_after_s": 0.0}, "clear_after_s"),
        ({"reseed_length": 0}, "reseed_length"),
        ({"predictor": object()}, "predictor"),
    ],
)
def test_detector_rejects_bad_arguments(kwargs: dict, match: str) -> None:
    args = {"predictor": ImprovedGreyPredictor(8), "threshold": 0.1, "sample_period_s": 1.0}
    args.update(kwargs)
    with pytest.raises((ValueError, TypeError), match=match):
        GreyFaultDetector(**args)


def test_detector_rejects_non_numeric_sample_and_bad_time() -> None:
    det = GreyFaultDetector(ImprovedGreyPredictor(8), 0.1, 1.0)
    with pytest.raises(TypeError, match="y must be a number"):
        det.update("1.0x")
    with pytest.raises(ValueError, match="time_s"):
        det.update(1.0, time_s=math.inf)


# ------------------------------------------------------------------ metrics


def test_prediction_errors_percent_known_answer() -> None:
    y = np.array([1.0, 2.0, -4.0, 5.0])
    y_hat = np.array([np.nan, 2.2, -3.8, np.nan])
    mean, worst = prediction_errors_percent(y, y_hat)
    assert mean == pytest.approx(7.5)  # (10 % + 5 %) / 2, relative to |y|
    assert worst == pytest.approx(10.0)


def test_prediction_errors_percent_rejects_bad_input() -> None:
    with pytest.raises(ValueError, match="non-zero"):
        prediction_errors_percent([0.0, 1.0], [0.1, 1.0])
    with pytest.raises(ValueError, match="no finite prediction"):
        prediction_errors_percent([1.0, 1.0], [np.nan, np.nan])
    with pytest.raises(ValueError, match="equal length"):
        prediction_errors_percent([1.0, 1.0], [1.0])
