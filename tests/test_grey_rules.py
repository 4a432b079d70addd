"""The grey detector's decision rules as strategy objects (issue 31 item 2): the
constructor's mode arguments name one rule, and a saved state keeps the layout (keys and
their order) that states saved before the rules were split have."""

from __future__ import annotations

import numpy as np
import pytest

from gyrodiag.grey import (
    FixedThreshold,
    GreyFaultDetector,
    ImprovedGreyPredictor,
    KSigmaTest,
    LaggedStepTest,
    SequentialTest,
)

H = 0.5

#: keys after the predictor's of every saved state, in their order
LAYOUT = ["pending_prediction", "in_alarm", "onset_time_s", "recent", "n_accepted",
          "envelope_min", "envelope_max", "hold", "cal_errors", "sigma", "statistic",
          "sq_sum", "sq_n", "cusum", "clean", "n_clean", "substituting", "run", "settle",
          "held", "chosen", "cand_pending", "cand_sq"]
LAGGED = ["lag_buf", "lag_hist_pending", "noise_tail", "noise_sq", "noise_n", "lag_z"]

KINDS = {
    "paper": {},
    "k_sigma": {"calibrate_samples": 20},
    "cusum_only": {"calibrate_samples": 20, "sequential": True, "lag_max": 0},
    "sequential": {"calibrate_samples": 20, "sequential": True, "lag_max": 2},
}


def _detector(kind: str, candidates: bool = False) -> GreyFaultDetector:
    extra = ({"candidates": [ImprovedGreyPredictor(10, residual_order=1)]}
             if candidates else {})
    return GreyFaultDetector(ImprovedGreyPredictor(10), 0.01, H, 20.0, **KINDS[kind],
                             **extra)


def test_the_mode_arguments_name_one_rule() -> None:
    rules = {kind: _detector(kind).rule for kind in KINDS}
    assert type(rules["paper"]) is FixedThreshold and not rules["paper"].calibrated
    assert type(rules["k_sigma"]) is KSigmaTest and rules["k_sigma"].calibrated
    assert type(rules["cusum_only"]) is SequentialTest
    assert rules["cusum_only"].lag_test is None and rules["cusum_only"].lag_thresholds == ()
    lagged = rules["sequential"].lag_test
    assert isinstance(lagged, LaggedStepTest) and len(lagged.thresholds) == 2
    assert _detector("sequential").lag_thresholds == list(lagged.thresholds)


@pytest.mark.parametrize("kind", list(KINDS))
def test_a_saved_state_keeps_its_layout(kind: str) -> None:
    det = _detector(kind, candidates=kind != "paper")
    rng = np.random.default_rng(3)
    y = 1.0 + 0.01 * np.arange(120) * H + 0.002 * rng.standard_normal(120)
    y[80:] += 0.1
    for v in y:
        det.update(float(v))
    keys = list(det.get_state())
    n_pred = sum(k.startswith("predictor.") for k in keys)
    assert n_pred and all(k.startswith("predictor.") for k in keys[:n_pred])
    assert keys[n_pred:n_pred + len(LAYOUT)] == LAYOUT
    rest = keys[n_pred + len(LAYOUT):]
    n_cand = sum(k.startswith("candidate0.") for k in rest)
    assert all(k.startswith("candidate0.") for k in rest[:n_cand])
    rest = rest[n_cand:]
    if kind == "sequential":
        assert rest[:len(LAGGED)] == LAGGED
        assert all(k.startswith("lag_hist") for k in rest[len(LAGGED):])
    else:
        assert rest == []
