"""Learning the DTG pattern library from training runs (gyrodiag.dtg.learning), on
synthetic runs whose statistics follow a known library."""

from __future__ import annotations

import math

import numpy as np
import pytest
from _dtg_patterns import learned_library_dict

from gyrodiag.dtg.learning import PatternRun, learn_patterns
from gyrodiag.dtg.patterns import PatternLibrary

TRUE = PatternLibrary.from_dict(learned_library_dict())
DT = 0.025  # one row per block
ONSET, END = 8.0, 11.0
SIZES = {"step": (0.2, -0.6, 2.0), "drift": (0.2, -0.6, 2.0), "noise": (0.05, 0.2, 2.0),
         "loss": (0.0, 0.001, 0.003), "spin": (0.8, 0.6), "torquer": (0.8, 0.6)}
TORQUER_SIZES = {"noise": (0.6, 1.2, 2.5), "loss": (0.0, 0.01, 0.1)}
REFERENCE = {"theta0": np.array([2.0036, 1.0044, -0.0306, -0.0292, 2.0e-4]), "status": 1,
             "mean": np.zeros(6), "block_std": np.full(6, 0.1), "var_short": np.ones(6),
             "var_long": np.ones(6)}


def _run(name: str, size: float, seed: int, nominal: bool = False) -> PatternRun:
    rng = np.random.default_rng(seed)
    c = TRUE.classes[TRUE.names.index(name)] if not nominal else None
    t = np.arange(1, round(END / DT) + 1) * DT
    n = t.size
    fault = (t >= ONSET) & (not nominal)
    alarm = (t >= ONSET + 0.05) & (not nominal) & (c is None or c.signal is not None)
    window = np.where(alarm, np.clip(t - ONSET - 0.1, 0.5, 2.0), 0.5)
    f = TRUE.noise.scale(20) * np.ones(n)
    level = rng.normal(0.0, 1.0, (n, 6)) * TRUE.noise.level_std * f[:, None]
    log_var = rng.normal(0.0, 1.0, (n, 6)) * TRUE.noise.log_variance_std * f[:, None]
    eta = 10.0 ** (rng.normal(0.0, 1.0, (n, 10)) * TRUE.noise.log_eta_std)
    growth = rng.normal(0.0, 0.02, n)
    if c is not None:
        if c.type == "step":
            level[fault] += size * c.response
        elif c.type == "drift":
            age = np.maximum(t - 0.5 * window - ONSET, 1e-3)
            level[fault] += (size * age[:, None] * c.response)[fault]
            growth[fault] = 0.4
        elif c.type == "noise":
            log_var[fault] += np.log10(1.0 + size ** 2 * c.response)
        elif c.type == "loss":
            lost = np.isnan(c.base)
            base = np.where(lost, 0.0, 1.0 + np.nan_to_num(c.base))
            log_var[fault] += np.log10(np.maximum(base + size ** 2 * c.response, 1e-9))
        else:
            eta[fault] *= size ** c.response
    return PatternRun(scenario=f"{name}_{size}_{seed}", name=name if c else "nominal",
                      type=c.type if c else "nominal", signal=c.signal if c else None,
                      size=size if c else math.nan, onset_s=None if nominal else ONSET,
                      learn_end_s=5.0, time=t, alarm=alarm, residual_alarm=alarm.copy(),
                      level=level, log_var=log_var, growth=growth, window_s=window,
                      eta=eta, reference={k: np.array(v) if k != "status" else v
                                          for k, v in REFERENCE.items()})


def _training_set() -> list[PatternRun]:
    runs, seed = [], 0
    for c in TRUE.classes:
        sizes = SIZES[c.type]
        if c.signal in ("Ux", "Uy"):
            sizes = TORQUER_SIZES.get(c.type, sizes)
        for size in sizes:
            seed += 1
            runs.append(_run(c.name, size, seed))
    runs.append(_run("", 0.0, 999, nominal=True))
    return runs


def _learn(runs, drop=()):
    names = [c.name for c in TRUE.classes if c.name not in drop]
    codes = {n: i + 1 for i, n in enumerate(names)}
    return learn_patterns(runs, codes, sample_period_s=DT, block_s=DT, short_window_s=0.5,
                          long_window_s=2.0)


def test_the_responses_of_the_generating_library_are_recovered():
    lib, record = _learn(_training_set())
    assert lib.names == TRUE.names
    for got, true in zip(lib.classes, TRUE.classes, strict=True):
        assert (got.type, got.signal) == (true.type, true.signal)
        big = np.abs(true.response) > 0.05 * np.abs(true.response).max()
        # three runs per class, each end statistic with a 0.5 s window's noise (±25 %
        # on a variance ratio): the median is within 30 %
        np.testing.assert_allclose(got.response[big], true.response[big], rtol=0.3,
                                   err_msg=got.name)
        if true.base is not None:
            np.testing.assert_array_equal(np.isnan(got.base), np.isnan(true.base))
    # noise model: the spread of the fault-free rows (a window of 20 blocks)
    f = TRUE.noise.scale(20)
    np.testing.assert_allclose(lib.noise.level_std, TRUE.noise.level_std * f, rtol=0.2)
    assert lib.noise.reference_blocks == 20
    # growth: steps ~0 ± 0.02, drifts 0.4: the threshold lies between
    assert 0.05 < lib.growth_threshold < 0.4
    assert lib.prior is not None
    np.testing.assert_allclose(lib.prior.theta0, REFERENCE["theta0"])
    # every training run is classified as its own class, within max_distance
    assert all(r["classified"] == r["class"] for r in record["runs"]), [
        r for r in record["runs"] if r["classified"] != r["class"]]
    signal = [r["distance"] for r in record["runs"] if r["class"] not in ("spin", "torquer")]
    physical = [r["distance"] for r in record["runs"] if r["class"] in ("spin", "torquer")]
    assert lib.max_distance == pytest.approx(4 * max(signal))
    assert lib.physical_max_distance == pytest.approx(4 * max(physical))


def test_learning_errors_name_the_problem():
    runs = _training_set()
    with pytest.raises(ValueError, match="class 'uy_drift' has no training run"):
        _learn([r for r in runs if r.name != "uy_drift"])
    bad = _run("ux_step", 0.2, 5)
    bad.residual_alarm[:] = False
    with pytest.raises(ValueError, match="does not end in residual alarm"):
        _learn([*runs, bad])
    with pytest.raises(ValueError, match="needs a noise class on Ux"):
        _learn([r for r in runs if r.name != "ux_noise"], drop=("ux_noise",))
