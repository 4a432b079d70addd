"""Tunable parameters set between steps reach the plant FMUs and are validated again.

Aircraft.fmu and PitchController.fmu validate their tunables only after one was set
(not on every step): a tunable changed mid-run must still take effect, a bad value must
give fmi2Error naming it (never fmi2Fatal), and a good value after it must let the run
go on. Each FMU runs in a fresh process (fmpy's FMU2Slave).
"""

from __future__ import annotations

import json
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

pytestmark = pytest.mark.slow
HERE = Path(__file__).resolve().parent
ERROR = 3

_RUNNER = textwrap.dedent(
    """
    import json, sys
    sys.path.insert(0, sys.argv[3])
    from _fmu_calls import Instance
    path, kind = sys.argv[1], sys.argv[2]
    out = {}
    if kind == "aircraft":
        s = Instance(path, "ac", {}, step=0.01)
        def noise(n):
            rows = []
            for _ in range(n):
                s.step()
                rows.append(s.get("y_q") - s.get("x_q"))
            return rows
        out["calm_noise"] = noise(20)
        s.set("noise_std_q", 0.5)
        out["loud_noise"] = noise(20)
        s.set("noise_std_q", float("nan"))
        mark = len(s.log)
        out["bad_status"] = s.call(s.fmu.doStep, s.k * s.h, s.h)
        out["bad_log"] = s.messages(mark)
        s.set("noise_std_q", 0.0)
        out["after"] = noise(5)
    else:
        s = Instance(path, "pc", {"command_source": 1, "cmd_amplitude": 0.1,
                                  "cmd_period": 100.0}, step=0.01)
        def cmd(n):
            rows = []
            for _ in range(n):
                s.step()
                rows.append(s.get("theta_cmd"))
            return rows
        out["small"] = cmd(5)
        s.set("cmd_amplitude", 0.3)
        out["large"] = cmd(5)
        s.set("command_source", 99)
        mark = len(s.log)
        out["bad_status"] = s.call(s.fmu.doStep, s.k * s.h, s.h)
        out["bad_log"] = s.messages(mark)
        s.set("command_source", 1)
        out["after"] = cmd(5)
    s.close()
    print(json.dumps(out))
    """
)


def _run(fmu: Path, kind: str) -> dict:
    proc = subprocess.run([sys.executable, "-c", _RUNNER, str(fmu), kind, str(HERE)],
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr[-3000:]
    return json.loads(proc.stdout.splitlines()[-1])


def test_aircraft_noise_tunable_mid_run(fmu_dir: Path) -> None:
    out = _run(fmu_dir / "Aircraft.fmu", "aircraft")
    assert max(abs(v) for v in out["calm_noise"]) == 0.0  # default: no sensor noise
    assert max(abs(v) for v in out["loud_noise"]) > 0.1  # std 0.5 rad/s took effect
    assert out["bad_status"] == ERROR, out
    assert "noise_std" in out["bad_log"], out["bad_log"]
    assert out["after"] == [0.0] * 5  # valid again: the run goes on


def test_controller_command_tunable_mid_run(fmu_dir: Path) -> None:
    out = _run(fmu_dir / "PitchController.fmu", "controller")
    assert out["small"] == [0.1] * 5
    assert out["large"] == [0.3] * 5
    assert out["bad_status"] == ERROR, out
    assert "command_source" in out["bad_log"], out["bad_log"]
    assert out["after"] == [0.3] * 5
