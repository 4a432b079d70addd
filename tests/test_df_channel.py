"""The detection-filter channel (design + online calibration + isolation) on the
closed-loop seed aircraft of test_isolation_closed_loop."""

import numpy as np
import pytest
from test_isolation_closed_loop import DT, T_FAULT, simulate

from gyrodiag.df_channel import DFChannel, DFChannelConfig
from gyrodiag.isolation import FaultType

CFG = DFChannelConfig(sample_period_s=DT, calibrate_s=8.0, burn_in_s=2.0, k_sigma=6.0)


def _run(ch, u, y):
    return [ch.update(uk, yk) for uk, yk in zip(u, y, strict=True)]


def test_calibrates_online_then_detects_and_isolates_the_pitch_rate_bias():
    t, u, y = simulate(20.0, seed=21, fault=(2, "bias", 0.1))
    ch = DFChannel(CFG)
    outs = _run(ch, u, y)
    k_cal = round(8.0 / DT)
    assert outs[k_cal - 2].calibrating and not outs[k_cal].calibrating
    assert ch.thresholds is not None and len(ch.thresholds) == 7
    assert not any(o.detected for o in outs[: round(T_FAULT / DT)]), "alarm before onset"
    first = next(k for k, o in enumerate(outs) if o.detected)
    assert t[first] - T_FAULT < 0.5
    last = outs[-1]
    assert last.isolated_sensor == 3  # 1-based: q
    assert last.fault_type == int(FaultType.BIAS)
    assert last.magnitude == pytest.approx(0.1, abs=0.01)


def test_fault_free_run_raises_no_alarm():
    _, u, y = simulate(40.0, seed=22)
    outs = _run(DFChannel(CFG), u, y)
    assert not any(o.detected for o in outs)
    assert not any(o.alarms.any() for o in outs)


def test_given_thresholds_equal_learned_ones_in_effect():
    _, u, y = simulate(20.0, seed=23, fault=(2, "fail", None))
    learned = DFChannel(CFG)
    _run(learned, u[: round(8.0 / DT)], y[: round(8.0 / DT)])
    thr = learned.thresholds
    given = DFChannel(DFChannelConfig(
        sample_period_s=DT, calibrate_s=0.0, main_thresholds=thr[0],
        bank_thresholds=np.vstack(thr[1:])))
    outs = _run(given, u, y)
    assert outs[-1].isolated_sensor == 3
    assert outs[-1].fault_type == int(FaultType.FAILURE)


def test_nan_sample_skipped_and_state_round_trip_exact():
    _, u, y = simulate(14.0, seed=24, fault=(2, "bias", 0.1))
    ch = DFChannel(CFG)
    _run(ch, u[:900], y[:900])
    saved = ch.get_state()
    bad = y[900].copy()
    bad[3] = np.nan
    out = ch.update(u[900], bad)
    assert not out.valid
    ref = _run(ch, u[900:], y[900:])
    fresh = DFChannel(CFG)  # restore into another instance, as the FMU does
    fresh.set_state(saved)
    again = _run(fresh, u[900:], y[900:])
    for a, b in zip(ref, again, strict=True):
        np.testing.assert_array_equal(a.residual, b.residual)
        assert (a.detected, a.isolated_sensor, a.fault_type) == (
            b.detected, b.isolated_sensor, b.fault_type)
    # restoring a calibrated state into a fresh instance also works after calibration
    saved2 = ch.get_state()
    other = DFChannel(CFG)
    other.set_state(saved2)
    assert other.thresholds is not None


@pytest.mark.parametrize(
    ("changes", "name"),
    [
        ({"A": np.zeros((5, 4))}, "A must be square"),
        ({"eigenvalues": [-1, -1, -2, -3, -4]}, "distinct"),
        ({"eigenvalues": [1, -2, -3, -4, -5]}, "stable"),
        ({"calibrate_s": 0.0}, "main_thresholds"),
        ({"calibrate_s": 1.0, "burn_in_s": 1.0}, "calibrate_s"),
        ({"persistence_k": 6, "persistence_n": 5}, "persistence_k"),
        ({"sample_period_s": -1.0}, "sample_period_s"),
    ],
)
def test_invalid_settings_name_the_problem(changes, name):
    with pytest.raises((ValueError, TypeError), match=name):
        DFChannel(DFChannelConfig(**changes))
