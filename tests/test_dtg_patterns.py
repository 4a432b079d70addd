"""Pattern classification of DTG faults (gyrodiag.dtg.patterns): magnitude-free fits,
merged classes, physical classes, library validation."""

from __future__ import annotations

import copy
import math

import numpy as np
import pytest
from _dtg_patterns import learned_library_dict

from gyrodiag.dtg.decision import UNKNOWN_CODE
from gyrodiag.dtg.patterns import PatternClassifier, PatternLibrary
from gyrodiag.dtg.reference import ClassificationStatistics

LIB = PatternLibrary.from_dict(learned_library_dict())
CLF = PatternClassifier(LIB)
SIGNALS = ("Utx", "Uty", "Ux", "Uy")
#: Spread of each pick-off / torquer signal, V: a loss leaves less noise than that.
SPREAD = {"Utx": 0.01, "Uty": 0.01, "Ux": 1.0, "Uy": 1.0}


def _stats(name: str, size: float, rng, blocks: int = 80, growth: float = 0.0,
           ratio: float = 1.0) -> ClassificationStatistics:
    """What the channel would see for class ``name`` at ``size``: the class's own model
    plus the library's nominal noise for a window of ``blocks``."""
    c = LIB.classes[LIB.names.index(name)]
    f = LIB.noise.scale(blocks)
    level = rng.normal(0.0, LIB.noise.level_std * f)
    log_var = rng.normal(0.0, LIB.noise.log_variance_std * f)
    log_eta = rng.normal(0.0, LIB.noise.log_eta_std * f)
    if c.type in ("step", "drift"):
        level = level + size * c.response
    elif c.type == "noise":
        log_var = log_var + np.log10(1.0 + size ** 2 * c.response)
    elif c.type == "loss":
        lost = np.isnan(c.base)
        base = np.where(lost, 0.0, 1.0 + np.nan_to_num(c.base))
        log_var = log_var + np.log10(np.maximum(base + size ** 2 * c.response, 1e-12))
    else:
        log_eta = log_eta + math.log10(ratio) * c.response
    return ClassificationStatistics(level=level, log_variance=log_var, slope=np.zeros(6),
                                    growth=growth, log_eta=log_eta, window_blocks=blocks,
                                    window_s=blocks * 0.025)


@pytest.mark.parametrize("signal", SIGNALS)
@pytest.mark.parametrize("typ", ["step", "noise", "drift"])
def test_classes_hold_across_three_decades_of_size(typ, signal):
    """Sizes 0.03-3 V (V/s) around one learned response: the class, the axis and the size
    come out right at every size (the fit has the size as its free parameter). Torquer
    noise from 1 V: below, its only clear witness is the residual variance, which a
    1 mV pick-off noise raises alike (docs/notes.md)."""
    rng = np.random.default_rng(sum(map(ord, typ + signal)))
    name = f"{signal.lower()}_{typ}"
    lo = 1.0 if (typ == "noise" and signal in ("Ux", "Uy")) else 0.03
    for size in np.geomspace(lo, 3.0, 7):
        s = _stats(name, size, rng, growth=0.4 if typ == "drift" else 0.0)
        res = CLF.classify_signal_fault(s)
        assert res.name == name, (size, res)
        assert res.axis == (1 if signal in ("Utx", "Ux") else 2)
        assert res.signal == SIGNALS.index(signal) + 1
        assert res.fault_type == {"step": 1, "noise": 2, "drift": 4}[typ]
        assert res.code == LIB.names.index(name) + 1
        assert abs(res.size) == pytest.approx(size, rel=0.25), (size, res.size)


@pytest.mark.parametrize("signal", SIGNALS)
def test_loss_is_told_from_noise_until_the_noise_left_exceeds_the_signal(signal):
    rng = np.random.default_rng(SIGNALS.index(signal))
    name = f"{signal.lower()}_loss"
    for left in (0.0, 0.01 * SPREAD[signal], 0.3 * SPREAD[signal]):
        res = CLF.classify_signal_fault(_stats(name, left, rng))
        assert res.name == name, (left, res)
    # several times the signal's own spread: every statistic is a noise fault's, the
    # classes are merged and noise is reported
    res = CLF.classify_signal_fault(_stats(name, 10.0 * SPREAD[signal], rng))
    assert res.name == f"{signal.lower()}_noise"


def test_drift_and_step_differ_by_the_growth_of_the_level():
    rng = np.random.default_rng(4)
    for growth, expected in ((0.0, "ux_step"), (0.05, "ux_step"), (0.3, "ux_drift")):
        res = CLF.classify_signal_fault(_stats("ux_step", 0.5, rng, growth=growth))
        assert res.name == expected
    res = CLF.classify_signal_fault(_stats("ux_step", 0.5, rng, growth=0.3))
    assert res.rate == 0.0  # no slope in these statistics
    stats = _stats("uty_step", 0.5, rng, growth=0.3)
    c = LIB.classes[LIB.names.index("uty_step")]
    stats = ClassificationStatistics(stats.level, stats.log_variance, 0.2 * c.response,
                                     0.3, stats.log_eta, stats.window_blocks, stats.window_s)
    res = CLF.classify_signal_fault(stats)
    assert res.name == "uty_drift" and res.rate == pytest.approx(0.2, rel=0.05)


def test_a_growing_step_is_read_as_its_signals_drift_with_the_slopes_rate():
    """as_drift (the pattern rule's hold of a drift that still grows): the same signal's
    drift class, the rate fitted to the slopes, the size kept; no drift for a noise."""
    rng = np.random.default_rng(6)
    c = LIB.classes[LIB.names.index("uy_step")]
    s = _stats("uy_step", -0.7, rng)
    s = ClassificationStatistics(s.level, s.log_variance, -0.08 * c.response, 0.0,
                                 s.log_eta, s.window_blocks, s.window_s)
    step = CLF.classify_signal_fault(s)
    assert step.name == "uy_step"
    drift = CLF.as_drift(step, s)
    assert drift is not None and drift.name == "uy_drift" and drift.fault_type == 4
    assert drift.code == LIB.names.index("uy_drift") + 1
    assert drift.rate == pytest.approx(-0.08, rel=0.05)
    assert drift.size == step.size and drift.signal == step.signal
    assert CLF.as_drift(CLF.classify_signal_fault(_stats("ux_noise", 2.0, rng)), s) is None


@pytest.mark.parametrize(("first", "second"), [("utx", "uy"), ("utx", "uty"), ("ux", "uy"),
                                               ("uty", "ux")])
def test_two_level_faults_are_both_named(first, second):
    """Two steps on different signals (0.3 and -0.5 V): the single-class fit names one;
    the pair fit names both (code -2, both bits, the larger first)."""
    rng = np.random.default_rng(sum(map(ord, first + second)))
    a = _stats(f"{first}_step", 0.3, rng)
    p_b = LIB.classes[LIB.names.index(f"{second}_step")].response
    both = ClassificationStatistics(a.level - 0.5 * p_b, a.log_variance, a.slope, 0.0,
                                    a.log_eta, a.window_blocks, a.window_s)
    single = CLF.classify_signal_fault(both)
    pair = CLF.classify_pair(both, single)
    assert pair is not None, single
    assert pair.code == -2 and pair.signal == -1 and pair.fault_type == 1
    assert pair.name == f"{second}_step+{first}_step"
    bits = {"utx": 1, "uty": 2, "ux": 4, "uy": 8}
    assert pair.signal_mask == bits[first] | bits[second]
    assert pair.axis == (3 if (first in ("utx", "ux")) != (second in ("utx", "ux")) else
                         1 if first in ("utx", "ux") else 2)


@pytest.mark.parametrize("signal", SIGNALS)
def test_one_level_fault_is_never_read_as_two(signal):
    """Single steps and drifts of 0.03-3 V on every signal, 5 noise draws each: no pair."""
    rng = np.random.default_rng(10 + SIGNALS.index(signal))
    for typ in ("step", "drift"):
        for size in np.geomspace(0.03, 3.0, 7):
            for _ in range(5):
                s = _stats(f"{signal.lower()}_{typ}", size, rng,
                           growth=0.4 if typ == "drift" else 0.0)
                single = CLF.classify_signal_fault(s)
                assert CLF.classify_pair(s, single) is None, (typ, size, single)


@pytest.mark.parametrize(("name", "ratio"), [("spin", 0.9), ("spin", 0.6), ("torquer", 0.8),
                                              ("torquer", 1.2)])
def test_physical_classes_from_log_eta(name, ratio):
    rng = np.random.default_rng(5)
    res = CLF.classify_physical(_stats(name, 0.0, rng, ratio=ratio))
    assert res.name == name and res.axis == 3 and res.signal == 0
    assert res.ratio == pytest.approx(ratio, abs=0.03)


def test_statistics_unlike_every_class_are_unknown():
    rng = np.random.default_rng(6)
    s = _stats("utx_step", 0.5, rng)
    # level shifts on Ux and Uy and a noisier y residual with the residuals of a Utx
    # step: no class explains them (one unexplained channel alone costs a capped term,
    # 25/12 per channel, not enough for "unknown")
    odd = ClassificationStatistics(s.level + np.array([0, 0, 40.0, 40.0, 0, 0]),
                                   s.log_variance + np.array([0, 0, 0, 0, 0, 2.0]),
                                   s.slope, 0.0, s.log_eta, s.window_blocks, s.window_s)
    res = CLF.classify_signal_fault(odd)
    assert res.code == UNKNOWN_CODE and res.name == "unknown" and res.distance > 3.6


@pytest.mark.parametrize("name", ["utx_step", "uty_step", "ux_step", "uy_step"])
def test_without_raw_signals_the_residuals_alone_classify_a_step(name):
    """A case-rate channel in a manoeuvre: the four voltages' levels and variances carry
    the manoeuvre (here: the torquer voltages moved by 300 block spreads, the pick-offs
    noisier). With ``raw_signals`` False they weigh nothing and the residuals' levels
    name the step; with them, the same statistics are unknown."""
    rng = np.random.default_rng(11)
    s = _stats(name, 0.3, rng)
    moved = ClassificationStatistics(
        s.level + np.array([5.0, -5.0, 300.0, -300.0, 0, 0]),
        s.log_variance + np.array([1.0, 1.0, 2.0, 2.0, 0, 0]),
        s.slope, 0.0, s.log_eta, s.window_blocks, s.window_s)
    assert CLF.classify_signal_fault(moved).name == "unknown"
    masked = CLF.classify_signal_fault(
        ClassificationStatistics(**{**moved.__dict__, "raw_signals": False}))
    assert masked.name == name
    assert masked.size == pytest.approx(0.3, rel=0.2)


def _broken(path: str, value):
    d = copy.deepcopy(learned_library_dict())
    keys = path.split(".")
    target = d
    for k in keys[:-1]:
        target = target[int(k)] if isinstance(target, list) else target[k]
    last = keys[-1]
    if isinstance(target, list):
        target[int(last)] = value
    else:
        target[last] = value
    return d


@pytest.mark.parametrize(("path", "value", "message"), [
    ("format", "other/1", "patterns.format"),
    ("classes.0.type", "stepp", r"patterns.classes\[0\].type"),
    ("classes.2.signal", "Uz", r"patterns.classes\[2\].signal"),
    ("classes.4.response", [1.0, -2.0, 0, 0, 0, 0], r"patterns.classes\[4\].response"),
    ("classes.8.base", [0.0, 0.0, 0.0, 0.0, 1.0, 1.0], r"patterns.classes\[8\].base"),
    ("classes.16.signal", "Utx", r"patterns.classes\[16\].signal"),
    ("noise.level_std", [0.1] * 5, "patterns.noise.level_std"),
    ("noise.reference_blocks", 0, "patterns.noise.reference_blocks"),
    ("sample_period_s", -1.0, "patterns.sample_period_s"),
    ("max_distance", -1.0, "patterns.max_distance"),
])
def test_library_errors_name_the_entry(path, value, message):
    with pytest.raises(ValueError, match=message):
        PatternLibrary.from_dict(_broken(path, value))


def test_library_round_trip_and_duplicate_names():
    lib = PatternLibrary.from_dict(PatternLibrary.from_dict(learned_library_dict()).to_dict())
    assert lib.names == LIB.names
    np.testing.assert_array_equal(lib.classes[9].base, LIB.classes[9].base)
    d = learned_library_dict()
    d["classes"][1]["name"] = "utx_step"
    with pytest.raises(ValueError, match="duplicate class names"):
        PatternLibrary.from_dict(d)
