"""Test-only pattern libraries (hand-made, valid, physically plausible in sign)."""

from __future__ import annotations

import math
from typing import Any

from gyrodiag.dtg.channel import BLOCK_S
from gyrodiag.dtg.patterns import FORMAT


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


#: Responses of a library learned on the paper plant (offline study, docs/notes.md),
#: rounded: (name, type, signal, response, base).
_LEARNED = [
    ("utx_step", "step", "Utx", [102.6, 0.0, 0.0, 0.0, 213.0, 348.7], None),
    ("uty_step", "step", "Uty", [0.0, 110.8, 0.0, 0.0, -332.9, 205.5], None),
    ("ux_step", "step", "Ux", [0.0, 0.0, 5.442, 0.0, -50.49, 0.0], None),
    ("uy_step", "step", "Uy", [0.0, 0.0, 0.0, 5.344, 0.0, -45.89], None),
    ("utx_noise", "noise", "Utx", [10730.0, 0.0, 0.0, 0.0, 864800.0, 10340.0], None),
    ("uty_noise", "noise", "Uty", [0.0, 10480.0, 0.0, 0.0, 10580.0, 812500.0], None),
    ("ux_noise", "noise", "Ux", [0.0, 0.0, 0.948, 0.0, 10.15, 0.0], None),
    ("uy_noise", "noise", "Uy", [0.0, 0.0, 0.0, 0.9831, 0.0, 11.21], None),
    ("utx_loss", "loss", "Utx", [10730.0, 0.0, 0.0, 0.0, 864800.0, 10340.0],
     [None, 0.0, 0.0, 0.0, 13.03, 1.918]),
    ("uty_loss", "loss", "Uty", [0.0, 10480.0, 0.0, 0.0, 10580.0, 812500.0],
     [0.0, None, 0.0, 0.0, 1.758, 13.65]),
    ("ux_loss", "loss", "Ux", [0.0, 0.0, 0.948, 0.0, 10.15, 0.0],
     [0.0, 0.0, None, 0.0, 14.71, 0.0]),
    ("uy_loss", "loss", "Uy", [0.0, 0.0, 0.0, 0.9831, 0.0, 11.21],
     [0.0, 0.0, 0.0, None, 0.0, 12.55]),
    ("utx_drift", "drift", "Utx", [110.6, 0.0, 0.0, 0.0, 213.5, 366.4], None),
    ("uty_drift", "drift", "Uty", [0.0, 111.3, 0.0, 0.0, -339.0, 217.8], None),
    ("ux_drift", "drift", "Ux", [0.0, 0.0, 5.386, 0.0, -48.64, 0.0], None),
    ("uy_drift", "drift", "Uy", [0.0, 0.0, 0.0, 5.337, 0.0, -45.69], None),
    ("spin", "spin", None, [0.0, 0.0, 1.0, 1.0, 0.0, 0.0, 0.0, 1.0, 1.0, 0.0], None),
    ("torquer", "torquer", None, [0.0, 0.0, 0.0, 0.0, 0.95, 0.0, 0.0, 0.0, 0.0, 1.02], None),
]


def learned_library_dict() -> dict[str, Any]:
    """The 18 classes of the paper plant at 1 kHz with their learned noise model."""
    return {
        "format": FORMAT, "sample_period_s": 1e-3, "block_s": 0.025,
        "classes": [{"name": n, "type": t, "signal": s, "response": r,
                     **({} if b is None else {"base": b})} for n, t, s, r, b in _LEARNED],
        "noise": {"level_std": [0.217, 0.262, 0.109, 0.11, 0.0958, 0.094],
                  "log_variance_std": [0.164, 0.177, 0.0306, 0.0332, 0.127, 0.111],
                  "log_eta_std": [0.0003, 0.0007, 0.0152, 0.0161, 0.0084, 0.0003, 0.0007,
                                  0.0163, 0.0169, 0.007],
                  "reference_blocks": 20, "exponent": 0.4},
        "growth_threshold": 0.13, "loss_margin": 2.0, "max_distance": 3.6,
    }
