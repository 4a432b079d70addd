"""Parameters that depend on the sample period follow it: a Diagnoser given only
``sample_period_s`` initialises and steps at 10 µs to 2 s, with one sample per step and
with the default experiment's 1 ms step (docs/fmu.md, "Sample period")."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from gyrodiag.df.channel import DFChannel, DFChannelConfig
from gyrodiag.dtg.channel import AUTO_SETTINGS, DTGChannel, DTGChannelConfig
from gyrodiag.dtg.patterns import default_library

RUNNER = Path(__file__).with_name("_sample_period_runner.py")


@pytest.fixture(scope="module")
def runs(run_fmu_script):
    return run_fmu_script(RUNNER)


def test_only_the_sample_period_set_initialises_and_steps_at_every_period(runs):
    from _sample_period_runner import DEFAULT_RUN_S, DEFAULT_STEP, N_SAMPLES

    assert runs["taken"].tolist() == [N_SAMPLES] * len(runs["periods"]), runs["periods"]
    n_default = round(DEFAULT_RUN_S / DEFAULT_STEP)
    assert runs["taken_default_step"].tolist() == [n_default] * len(runs["periods"])
    # after 25 samples: the DTG still learning below 1 s per sample (learning window
    # 1-5 s), the filter still calibrating at 0.1 s and faster, no alarm, inputs valid
    learning, calibrating, alarm, valid = runs["outputs"].T
    periods = runs["periods"]
    np.testing.assert_array_equal(alarm, 0)
    np.testing.assert_array_equal(valid, 1)
    np.testing.assert_array_equal(calibrating, periods * N_SAMPLES < 10.0)
    np.testing.assert_array_equal(learning, periods * N_SAMPLES < 5.0)


@pytest.mark.parametrize(("period", "cutoff"), [(1e-4, 500.0), (1e-3, 50.0), (0.01, 5.0),
                                                (0.5, 0.1)])
def test_the_automatic_prefilter_cutoff_is_a_twentieth_of_the_sample_rate(period, cutoff):
    assert DTGChannelConfig(sample_period_s=period).cutoff_hz == pytest.approx(cutoff)
    assert DTGChannelConfig(sample_period_s=period, prefilter_cutoff_hz=3.0).cutoff_hz == 3.0


def test_automatic_dtg_settings_follow_the_use_and_explicit_ones_win():
    bench = DTGChannelConfig()
    assert (bench.forgetting, bench.learn_start_s, bench.learn_end_s, bench.low, bench.high,
            bench.persistence_k, bench.persistence_n) == (0.999, 1.0, 5.0, 0.5, 1.5, 1, 1)
    manoeuvre = DTGChannelConfig(case_rate="central")
    assert (manoeuvre.forgetting, manoeuvre.learn_start_s, manoeuvre.learn_end_s,
            manoeuvre.low, manoeuvre.high, manoeuvre.persistence_k,
            manoeuvre.persistence_n) == (0.9998, 2.0, 10.0, 0.93, 1.07, 100, 200)
    # persistence is kept in seconds: 10 of 20 samples at 100 Hz
    slow = DTGChannelConfig(case_rate="central", sample_period_s=0.01)
    assert (slow.persistence_k, slow.persistence_n) == (10, 20)
    assert DTGChannelConfig(case_rate="central", forgetting=0.99).forgetting == 0.99
    assert set(AUTO_SETTINGS["bench"]) == set(AUTO_SETTINGS["case_rate"])
    # the learning window holds two reference blocks at any rate (10 s per sample)
    very_slow = DTGChannelConfig(sample_period_s=10.0)
    assert very_slow.learn_end_s == very_slow.learn_start_s + 20.0
    DTGChannel(very_slow)


def test_class_names_follow_the_codes_of_the_library():
    ch = DTGChannel(DTGChannelConfig(patterns=default_library()))
    assert [ch.class_name(c) for c in (0, 1, 2, 17, 18, -1, 19)] == [
        "", "utx_step", "uty_step", "spin", "torquer", "unknown", "unknown"]
    paper = DTGChannel(DTGChannelConfig(classifier="paper",
                                        signatures={"weak_torquer": [0, 0, 0, 0, -1]}))
    assert [paper.class_name(c) for c in (0, 1, -1)] == ["", "weak_torquer", "unknown"]


def test_slow_rates_lengthen_the_filter_windows_instead_of_refusing():
    cfg = DFChannelConfig(sample_period_s=2.0, calibrate_s=10.0, burn_in_s=2.0,
                          decision="paper")
    cfg.validate()
    assert cfg.isolation_window_in_use == 20.0
    DFChannel(cfg)
