"""Fake per-run functions for tests/test_campaign.py (run in the campaign's run process).

``fake``'s behaviour is chosen by the run's fault magnitude: 1 raises, 2 to 3 hang, 3 kills
its process (abort), anything else returns a synthetic record: detected when the
magnitude is >= 0.5, delay = 0.1 / magnitude s, one false alarm per nominal run, 60 s of
fault-free time, diagnosed = the injected label.  When ``GD_FAKE_LOG`` names a folder,
every execution leaves a file ``<run_id>.<pid>`` there (to count executions) holding
its ``/proc/self/autogroup`` line (where there is one).
"""

from __future__ import annotations

import os
import time
from pathlib import Path
from typing import Any


def fake(run: dict[str, Any]) -> dict[str, Any]:
    log = os.environ.get("GD_FAKE_LOG")
    if log:
        group = Path("/proc/self/autogroup")
        Path(log, f"{run['run_id']}.{os.getpid()}").write_text(
            group.read_text() if group.exists() else "", encoding="utf-8")
    mag = run.get("magnitude")
    if mag == 1.0:
        raise ValueError("fake runner: magnitude 1 raises")
    if mag is not None and 2.0 <= mag < 3.0:
        time.sleep(3600)
    if mag == 3.0:
        os.abort()
    nominal = run["kind"] == "nominal"
    detected = (not nominal) and mag is not None and mag >= 0.5
    thresholds = run["thresholds"]
    return {
        "detected": detected, "delay_s": (0.1 / mag) if detected else None,
        "false_alarms": 1 if nominal else 0, "fault_free_s": 60.0, "t_ready_s": 0.0,
        "diagnosed": run["injected"] if detected else "none", "threshold_config": 6.0,
        "sweep": {"detected": [detected and t <= 6.0 for t in thresholds],
                  "delay_s": [None] * len(thresholds),
                  "false_alarms": [int(nominal and t <= 6.0) for t in thresholds]},
        "sweep_mismatch": 0.0, "peak_before": 0.0, "peak_after": None,
    }
