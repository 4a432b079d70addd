"""Versioned channel states: saved states carry their version, an unversioned (version 0)
state is migrated and continues exactly, a newer version is refused by name."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from _aircraft_loop import DT
from _aircraft_loop import Fault as F
from _aircraft_loop import simulate as simulate_loop
from _dtg_sim import STABLE_ROTOR, simulate_difference_equation

from gyrodiag.common.state import STATE_VERSION_KEY, migrate, stamp
from gyrodiag.df import channel as df_channel
from gyrodiag.df.channel import DFChannel, DFChannelConfig
from gyrodiag.dtg import channel as dtg_channel
from gyrodiag.dtg import default_library
from gyrodiag.dtg.channel import DTGChannel, DTGChannelConfig
from gyrodiag.dtg.model import theta_from_physical

T = 1e-3


def test_migrate_steps_through_each_version_and_refuses_newer_ones() -> None:
    steps = {0: lambda s: {**s, "a": 1}, 1: lambda s: {**s, "b": s["a"] + 1}}
    assert migrate({"x": 0}, 2, steps, "thing") == {"x": 0, "a": 1, "b": 2,
                                                     STATE_VERSION_KEY: 2}
    assert migrate(stamp({"a": 5}, 1), 2, steps, "thing")["b"] == 6  # from version 1
    for bad in (3, -1, "1", True, 1.0):
        with pytest.raises(ValueError, match=r"thing state version .* versions 0 to 2"):
            migrate({STATE_VERSION_KEY: bad}, 2, steps, "thing")


def _dtg_record(n: int, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    ux, uy = rng.standard_normal(n), rng.standard_normal(n)
    tx, ty = simulate_difference_equation(theta_from_physical(STABLE_ROTOR, T), ux, uy)
    noise = 1e-4 * rng.standard_normal((n, 2))
    return np.column_stack([tx + noise[:, 0], ty + noise[:, 1], ux, uy])


def _dtg_as_version_1(saved: dict, cfg: DTGChannelConfig) -> dict:
    """What the same state looked like before the classifier strategies (version 1): the
    classifier's keys at the top, the unused ones of the other classifier as a fresh
    channel has them (a paper channel never filled the monitor and rollback, a pattern
    channel never the windowed features and θ0 sums)."""
    other = "paper" if cfg.classifier == "pattern" else "pattern"
    fresh = DTGChannel(replace(cfg, classifier=other, signatures={},
                               patterns=None)).get_state()["classifier"]
    old = {k: v for k, v in saved.items() if k != "classifier"}
    # nor had its diagnosis a signal mask (version 3)
    old["diagnosis"] = {k: v for k, v in saved["diagnosis"].items() if k != "signal_mask"}
    return {**old, **fresh, **saved["classifier"], STATE_VERSION_KEY: 1}


def _dtg_continue_equally(cfg: DTGChannelConfig, old: dict, rec: np.ndarray,
                          ref: list) -> None:
    restored = DTGChannel(cfg)
    restored.set_state(old)
    again = [restored.update(*row) for row in rec]
    for a, b in zip(ref, again, strict=True):
        np.testing.assert_array_equal(a.theta, b.theta)
        np.testing.assert_array_equal(a.eta, b.eta)
        assert (a.alarm, a.fault_code, a.diagnosis.block) == (b.alarm, b.fault_code,
                                                              b.diagnosis.block)


def test_dtg_channel_state_is_versioned_and_an_unversioned_one_still_restores() -> None:
    cfg = DTGChannelConfig(sample_period_s=T, learn_start_s=0.2, learn_end_s=0.5, p0=1e8)
    rec = _dtg_record(1500, seed=4)
    ch = DTGChannel(cfg)
    for row in rec[:800]:
        ch.update(*row)
    saved = ch.get_state()
    assert saved[STATE_VERSION_KEY] == dtg_channel.STATE_VERSION == 6
    # what a state saved before versioning looked like: no tag, no case-rate part, no
    # alignment queue (this channel has neither in use)
    old = {k: v for k, v in _dtg_as_version_1(saved, cfg).items()
           if k not in (STATE_VERSION_KEY, "omega", "alignment")}
    ref = [ch.update(*row) for row in rec[800:]]
    _dtg_continue_equally(cfg, old, rec[800:], ref)
    with pytest.raises(ValueError, match="DTG channel state version 7"):
        DTGChannel(cfg).set_state({**saved, STATE_VERSION_KEY: 7})


@pytest.mark.parametrize("classifier", ["pattern", "paper"])
def test_dtg_channel_version_1_state_restores_and_migrates_to_the_saved_one(
        classifier: str) -> None:
    cfg = DTGChannelConfig(sample_period_s=T, learn_start_s=0.2, learn_end_s=0.5, p0=1e8,
                           classifier=classifier, low=0.9, high=1.1)  # type: ignore[arg-type]
    rec = _dtg_record(1500, seed=5)
    ch = DTGChannel(cfg)
    for row in rec[:900]:
        ch.update(*row)
    saved = ch.get_state()
    v1 = _dtg_as_version_1(saved, cfg)
    migrated = migrate(v1, dtg_channel.STATE_VERSION, dtg_channel._MIGRATIONS, "DTG channel")
    assert set(migrated["classifier"]) >= set(saved["classifier"])
    ref = [ch.update(*row) for row in rec[900:]]
    _dtg_continue_equally(cfg, v1, rec[900:], ref)


def _df_saved(k0: int) -> tuple[DFChannelConfig, np.ndarray, np.ndarray, DFChannel, dict]:
    """A DF channel in a q-bias episode after k0 samples, and its saved state."""
    config = DFChannelConfig(sample_period_s=DT, calibrate_s=8.0, burn_in_s=2.0)
    _, u, y = simulate_loop(12.0, seed=24, faults=(F(2, "bias", 0.01, start_s=9.0),))
    ch = DFChannel(config)
    for k in range(k0):
        ch.update(u[k], y[k])
    return config, u, y, ch, ch.get_state()


def _df_continue_equally(config: DFChannelConfig, state: dict, u: np.ndarray,
                         y: np.ndarray, k0: int, ref: list,
                         fields: tuple[str, ...] = ("detected", "isolated_sensor")) -> None:
    """A channel restored from ``state`` continues as ``ref`` (residuals bit for bit,
    and the outputs ``fields``)."""
    restored = DFChannel(config)
    restored.set_state(state)
    again = [restored.update(u[k], y[k]) for k in range(k0, len(u))]
    for a, b in zip(ref, again, strict=True):
        np.testing.assert_array_equal(a.residual, b.residual)
        assert [getattr(a, f) for f in fields] == [getattr(b, f) for f in fields]


def test_df_channel_state_is_versioned_and_an_unversioned_one_still_restores() -> None:
    config, u, y, ch, saved = _df_saved(920)
    assert saved[STATE_VERSION_KEY] == df_channel.STATE_VERSION == 3
    old = {k: v for k, v in saved.items()
           if k not in (STATE_VERSION_KEY, "equaliser", "skew_u", "skew_y", "cal_raw")}
    ref = [ch.update(u[k], y[k]) for k in range(920, len(u))]
    _df_continue_equally(config, old, u, y, 920, ref)
    assert ref[-1].detected
    with pytest.raises(ValueError, match="detection-filter channel state version 7"):
        DFChannel(config).set_state({**saved, STATE_VERSION_KEY: 7})


def test_df_channel_version_2_state_restores_without_the_presence_growth_record() -> None:
    config, u, y, ch, saved = _df_saved(1000)
    engine = {k: v for k, v in saved["engine"].items() if k not in ("hist_p", "presence_grew")}
    v2 = stamp({**{k: v for k, v in saved.items() if k != STATE_VERSION_KEY},
                "engine": engine}, 2)
    migrated = migrate(v2, df_channel.STATE_VERSION, df_channel._MIGRATIONS,
                       "detection-filter channel")
    assert migrated["engine"]["hist_p"].shape == saved["engine"]["hist_p"].shape
    ref = [ch.update(u[k], y[k]) for k in range(1000, len(u))]
    _df_continue_equally(config, v2, u, y, 1000, ref,
                         ("detected", "isolated_sensor", "fault_type"))
    assert ref[-1].isolated_sensor == 3


@pytest.mark.slow
def test_dtg_channel_version_5_state_restores_without_the_fit_over_a_hold() -> None:
    """Version 6 adds the physical test's fit over a hold (the axis a read-out's noise
    attenuates). A version-5 state restores: outside a hold the channel continues
    exactly; inside one the fit starts with the next hold, so the read-out naming waits
    for it instead of using a fit it never saw."""
    from test_dtg_physical_test import ONSET_S, _bench

    cfg = DTGChannelConfig(patterns=default_library())
    rec = _bench(11, 14.0)
    k0 = round(ONSET_S / T)
    rec[k0:, 3] += 0.15 * np.random.default_rng(12).standard_normal(len(rec) - k0)
    ch = DTGChannel(cfg)
    for row in rec[:7000]:
        ch.update(*row)
    saved = ch.get_state()
    assert saved["physical_test"]["held"]["holding"] is False
    v5 = {**saved, STATE_VERSION_KEY: 5,
          "physical_test": {k: v for k, v in saved["physical_test"].items() if k != "held"}}
    ref = [ch.update(*row) for row in rec[7000:]]
    assert ch.physical_test is not None and ch.physical_test.axis_evidence() is not None
    restored = DTGChannel(cfg)
    restored.set_state(v5)
    again = [restored.update(*row) for row in rec[7000:]]
    assert [o.diagnosis.class_name for o in again] == [o.diagnosis.class_name for o in ref]
    # saved in the hold: the fit restarts, and nothing fails
    held = ch.get_state()
    assert held["physical_test"]["held"]["holding"] is True
    v5 = {**held, STATE_VERSION_KEY: 5,
          "physical_test": {k: v for k, v in held["physical_test"].items() if k != "held"}}
    restored = DTGChannel(cfg)
    restored.set_state(v5)
    assert restored.physical_test is not None
    assert restored.physical_test.axis_evidence() is None
    restored.update(*rec[-1])
