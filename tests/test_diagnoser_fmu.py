"""Diagnoser.fmu acceptance: the FMU equals the library, keeps its full state, recovers
from NaN inputs and rejects bad parameters with fmi2Error.

All FMU calls run in one fresh process (tests/_diagnoser_runner.py, docs/methods.md §6.11); the
library references are computed here, from the same input records, with channel
objects configured independently of the facade's parameter mapping.
"""

from __future__ import annotations

import dataclasses
import json
import xml.etree.ElementTree as ET
import zipfile
from pathlib import Path

import numpy as np
import pytest
from _diagnoser_runner import (
    ALL_H,
    ALL_START,
    DTG_H,
    DTG_START,
    GREY_H,
    IN_NAMES,
    K_PATTERN_NAN,
    K_PATTERN_RERUN,
    K_PATTERN_SAVE,
    K_RERUN_1,
    K_RERUN_2,
    K_RERUN_OTHER,
    K_SAVE_1,
    K_SAVE_2,
    N_INTERLEAVE,
    N_RESET,
    NAN_STEPS,
)
from _dtg_patterns import pattern_library_dict
from _dtg_sim import STABLE_ROTOR, simulate_difference_equation
from conftest import load_builder
from fmpy.validation import validate_fmu
from test_isolation_closed_loop import T_FAULT, simulate

from gyrodiag.df.channel import DFChannel, DFChannelConfig
from gyrodiag.df.isolation import FaultType
from gyrodiag.dtg.channel import DTGChannel, DTGChannelConfig
from gyrodiag.dtg.decision import UNKNOWN_CODE
from gyrodiag.dtg.model import N_THETA, theta_from_physical
from gyrodiag.dtg.patterns import PatternLibrary
from gyrodiag.grey import ClassicGreyPredictor, GreyFaultDetector, ImprovedGreyPredictor

RUNNER = Path(__file__).resolve().parent / "_diagnoser_runner.py"
PHYSICAL = ("c_over_J", "k_over_J", "L_over_J", "lambda_over_J", "Ku_over_KT_J")
SIGNATURES = {"signature_1": [0, 0, 0, 0, -1], "signature_2": [-3, -1, 1, 1, 2]}
#: The file library lists the torquer signature second: its code is 2 there.
FILE_SIGNATURES = {"pickoff_loss": [-3, -1, 1, 1, 2], "torquer_gain": [0, 0, 0, 0, -1]}
TOL = {"rtol": 1e-12, "atol": 1e-12}


# ---------------------------------------------------------------------------------------
# input records
# ---------------------------------------------------------------------------------------

def _dtg_record(T, n_nominal, n_fault, seed, noise):
    """Nominal rotor, then the torquer gain Ku drops to 30 % (θ5 × 0.3)."""
    rng = np.random.default_rng(seed)
    broken = dataclasses.replace(STABLE_ROTOR, Ku=0.3 * STABLE_ROTOR.Ku)
    parts = []
    for params, n in ((STABLE_ROTOR, n_nominal), (broken, n_fault)):
        ux, uy = rng.standard_normal(n), rng.standard_normal(n)
        tx, ty = simulate_difference_equation(theta_from_physical(params, T), ux, uy)
        parts.append(np.column_stack([tx + noise * rng.standard_normal(n),
                                      ty + noise * rng.standard_normal(n), ux, uy]))
    return np.vstack(parts)


def _grey_signal(n, h, freq, noise, fault_t, fault, seed):
    rng = np.random.default_rng(seed)
    t = np.arange(n) * h
    return (2.0 + 0.3 * np.sin(2 * np.pi * freq * t) + noise * rng.standard_normal(n)
            + fault * (t >= fault_t))


def _record(n, dtg=None, grey=None, u=None, y=None):
    rec = np.zeros((n, len(IN_NAMES)))
    if dtg is not None:
        rec[:, 0:4] = dtg[:n]
    if grey is not None:
        rec[:, 4] = grey[:n]
    if u is not None:
        rec[:, 5:7] = u[:n]
        rec[:, 7:13] = y[:n]
    return rec


def _inputs(tmp: Path) -> dict[str, np.ndarray]:
    _, u_df, y_df = simulate(20.0, seed=31, fault=(2, "bias", 0.1))
    _, u_all, y_all = simulate(20.0, seed=32, fault=(2, "bias", 0.1))
    _, u_all2, y_all2 = simulate(20.0, seed=33, fault=(3, "stuck", None))
    sig_path = tmp / "signatures.json"
    sig_path.write_text(json.dumps({"signatures": FILE_SIGNATURES}), encoding="utf-8")
    paths = {}
    for key, h in (("patterns_1khz_path", DTG_H), ("patterns_100hz_path", ALL_H)):
        paths[key] = tmp / f"{key}.json"
        paths[key].write_text(json.dumps({"patterns": pattern_library_dict(h)}),
                              encoding="utf-8")
    return {
        "dtg": _record(4500, dtg=_dtg_record(DTG_H, 3000, 1500, seed=1, noise=1e-4)),
        "grey": _record(600, grey=_grey_signal(600, GREY_H, 0.01, 1e-3, 30.0, 0.1, seed=2)),
        "df": _record(2000, u=u_df, y=y_df),
        "all": _record(2000, dtg=_dtg_record(ALL_H, 1200, 800, seed=3, noise=1e-4),
                       grey=_grey_signal(2000, ALL_H, 0.05, 2e-4, 14.0, 0.05, seed=4),
                       u=u_all, y=y_all),
        "all2": _record(2000, dtg=_dtg_record(ALL_H, 1200, 800, seed=5, noise=3e-4),
                        grey=_grey_signal(2000, ALL_H, 0.07, 5e-4, 9.0, -0.05, seed=6),
                        u=u_all2, y=y_all2),
        "sigfile": _record(1200, dtg=_dtg_record(DTG_H, 500, 700, seed=7, noise=0.0)),
        "sigfile_path": np.array(str(sig_path)),
        "sigfile_theta0": theta_from_physical(STABLE_ROTOR, DTG_H),
        **{k: np.array(str(v)) for k, v in paths.items()},
    }


@pytest.fixture(scope="module")
def data(tmp_path_factory) -> dict[str, np.ndarray]:
    return _inputs(tmp_path_factory.mktemp("diagnoser_in"))


@pytest.fixture(scope="module")
def fmu(run_fmu_script, data, tmp_path_factory) -> dict[str, np.ndarray]:
    inp = tmp_path_factory.mktemp("diagnoser_in") / "inputs.npz"
    np.savez(inp, **data)
    return run_fmu_script(RUNNER, str(inp))


class Rows:
    """FMU output rows addressed by variable name."""

    def __init__(self, rows: np.ndarray, columns: np.ndarray) -> None:
        self.rows = rows
        self.index = {str(c): i for i, c in enumerate(columns)}

    def __getitem__(self, name: str) -> np.ndarray:
        return self.rows[:, self.index[name]]


def rows(fmu, key: str) -> Rows:
    return Rows(fmu[key], fmu["columns"])


def assert_columns(got: Rows, expected: dict[str, np.ndarray]) -> None:
    for name, exp in expected.items():
        np.testing.assert_allclose(got[name], np.asarray(exp, dtype=float), equal_nan=True,
                                   err_msg=name, **TOL)


# ---------------------------------------------------------------------------------------
# library references (configured here, not through the facade)
# ---------------------------------------------------------------------------------------

def _dtg_channel(T, cutoff_hz=50.0, signatures=SIGNATURES, **kw):
    cfg = dict(sample_period_s=T, prefilter_cutoff_hz=cutoff_hz, estimator="forgetting",
               forgetting=0.99, p0=1e8, learn_start_s=0.5, learn_end_s=2.0,
               persistence_k=3, persistence_n=5, signatures=signatures, classifier="paper")
    cfg.update(kw)
    return DTGChannel(DTGChannelConfig(**cfg))


def _pattern_channel(T, **kw):
    """The pattern classifier with the hand-made library of that sample period."""
    cfg = dict(sample_period_s=T, p0=1e8, learn_start_s=0.5, learn_end_s=2.0,
               patterns=PatternLibrary.from_dict(pattern_library_dict(T)))
    cfg.update(kw)
    return DTGChannel(DTGChannelConfig(**cfg))


CHANNEL_STATS = ("level", "log_var_ratio")


def _diagnosis_columns(put, ch: DTGChannel, o) -> None:
    """The facade's mapping of the block-rate outputs, with its sentinels."""
    d = o.diagnosis

    def fin(x, fallback):
        return float(x) if np.isfinite(x) else fallback

    alarm = bool(o.alarm)
    put("dtg.reference_status", d.reference_status)
    put("dtg.reference_valid", d.reference_status == 1)
    put("dtg.residual_alarm", d.residual_alarm)
    put("dtg.fault_type", d.fault_type if alarm else 0)
    put("dtg.fault_signal", d.fault_signal if alarm else 0)
    put("dtg.fault_axis", d.fault_axis if alarm else 0)
    put("dtg.class_distance", fin(d.distance, -1.0) if alarm else -1.0)
    size_ok = alarm and np.isfinite(d.size)
    put("dtg.fault_size", d.size if size_ok else 0.0)
    put("dtg.fault_size_valid", size_ok)
    put("dtg.fault_rate", fin(d.rate, 0.0) if alarm else 0.0)
    put("dtg.fault_ratio", fin(d.ratio, 1.0) if alarm else 1.0)
    for i in range(6):
        put(f"dtg.level[{i + 1}]", fin(d.level[i], 0.0))
        put(f"dtg.log_var_ratio[{i + 1}]", fin(d.log_variance[i], 0.0))
    put("dtg.level_growth", fin(d.growth, 0.0))
    put("dtg.stat_window_s", d.window_s)
    for a in range(2):
        put(f"dtg.residual_level_z[{a + 1}]", d.tests[a])
        put(f"dtg.residual_var_ratio[{a + 1}]", d.tests[2 + a])
        put(f"dtg.residual_long_var_ratio[{a + 1}]", d.tests[4 + a])
    ref = ch.reference
    for i in range(N_THETA):
        put(f"dtg.ref_theta0[{i + 1}]", 0.0 if ref is None else ref.theta0[i])
    for key, attr in (("ref_mean", "mean"), ("ref_block_std", "block_std"),
                      ("ref_var_short", "var_short"), ("ref_var_long", "var_long")):
        for i in range(6):
            put(f"dtg.{key}[{i + 1}]", 0.0 if ref is None else getattr(ref, attr)[i])


def _dtg_columns(ch: DTGChannel, samples: np.ndarray, start: float) -> dict[str, np.ndarray]:
    cols: dict[str, list] = {}

    def put(name, value):
        cols.setdefault(name, []).append(value)

    for s in samples:
        o = ch.update(*s)
        for a, axis in enumerate("xy"):
            for i in range(N_THETA):
                put(f"dtg.theta_{axis}[{i + 1}]", o.theta[a, i])
                put(f"dtg.eta_{axis}[{i + 1}]", o.eta[a, i])
        for i in range(N_THETA):
            put(f"dtg.theta0_used[{i + 1}]", 0.0 if ch.theta0 is None else ch.theta0[i])
        physical_valid = bool(np.all(np.isfinite(o.physical)))  # else 0 (sentinel)
        for i, name in enumerate(PHYSICAL):
            put(f"dtg.{name}", o.physical[i] if physical_valid else 0.0)
        put("dtg.physical_valid", physical_valid)
        put("dtg.learning", o.learning)
        put("dtg.alarm", o.alarm)
        put("dtg.fault_code", o.fault_code)
        first = o.first_alarm_time_s
        put("dtg.first_alarm_time", -1.0 if np.isnan(first) else start + first)
        put("dtg.valid", o.valid)
        _diagnosis_columns(put, ch, o)
    return {k: np.array(v, dtype=float) for k, v in cols.items()}


def _grey_detector(model=1, window=10, threshold=0.02, clear=5.0, h=GREY_H):
    pred = ImprovedGreyPredictor(window, a_min=1e-6) if model else ClassicGreyPredictor(window)
    return GreyFaultDetector(pred, threshold, h, clear)


def _grey_columns(det, y, times) -> dict[str, np.ndarray]:
    outs = [det.update(float(v), time_s=float(t)) for v, t in zip(y, times, strict=True)]
    prediction = np.array([o.prediction for o in outs])
    error = np.array([o.error for o in outs])
    return {  # the FMU publishes 0 for a missing prediction or error (sentinels)
        "grey.prediction": np.where(np.isfinite(prediction), prediction, 0.0),
        "grey.error": np.where(np.isfinite(error), error, 0.0),
        "grey.prediction_valid": np.isfinite(prediction).astype(float),
        "grey.alarm": np.array([o.alarm for o in outs], dtype=float),
        "grey.valid": np.array([o.valid for o in outs], dtype=float),
        "grey.calibrating": np.array([o.calibrating for o in outs], dtype=float),
        "grey.statistic": np.array([o.statistic for o in outs], dtype=float),
    }


def _df_channel(calibrate_s, burn_in_s, T=0.01):
    return DFChannel(DFChannelConfig(sample_period_s=T, calibrate_s=calibrate_s,
                                     burn_in_s=burn_in_s, k_sigma=6.0))


def _df_columns(ch: DFChannel, u, y) -> dict[str, np.ndarray]:
    outs = [ch.update(uk, yk) for uk, yk in zip(u, y, strict=True)]
    cols = {f"df.residual[{i + 1}]": np.array([o.residual[i] for o in outs]) for i in range(6)}
    cols.update({f"df.alarm[{i + 1}]": np.array([o.alarms[i] for o in outs], dtype=float)
                 for i in range(6)})
    cols.update({f"df.statistic[{i + 1}]": np.array([o.statistic[i] for o in outs])
                 for i in range(6)})
    cols.update({f"df.sensor_fault_type[{i + 1}]": np.array(
        [o.sensor_fault_type[i] for o in outs], dtype=float) for i in range(6)})
    for name, attr in (("calibrating", "calibrating"), ("detected", "detected"),
                       ("isolated_sensor", "isolated_sensor"), ("fault_type", "fault_type"),
                       ("fault_magnitude", "magnitude"), ("valid", "valid"),
                       ("episodes", "episodes"), ("isolated_mask", "isolated_mask"),
                       ("fault_magnitude_valid", "magnitude_valid"),
                       ("input_delay_in_use", "input_delay")):
        cols[f"df.{name}"] = np.array([getattr(o, attr) for o in outs], dtype=float)
    known = np.isfinite(cols["df.fault_magnitude"]) & (cols["df.fault_magnitude_valid"] > 0)
    cols["df.fault_magnitude"] = np.where(known, cols["df.fault_magnitude"], 0.0)
    cols["df.fault_magnitude_valid"] = known.astype(float)
    return cols


def _summary(cols: dict[str, np.ndarray], n: int) -> dict[str, np.ndarray]:
    """any_alarm and fault_code as documented: DTG first, then grey, then DF."""
    zeros = np.zeros(n)
    dtg_alarm = cols.get("dtg.alarm", zeros).astype(bool)
    grey_alarm = cols.get("grey.alarm", zeros).astype(bool)
    df_alarm = cols.get("df.detected", zeros).astype(bool)
    code = np.zeros(n)
    dtg_code = cols.get("dtg.fault_code", zeros)
    iso = cols.get("df.isolated_sensor", zeros)
    for k in range(n):
        if dtg_alarm[k]:
            code[k] = 100 + (dtg_code[k] if dtg_code[k] > 0 else -1)
        elif grey_alarm[k]:
            code[k] = 200
        elif df_alarm[k]:
            code[k] = 300 + (iso[k] if iso[k] > 0 else (-2 if iso[k] == -2 else -1))
    return {"any_alarm": (dtg_alarm | grey_alarm | df_alarm).astype(float), "fault_code": code}


def _all_reference(data, skip: dict[str, set[int]] | None = None) -> dict[str, np.ndarray]:
    """Library outputs of the all-channel scenario, each channel fed its valid samples."""
    rec = data["all"]
    n = len(rec)
    skip = skip or {}
    times = ALL_START + ALL_H * np.arange(n)
    keep = {c: np.array([k not in skip.get(c, set()) for k in range(n)]) for c in
            ("dtg", "grey", "df")}
    cols = {}
    # the DTG channel is fed the non-finite samples too: it remembers the gap (the
    # regression rows spanning it are left out of its reference statistics), so its
    # outputs are aligned with the host steps
    dtg_rec = rec[:, 0:4].copy()
    dtg_rec[~keep["dtg"]] = np.nan
    cols.update(_dtg_columns(
        _pattern_channel(ALL_H, prefilter_cutoff_hz=20.0, forgetting=0.99, persistence_k=3,
                         persistence_n=5), dtg_rec, ALL_START))
    cols.update(_grey_columns(_grey_detector(threshold=0.01, clear=3.0, h=ALL_H),
                              rec[keep["grey"], 4], times[keep["grey"]]))
    cols.update(_df_columns(_df_channel(5.0, 1.0), rec[keep["df"], 5:7],
                            rec[keep["df"], 7:13]))
    return cols, keep


@pytest.fixture(scope="module")
def all_reference(data):
    cols, _ = _all_reference(data)
    cols.update(_summary(cols, len(data["all"])))
    return cols


# ---------------------------------------------------------------------------------------
# FMU equals library
# ---------------------------------------------------------------------------------------

def test_diagnoser_is_built_and_validates(fmu_dir):
    builder = load_builder()
    assert "Diagnoser" in [e[0] for e in builder.REGISTRY if builder.available(e)]
    assert validate_fmu(str(fmu_dir / "Diagnoser.fmu")) == []


def test_dtg_channel_equals_library(fmu, data):
    got = rows(fmu, "dtg")
    ref = _dtg_columns(_dtg_channel(DTG_H), data["dtg"][:, 0:4], DTG_START)
    assert_columns(got, ref)
    assert_columns(got, _summary(ref, len(data["dtg"])))
    # the record is diagnosed: θ0 learned, the torquer fault (signature 1) from 3 s on
    assert got["dtg.learning"][1999] == 1 and got["dtg.learning"][2001] == 0
    alarm_t = got["dtg.first_alarm_time"][-1] - DTG_START
    assert 3.0 <= alarm_t < 3.2
    assert got["dtg.fault_code"][-1] == 1 and got["fault_code"][-1] == 101
    assert got["dtg.Ku_over_KT_J"][2500] == pytest.approx(STABLE_ROTOR.Ku / STABLE_ROTOR.KT,
                                                          rel=1e-2)
    assert np.all(got["inputs_valid"] == 1)


@pytest.mark.parametrize(("key", "model", "window", "clear"),
                         [("grey", 1, 10, 5.0), ("grey_classic", 0, 8, None)])
def test_grey_channel_equals_library(fmu, data, key, model, window, clear):
    got = rows(fmu, key)
    y = data["grey"][:, 4]
    times = GREY_H * np.arange(len(y))
    ref = _grey_columns(_grey_detector(model, window, 0.02, clear), y, times)
    assert_columns(got, ref)
    assert_columns(got, _summary(ref, len(y)))
    alarm = got["grey.alarm"].astype(bool)
    assert not alarm[times < 30.0].any() and alarm[times >= 30.0].any()
    assert got["fault_code"][np.argmax(alarm)] == 200


def test_detection_filter_channel_equals_library(fmu, data):
    got = rows(fmu, "df")
    rec = data["df"]
    ref = _df_columns(_df_channel(8.0, 2.0), rec[:, 5:7], rec[:, 7:13])
    assert_columns(got, ref)
    assert_columns(got, _summary(ref, len(rec)))
    t = 0.01 * np.arange(len(rec))
    assert not got["df.detected"][t < T_FAULT].any()
    assert got["df.calibrating"][798] == 1 and got["df.calibrating"][800] == 0
    assert got["df.isolated_sensor"][-1] == 3  # q, 1-based
    assert got["df.fault_type"][-1] == int(FaultType.BIAS)
    assert got["df.fault_magnitude"][-1] == pytest.approx(0.1, abs=0.01)
    assert got["fault_code"][-1] == 303
    assert t[np.argmax(got["df.detected"])] - T_FAULT < 0.5


def test_all_channels_together_equal_library(fmu, all_reference):
    got = rows(fmu, "all")
    assert_columns(got, all_reference)
    # every channel alarms in this record, and the summary code gives DTG precedence
    for flag in ("dtg.alarm", "grey.alarm", "df.detected"):
        assert got[flag].any(), flag
    both = (got["dtg.alarm"] == 1) & (got["df.detected"] == 1)
    code = got["dtg.fault_code"][both]
    assert both.any() and np.all(got["fault_code"][both] == 100 + np.where(code > 0, code, -1))
    # the pattern classifier's reference was learned and checked, and the torquer fault
    # (θ5 × 0.3 at 12 s) raised the residual tests
    assert got["dtg.reference_status"][-1] == 1 and got["dtg.reference_valid"][-1] == 1
    assert got["dtg.residual_alarm"][-1] == 1


def test_dtg_pattern_classifier_equals_library_through_nan_and_state(fmu, data):
    """The default classifier: reference learning with a NaN sample inside the window (the
    regression rows spanning it are left out: the reference stays valid), residual
    tests, classification; a fresh instance restored from a state saved inside the
    learning window continues identically."""
    got = rows(fmu, "pattern")
    rec = data["dtg"][:, 0:4].copy()
    rec[K_PATTERN_NAN, 0] = np.nan
    expected = _dtg_columns(_pattern_channel(DTG_H), rec, DTG_START)
    assert expected["dtg.valid"][K_PATTERN_NAN] == 0
    # the first-alarm time is the host time: one period later than the channel's clock
    k_first = int(np.argmax(expected["dtg.alarm"]))
    expected["dtg.first_alarm_time"] = np.where(
        np.arange(len(rec)) >= k_first, DTG_START + k_first * DTG_H, -1.0)
    expected.update(_summary(expected, len(rec)))
    assert_columns(got, expected)
    # learned and checked at 2.0 s on the channel's clock (the NaN sample makes that host
    # step 2001); no alarm before the torquer fault at 3.0 s, held to the end
    assert got["dtg.reference_status"][2002] == 1
    assert got["dtg.reference_status"][1990] == 0
    assert not got["dtg.alarm"][2002:3000].any()
    assert got["dtg.residual_alarm"][3200:].all()
    seg = slice(K_PATTERN_SAVE, K_PATTERN_SAVE + K_PATTERN_RERUN)
    np.testing.assert_array_equal(fmu["pattern_restored"], fmu["pattern"][seg])


# ---------------------------------------------------------------------------------------
# FMU state
# ---------------------------------------------------------------------------------------

def test_state_get_set_and_serialize_restore_everything(fmu):
    full = fmu["all"]
    got = rows(fmu, "all")
    seg1 = slice(K_SAVE_1, K_SAVE_1 + K_RERUN_1)
    seg2 = slice(K_SAVE_2, K_SAVE_2 + K_RERUN_2)
    # the first segment spans the end of the DF calibration and the grey fault-free
    # run; the second starts with the DF in alarm and spans the DTG and grey faults
    assert got["df.calibrating"][K_SAVE_1] == 1 and got["df.calibrating"][seg1.stop - 1] == 0
    assert got["dtg.learning"][K_SAVE_1] == 0 and got["dtg.alarm"][seg2].any()
    assert got["df.detected"][K_SAVE_2] == 1 and got["grey.alarm"][seg2].any()
    np.testing.assert_array_equal(fmu["restore_1"], full[seg1])
    np.testing.assert_array_equal(fmu["restore_2"], full[seg2])
    # a fresh instance with default parameters takes everything from the serialised state
    assert fmu["other_period_before"] == 1e-3 and fmu["other_period_after"] == ALL_H
    np.testing.assert_array_equal(fmu["restore_other"],
                                  full[K_SAVE_1:K_SAVE_1 + K_RERUN_OTHER])


def test_reset_gives_a_fresh_instance(fmu):
    assert fmu["reset_status"] == 0 and fmu["reset_init_status"] == 0
    assert fmu["reset_period"] == 1e-3  # parameters back at their start values
    np.testing.assert_array_equal(fmu["reset_run"], fmu["all"][:N_RESET])


def test_two_instances_do_not_interfere(fmu):
    np.testing.assert_array_equal(fmu["inter_a"], fmu["all"][:N_INTERLEAVE])
    np.testing.assert_array_equal(fmu["inter_b"], fmu["alone_b"])
    assert not np.array_equal(fmu["inter_a"], fmu["inter_b"])


# ---------------------------------------------------------------------------------------
# NaN / Inf inputs
# ---------------------------------------------------------------------------------------

def _held_index(n: int, bad: set[int]) -> np.ndarray:
    """Library sample index whose outputs the FMU shows at host step k."""
    idx, j = [], -1
    for k in range(n):
        if k not in bad:
            j += 1
        idx.append(j)
    return np.array(idx)


def test_non_finite_input_skips_the_sample_and_the_channel_recovers(fmu, data):
    """Decision: a non-finite sample is dropped from that channel's sample stream (its
    valid output and inputs_valid go false, outputs are held); afterwards every output
    equals a library run on the record without that sample. Times reported by the FMU
    (the DTG first alarm) stay simulation times."""
    n = len(data["all"])
    bad = {"dtg": set(), "grey": set(), "df": set()}
    for k, (name, _) in NAN_STEPS.items():
        bad[name.split(".")[0]].add(k)
    lib, _ = _all_reference(data, bad)
    got = rows(fmu, "nan")
    expected: dict[str, np.ndarray] = {}
    for channel in ("dtg", "grey", "df"):
        # the DTG reference was fed the non-finite samples (aligned with the host steps)
        idx = np.arange(n) if channel == "dtg" else _held_index(n, bad[channel])
        for name, col in lib.items():
            if name.startswith(channel + "."):
                expected[name] = col[idx]
        expected[f"{channel}.valid"] = np.array([k not in bad[channel] for k in range(n)],
                                                dtype=float)
    # grey at the skipped sample: no error (0), the pending prediction, the alarm held
    (k_grey,) = bad["grey"]
    expected["grey.error"][k_grey] = 0.0
    expected["grey.prediction"][k_grey] = lib["grey.prediction"][k_grey]
    expected["grey.prediction_valid"][k_grey] = 1.0
    # the DTG first-alarm time is the host time of the alarming step: one period after
    # the time on the channel's valid-sample clock, since one sample was skipped before
    k_first = int(np.argmax(expected["dtg.alarm"]))
    lib_first = lib["dtg.first_alarm_time"][-1]
    expected["dtg.first_alarm_time"] = np.where(
        np.arange(n) >= k_first, ALL_START + k_first * ALL_H, -1.0)
    assert ALL_START + k_first * ALL_H == pytest.approx(lib_first + ALL_H, abs=1e-9)
    expected.update(_summary(expected, n))
    expected["inputs_valid"] = np.array([k not in NAN_STEPS for k in range(n)], dtype=float)
    assert_columns(got, expected)
    # the NaN steps left visible marks: held outputs, and the DF calibration ended late
    assert got["dtg.valid"][300] == 0 and got["inputs_valid"][300] == 0
    assert got["df.calibrating"][499] == 1 and got["df.calibrating"][500] == 0
    assert fmu["nan_log"].tolist() == [""]  # a NaN input is not an error


# ---------------------------------------------------------------------------------------
# errors
# ---------------------------------------------------------------------------------------

def _invalid(fmu):
    return dict(zip(fmu["invalid_labels"].tolist(), zip(
        fmu["invalid_exit_status"].tolist(), fmu["invalid_exit_log"].tolist(),
        fmu["invalid_step_status"].tolist(), fmu["invalid_step_log"].tolist(),
        strict=True), strict=True))


def test_valid_defaults_initialise_without_messages(fmu):
    exit_status, exit_log, step_status, step_log = _invalid(fmu)["valid defaults"]
    assert (exit_status, exit_log, step_status, step_log) == (0, "", 0, "")


@pytest.mark.parametrize("label", [
    "dtg.forgetting", "dtg.estimator", "dtg.prefilter_cutoff_hz", "dtg.window",
    "dtg.n_signatures", "dtg.signature_file", "dtg.signature_file (bad JSON)",
    "dtg.classifier", "dtg.long_window_s", "dtg.var_threshold",
    "dtg.signature_file (paper signatures, pattern classifier)",
    "dtg.n_signatures (pattern classifier)",
    "grey.window", "grey.threshold", "df.eigenvalue (unstable)", "df.eigenvalue (repeated)",
    "df.persistence_k", "df.calibrate_s", "df.isolation_window_s",
    "df.isolation_baseline_s", "sample_period_s (zero)",
    "sample_period_s (negative)",
])
def test_invalid_parameter_is_fmi2error_naming_it(fmu, label):
    exit_status, exit_log, step_status, step_log = _invalid(fmu)[label]
    parameter = label.split(" ")[0]
    assert exit_status == 3, exit_log  # fmi2Error, not fmi2Fatal
    assert exit_log.startswith("[3] ") and parameter in exit_log, exit_log
    assert "Traceback" not in exit_log  # an expected error, not a crash report
    # doStep after the failed initialisation: fmi2Error again, with a clear message
    assert step_status == 3, step_log
    assert "initialisation did not succeed" in step_log


def test_step_of_n_sample_periods_processes_n_samples_with_inputs_held(fmu, data):
    """A doStep of n·sample_period_s (n = 1..7, sizes jittered inside the 1e-6
    tolerance) equals the library fed the step's first input n times; the outputs after
    the step are those of its last sample."""
    counts = fmu["multi_n"]
    assert set(counts.tolist()) >= {1, 2, 3, 4, 5, 7} and counts.sum() == len(data["all"])
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
    held = np.repeat(data["all"][starts], counts, axis=0)
    ref = _all_reference({"all": held})[0]
    ref.update(_summary(ref, len(held)))
    last = np.cumsum(counts) - 1
    assert_columns(rows(fmu, "multi"), {name: col[last] for name, col in ref.items()})
    # held inputs are not the record: the run differs from the one-sample-per-step run
    got = rows(fmu, "multi")
    assert not np.allclose(got["df.residual[3]"], rows(fmu, "all")["df.residual[3]"][last])
    assert got["df.detected"][-1] == 1 and got["dtg.alarm"].any()


@pytest.mark.parametrize("index", range(4))
def test_other_steps_are_refused_with_the_reason(fmu, index):
    from _diagnoser_runner import BAD_STEPS

    assert fmu["wrong_step_status"][index] == 3  # fmi2Error, the instance lives on
    log = str(fmu["wrong_step_log"][index])
    assert "must be finite and > 0" in log and f"{BAD_STEPS[index]!r} s" in log, log


def test_refused_steps_consume_no_sample(fmu):
    np.testing.assert_array_equal(fmu["after_wrong_step"], fmu["grey"][:20])
    assert fmu["after_wrong_step_log"] == 0


@pytest.mark.parametrize("m", [0.5, 1.5, 3.0 * (1 + 5e-6)])
def test_a_step_off_the_sample_grid_takes_the_sample_instants_it_spans(fmu, m):
    """Steps of m sample periods: each takes the samples k·T in [t, t + h) with the
    step's input, and a step with none holds the outputs (a half-period step ignores
    the decoy input set before it)."""
    assert not fmu[f"off_grid_{m}_status"].any()
    counts, ref, got = (fmu[f"off_grid_{m}_counts"], fmu[f"off_grid_{m}_ref"],
                        fmu[f"off_grid_{m}"])
    expected_counts = {0.5: {0, 1}, 1.5: {1, 2}}.get(m, {3, 4})
    assert set(counts.tolist()) == expected_counts
    last = np.cumsum(counts) - 1
    for j in np.flatnonzero(counts):
        np.testing.assert_array_equal(got[j], ref[last[j]])
    for j in np.flatnonzero(counts == 0):
        np.testing.assert_array_equal(got[j], got[j - 1])


# ---------------------------------------------------------------------------------------
# tunable parameters
# ---------------------------------------------------------------------------------------

def _tuned_reference(data) -> dict[str, np.ndarray]:
    """Library run of the "all" record where the tuned channels are rebuilt with the new
    values at K_TUNE and take over the running channels' state."""
    from _diagnoser_runner import K_TUNE, TUNED

    rec = data["all"]
    times = ALL_START + ALL_H * np.arange(len(rec))
    common = dict(prefilter_cutoff_hz=20.0, forgetting=0.99, persistence_n=5)
    dtg = _pattern_channel(ALL_H, persistence_k=3, **common)
    grey = _grey_detector(threshold=0.01, clear=3.0, h=ALL_H)
    cols = {k: list(v) for k, v in _dtg_columns(dtg, rec[:K_TUNE, 0:4], ALL_START).items()}
    for k, v in _grey_columns(grey, rec[:K_TUNE, 4], times[:K_TUNE]).items():
        cols[k] = list(v)
    dtg2 = _pattern_channel(ALL_H, low=TUNED["dtg.low"], high=TUNED["dtg.high"],
                            persistence_k=TUNED["dtg.persistence_k"],
                            level_threshold=TUNED["dtg.level_threshold"],
                            var_threshold=TUNED["dtg.var_threshold"], **common)
    dtg2.set_state(dtg.get_state())
    grey2 = _grey_detector(threshold=TUNED["grey.threshold"],
                           clear=TUNED["grey.clear_after_s"], h=ALL_H)
    grey2.set_state(grey.get_state())
    for k, v in _dtg_columns(dtg2, rec[K_TUNE:, 0:4], ALL_START).items():
        cols[k].extend(v)
    for k, v in _grey_columns(grey2, rec[K_TUNE:, 4], times[K_TUNE:]).items():
        cols[k].extend(v)
    return {k: np.array(v, dtype=float) for k, v in cols.items()}


def test_tunable_changes_apply_from_the_next_sample(fmu, data, all_reference):
    from _diagnoser_runner import K_TUNE

    got = rows(fmu, "tune")
    ref = _tuned_reference(data)
    assert_columns(got, ref)
    # the detection filter is not tuned: as in the untuned run
    assert_columns(got, {k: v for k, v in all_reference.items() if k.startswith("df.")})
    untuned = rows(fmu, "all")
    for name in ("dtg.alarm", "grey.alarm"):
        np.testing.assert_array_equal(got[name][:K_TUNE], untuned[name][:K_TUNE])
    # lower residual-test thresholds alarm more, the higher grey threshold less
    assert got["dtg.alarm"][K_TUNE:].sum() > untuned["dtg.alarm"][K_TUNE:].sum()
    assert got["grey.alarm"][K_TUNE:].sum() < untuned["grey.alarm"][K_TUNE:].sum()


def test_refused_tunable_change_is_fmi2error_and_keeps_the_value_in_use(fmu):
    from _diagnoser_runner import REFUSED_TUNES, TUNED

    assert fmu["tune_refused_status"].tolist() == [3, 3]
    high_log, k_log = (str(x) for x in fmu["tune_refused_log"])
    assert "dtg.high = 0.9 is outside its range [1.000000001, inf]" in high_log
    assert "dtg.persistence_k" in k_log and "Traceback" not in k_log
    for log in (high_log, k_log):
        assert "step was not taken" in log and "Kept" in log
    assert fmu["tune_refused_kept"].tolist() == [TUNED[n] for n, _ in REFUSED_TUNES]
    assert fmu["tune_after_log"] == 0


# ---------------------------------------------------------------------------------------
# signature library from a file
# ---------------------------------------------------------------------------------------

def test_signature_file_absolute_and_in_resources_classify(fmu, data):
    got = rows(fmu, "sigfile_abs")
    truth = theta_from_physical(STABLE_ROTOR, DTG_H)
    ch = _dtg_channel(DTG_H, prefilter_enabled=False, theta0=list(truth),
                      signatures=FILE_SIGNATURES, persistence_k=1, persistence_n=1)
    ref = _dtg_columns(ch, data["sigfile"][:, 0:4], 0.0)
    assert_columns(got, ref)
    assert got["dtg.fault_code"][-1] == 2  # torquer_gain is the file's second signature
    assert got["fault_code"][-1] == 102
    # the estimator starts from θ = 0 (an alarm) and converges within the nominal part
    assert got["dtg.alarm"][0] == 1 and not got["dtg.alarm"][100:500].any()
    np.testing.assert_array_equal(fmu["sigfile_rel"], fmu["sigfile_abs"])
    assert UNKNOWN_CODE not in got["dtg.fault_code"]


# ---------------------------------------------------------------------------------------
# model description
# ---------------------------------------------------------------------------------------

#: Real variables without a unit: none (the grey channel is declared in V, the unit of
#: the HRG output it was made for; df.fault_magnitude as dimensionless, see its text).
UNITLESS: set[str] = set()


def test_every_variable_has_a_description_and_every_real_a_unit(fmu_dir):
    with zipfile.ZipFile(fmu_dir / "Diagnoser.fmu") as zf:
        root = ET.fromstring(zf.read("modelDescription.xml"))
    declared = {u.get("name") for u in root.iter("Unit")}
    svs = list(root.find("ModelVariables"))
    assert len(svs) > 250
    units = {}
    for sv in svs:
        name = sv.get("name")
        assert len(sv.get("description", "")) > 5, name
        if sv[0].tag == "Real":
            unit = sv[0].get("unit")
            assert (unit is None) == (name in UNITLESS), name
            assert unit is None or unit in declared, name
            units[name] = unit
    assert units["sample_period_s"] == "s" and units["dtg.Utx"] == "V"
    assert units["dtg.theta_x[1]"] == "1" and units["dtg.k_over_J"] == "1/s2"
    assert units["df.y[3]"] == "rad/s" and units["df.residual[6]"] == "m"
    assert units["df.A[1,2]"] == "m/(rad.s2)"  # dv/dt per alpha
    assert units["df.B[3,2]"] == "1/s2"        # dq/dt per elevator (rad/s per rad, per s)
    assert units["df.C[6,5]"] == "1"
    assert units["df.bank_threshold[3,3]"] == "rad"  # observer without q: 3rd is theta
    var = {sv.get("name"): sv for sv in svs}
    forgetting = var["dtg.forgetting"][0]
    assert (forgetting.get("min"), forgetting.get("max")) == ("-1", "1")  # -1: automatic
