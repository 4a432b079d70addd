"""Torquer read-out noise on the seed DTG chain: the residuals' low-frequency power CUSUM
(gyrodiag.dtg.reference) is its witness.

The chain is the plant of the DTG campaign (models/dtg simulator, paper set, rebalance
loop, 1 V dither, 1 mV pick-off noise) at 1 kHz, diagnosed by the library channel with
the pattern classifier's defaults and the campaign's learning window (1-5 s). A noise on
the Ux read-out moves the x residual by θ5·n through the 50 Hz prefilter: ×2.2 over all
frequencies at 0.3 V, but ×12-45 below 20 Hz, where the nominal residual has little power
(docs/notes.md, DTG).
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

from gyrodiag.dtg.channel import DTGChannel, DTGChannelConfig
from gyrodiag.dtg.reference import POWER_KAPPA, POWER_Q_CAP, POWER_THRESHOLD

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT / "models" / "dtg") not in sys.path:
    sys.path.insert(0, str(ROOT / "models" / "dtg"))

from gd_dtg_sets import paper_set  # noqa: E402
from gd_dtg_sim import DTGSimulator  # noqa: E402

T = 1e-3
ONSET_S = 6.0


def _chain(seed: int, seconds: float) -> np.ndarray:
    """[Utx, Uty, Ux, Uy] (V) of the campaign's DTG at 1 kHz from t = T."""
    sim = DTGSimulator(paper_set(), rebalance=True, noise_std=1e-3, dither_std=1.0,
                       seed=seed)
    n = round(seconds / T)
    rec = np.empty((n, 4))
    for k in range(n):
        sim.advance((k + 1) * T, 0.0, 0.0)
        rec[k, :2] = sim.pickoff
        rec[k, 2:] = sim.torquer_mean
    return rec


def _run(rec: np.ndarray, **config: float) -> tuple[np.ndarray, np.ndarray, DTGChannel]:
    """Residual alarm and power statistics (x, y) per sample."""
    ch = DTGChannel(DTGChannelConfig(sample_period_s=T, estimator="forgetting",
                                     forgetting=0.999, learn_start_s=1.0, learn_end_s=5.0,
                                     **config))
    alarm = np.zeros(rec.shape[0], dtype=bool)
    power = np.zeros((rec.shape[0], 2))
    for k, row in enumerate(rec):
        out = ch.update(*row)
        alarm[k] = out.diagnosis.residual_alarm
        power[k] = out.diagnosis.tests[6:8]
    return alarm, power, ch


def _with_noise(rec: np.ndarray, column: int, std_v: float, seed: int) -> np.ndarray:
    out = rec.copy()
    k0 = round(ONSET_S / T)
    out[k0:, column] += std_v * np.random.default_rng(seed).standard_normal(len(out) - k0)
    return out


@pytest.fixture(scope="module")
def records() -> dict[int, np.ndarray]:
    return {seed: _chain(seed, 9.5) for seed in (31, 32)}


@pytest.mark.parametrize("seed", [31, 32])
@pytest.mark.parametrize(("column", "axis"), [(2, 0), (3, 1)])
def test_0p3_volt_torquer_noise_is_detected_within_1p5_s_on_its_axis(records, seed,
                                                                       column, axis):
    rec = records[seed]
    alarm, power, _ = _run(_with_noise(rec, column, 0.3, seed + column))
    k0 = round(ONSET_S / T)
    assert not alarm[:k0].any()
    hits = np.flatnonzero(alarm[k0:])
    assert hits.size and hits[0] * T <= 1.5
    # the faulty axis' CUSUM holds the alarm (above half its threshold); the other's is low
    assert power[-1, axis] > 0.5
    assert power[-1, 1 - axis] < 0.5


def test_without_the_power_cusum_the_same_noise_is_missed(records):
    """The other residual tests (window level, 0.5 s / 2 s variance ratios) do not see a
    0.3 V read-out noise within 3.5 s on this seed: the CUSUM is what detects it."""
    rec = _with_noise(records[32], 2, 0.3, 34)
    alarm, power, _ = _run(rec, power_threshold=0.0)
    assert not alarm.any()
    assert not power.any()


def test_fault_free_chain_keeps_the_power_cusum_low(records):
    for rec in records.values():
        alarm, power, _ = _run(rec)
        assert not alarm.any()
        assert power.max() < 0.5


def test_power_cusum_is_the_capped_likelihood_ratio_recursion(records):
    """Recompute S from the monitor's own block means: S ← clip(S + min(q, cap) − κ, 0, h),
    q = ((m − μ)/σ_block)², and compare it with the channel's statistic."""
    rec = _with_noise(records[32], 3, 0.2, 5)
    n_end = round(5.0 / T)
    _, power, ch = _run(rec[:n_end + 1500])
    mon = ch.monitor
    assert mon is not None
    ref = mon.reference
    blocks = mon._block_index          # blocks since learning ended, all fresh
    means = mon._last(blocks)[0][:, 4:6]
    q = ((means - ref.mean[4:6]) / ref.block_std[4:6]) ** 2
    s = np.zeros(2)
    for row in q:
        s = np.clip(s + np.minimum(row, POWER_Q_CAP) - POWER_KAPPA, 0.0, POWER_THRESHOLD)
    np.testing.assert_allclose(power[-1], s / POWER_THRESHOLD, rtol=1e-12, atol=1e-15)
    assert s[1] > 0.0  # the noisy y axis moved it (0.2 V)
