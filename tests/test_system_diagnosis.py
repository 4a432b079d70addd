"""System level (issue 12): the DTG as the aircraft's pitch gyro in manoeuvres and off trim.

Library: the DTG channel with the case rate (``DTGChannelConfig.case_rate``, a second
gyro's q as the independent estimate) keeps θ at its level-flight value and stays silent
in a fault-free manoeuvre and off trim, where the paper's regression alarms; the
detection filter with the DTG's read-out dynamics (``DFChannelConfig.sensor_dynamics``)
does not type a manoeuvre as a q gain fault. FMU: Diagnoser.fmu equals the library on
both new paths (tests/_system_diagnoser_runner.py, a fresh process).
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
import pytest
from _system_chain import ROOT, PitchCommand, run_chain

from gyrodiag.df.channel import DFChannel, DFChannelConfig
from gyrodiag.df.sensor_dynamics import SensorDynamics, SensorDynamicsEqualiser
from gyrodiag.dtg.channel import DTGChannel, DTGChannelConfig
from gyrodiag.dtg.model import N_THETA
from gyrodiag.dtg.patterns import PatternLibrary

sys.path.insert(0, str(ROOT / "models" / "dtg"))
import gd_dtg_readout as readout
import gd_dtg_sets as sets

RUNNER = Path(__file__).resolve().parent / "_system_diagnoser_runner.py"
T = 1e-3
#: Second gyro: 2e-4 rad/s per 1 kHz sample (docs/dtg_case_rate.md §4).
GYRO2_STD = 2e-4
#: The DTG channel of the system scenarios (dtg_physical_*: forgetting 0.9998, θ0 learned
#: 2-10 s, band 0.93/1.07, low-pass only).
SYSTEM_DTG = dict(classifier="paper", forgetting=0.9998, learn_start_s=2.0, learn_end_s=10.0,
                  low=0.93, high=1.07)
SQUARE = {"command": PitchCommand(1, -0.05, start=10.0, period=8.0)}
DOUBLET = {"command": PitchCommand(3, 0.1, start=10.0, period=4.0, pulse=1.0)}
SQUARE_25 = {"command": PitchCommand(1, -0.25, start=10.0, period=8.0)}
SQUARE_FROM_0 = {"command": PitchCommand(1, 0.05, period=8.0)}
OFF_TRIM = {"x0": (0.0, 0.05, 0.1, 0.1, 0.0)}


def _chain(duration: float, **kw) -> dict[str, np.ndarray]:
    o = run_chain(duration, **kw)
    o["gyro2"] = o["q"] + GYRO2_STD * np.random.default_rng(7).standard_normal(o["q"].size)
    return o


@pytest.fixture(scope="module")
def runs() -> dict[str, dict[str, np.ndarray]]:
    return {"level": _chain(20.0), "square": _chain(20.0, **SQUARE),
            "square_from_0": _chain(20.0, **SQUARE_FROM_0), "off_trim": _chain(20.0, **OFF_TRIM),
            "doublet": _chain(20.0, **DOUBLET), "square_25": _chain(20.0, **SQUARE_25)}


def _dtg_inputs(o: dict[str, np.ndarray]) -> np.ndarray:
    """(Utx, Uty, Ux, Uy, ωx, ωy): the pitch rate drives the gyro's y axis."""
    return np.column_stack([o["Utx"], o["Uty"], o["Ux"], o["Uy"], np.zeros_like(o["q"]),
                            o["gyro2"]])


def _run_dtg(o, case_rate, **kw):
    ch = DTGChannel(DTGChannelConfig(**{**SYSTEM_DTG, "case_rate": case_rate, **kw}))
    outs = [ch.update(*row) for row in _dtg_inputs(o)]
    return ch, outs


# ------------------------------------------------------------------------ DTG, library
def test_case_rate_keeps_theta_at_its_level_flight_value(runs) -> None:
    """Mean θ over 10-20 s of a square wave from 0 s against level flight, per axis:
    with the case rate within what noise explains (seed spread of the central θ at rest
    1.2-2.2 %, docs/dtg_case_rate.md), without it θ3/θ4 move by tens of per cent."""
    change = {}
    for cr in (None, "central"):
        th = {}
        for name in ("level", "square_from_0", "off_trim"):
            _, outs = _run_dtg(runs[name], cr)
            th[name] = np.mean([o.theta for o in outs[10000:]], axis=0)
        change[cr] = {n: np.abs(th[n] / th["level"] - 1.0) for n in ("square_from_0", "off_trim")}
    # measured (forgetting 0.9998, seed as here): ≤ 1.9 % (square) and ≤ 2.3 % (off trim,
    # θL of x) with the case rate; 72-233 % on θ3/θ4 and up to 100 % on θ5 without
    for name, d in change["central"].items():
        assert d.max() < 0.025, (name, (100 * d).round(2))
    assert change[None]["square_from_0"][:, 2:4].min() > 0.3, change[None]
    assert change[None]["off_trim"][0, 2:5].min() > 0.1, change[None]


@pytest.mark.parametrize("name", ["square", "square_from_0", "off_trim"])
def test_case_rate_channel_is_silent_in_a_fault_free_manoeuvre(runs, name) -> None:
    """The system scenarios' DTG channel (paper classifier, ratio band 0.93/1.07) alarms
    at the end of learning or with the first edge without the case rate, and stays
    silent with it."""
    o = runs[name]
    _, without = _run_dtg(o, None)
    ch, with_rate = _run_dtg(o, "central")
    assert any(x.alarm for x in without)
    assert not any(x.alarm for x in with_rate)
    eta = np.array([x.eta for x in with_rate[10000:]])
    assert np.abs(eta - 1.0).max() < 0.05, np.abs(eta - 1.0).max()
    assert ch.theta0.shape == (2, N_THETA)
    assert ch.reference is not None and ch.reference.theta0.shape == (2 * N_THETA,)


@pytest.mark.parametrize("name", ["square", "square_25", "doublet", "square_from_0",
                                  "off_trim", "level"])
def test_case_rate_pattern_classifier_is_silent_in_manoeuvres(runs, name) -> None:
    """The residual tests with the per-axis reference refined by the fault-free blocks
    (docs/dtg_case_rate.md §8): silent in square waves, a doublet and off trim. Measured
    (this seed): level z ≤ 1.5, variance ratios ≤ 2.1 (0.5 s) and ≤ 1.5 (2 s), as in
    level flight; with θ0 frozen at its learned value level z reached 450-2200 and the
    channel alarmed from the first edge to the end. A square wave from 0 s puts edges
    into the learning window: its guard allows for the uncertainty of the segments-before
    fit the same way (without, it reported a change at the first edge inside the window
    and the channel alarmed 0.9 s after learning)."""
    _, outs = _run_dtg(runs[name], "central", classifier="pattern")
    assert outs[-1].diagnosis.reference_status == 1
    assert not any(x.alarm for x in outs)
    tests = np.array([x.diagnosis.tests for x in outs[10025:]])
    assert tests[:, :2].max() < 3.0, tests[:, :2].max()
    assert tests[:, 2:4].max() < 3.0, tests[:, 2:4].max()
    assert tests[:, 4:].max() < 1.8, tests[:, 4:].max()


def test_case_rate_pattern_classifier_alarms_off_trim_without_the_case_rate(runs) -> None:
    _, outs = _run_dtg(runs["off_trim"], None, classifier="pattern")
    assert any(x.alarm for x in outs)


def test_case_rate_channel_started_in_a_manoeuvre_is_silent() -> None:
    """A channel whose first sample falls inside a manoeuvre (an FMU chain whose DTG
    starts at the case rate; here the off-trim recovery from 0.2 s: q −0.40 rad/s, Ux
    46 V): its zero-state prefilter shows every signal jumping at the start, a J·Δω
    impulse on the y line that the rotor never had. The rows of the filter's start are
    left out of the estimators (as after a gap). Measured: |η − 1| ≤ 0.034 and no alarm;
    with those rows the y estimator was kicked, |η − 1| up to 15.9, alarm 54 % of the
    time."""
    o = _chain(22.0, **OFF_TRIM)
    cut = {k: v[200:] for k, v in o.items()}
    assert abs(cut["q"][0]) > 0.3 and abs(cut["Ux"][0]) > 30.0
    _, outs = _run_dtg(cut, "central", classifier="pattern")
    assert not any(x.alarm for x in outs)
    eta = np.array([x.eta for x in outs[10000:]])
    assert np.abs(eta - 1.0).max() < 0.06, np.abs(eta - 1.0).max()


def _with_fault(o, signal: str, size: float, t0: float) -> dict[str, np.ndarray]:
    faulty = dict(o)
    faulty[signal] = np.where(o["t"] >= t0, o[signal] + size, o[signal])
    return faulty


@pytest.mark.parametrize(("signal", "t0", "bound"), [
    ("Utx", 14.05, 0.05), ("Uty", 10.3, 0.05), ("Ux", 12.0, 0.5), ("Uy", 16.0, 0.5)])
def test_case_rate_pattern_classifier_detects_faults_in_a_manoeuvre(runs, signal, t0,
                                                                   bound) -> None:
    """0.1 V steps in the square wave (edges at 10, 14, 18 s): a pick-off step right after
    an edge (and in the first edge, before the reference is refined) within 50 ms, as in
    level flight (10-25 ms); a torquer step 2 s after an edge within 0.5 s (level flight
    0.25 s). Without a pattern library the alarm is reported "unknown"."""
    delays = {}
    for name in ("level", "square"):
        _, outs = _run_dtg(_with_fault(runs[name], signal, 0.1, t0), "central",
                           classifier="pattern")
        k0 = round(t0 / T) - 1  # row k holds t = (k + 1)·T
        assert not any(x.alarm for x in outs[:k0])
        first = next(k for k in range(k0, len(outs)) if outs[k].alarm)
        delays[name] = (first - k0) * T
        assert outs[-1].alarm and outs[-1].fault_code == -1
        assert outs[-1].diagnosis.class_name == "unknown"
    assert delays["square"] <= bound, delays
    assert delays["level"] <= bound, delays


@pytest.mark.parametrize("flight", ["level", "square", "doublet"])
@pytest.mark.parametrize(("signal", "t0", "size", "name"), [
    ("Utx", 14.05, 0.1, "utx_step"), ("Ux", 12.0, 0.3, "ux_step")])
def test_case_rate_channel_classifies_with_a_level_library_and_ignores_its_prior(
        runs, flight, signal, t0, size, name) -> None:
    """The level-flight library (18 learned classes) classifies pick-off and torquer steps
    of the case-rate channel in level flight and in manoeuvres (there from the residuals
    alone: the voltages carry the manoeuvre; before, 8 of 24 signal faults were right in
    the square wave and doublets, all as physical classes); the library's nominal prior
    (the paper regression's one-axis θ0) is accepted but not used: the same outputs
    without it. Measured: the right class in 65-93 % of the alarm samples."""
    from _dtg_patterns import learned_library_dict, pattern_library_dict

    lib = learned_library_dict()
    with_prior = {**lib, "nominal": pattern_library_dict(T, prior=True)["nominal"]}
    o = _with_fault(runs[flight], signal, size, t0)
    out = {}
    for key, d in (("plain", lib), ("prior", with_prior)):
        _, outs = _run_dtg(o, "central", classifier="pattern",
                           patterns=PatternLibrary.from_dict(d))
        out[key] = outs
    k0 = round(t0 / T) - 1
    assert not any(x.alarm for x in out["plain"][:k0])
    assert out["plain"][-1].alarm and out["plain"][-1].diagnosis.class_name == name
    classes = [x.diagnosis.class_name for x in out["plain"][k0:] if x.alarm]
    assert classes.count(name) > 0.6 * len(classes)
    for a, b in zip(out["plain"], out["prior"], strict=True):
        assert a.alarm == b.alarm and a.diagnosis.class_name == b.diagnosis.class_name
        np.testing.assert_array_equal(a.eta, b.eta)


def test_case_rate_channel_state_round_trip(runs) -> None:
    rec = _dtg_inputs(runs["square"])
    for cl in ("paper", "pattern"):
        a = DTGChannel(DTGChannelConfig(**{**SYSTEM_DTG, "classifier": cl,
                                           "case_rate": "central"}))
        for row in rec[:6013]:
            a.update(*row)
        b = DTGChannel(DTGChannelConfig(**{**SYSTEM_DTG, "classifier": cl,
                                           "case_rate": "central"}))
        b.set_state(a.get_state())
        for row in rec[6013:11000]:
            oa, ob = a.update(*row), b.update(*row)
            np.testing.assert_array_equal(oa.theta, ob.theta)
            assert oa.alarm == ob.alarm
        np.testing.assert_array_equal(a.theta0, b.theta0)


def test_case_rate_skips_a_non_finite_rate_and_ignores_it_when_off() -> None:
    ch = DTGChannel(DTGChannelConfig(case_rate="central"))
    assert not ch.update(0.1, 0.2, 0.3, 0.4, 0.0, float("nan")).valid
    off = DTGChannel(DTGChannelConfig())
    assert off.update(0.1, 0.2, 0.3, 0.4, 0.0, float("nan")).valid


def test_case_rate_settings_are_validated() -> None:
    with pytest.raises(ValueError, match="case_rate"):
        DTGChannel(DTGChannelConfig(case_rate="trapezoid"))
    with pytest.raises(ValueError, match="pickoff_scale"):
        DTGChannel(DTGChannelConfig(case_rate="central", pickoff_scale=0.0))
    with pytest.raises(ValueError, match="theta0"):
        DTGChannel(DTGChannelConfig(case_rate="central", theta0=np.ones((3, N_THETA))))
    # θ0 of one axis is used for both; per axis is accepted too
    ch = DTGChannel(DTGChannelConfig(case_rate="central", classifier="paper",
                                     theta0=[1.0, 0.9, 0.1, 0.2, 0.3]))
    assert ch.theta0.shape == (2, N_THETA)
    theta0 = np.arange(1.0, 11.0).reshape(2, N_THETA)
    ch = DTGChannel(DTGChannelConfig(case_rate="central", classifier="paper", theta0=theta0))
    np.testing.assert_array_equal(ch.theta0, theta0)


def test_default_channel_ignores_the_case_rate_inputs(runs) -> None:
    """Without ``case_rate`` the channel is the paper's, whatever the rate inputs hold."""
    rec = _dtg_inputs(runs["square"])[:4000]
    a = DTGChannel(DTGChannelConfig(**SYSTEM_DTG))
    b = DTGChannel(DTGChannelConfig(**SYSTEM_DTG))
    for row in rec:
        oa, ob = a.update(*row[:4]), b.update(*row)
        np.testing.assert_array_equal(oa.theta, ob.theta)


# ------------------------------------------------------------------------- DF, library
def _readout() -> SensorDynamics:
    return SensorDynamics.from_dict(readout.readout_dict(sets.paper_set(), "y", 3, T), T)


def _df_inputs(o):
    u = np.column_stack([np.zeros_like(o["elevator"]), o["elevator"]])
    y = np.column_stack([o["y_v"], o["y_alpha"], o["q_read"], o["y_theta"], o["y_gamma"],
                         o["y_h"]])
    return u, y


def _df_config(**kw) -> DFChannelConfig:
    return DFChannelConfig(**{**dict(sample_period_s=T, calibrate_s=10.0, burn_in_s=2.0,
                                     decision="paper", align_auto=False), **kw})


def test_df_with_readout_dynamics_equals_the_equaliser_in_front(runs) -> None:
    u, y = _df_inputs(runs["square"])
    ch = DFChannel(_df_config(sensor_dynamics=_readout()))
    ref = DFChannel(_df_config())
    eq = SensorDynamicsEqualiser(_readout(), 2, 6)
    for k in range(u.shape[0]):
        a = ch.update(u[k], y[k])
        b = ref.update(*eq.update(u[k], y[k]))
        np.testing.assert_array_equal(a.residual, b.residual)
        assert a.detected == b.detected


@pytest.mark.parametrize("decision", ["paper", "sequential"])
def test_df_manoeuvre_is_not_a_q_gain_fault_with_the_readout_modelled(runs, decision) -> None:
    """Measured: without the read-out model the paper rule detects at the first edge
    (10.012 s) and types q gain 0.87, the sequential rule detects q at 10.009 s; with it
    neither detects."""
    u, y = _df_inputs(runs["square"])
    last = {}
    for g in (None, _readout()):
        ch = DFChannel(_df_config(decision=decision, sensor_dynamics=g))
        detected = False
        for k in range(u.shape[0]):
            out = ch.update_floats(tuple(u[k]), tuple(y[k]))
            detected = detected or out.detected
        last[g is None] = (detected, out)
    assert last[True][0] and last[True][1].isolated_sensor == 3
    if decision == "paper":
        assert last[True][1].fault_type == 2 and 0.8 < last[True][1].magnitude < 0.9
    assert not last[False][0]


@pytest.mark.parametrize(("spin", "bias"), [(0.95, 0.0), (0.97, 0.0), (None, 0.003)])
def test_df_paper_rule_types_small_scale_errors_as_gains_and_biases_as_biases(
        spin, bias) -> None:
    """Measured (2026-11-26): with the read-out modelled the fitted gain of a spin
    slow-down is the spin fraction to 1e-3 (0.9506, 0.9702), of a q bias 0.9996; the
    former fixed 5 % tolerance typed the 5 % slow-down as a bias of 5e-4."""
    o = run_chain(18.0, command=PitchCommand(1, -0.05, start=10.0, period=8.0),
                  spin=None if spin is None else (12.0, spin))
    u, y = _df_inputs(o)
    y[:, 2] += np.where(o["t"] > 12.0, bias, 0.0)
    ch = DFChannel(_df_config(sensor_dynamics=_readout()))
    for k in range(u.shape[0]):
        out = ch.update_floats(tuple(u[k]), tuple(y[k]))
    assert out.detected and out.isolated_sensor == 3
    if spin is not None:
        assert out.fault_type == 2 and out.magnitude == pytest.approx(spin, abs=0.003)
    else:
        assert out.fault_type == 1 and out.magnitude == pytest.approx(bias, rel=0.1)


def test_df_paper_rule_isolates_a_small_scale_error_in_turbulence_by_energy() -> None:
    """3 % spin slow-down during 0.1 rad doublets in moderate turbulence (measured
    2026-11-26): the bank's alarm pattern never isolates it (the gust response of the
    calibration widened the per-sample thresholds); the bank's residual energy isolates
    q and types the gain: 3.9 s after the detection against the calibration alone, 1.0 s
    against the fault-free baseline (the gusts before the fault raised ¬q's energy most,
    1.28, so the q fault's share stands out earlier)."""
    o = run_chain(26.3, command=PitchCommand(3, 0.1, start=12.0, period=4.0, pulse=0.5),
                  sigma_w=0.77, spin=(21.3, 0.97), seed=13, dtg_seed=14)
    u, y = _df_inputs(o)
    last = {}
    for window in (0.0, 4.0):
        ch = DFChannel(_df_config(sensor_dynamics=_readout(), isolation_window_s=window))
        t_iso = None
        for k in range(u.shape[0]):
            out = ch.update_floats(tuple(u[k]), tuple(y[k]))
            if out.isolated_sensor > 0 and t_iso is None:
                t_iso = o["t"][k]
        last[window] = (out, t_iso)
    assert last[0.0][0].detected and last[0.0][0].isolated_sensor == -1
    out, t_iso = last[4.0]
    assert out.isolated_sensor == 3 and t_iso is not None and t_iso < 21.3 + 4.5
    assert out.fault_type == 2 and out.magnitude == pytest.approx(0.97, abs=0.01)


def test_df_energy_isolation_abstains_rather_than_naming_the_least_gusty_observer(
) -> None:
    """5 % spin slow-down (a q scale error) during 0.1 rad doublets in turbulence twice
    as strong as the campaign's (σ_w 1.5 m/s), aircraft/DTG seeds 17/41, measured
    2026-11-26. Against the calibration alone the energy test isolated ϑ 1.9 s after
    detection (a wrong sensor, typed a bias): before the fault the gusts had raised the
    bank's energies to ¬v 1.39, ¬α 1.20, ¬q 1.87, ¬ϑ 1.02, ¬γ 1.19, ¬h 1.41 (10 s
    baseline), so the least gust-sensitive observer looked faultless. Against the
    baseline no observer stands out and the channel abstains (detected, not isolated)."""
    o = run_chain(28.0, command=PitchCommand(3, 0.1, start=12.0, period=5.0, pulse=0.5),
                  sigma_w=1.5, spin=(23.0, 0.95), seed=17, dtg_seed=41)
    u, y = _df_inputs(o)
    last = {}
    for baseline in (0.0, 10.0):
        ch = DFChannel(_df_config(sensor_dynamics=_readout(),
                                  isolation_baseline_s=baseline))
        for k in range(u.shape[0]):
            out = ch.update_floats(tuple(u[k]), tuple(y[k]))
        last[baseline] = (out, ch)
    assert last[0.0][0].detected and last[0.0][0].isolated_sensor == 4  # ϑ: wrong
    out, ch = last[10.0]
    assert out.detected and out.isolated_sensor == -1
    baseline = ch._engine.energy_baseline
    assert np.argmax(baseline) == 2 and np.argmin(baseline) == 3  # ¬q most, ¬ϑ least
    assert baseline[2] > 1.5 and baseline[3] < 1.1


def test_df_readout_state_round_trip_and_validation(runs) -> None:
    u, y = _df_inputs(runs["square"])
    a = DFChannel(_df_config(sensor_dynamics=_readout()))
    for k in range(10500):
        a.update(u[k], y[k])
    b = DFChannel(_df_config(sensor_dynamics=_readout()))
    b.set_state(a.get_state())
    for k in range(10500, 11500):
        np.testing.assert_array_equal(a.update(u[k], y[k]).residual,
                                      b.update(u[k], y[k]).residual)
    with pytest.raises(ValueError, match="equaliser"):
        DFChannel(_df_config()).set_state(a.get_state())
    with pytest.raises(ValueError, match="sample_period_s"):
        DFChannel(_df_config(sample_period_s=0.01, sensor_dynamics=_readout()))
    with pytest.raises(TypeError, match="sensor_dynamics"):
        DFChannel(_df_config(sensor_dynamics="readout.json"))


# ------------------------------------------------------------------------------- FMU
TOL = {"rtol": 1e-12, "atol": 1e-12}
K_SAVE, K_RERUN = 6000, 1500
K_SAVE_PATTERN, K_RERUN_PATTERN = 13900, 1000  # as tests/_system_diagnoser_runner.py


@pytest.fixture(scope="module")
def fmu(run_fmu_script, runs, tmp_path_factory):
    tmp = tmp_path_factory.mktemp("system_diag")
    path = tmp / "readout.json"
    path.write_text(json.dumps(readout.readout_dict(sets.paper_set(), "y", 3, T)),
                    encoding="utf-8")
    o = runs["square"]
    u, y = _df_inputs(o)
    inp = tmp / "inputs.npz"
    np.savez(inp, dtg=_dtg_inputs(o), df=np.hstack([u, y]), readout_path=np.array(str(path)))
    out = run_fmu_script(RUNNER, str(inp))
    out["readout_path"] = path
    return out


def _col(fmu, key, name):
    return fmu[key][:, list(fmu["columns"]).index(name)]


def test_fmu_dtg_case_rate_equals_library(fmu, runs) -> None:
    ch, outs = _run_dtg(runs["square"], "central")
    for a, axis in enumerate("xy"):
        for i in range(N_THETA):
            np.testing.assert_allclose(_col(fmu, "dtg", f"dtg.theta_{axis}[{i + 1}]"),
                                       [o.theta[a, i] for o in outs], **TOL)
            np.testing.assert_allclose(_col(fmu, "dtg", f"dtg.eta_{axis}[{i + 1}]"),
                                       [o.eta[a, i] for o in outs], **TOL)
    for i, name in enumerate(("c_over_J", "k_over_J", "L_over_J", "lambda_over_J",
                              "Ku_over_KT_J")):
        np.testing.assert_allclose(_col(fmu, "dtg", f"dtg.{name}"),
                                   [o.physical[i] for o in outs], **TOL)
    for i in range(N_THETA):
        assert _col(fmu, "dtg", f"dtg.theta0_used[{i + 1}]")[-1] == pytest.approx(
            ch.theta0[0, i], rel=1e-12)
        assert _col(fmu, "dtg", f"dtg.theta0_used_y[{i + 1}]")[-1] == pytest.approx(
            ch.theta0[1, i], rel=1e-12)
        assert _col(fmu, "dtg", f"dtg.ref_theta0_y[{i + 1}]")[-1] == pytest.approx(
            ch.reference.theta0[N_THETA + i], rel=1e-12)
    assert not _col(fmu, "dtg", "dtg.alarm").any()
    seg = slice(K_SAVE, K_SAVE + K_RERUN)
    np.testing.assert_array_equal(fmu["dtg_restored"], fmu["dtg"][seg])


def test_fmu_dtg_case_rate_pattern_equals_library(fmu, runs) -> None:
    """The pattern classifier with the case rate: the residual tests (with the refined
    reference and its allowance) equal the library's to 1e-12, and the FMU state saved
    in the manoeuvre (refinement included) restores them exactly."""
    _, outs = _run_dtg(runs["square"], "central", classifier="pattern")
    for a in range(2):
        for i, name in enumerate(("residual_level_z", "residual_var_ratio",
                                  "residual_long_var_ratio")):
            np.testing.assert_allclose(_col(fmu, "dtg_pattern", f"dtg.{name}[{a + 1}]"),
                                       [o.diagnosis.tests[2 * i + a] for o in outs], **TOL)
    z = _col(fmu, "dtg_pattern", "dtg.residual_level_z[1]")
    assert z[10100:].max() > 0.1  # the tests ran (not a silent zero)
    assert not _col(fmu, "dtg_pattern", "dtg.alarm").any()
    seg = slice(K_SAVE_PATTERN, K_SAVE_PATTERN + K_RERUN_PATTERN)
    np.testing.assert_array_equal(fmu["dtg_pattern_restored"], fmu["dtg_pattern"][seg])


def test_fmu_df_readout_dynamics_equals_library(fmu, runs) -> None:
    u, y = _df_inputs(runs["square"])
    g = SensorDynamics.from_json(fmu["readout_path"], T)
    ch = DFChannel(_df_config(sensor_dynamics=g))
    outs = [ch.update_floats(tuple(u[k]), tuple(y[k])) for k in range(u.shape[0])]
    for i in range(6):
        np.testing.assert_allclose(_col(fmu, "df", f"df.residual[{i + 1}]"),
                                   [o.residual[i] for o in outs], **TOL)
    np.testing.assert_array_equal(_col(fmu, "df", "df.detected"), [o.detected for o in outs])
    assert not _col(fmu, "df", "df.detected").any()


def test_fmu_warns_that_the_sequential_rule_does_not_isolate_with_the_readout(fmu) -> None:
    log = str(fmu["sequential_log"])
    # a warning (status 1; fmpy does not raise on it), and the instance initialised
    assert int(fmu["sequential_status"]) == 0, log
    warnings = [line for line in log.splitlines() if line.startswith("[1] ")]
    assert len(warnings) == 1, log
    assert "df.decision = 0" in warnings[0] and "df.sensor_dynamics_file" in warnings[0], log


def test_fmu_default_decision_with_readout_is_the_paper_rule(fmu) -> None:
    """df.decision left at its default (2, auto) with a read-out model: the same record
    as the paper rule (0), sample for sample, and no warning."""
    np.testing.assert_array_equal(fmu["df_auto"], fmu["df"])
    assert "[1] " not in str(fmu["auto_log"]), str(fmu["auto_log"])


@pytest.mark.parametrize("label", ["dtg.case_rate", "dtg.pickoff_scale",
                                   "df.sensor_dynamics_file", "dtg.case_rate_delay_samples",
                                   "dtg.case_rate_align_max", "dtg.case_rate_lookahead_s",
                                   "df.sensor_delay[3]"])
def test_fmu_bad_new_parameters_are_fmi2error_naming_them(fmu, label) -> None:
    i = list(fmu["invalid_labels"]).index(label)
    log = str(fmu["invalid_log"][i])
    assert fmu["invalid_status"][i] == 3, log
    assert label in log and "Traceback" not in log, log


# ------------------------------------------- DTG band significance (issue 16, calm air)
#: The system scenarios' project rule: pattern classifier, fine band held 100 of 200.
FINE_BAND = dict(SYSTEM_DTG, classifier="pattern", persistence_k=100, persistence_n=200)


@pytest.fixture(scope="module")
def calm() -> dict[str, dict[str, np.ndarray]]:
    """Calm level flight, fault-free and with the DTG's torquer gain at 90 % from 20 s."""
    return {"nominal": _chain(40.0),
            "torquer": _chain(32.0, faults=(20.0, {"torquer_scale": 0.9}))}


def _first_alarm(outs, k0: int) -> int | None:
    return next((k for k in range(k0, len(outs)) if outs[k].alarm), None)


def test_band_significance_ignores_the_calm_air_wander_of_theta(calm) -> None:
    """In calm level flight the gyro sees only its dither: θ3/θ4's fast estimates wander
    by ~1.6 % (τ ≈ 5 s) about a θ0 known to ~1.6 %, so a band of ±3 % alarms within
    seconds; with ``band_sigma`` every such excursion is within 5 standard errors and
    the same band stays quiet (the FMU campaign's 8 false alarms in 2 of 8 ten-minute
    runs came from the same wander reaching the 7 % band)."""
    tight = dict(FINE_BAND, low=0.97, high=1.03)
    _, plain = _run_dtg(calm["nominal"], "central", **{**tight, "band_sigma": 0.0})
    assert _first_alarm(plain, round(10.0 / T)) is not None
    ch, gated = _run_dtg(calm["nominal"], "central", **tight)
    assert ch.config.band_sigma == 5.0  # the default
    assert not any(x.alarm for x in gated)
    out_of_band = sum(1 for x in gated[round(10.0 / T):]
                      if np.any(np.abs(x.eta - 1.0) > 0.03))
    # the wander is there (647 samples with band_sigma 5, whose θ0 is refined more
    # than 3's); only its significance is missing
    assert out_of_band > 300


def test_band_significance_keeps_physical_faults_in_level_flight(calm) -> None:
    """Torquer gain 90 % at 20 s in calm level flight: θ5 moves 5-10 % and 5-12 standard
    errors (θ5 is well determined by the dither); detected within 10 s (band alone
    3.5-4.5 s on two seeds, with band_sigma 5 6.1-7.1 s), never before the fault. The reference
    the band is judged against has been refined by the quiet blocks since learning."""
    k0 = round(20.0 / T) - 1
    ch, outs = _run_dtg(calm["torquer"], "central", **FINE_BAND)
    assert not any(x.alarm for x in outs[:k0])
    first = _first_alarm(outs, k0)
    assert first is not None and (first - k0) * T < 10.0
    assert outs[-1].alarm and outs[-1].diagnosis.class_name == "unknown"  # no library
    assert not np.allclose(ch.theta0, ch.reference.theta0_eta.reshape(2, N_THETA))


def test_band_significance_detects_spin_in_a_manoeuvre_as_fast(runs) -> None:
    """Spin motor at 90 % at 15 s in the square wave: a manoeuvre pins θ (small P), so the
    significance costs nothing there."""
    k0 = round(15.0 / T) - 1
    spun = _chain(20.0, spin=(15.0, 0.9), **SQUARE)
    delays = {}
    for sigma in (0.0, 5.0):
        _, outs = _run_dtg(spun, "central", **{**FINE_BAND, "band_sigma": sigma})
        assert not any(x.alarm for x in outs[:k0])
        first = _first_alarm(outs, k0)
        assert first is not None
        delays[sigma] = (first - k0) * T
    assert delays[5.0] <= delays[0.0] + 0.05, delays


def test_band_significance_state_round_trip(runs) -> None:
    """A state saved after the band's reference has been refined restores it."""
    rec = _dtg_inputs(runs["square"])
    a = DTGChannel(DTGChannelConfig(**FINE_BAND, case_rate="central"))
    for row in rec[:14013]:
        a.update(*row)
    b = DTGChannel(DTGChannelConfig(**FINE_BAND, case_rate="central"))
    b.set_state(a.get_state())
    np.testing.assert_array_equal(a.theta0, b.theta0)
    for row in rec[14013:]:
        oa, ob = a.update(*row), b.update(*row)
        np.testing.assert_array_equal(oa.eta, ob.eta)
        assert oa.alarm == ob.alarm
    np.testing.assert_array_equal(a.theta0, b.theta0)


def test_band_sigma_is_validated() -> None:
    with pytest.raises(ValueError, match="band_sigma"):
        DTGChannel(DTGChannelConfig(band_sigma=-1.0))


def test_a_readout_model_sets_the_timing_and_no_alignment_is_searched() -> None:
    """With the DTG's read-out model the alignment search is off whatever align_auto
    says (it picked pairings that false-alarmed in off-trim and large-step flights)."""
    assert _df_config(align_auto=True).aligns
    with_model = _df_config(align_auto=True, sensor_dynamics=_readout())
    assert not with_model.aligns
    assert DFChannel(with_model)._choose_alignment() == with_model.input_delay_samples
