"""Closed-loop seed aircraft: detection and isolation of sensor faults (docs/methods.md §4).

Test simulation only: the open-loop aircraft is unstable (+1.46, +0.99), so an LQR
pitch-attitude controller with integral action closes the loop on the true state
(one test uses the measured, possibly faulty, sensors instead). The plant is stepped
exactly (ZOH) at 100 Hz; the command is a ±0.25 rad square wave on pitch, period 8 s.

Sensor noise (white, seeded), chosen as typical of the class of sensor at 100 Hz:
angles α, θ, γ 1e-3 rad (0.06°, vane / AHRS grade), pitch rate 1e-3 rad/s (0.06°/s,
tactical rate gyro), speed 0.05 m/s (air data), height 0.2 m (radar altimeter). The
paper's fault, 0.1 rad/s, is then 100 σ of the gyro noise.
"""

from __future__ import annotations

import control
import numpy as np
import pytest
import scipy.signal

from gyrodiag.df.filter import design_detection_filter
from gyrodiag.df.isolation import AMBIGUOUS, NO_FAULT, FaultType, SensorFaultIsolator
from gyrodiag.df.plant import PAPER_EIGENVALUES, seed_aircraft

MODEL = seed_aircraft()
A, B, C = MODEL.A, MODEL.B, MODEL.C
DT = 0.01
NOISE_STD = np.array([0.05, 1e-3, 1e-3, 1e-3, 1e-3, 0.2])
T_FAULT = 10.0
Q = 2  # pitch-rate sensor index


def _controller_gain() -> np.ndarray:
    # LQR on [α, q, θ, ∫(θ − θ_cmd)] with the elevator; v and h do not feed back.
    a_i = np.zeros((4, 4))
    a_i[:3, :3] = A[1:4, 1:4]
    a_i[3, 2] = 1.0
    b_i = np.zeros((4, 1))
    b_i[:3, 0] = B[1:4, 1]
    gain, _, _ = control.lqr(a_i, b_i, np.diag([1.0, 1.0, 10.0, 10.0]), np.eye(1))
    return np.asarray(gain)[0]


CONTROLLER = _controller_gain()
PHI, GAMMA, *_ = scipy.signal.cont2discrete((A, B, C, np.zeros((6, 2))), DT, method="zoh")


def simulate(duration_s, seed, fault=None, feedback_from_sensors=False,
             command=(0.0, 0.25)):
    """Return t, u, y for ``fault = (sensor, kind, value)`` from ``T_FAULT``.

    kind: "bias" y + value, "gain" value·y, "stuck" y frozen at value (None: the
    sample at onset), "fail" y = 0.  ``command``: the pitch command's (offset,
    amplitude), rad, a square wave of period 8 s.
    """
    rng = np.random.default_rng(seed)
    n = round(duration_s / DT)
    t = np.arange(n) * DT
    x = np.zeros(5)
    integ = 0.0
    u_log, y_log = np.zeros((n, 2)), np.zeros((n, 6))
    stuck = None
    for k in range(n):
        y = C @ x + NOISE_STD * rng.standard_normal(6)
        if fault is not None and t[k] >= T_FAULT:
            i, kind, value = fault
            if kind == "bias":
                y[i] += value
            elif kind == "gain":
                y[i] *= value
            elif kind == "stuck":
                stuck = (y[i] if value is None else value) if stuck is None else stuck
                y[i] = stuck
            elif kind == "fail":
                y[i] = 0.0
        fb = y[[1, 2, 3]] if feedback_from_sensors else x[[1, 2, 3]]
        u = np.array([0.0, -CONTROLLER @ np.append(fb, integ)])
        cmd = command[0] + (command[1] if (t[k] % 8.0) < 4.0 else -command[1])
        integ += DT * ((y[3] if feedback_from_sensors else x[3]) - cmd)
        u_log[k], y_log[k] = u, y
        x = PHI @ x + GAMMA @ u
    return t, u_log, y_log


@pytest.fixture(scope="module")
def isolator():
    k = design_detection_filter(A, C, np.eye(5), PAPER_EIGENVALUES)
    iso = SensorFaultIsolator(A, B, C, k, DT)
    _, u, y = simulate(60.0, seed=100)  # training run, its own seed
    iso.calibrate(u, y, k_sigma=6.0)
    return iso


def run(iso, t, u, y):
    iso.reset()
    results = [iso.update(u[k], y[k]) for k in range(t.size)]
    detected = np.array([r.detected for r in results])
    isolated = np.array([r.isolated for r in results])
    any_alarm = np.array([r.main_alarms.any() or r.observer_alarms.any() for r in results])
    return results, detected, isolated, any_alarm


def first_time(t, flags):
    return float(t[np.argmax(flags)]) if flags.any() else np.inf


def test_fault_free_run_has_no_alarm(isolator):
    t, u, y = simulate(60.0, seed=1)
    results, detected, isolated, any_alarm = run(isolator, t, u, y)
    assert not any_alarm.any()
    assert not detected.any()
    assert (isolated == NO_FAULT).all()
    peak = max(np.abs(r.main_normalised).max() for r in results)
    assert 0.3 < peak < 1.0  # at noise level: neither silent nor alarming
    assert results[-1].fault_type == FaultType.NONE


def test_pitch_rate_bias_detected_isolated_and_sized(isolator):
    t, u, y = simulate(20.0, seed=2, fault=(Q, "bias", 0.1))
    results, detected, isolated, any_alarm = run(isolator, t, u, y)
    assert not any_alarm[t < T_FAULT].any()
    t_det = first_time(t, detected)
    t_iso = first_time(t, isolated >= 0)
    assert T_FAULT <= t_det <= T_FAULT + 0.5
    assert t_iso <= T_FAULT + 0.5
    assert (isolated[t >= t_iso] == Q).all()
    last = results[-1]
    assert last.onset_sensor == Q
    assert last.fault_type == FaultType.BIAS
    assert last.magnitude == pytest.approx(0.1, abs=0.005)
    # The GOS pattern: every observer but the one without q alarms.
    assert list(last.observer_alarms) == [True, True, False, True, True, True]


@pytest.mark.parametrize(
    ("kind", "value", "expected_type", "expected_size", "tol"),
    [
        ("gain", 1.5, FaultType.GAIN, 1.5, 0.05),
        ("stuck", None, FaultType.STUCK, None, 1e-12),
        ("stuck", 0.05, FaultType.STUCK, 0.05, 1e-12),
        ("fail", None, FaultType.FAILURE, 0.0, 0.0),
    ],
)
def test_pitch_rate_fault_types(isolator, kind, value, expected_type, expected_size, tol):
    t, u, y = simulate(20.0, seed=3, fault=(Q, kind, value))
    results, detected, isolated, any_alarm = run(isolator, t, u, y)
    assert not any_alarm[t < T_FAULT].any()
    assert first_time(t, detected) <= T_FAULT + 0.5
    assert first_time(t, isolated == Q) <= T_FAULT + 1.0
    assert isolated[-1] == Q
    assert results[-1].fault_type == expected_type
    size = y[-1, Q] if expected_size is None else expected_size  # stuck at onset sample
    assert results[-1].magnitude == pytest.approx(size, abs=tol)


@pytest.mark.parametrize("sensor", [1, 3, 4])
def test_angle_sensor_biases_isolated(isolator, sensor):
    t, u, y = simulate(15.0, seed=4, fault=(sensor, "bias", 0.02))
    results, _, isolated, any_alarm = run(isolator, t, u, y)
    assert not any_alarm[t < T_FAULT].any()
    assert first_time(t, isolated == sensor) <= T_FAULT + 0.5
    assert isolated[-1] == sensor
    assert results[-1].fault_type == FaultType.BIAS
    assert results[-1].magnitude == pytest.approx(0.02, abs=0.005)


def test_speed_bias_seen_only_at_onset(isolator):
    # v bias = a different initial speed: only the step is visible, and only while the
    # observers absorb it. Isolation is latched from that transient; size unknowable.
    t, u, y = simulate(15.0, seed=5, fault=(0, "bias", 1.0))
    results, detected, isolated, _ = run(isolator, t, u, y)
    assert first_time(t, detected) <= T_FAULT + 0.1
    assert isolated[-1] == 0
    assert results[-1].onset_sensor == 0
    assert results[-1].fault_type == FaultType.UNKNOWN
    assert np.isnan(results[-1].magnitude)
    # The alarm itself dies away: no main-filter alarm 5 s later.
    assert not any(r.main_alarms.any() for r in results[-100:])


def test_height_stuck_classified_from_output_alone(isolator):
    t, u, y = simulate(15.0, seed=6, fault=(5, "stuck", None))
    results, _, isolated, _ = run(isolator, t, u, y)
    assert isolated[-1] == 5
    assert results[-1].fault_type == FaultType.STUCK
    assert results[-1].magnitude == pytest.approx(y[-1, 5], abs=1e-9)


def test_isolation_with_controller_reading_faulty_sensors(isolator):
    # The realistic loop: the controller feeds back the biased gyro. The residuals do
    # not depend on the (known) input, so isolation is unchanged.
    t, u, y = simulate(20.0, seed=7, fault=(Q, "bias", 0.1), feedback_from_sensors=True)
    results, detected, isolated, any_alarm = run(isolator, t, u, y)
    assert not any_alarm[t < T_FAULT].any()
    assert first_time(t, detected) <= T_FAULT + 0.5
    assert isolated[-1] == Q
    assert results[-1].fault_type == FaultType.BIAS
    assert results[-1].magnitude == pytest.approx(0.1, abs=0.005)


def test_ambiguous_before_confirmation(isolator):
    t, u, y = simulate(10.1, seed=8, fault=(Q, "bias", 0.1))
    _, detected, isolated, _ = run(isolator, t, u, y)
    # Between detection (3-of-5 persistence) and the 5-sample confirmation: -2.
    first = np.argmax(detected)
    assert isolated[first] == AMBIGUOUS
    assert isolated[-1] == Q


def test_state_round_trip_reset_and_bad_arguments(isolator):
    t, u, y = simulate(12.0, seed=9, fault=(Q, "bias", 0.1))
    isolator.reset()
    for k in range(1000):
        isolator.update(u[k], y[k])
    snap = isolator.get_state()
    assert all(isinstance(v, (np.ndarray, int, float)) for v in snap.values())
    first = [isolator.update(u[k], y[k]) for k in range(1000, t.size)]
    isolator.set_state(snap)
    second = [isolator.update(u[k], y[k]) for k in range(1000, t.size)]
    for a, b in zip(first, second, strict=True):
        assert (a.isolated, a.fault_type) == (b.isolated, b.fault_type)
        np.testing.assert_array_equal(a.main_normalised, b.main_normalised)
        np.testing.assert_array_equal(a.observer_alarms, b.observer_alarms)
        assert a.magnitude == b.magnitude or (np.isnan(a.magnitude) and np.isnan(b.magnitude))
    assert second[-1].isolated == Q

    before = isolator.get_state()
    with pytest.raises(ValueError, match=r"^y must"):
        isolator.update(u[0], np.full(6, np.nan))
    with pytest.raises(ValueError, match=r"^u must"):
        isolator.update([0.0, np.inf], y[0])
    after = isolator.get_state()
    for key, val in before.items():
        np.testing.assert_array_equal(after[key], val)

    broken = dict(before)
    broken["sums"] = np.zeros((6, 5))
    with pytest.raises(ValueError, match="sums"):
        isolator.set_state(broken)
    for key, val in before.items():  # failed set_state leaves the state as it was
        np.testing.assert_array_equal(isolator.get_state()[key], val)

    isolator.reset()
    fresh = [isolator.update(u[k], y[k]) for k in range(200)]
    isolator.reset()
    again = [isolator.update(u[k], y[k]) for k in range(200)]
    for a, b in zip(fresh, again, strict=True):
        np.testing.assert_array_equal(a.main_normalised, b.main_normalised)


def test_uncalibrated_and_bad_construction():
    k = design_detection_filter(A, C, np.eye(5), PAPER_EIGENVALUES)
    iso = SensorFaultIsolator(A, B, C, k, DT)
    assert not iso.calibrated
    with pytest.raises(RuntimeError, match="calibrate"):
        iso.update([0.0, 0.0], np.zeros(6))
    with pytest.raises(ValueError, match="persistence_k"):
        SensorFaultIsolator(A, B, C, k, DT, persistence_k=6, persistence_n=5)
    with pytest.raises(ValueError, match="sample_period_s"):
        SensorFaultIsolator(A, B, C, k, -1.0)
    with pytest.raises(ValueError, match="bank_eigenvalues"):
        SensorFaultIsolator(A, B, C, k, DT, bank_eigenvalues=[-1.0, 2.0, -3.0, -4.0, -5.0])


@pytest.mark.parametrize("fault, expected_type, size, tol", [
    ((3, "gain", 1.05), FaultType.GAIN, 1.05, 0.005),
    ((3, "bias", 0.01), FaultType.BIAS, 0.01, 0.002),
])
def test_a_gain_on_a_signal_with_a_mean_is_a_gain(fault, expected_type, size, tol):
    # pitch flown at 0.2 +- 0.05 rad: a 5 % theta gain moves y - yhat by ~0.007 on
    # average, more than its variation explains; the former test against the mean
    # deviation typed it BIAS 0.0073 (g = 1.0488, 39 standard errors from 1)
    k = design_detection_filter(A, C, np.eye(5), PAPER_EIGENVALUES)
    iso = SensorFaultIsolator(A, B, C, k, DT)
    _, u, y = simulate(60.0, seed=100, command=(0.2, 0.05))
    iso.calibrate(u, y, k_sigma=6.0)
    t, u, y = simulate(30.0, seed=3, fault=fault, command=(0.2, 0.05))
    results, *_ = run(iso, t, u, y)
    last = results[-1]
    assert last.isolated == 3
    assert last.fault_type == expected_type
    assert last.magnitude == pytest.approx(size, abs=tol)


def test_an_energy_window_too_short_to_decide_is_refused():
    k = design_detection_filter(A, C, np.eye(5), PAPER_EIGENVALUES)
    for window in (0.004, 0.05, 0.09):  # 0, 5, 9 samples at 100 Hz: never decided
        with pytest.raises(ValueError, match=r"energy_window_s must be 0 \(off\) or at "
                                             r"least 10 samples \(0\.1 s"):
            SensorFaultIsolator(A, B, C, k, DT, energy_window_s=window)
    SensorFaultIsolator(A, B, C, k, DT, energy_window_s=0.1)
    SensorFaultIsolator(A, B, C, k, DT, energy_window_s=0.0)


def test_the_energy_baseline_follows_fault_free_energy_before_detection():
    """Sensor noise 1.5 times the calibration's: every bank observer's residual is
    linear in the noise, so its fault-free energy, and with it the baseline, tends to
    1.5² = 2.25 (no fault: no detection, the baseline keeps following). Off (0 s) it
    stays the calibration's 1. The baseline is part of the state."""
    k = design_detection_filter(A, C, np.eye(5), PAPER_EIGENVALUES)
    _, u_cal, y_cal = simulate(60.0, seed=100)
    t, u, y = simulate(40.0, seed=7)
    rng = np.random.default_rng(8)
    y = y + rng.normal(0.0, 1.0, y.shape) * NOISE_STD * np.sqrt(1.5**2 - 1.0)
    baselines = {}
    for tau in (0.0, 5.0):
        iso = SensorFaultIsolator(A, B, C, k, DT, energy_window_s=4.0,
                                  energy_baseline_s=tau)
        iso.calibrate(u_cal, y_cal, k_sigma=8.0, burn_in=200)
        half = t.size // 2
        for i in range(half):
            assert not iso.update(u[i], y[i]).detected
        copy = SensorFaultIsolator(A, B, C, k, DT, energy_window_s=4.0,
                                   energy_baseline_s=tau)
        copy.calibrate(u_cal, y_cal, k_sigma=8.0, burn_in=200)
        copy.set_state(iso.get_state())
        for i in range(half, t.size):
            iso.update(u[i], y[i])
            copy.update(u[i], y[i])
        np.testing.assert_array_equal(copy.energy_baseline, iso.energy_baseline)
        baselines[tau] = iso.energy_baseline
    np.testing.assert_array_equal(baselines[0.0], np.ones(6))
    np.testing.assert_allclose(baselines[5.0], 2.25, rtol=0.1)
    with pytest.raises(ValueError, match="energy_baseline_s"):
        SensorFaultIsolator(A, B, C, k, DT, energy_baseline_s=-1.0)
