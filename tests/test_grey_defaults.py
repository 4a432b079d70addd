"""The grey channel's default decision rule (issue 32 item 1): the learned sequential rule
(``grey.decision = 1``) from ``sample_period_s`` alone, and the paper's fixed threshold as
the option ``grey.decision = 0``.

Library: the rules of :mod:`gyrodiag.grey.decision` build the detectors the hand-tuned
scenarios configured (so the measurements of tests/test_grey_calibrated.py hold for the
default), and the fault-free start follows the sample period. FMU: the seed-001 HRG
timeline with 0–20 mV of output noise, the Diagnoser at its defaults, through the
scenario master (scenarios/hrg_seed001_defaults_noise20mv.toml with other noise levels
and a noise seed that no scenario uses).
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from test_grey_calibrated import H, detector, timeline

from gyrodiag.grey import (
    CalibratedKSigma,
    CalibratedSequential,
    GreyFaultDetector,
    ImprovedGreyPredictor,
    PaperThreshold,
)
from gyrodiag_harness.verification.metrics import detection_delay_s, false_alarms

ROOT = Path(__file__).resolve().parents[1]
DEFAULTS_SCENARIO = ROOT / "scenarios" / "hrg_seed001_defaults_noise20mv.toml"
FAULT_WINDOWS = [(27.0, 47.0), (252.0, 272.0), (420.0, math.inf)]


def _improved() -> ImprovedGreyPredictor:
    return ImprovedGreyPredictor(10, a_min=1e-6)


def _candidates() -> list[ImprovedGreyPredictor]:
    return [ImprovedGreyPredictor(10, a_min=1e-6, residual_order=o) for o in (1, 0)]


def _outputs(det: GreyFaultDetector, t: np.ndarray, y: np.ndarray) -> np.ndarray:
    return np.array([(o.alarm, o.prediction, o.statistic, o.calibrating)
                     for o in (det.update(v, time_s=tk) for v, tk in zip(y, t, strict=True))],
                    dtype=float)


def test_default_rule_is_the_hand_tuned_calibrated_detector():
    """CalibratedSequential() = the detector of the hand-tuned noise scenarios (floor
    0.01 V, 40 errors after the 10-sample warm-up at 2 Hz, sequential, residual orders
    compared): bit for bit on the seed timeline at 12 mV."""
    t, y = timeline(0.012, 7)
    default = CalibratedSequential().build(_improved(), H, 20.0, _candidates())
    assert default.calibrate_samples == 40 and default.sequential
    np.testing.assert_array_equal(_outputs(default, t, y), _outputs(detector(), t, y))


def test_paper_rule_is_the_fixed_threshold_detector():
    t, y = timeline(0.012, 7, duration=300.0)
    paper = PaperThreshold().build(_improved(), H, 20.0, _candidates())
    assert not paper.calibrated and paper.threshold == 0.05
    fixed = GreyFaultDetector(_improved(), 0.05, H, 20.0)
    got = _outputs(paper, t, y)
    np.testing.assert_array_equal(got, _outputs(fixed, t, y))
    assert got[:, 0].any()  # 12 mV: the fixed rule does alarm outside the faults too


@pytest.mark.parametrize(("period", "errors"), [(0.5, 40), (0.25, 90), (1.0, 15), (0.01, 2490)])
def test_fault_free_start_is_seconds_and_includes_the_warm_up(period, errors):
    """learn_end_s = 25 s whatever the sample period: the 10-sample warm-up, then the rest
    of the 25 s calibrates (the first fault of the seed timeline is at 27 s)."""
    for rule in (CalibratedSequential(), CalibratedKSigma()):
        assert rule.build(_improved(), period).calibrate_samples == errors


@pytest.mark.parametrize(("period", "samples"),
                         [(0.5, 60), (0.25, 120), (1.0, 30), (0.1, 300), (0.01, 400)])
def test_reference_window_is_seconds_up_to_400_samples(period, samples):
    """The lagged test's reference spans 30 s at any sample period (60 samples at 2 Hz,
    the hand-tuned value), at most 400 samples."""
    assert CalibratedSequential().build(_improved(), period).reference_window == samples


def test_windows_too_short_for_the_sample_period_are_lengthened():
    """2 s holds 4 samples at 2 Hz: the reference polynomial of degree 3 gets its 6; 25 s
    holds 12 samples at 0.5 Hz: the 10-sample warm-up and 10 calibration errors."""
    assert CalibratedSequential(reference_window_s=2.0).build(
        _improved(), 0.5).reference_window == 6
    assert CalibratedSequential().build(_improved(), 2.0).calibrate_samples == 10
    assert CalibratedSequential(learn_end_s=60.0).build(
        _improved(), 2.0).calibrate_samples == 20


@pytest.mark.parametrize(("rule", "kwargs", "name"), [
    (PaperThreshold, {"threshold": 0.0}, "threshold"),
    (CalibratedSequential, {"threshold_floor": -1.0}, "threshold_floor"),
    (CalibratedSequential, {"learn_end_s": math.nan}, "learn_end_s"),
    (CalibratedSequential, {"cusum_k": 0.0}, "cusum_k"),
    (CalibratedSequential, {"reference_window_s": -30.0}, "reference_window_s"),
    (CalibratedKSigma, {"k_sigma": 0.0}, "k_sigma"),
])
def test_bad_rule_parameters_name_the_parameter(rule, kwargs, name):
    with pytest.raises(ValueError, match=rf"^{name} must"):
        rule(**kwargs)


# ------------------------------------------------------------------ FMU at defaults
#: Noise levels (V rms) of the sweep and a noise seed no scenario or benchmark uses.
NOISE_V = (0.0, 0.005, 0.010, 0.012, 0.020)
SWEEP_SEED = 61


@pytest.fixture(scope="module")
def defaults_runs(gyrodiag_run, tmp_path_factory) -> dict[float, object]:
    text = DEFAULTS_SCENARIO.read_text(encoding="utf-8")
    old = "noise_std = 0.02, bandwidth_hz = 10.0, seed = 4"
    assert old in text
    runs = {}
    for noise in NOISE_V:
        name = f"hrg_defaults_sweep_{round(noise * 1e3)}mv"
        path = tmp_path_factory.mktemp(name) / f"{name}.toml"
        path.write_text(text.replace(old, f"noise_std = {noise!r}, bandwidth_hz = 10.0, "
                                          f"seed = {SWEEP_SEED}"), encoding="utf-8")
        runs[noise] = gyrodiag_run(path)
    return runs


@pytest.mark.parametrize("noise", NOISE_V)
def test_defaults_detect_the_seed_faults_with_no_false_alarm(defaults_runs, noise):
    """Defaults (only sample_period_s and the channel switches): bias and stuck within
    1.5 s, the scale fault within 1.5 s up to 12 mV (at 20 mV, 5 sigma of the noise, it
    is not always found: docs/notes.md), no alarm outside the faults + 25 s; the paper's
    rule false-alarms from 10 mV on and not at 0 mV."""
    r = defaults_runs[noise]
    t, alarm = r.time, r.signal("diag.grey.alarm")
    delays = [detection_delay_s(t, alarm, start) for start, _ in FAULT_WINDOWS]
    # NaN (never detected) fails these comparisons
    assert delays[0] <= 1.5 and delays[1] <= 1.5, delays
    if noise <= 0.012:
        assert delays[2] <= 1.5, delays
    assert false_alarms(t, alarm, FAULT_WINDOWS, margin_s=25.0).count == 0
    assert not alarm[t < 27.0].any()
    paper = false_alarms(t, r.signal("paper.grey.alarm"), FAULT_WINDOWS, margin_s=25.0)
    if noise == 0.0:
        assert paper.count == 0
    elif noise >= 0.010:
        assert paper.count >= 1
    # sigma_e learned on the fault-free start: the floor (2 mV) without noise, else
    # 1.1-1.9 times the noise (the improved model's error on it)
    sigma = r.signal("diag.grey.sigma")[-1]
    assert (sigma == pytest.approx(0.002, rel=1e-6) if noise == 0.0
            else 1.1 * noise < sigma < 1.9 * noise), sigma


def test_a_tiny_design_rate_at_a_fast_sample_builds_with_the_longest_tabulated_run():
    """1e-9 per hour at 1 kHz asks for a CUSUM run length of 7.2e15 samples, beyond the
    shipped table (1e13): the CUSUM takes 1e13 (no false alarm in any record) instead of
    refusing the FMU's declared bound of grey.false_alarm_rate."""
    from gyrodiag.common.cusum import mean_cusum_threshold

    det = CalibratedSequential(false_alarms_per_h=1e-9).build(_improved(), 1e-3)
    assert det.cusum_threshold == mean_cusum_threshold(1e13, 1.5)
    assert det.cusum_threshold > CalibratedSequential().build(_improved(), 1e-3).cusum_threshold


def test_defaults_at_4_hz_calibrate_until_25_s_and_detect(gyrodiag_run, tmp_path):
    """The same scenario sampled at 4 Hz (step and sample_period_s 0.25 s), 10 mV: the
    fault-free start is still 25 s (10 samples of warm-up, then 90 errors), the lagged
    test's reference 30 s (120 samples), every fault is seen within 1.5 s and nothing
    else is."""
    text = DEFAULTS_SCENARIO.read_text(encoding="utf-8")
    for old, new in (("step_s = 0.5", "step_s = 0.25"),
                     ("sample_period_s = 0.5", "sample_period_s = 0.25"),
                     ("noise_std = 0.02, bandwidth_hz = 10.0, seed = 4",
                      f"noise_std = 0.01, bandwidth_hz = 10.0, seed = {SWEEP_SEED}")):
        assert old in text
        text = text.replace(old, new)
    path = tmp_path / "hrg_defaults_4hz_10mv.toml"
    path.write_text(text, encoding="utf-8")
    r = gyrodiag_run(path)
    t, alarm = r.time, r.signal("diag.grey.alarm")
    calibrating = t[r.signal("diag.grey.calibrating") > 0.5]
    assert 24.5 <= calibrating.max() < 25.0
    delays = [detection_delay_s(t, alarm, start) for start, _ in FAULT_WINDOWS]
    assert all(d <= 1.5 for d in delays), delays
    assert false_alarms(t, alarm, FAULT_WINDOWS, margin_s=25.0).count == 0
