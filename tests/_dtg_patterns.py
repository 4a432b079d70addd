"""Test-only pattern libraries (hand-made, valid, physically plausible in sign)."""

from __future__ import annotations

import math
from typing import Any

from gyrodiag.dtg_channel import BLOCK_S
from gyrodiag.dtg_patterns import FORMAT


def pattern_library_dict(sample_period_s: float, *, prior: bool = False) -> dict[str, Any]:
    """A library with a level, a noise, a loss, a drift and two physical classes.

    Responses follow the structure of the learned ones (docs/notes.md): a pick-off offset
    moves its own level and both residual levels, a torquer offset its own level and its
    axis' residual, noise raises the variances it feeds.
    """
    nb = max(1, round(BLOCK_S / sample_period_s))
    block_s = nb * sample_period_s
    nan = None
    lib: dict[str, Any] = {
        "format": FORMAT,
        "sample_period_s": sample_period_s,
        "block_s": block_s,
        "classes": [
            {"name": "utx_step", "type": "step", "signal": "Utx",
             "response": [480.0, 0.0, 0.0, 0.0, 930.0, 1520.0]},
            {"name": "ux_step", "type": "step", "signal": "Ux",
             "response": [0.0, 0.0, 24.0, 0.0, -220.0, 0.0]},
            {"name": "ux_drift", "type": "drift", "signal": "Ux",
             "response": [0.0, 0.0, 24.0, 0.0, -220.0, 0.0]},
            {"name": "ux_noise", "type": "noise", "signal": "Ux",
             "response": [0.0, 0.0, 0.96, 0.0, 13.4, 0.0]},
            {"name": "ux_loss", "type": "loss", "signal": "Ux",
             "response": [0.0, 0.0, 0.96, 0.0, 13.4, 0.0],
             "base": [0.0, 0.0, nan, 0.0, 16.4, 0.0]},
            {"name": "spin", "type": "spin", "signal": None,
             "response": [0.0, 0.0, 1.0, 1.0, 0.0, 0.0, 0.0, 1.0, 1.0, 0.0]},
            {"name": "torquer", "type": "torquer", "signal": None,
             "response": [0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0]},
        ],
        "noise": {"level_std": [1.1, 1.1, 0.5, 0.5, 0.4, 0.4],
                  "log_variance_std": [0.16, 0.17, 0.03, 0.03, 0.11, 0.11],
                  "log_eta_std": [0.001, 0.001, 0.02, 0.02, 0.01] * 2,
                  "reference_blocks": max(1, round(0.5 / block_s)), "exponent": 0.4},
        "growth_threshold": 0.15,
        "loss_margin": 2.0,
        "max_distance": None,
    }
    if prior:
        lib["nominal"] = {
            "theta0": [2.0036, 1.0044, -0.0306, -0.0292, 2.004e-4],
            "theta0_std": [5e-4, 5e-4, 4e-4, 4e-4, 1.6e-6],
            "mean": [0.0, 0.0, 0.0, 0.0, 0.0, 0.0],
            "block_std": [7.6e-3, 7.5e-3, 0.1, 0.1, 4e-6, 4e-6],
            "var_short": [5e-5, 5e-5, 1.0, 1.0, 2.9e-10, 2.9e-10],
            "var_long": [8e-5, 8e-5, 1.0, 1.0, 2.9e-10, 2.9e-10],
        }
    assert math.isfinite(block_s)
    return lib
