"""The Diagnoser facade's output reads and finiteness guard, in Python (no FMU built).

The reads serve every value reference set from cached gathers and copy the channels'
outputs on the first read after a step, guarding only what may be non-finite: the values
and types must be those of the per-variable path, and a non-finite output of any channel
must still be published as 0 with one warning.

The checks run in a subprocess (``python tests/test_diagnoser_outputs.py``): importing
the facade modules into the test process would make them the copy that FMUs loaded
in-process later share.
"""

from __future__ import annotations

import math
import subprocess
import sys
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]

H = 1e-3
# the paper's ratio band set (left automatic, a bench runs the physical test instead,
# which would not alarm on these inputs within the run)
PARAMS = {"sample_period_s": H, "df.calibrate_s": 0.5, "df.burn_in_s": 0.1,
          "dtg.learn_start_s": 0.2, "dtg.learn_end_s": 0.8, "dtg.low": 0.5,
          "dtg.high": 1.5, "grey.window": 10}


def test_output_reads_and_guard() -> None:
    proc = subprocess.run([sys.executable, __file__], cwd=ROOT,
                          capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    assert "checked" in proc.stdout


def _diagnoser_in_alarm(steps: int = 1106) -> Any:
    """All channels, every Real input sin(7 t) + noise: DTG in alarm, DF detected."""
    import gd_diagnoser_fmu as gd
    from pythonfmu import Fmi2Causality

    d = gd.Diagnoser(instance_name="outputs")
    d.values.update(PARAMS)
    d.setup_experiment(0.0)
    d.enter_initialization_mode()
    d.exit_initialization_mode()
    inputs = [vr for vr, v in d.vars.items() if v.causality == Fmi2Causality.input]
    rng = np.random.default_rng(3)
    for k in range(steps):
        row = math.sin(7.0 * k * H) + 1e-3 * rng.standard_normal(len(inputs))
        d.set_real(inputs, row.tolist())
        d.do_step(k * H, H)
    assert not d.log_queue, [m.msg for m in d.log_queue]
    return d


def _refs(d: Any, kind: type) -> list[int]:
    return [vr for vr, v in d.vars.items() if isinstance(v, kind)]


def check_reads_match_the_per_variable_path(d: Any) -> None:
    from pythonfmu.variables import Boolean, Integer, Real

    d._sync_outputs()
    assert d.values["dtg.alarm"] and d.values["df.detected"]
    for kind, getter, convert in ((Real, d.get_real, float), (Integer, d.get_integer, int),
                                  (Boolean, d.get_boolean, bool)):
        refs = _refs(d, kind)
        for order in (refs, refs[::-1], refs[:1], refs[3:5] * 2, []):
            for _ in range(2):  # the second read comes from the cached gather
                got = getter(order)
                want = [convert(d.vars[vr].getter()) for vr in order]
                assert got == want
                assert [type(x) for x in got] == [convert] * len(order)


def check_a_mixed_read_is_refused_as_before(d: Any) -> None:
    from pythonfmu.variables import Integer, Real

    real, integer = _refs(d, Real)[0], _refs(d, Integer)[0]
    d.log_queue.clear()
    assert d.get_real([real, integer]) == [0.0, 0.0]
    assert len(d.log_queue) == 1 and "not a Real" in d.log_queue[0].msg
    d.log_queue.clear()


#: (channel, attribute of its output record, output variable it feeds)
NON_FINITE_CASES = [
    ("df", "residual", "df.residual[1]"),
    ("df", "statistic", "df.statistic[2]"),
    ("dtg", "theta", "dtg.theta_x[1]"),
    ("dtg", "eta", "dtg.eta_y[5]"),
    ("grey", "statistic", "grey.statistic"),
]


def check_a_non_finite_output_is_published_as_zero(d: Any, k: int, channel: str, attr: str,
                                                   name: str) -> None:
    """Sample ``k`` (inside a DTG reference block: no block-rate or on-change copy, which
    would run the full guard anyway) with a non-finite value in one channel output."""
    d._sync_outputs()
    d.log_queue.clear()
    d.do_step(k * H, H)
    pending = getattr(d, f"_pending_{channel}")
    value = getattr(pending, attr)
    if isinstance(value, np.ndarray):
        value = value.copy()
        value.flat[-1 if name.endswith("[5]") else 0 if name.endswith("[1]") else 1] = math.inf
    else:
        value = math.nan
    try:
        setattr(pending, attr, value)
    except (AttributeError, TypeError):  # frozen output records
        object.__setattr__(pending, attr, value)
    d._outputs_pending = True
    vr = next(vr for vr, v in d.vars.items() if v.name == name)
    assert d.get_real([vr]) == [0.0]
    messages = [m.msg for m in d.log_queue]
    assert len(messages) == 1 and f"output {name} was" in messages[0]


if __name__ == "__main__":
    sys.path.insert(0, str(ROOT / "fmu_src"))
    diagnoser = _diagnoser_in_alarm()
    check_reads_match_the_per_variable_path(diagnoser)
    check_a_mixed_read_is_refused_as_before(diagnoser)
    for k, case in enumerate(NON_FINITE_CASES, start=1101 + 5):
        check_a_non_finite_output_is_published_as_zero(diagnoser, k, *case)
    print("checked")
