"""Diagnoser.fmu grey-channel options: the paper's ordinary GM(1,1) over the whole record
(``grey.window = 0``) and the textbook evaluation of the classic model
(``grey.classic_evaluation = 1``), compared with the library to 1e−12.

The FMU runs in a fresh process (tests/_grey_options_runner.py, docs/methods.md §6.11); the
references are built here from ``gyrodiag.grey`` directly.
"""

from __future__ import annotations

import numpy as np
import pytest
from _grey_options_runner import CALIBRATED, CASES, INVALID, K_SAVE, K_SAVE_CALIBRATED, H
from test_diagnoser_fmu import _grey_columns

from gyrodiag.grey import ClassicGreyPredictor, GreyFaultDetector, ImprovedGreyPredictor

RUNNER = "tests/_grey_options_runner.py"
THRESHOLD, CLEAR_S = 0.05, 10.0
TOL = {"rtol": 1e-12, "atol": 1e-12}


def signal() -> tuple[np.ndarray, np.ndarray]:
    """200 s at 2 Hz: a tapered sine that is exactly 2.0 from 80 s, a −0.2 bias in
    30–40 s and a +0.2 bias in 100–115 s (on the flat part, longer than the 10 s
    clearing, so that the detector re-seeds on constant windows)."""
    t = H * np.arange(400)
    y = np.where(t < 80.0,
                 2.0 + 0.3 * np.sin(2 * np.pi * t / 80.0) * np.clip((80.0 - t) / 40.0, 0, 1) ** 2,
                 2.0)
    y = np.where((t >= 30.0) & (t < 40.0), y - 0.2, y)
    y = np.where((t >= 100.0) & (t < 115.0), y + 0.2, y)
    return t, y


def noisy_signal() -> tuple[np.ndarray, np.ndarray]:
    """The same signal with 10 mV of white noise (seeded)."""
    t, y = signal()
    return t, y + 0.01 * np.random.default_rng(11).standard_normal(y.size)


def calibrated_library(label: str, t: np.ndarray, y: np.ndarray) -> dict[str, np.ndarray]:
    extra = CALIBRATED[label]
    sequential = extra["grey.decision"] == 1
    candidates = ([ImprovedGreyPredictor(10, a_min=1e-6, residual_order=o) for o in (1, 0)]
                  if extra.get("grey.auto_order") else [])
    lagged = {name: extra[f"grey.{name}"] for name in
              ("lag_max", "reference_order", "suspicion_sigma") if f"grey.{name}" in extra}
    if "grey.reference_window_s" in extra:  # seconds in the FMU, samples in the library
        lagged["reference_window"] = round(extra["grey.reference_window_s"] / H)
    det = GreyFaultDetector(
        ImprovedGreyPredictor(10, a_min=1e-6), extra["grey.threshold_floor"], H, CLEAR_S,
        # grey.learn_end_s counts from the start: the 10-sample warm-up, then calibration
        calibrate_samples=round(extra["grey.learn_end_s"] / H) - 10, sequential=sequential,
        candidates=candidates, **lagged)
    return _grey_columns(det, y, t)


def library(label: str, t: np.ndarray, y: np.ndarray) -> dict[str, np.ndarray]:
    model, window, evaluation = CASES[label]
    if model == 1:
        predictor = ImprovedGreyPredictor(window, a_min=1e-6)
    else:
        predictor = ClassicGreyPredictor(None if window == 0 else window,
                                         evaluation="textbook" if evaluation else "careful")
    return _grey_columns(GreyFaultDetector(predictor, THRESHOLD, H, CLEAR_S), y, t)


@pytest.fixture(scope="module")
def fmu(run_fmu_script, tmp_path_factory) -> dict[str, np.ndarray]:
    inp = tmp_path_factory.mktemp("grey_options_in") / "inputs.npz"
    np.savez(inp, y=signal()[1], y_noisy=noisy_signal()[1])
    return run_fmu_script(RUNNER, str(inp))


def column(fmu, key: str, name: str) -> np.ndarray:
    index = {str(c): i for i, c in enumerate(fmu["columns"])}
    return fmu[key][:, index[name]]


def onsets(t: np.ndarray, alarm: np.ndarray) -> np.ndarray:
    return t[np.flatnonzero(np.diff(np.r_[0, alarm.astype(int)]) == 1)]


@pytest.mark.parametrize("label", list(CASES))
def test_fmu_equals_library(fmu, label):
    t, y = signal()
    ref = library(label, t, y)
    for name, expected in ref.items():
        np.testing.assert_allclose(column(fmu, label, name), expected, equal_nan=True,
                                   err_msg=f"{label}: {name}", **TOL)


@pytest.mark.parametrize("label", list(CALIBRATED))
def test_calibrated_detector_fmu_equals_library(fmu, label):
    t, y = noisy_signal()
    ref = calibrated_library(label, t, y)
    for name, expected in ref.items():
        np.testing.assert_allclose(column(fmu, label, name), expected, equal_nan=True,
                                   err_msg=f"{label}: {name}", **TOL)
    alarm = column(fmu, label, "grey.alarm")
    # both biases seen at their first sample, nothing else raised (10 mV of noise)
    assert list(onsets(t, alarm)[:2]) == [30.0, 100.0]
    calibrating = column(fmu, label, "grey.calibrating")
    assert calibrating[:24].all() and not calibrating[31:].any()  # 5 s + 10 s
    sigma = column(fmu, label, "grey.sigma")
    assert 0.01 < sigma[-1] < 0.03  # the improved model's error on 10 mV of noise


def test_calibrated_state_save_and_restore(fmu):
    np.testing.assert_array_equal(fmu["cal_again"], fmu["cal_first"])
    t, y = noisy_signal()
    ref = calibrated_library("calibrated_sequential_auto", t, y)["grey.alarm"][
        K_SAVE_CALIBRATED:]
    got = column({"columns": fmu["columns"], "x": fmu["cal_again"]}, "x", "grey.alarm")
    np.testing.assert_array_equal(got, ref)


def test_textbook_evaluation_false_alarms_on_constant_reseeds_careful_does_not(fmu):
    t, _ = signal()
    textbook = onsets(t, column(fmu, "ordinary_textbook", "grey.alarm"))
    careful = onsets(t, column(fmu, "ordinary_careful", "grey.alarm"))
    # Both see the flat-part fault at 100 s. Cleared at 110 s, the textbook model is
    # re-seeded with a constant window, collapses and alarms again at once, and so
    # after every later clearing; the careful one only sees the fault's end (115 s).
    assert 100.0 in textbook and 100.0 in careful
    assert textbook[textbook > 100.0][0] == pytest.approx(110.5)
    assert np.sum(textbook > 115.0) >= 6
    assert list(careful[careful > 100.0]) == [115.0]


def test_whole_record_differs_from_a_moving_window(fmu):
    # window 0 is really "no window": the ordinary and the 8-sample textbook classic
    # models predict differently from the 9th sample on
    a = column(fmu, "ordinary_textbook", "grey.prediction")
    b = column(fmu, "moving_textbook", "grey.prediction")
    assert np.nanmax(np.abs(a[9:40] - b[9:40])) > 1e-3


def test_whole_record_state_save_and_restore(fmu):
    np.testing.assert_array_equal(fmu["state_again"], fmu["state_first"])
    t, y = signal()
    ref = library("ordinary_textbook", t, y)["grey.prediction"][K_SAVE:]
    np.testing.assert_allclose(column({"columns": fmu["columns"], "x": fmu["state_again"]},
                                      "x", "grey.prediction"), ref, equal_nan=True, **TOL)


@pytest.mark.parametrize(("i", "label", "names"), [
    (0, "window 0 with the improved model", ("grey.window", "grey.model")),
    (1, "classic_evaluation 2", ("grey.classic_evaluation",)),
    (2, "classic window 3", ("grey.window",)),
    (3, "grey.decision 3", ("grey.decision",)),
    (4, "grey.learn_end_s negative", ("grey.learn_end_s",)),
    (5, "grey.cusum_k 0", ("grey.cusum_k",)),
    (6, "grey.lag_max 5", ("grey.lag_max",)),
    (7, "grey.reference_window_s 0", ("grey.reference_window_s",)),
])
def test_invalid_options_are_fmi2error_naming_the_parameter(fmu, i, label, names):
    assert list(INVALID)[i] == label
    assert int(fmu["invalid_status"][i]) == 3  # fmi2Error
    log = str(fmu["invalid_log"][i])
    for name in names:
        assert name in log, log
