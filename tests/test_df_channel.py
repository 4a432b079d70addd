"""The detection-filter channel (design + calibration window + alignment + decisions) on
the closed-loop seed aircraft (tests/_aircraft_loop.py, and the paper-rule cases on the
loop of test_isolation_closed_loop)."""

import dataclasses

import numpy as np
import pytest
from _aircraft_loop import DT, NOISE_STD
from _aircraft_loop import Fault as F
from _aircraft_loop import simulate as simulate_loop
from test_isolation_closed_loop import T_FAULT, simulate

from gyrodiag.df.channel import DFChannel, DFChannelConfig
from gyrodiag.df.isolation import FaultType, SensorFaultIsolator
from gyrodiag.df.sequential_diagnosis import FaultKind

CFG = DFChannelConfig(sample_period_s=DT, calibrate_s=8.0, burn_in_s=2.0, k_sigma=6.0,
                      decision="paper")
SEQ = DFChannelConfig(sample_period_s=DT, calibrate_s=8.0, burn_in_s=2.0)
Q = 2  # pitch-rate sensor, 0-based (1-based 3 in the outputs)


def _run(ch, u, y):
    return [ch.update(uk, yk) for uk, yk in zip(u, y, strict=True)]


# ------------------------------------------------------------------ paper rule

def test_paper_rule_calibrates_then_detects_and_isolates_the_pitch_rate_bias():
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
    assert last.isolated_mask == 1 << Q
    assert last.fault_type == int(FaultType.BIAS)
    assert last.magnitude == pytest.approx(0.1, abs=0.01)
    assert last.input_delay == 0


def test_paper_rule_fault_free_run_raises_no_alarm():
    _, u, y = simulate(40.0, seed=22)
    outs = _run(DFChannel(CFG), u, y)
    assert not any(o.detected for o in outs)
    assert not any(o.alarms.any() for o in outs)


def test_paper_rule_given_thresholds_equal_learned_ones_in_effect():
    _, u, y = simulate(20.0, seed=23, fault=(2, "fail", None))
    learned = DFChannel(CFG)
    _run(learned, u[: round(8.0 / DT)], y[: round(8.0 / DT)])
    thr = learned.thresholds
    given = DFChannel(DFChannelConfig(
        sample_period_s=DT, calibrate_s=0.0, main_thresholds=thr[0],
        bank_thresholds=np.vstack(thr[1:]), decision="paper", align_auto=False))
    outs = _run(given, u, y)
    assert outs[-1].isolated_sensor == 3
    assert outs[-1].fault_type == int(FaultType.FAILURE)


@pytest.mark.parametrize("config", [CFG, SEQ], ids=["paper", "sequential"])
def test_nan_sample_skipped_and_state_round_trip_exact(config):
    _, u, y = simulate_loop(14.0, seed=24, faults=(F(Q, "bias", 0.01, start_s=9.0),))
    ch = DFChannel(config)
    _run(ch, u[:920], y[:920])  # calibrated, and in the episode (onset 9 s)
    saved = ch.get_state()
    bad = y[920].copy()
    bad[3] = np.nan
    out = ch.update(u[920], bad)
    assert not out.valid
    ref = _run(ch, u[920:], y[920:])
    fresh = DFChannel(config)  # restore into another instance, as the FMU does
    fresh.set_state(saved)
    again = _run(fresh, u[920:], y[920:])
    for a, b in zip(ref, again, strict=True):
        np.testing.assert_array_equal(a.residual, b.residual)
        # the paper rule's statistic normalises by the calibration mean: restored too
        np.testing.assert_array_equal(a.statistic, b.statistic)
        assert (a.detected, a.isolated_sensor, a.fault_type, a.magnitude, a.episodes) == (
            b.detected, b.isolated_sensor, b.fault_type, b.magnitude, b.episodes)
    assert ref[-1].isolated_sensor == 3
    # a state taken during the calibration window restores too
    early = DFChannel(config)
    _run(early, u[:300], y[:300])
    other = DFChannel(config)
    other.set_state(early.get_state())
    a, b = _run(early, u[300:1000], y[300:1000]), _run(other, u[300:1000], y[300:1000])
    assert [o.detected for o in a] == [o.detected for o in b]
    np.testing.assert_array_equal(a[-1].residual, b[-1].residual)


def test_a_bad_state_is_refused_and_leaves_the_channel_as_it_was():
    _, u, y = simulate_loop(10.0, seed=25)
    ch = DFChannel(SEQ)
    _run(ch, u[:850], y[:850])
    before = ch.get_state()
    broken = dict(before)
    broken["engine"] = dict(before["engine"], main_x=np.full(3, np.nan))
    with pytest.raises(ValueError, match="main_x"):
        ch.set_state(broken)
    after = ch.get_state()
    np.testing.assert_array_equal(after["engine"]["main_x"], before["engine"]["main_x"])


# ------------------------------------------------------------------ sequential rule

def test_sequential_rule_detects_a_two_sigma_bias_that_the_paper_rule_misses():
    t, u, y = simulate_loop(18.0, seed=26, faults=(F(Q, "bias", 2e-3),))
    paper = _run(DFChannel(CFG), u, y)
    seq_ch = DFChannel(SEQ)
    seq = _run(seq_ch, u, y)
    assert not any(o.detected for o in paper)
    onset = round(10.0 / DT)
    assert not any(o.detected for o in seq[:onset])
    first = next(k for k, o in enumerate(seq) if o.detected)
    # the default gust model (severe turbulence allowed for) costs calm-air delay; a
    # 2 sigma bias is still found well inside the 6 s of issue 33's calm-air figure
    assert t[first] - 10.0 < 2.0
    calm = _run(DFChannel(dataclasses.replace(SEQ, gust=None)), u, y)
    first_calm = next(k for k, o in enumerate(calm) if o.detected)
    assert t[first_calm] - 10.0 < 1.0
    assert t[first_calm] <= t[first]
    last = seq[-1]
    assert (last.isolated_sensor, last.fault_type) == (3, int(FaultKind.BIAS))
    assert last.magnitude == pytest.approx(2e-3, rel=0.2)
    assert last.detected and last.episodes == 1
    # the noise was learned from the window, within the scatter of 600 samples
    np.testing.assert_allclose(seq_ch.noise_std, NOISE_STD, rtol=0.1)


@pytest.mark.parametrize("delay", [0, 1, 2])
def test_alignment_is_found_and_the_verdict_does_not_depend_on_it(delay):
    """y arriving d samples after its u (a Jacobi master with d FMU boundaries) is
    realigned on the calibration window, and gives the Gauss-Seidel verdict."""
    _, u, y = simulate_loop(16.0, seed=27, faults=(F(Q, "bias", 3e-3),), input_delay=delay)
    outs = _run(DFChannel(SEQ), u, y)
    last = outs[-1]
    assert last.input_delay == delay
    assert (last.isolated_sensor, last.fault_type) == (3, int(FaultKind.BIAS))
    assert last.magnitude == pytest.approx(3e-3, rel=0.15)
    assert not any(o.detected for o in outs[:round(10.0 / DT) - delay])


def test_a_wrong_fixed_alignment_is_what_the_automatic_choice_avoids():
    _, u, y = simulate_loop(14.0, seed=28, input_delay=1)
    wrong = DFChannel(DFChannelConfig(sample_period_s=DT, calibrate_s=8.0, burn_in_s=2.0,
                                      align_auto=False, input_delay_samples=0))
    right = DFChannel(SEQ)
    _run(wrong, u, y)
    _run(right, u, y)
    # misaligned, the residual carries the input's changes: a much larger noise estimate
    assert right.input_delay == 1
    assert wrong.noise_std[2] > 3.0 * right.noise_std[2]


def test_given_noise_replaces_the_window():
    _, u, y = simulate_loop(16.0, seed=29, faults=(F(1, "bias", 3e-3),))
    ch = DFChannel(DFChannelConfig(sample_period_s=DT, calibrate_s=0.0, noise_std=NOISE_STD,
                                   align_auto=False))
    outs = _run(ch, u, y)
    assert not outs[0].calibrating
    assert not any(o.detected for o in outs[:round(10.0 / DT)])
    assert outs[-1].isolated_sensor == 2 and outs[-1].fault_type == int(FaultKind.BIAS)


@pytest.mark.parametrize(
    ("changes", "name"),
    [
        ({"A": np.zeros((5, 4))}, "A must be square"),
        ({"eigenvalues": [-1, -1, -2, -3, -4]}, "distinct"),
        ({"eigenvalues": [1, -2, -3, -4, -5]}, "stable"),
        ({"calibrate_s": 0.0, "decision": "paper", "align_auto": False}, "main_thresholds"),
        ({"calibrate_s": 0.0, "align_auto": False}, "noise_std"),
        ({"calibrate_s": 0.0, "noise_std": NOISE_STD}, "align_auto"),
        ({"calibrate_s": -1.0}, "calibrate_s"),
        ({"persistence_k": 6, "persistence_n": 5}, "persistence_k"),
        ({"sample_period_s": -1.0}, "sample_period_s"),
        ({"decision": "fast"}, "decision"),
        ({"false_alarms_per_h": 0.0}, "false_alarms_per_h"),
        ({"cusum_k": 0.0}, "cusum_k"),
        ({"variance_ratio": 1.0}, "variance_ratio"),
        ({"max_faults": 3}, "max_faults"),
        ({"align_max": -1}, "align_max"),
        ({"input_delay_samples": 1.5}, "input_delay_samples"),
        ({"noise_std": [1.0, 1.0, 1.0, 0.0, 1.0, 1.0]}, "noise_std"),
    ],
)
def test_invalid_settings_name_the_problem(changes, name):
    with pytest.raises((ValueError, TypeError), match=name):
        DFChannel(DFChannelConfig(**changes))


def test_update_floats_equals_update_through_calibration_faults_and_nan():
    """The host's plain-float entry gives the outputs and the state of the checked
    update: calibrating, nominal, a 5 σ q bias (episode, isolation), a NaN sample."""
    import dataclasses

    from gyrodiag.df.plant import seed_aircraft

    rng = np.random.default_rng(4)
    model = seed_aircraft()
    cfg = DFChannelConfig(sample_period_s=0.01, calibrate_s=2.0, burn_in_s=0.2)
    a, b = DFChannel(cfg), DFChannel(cfg)
    noise = np.array([0.05, 1e-3, 1e-3, 1e-3, 1e-3, 0.2])
    x = np.zeros(5)
    phi = np.eye(5) + 0.01 * model.A
    for k in range(900):
        u = np.array([0.0, 0.002 * rng.standard_normal()])
        y = model.C @ x + noise * rng.standard_normal(6)
        if k >= 500:
            y[2] += 5e-3
        if k == 700:
            y[1] = np.nan
        x = phi @ x + 0.01 * (model.B @ u) - 0.02 * x
        out_a = a.update(u, y)
        out_b = b.update_floats(u.tolist(), y.tolist())
        for f in dataclasses.fields(out_a):
            va, vb = getattr(out_a, f.name), getattr(out_b, f.name)
            np.testing.assert_array_equal(va, vb, err_msg=f"sample {k}: {f.name}")
    assert out_a.detected or out_a.episodes > 0


@pytest.mark.parametrize("config", [SEQ, CFG], ids=["sequential", "paper"])
def test_a_window_without_noise_calibrates_and_stays_quiet(config):
    # all-zero inputs (what `fmpy simulate` feeds an FMU by default): the sequential
    # rule's calibration failed with "array must not contain infs or NaNs"
    n = round(12.0 / DT)
    ch = DFChannel(config)
    outs = _run(ch, np.zeros((n, ch.p)), np.zeros((n, ch.m)))
    assert not outs[-1].calibrating
    assert not any(o.detected for o in outs)


def test_a_paper_state_from_before_the_energy_isolation_restores():
    # unversioned (version 0) states from before the energy isolation have neither
    # threshold statistics nor the isolator's energy sums; the migration accepts them
    _, u, y = simulate_loop(12.0, seed=24, faults=(F(Q, "bias", 0.01, start_s=9.0),))
    ch = DFChannel(CFG)
    _run(ch, u[:950], y[:950])
    old = ch.get_state()
    old.pop("state_version")
    old.pop("threshold_stats", None)
    engine = {k: v for k, v in old["engine"].items() if k not in ("energy", "energy_n")}
    old["engine"] = engine
    fresh = DFChannel(CFG)
    fresh.set_state(old)
    out = _run(fresh, u[950:], y[950:])
    assert out[-1].detected and out[-1].isolated_sensor == 3


def test_an_isolation_window_too_short_to_decide_is_lengthened_to_ten_samples():
    def window(seconds: float, period: float = DT) -> float:
        cfg = DFChannelConfig(sample_period_s=period, calibrate_s=8.0, burn_in_s=2.0,
                              decision="paper", isolation_window_s=seconds)
        cfg.validate()
        return cfg.isolation_window_in_use

    assert window(0.05) == pytest.approx(10 * DT)      # 5 samples: never isolates
    assert window(10 * DT) == pytest.approx(10 * DT)
    assert window(4.0) == 4.0 and window(0.0) == 0.0   # long enough; off stays off
    assert window(4.0, period=0.5) == 5.0               # the default at 2 Hz
    with pytest.raises(ValueError, match=r"energy_window_s must be 0 \(off\) or at least "
                                         r"10 samples"):
        ch = DFChannel(DFChannelConfig(sample_period_s=DT, calibrate_s=8.0, burn_in_s=2.0,
                                       decision="paper"))
        SensorFaultIsolator(ch.A, ch.B, ch.C, ch.K, DT, energy_window_s=0.05)


@pytest.mark.parametrize("value", [-1.0, float("nan"), 3601.0])
def test_an_invalid_isolation_baseline_is_refused_naming_it(value):
    cfg = DFChannelConfig(sample_period_s=DT, calibrate_s=8.0, burn_in_s=2.0,
                          decision="paper", isolation_baseline_s=value)
    with pytest.raises(ValueError, match="isolation_baseline_s"):
        cfg.validate()


def test_a_calibration_window_too_short_for_the_sample_period_is_lengthened():
    """10 s at a 1 s period leaves 8 samples after the 2 s burn-in: lengthened to 12
    samples so that 10 remain; at 10 ms the window is taken as given."""
    slow = DFChannel(DFChannelConfig(sample_period_s=1.0, calibrate_s=10.0, burn_in_s=2.0))
    assert (slow._n_burn, slow._n_cal) == (2, 12)
    fast = DFChannel(DFChannelConfig(sample_period_s=DT, calibrate_s=10.0, burn_in_s=2.0))
    assert (fast._n_burn, fast._n_cal) == (round(2.0 / DT), round(10.0 / DT))
