"""HRG.fmu acceptance tests (fmpy, fresh process).

voltage = scale·rate + bias through the exact first-order filter, seed-001 profile flat
(exactly constant) from 825 s, analytic step response, seeded noise, state round trip.
"""

from __future__ import annotations

import math
import sys
from pathlib import Path

import numpy as np
import pytest

SCALE, BIAS, BW = 10.0, 0.05, 0.2  # V/(rad/s), V, Hz


# ---------------------------------------------------------------------------------------
# scenario process
# ---------------------------------------------------------------------------------------

def _record(s, n: int, h: float, names=("voltage", "rate_true")) -> np.ndarray:
    rows = [[s.time, *s.get_many(list(names))]]
    for _ in range(n):
        s.step(h)
        rows.append([s.time, *s.get_many(list(names))])
    return np.array(rows)


def _scenarios(fmu_dir: Path, out: Path) -> None:
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from conftest import FmuSlave

    fmu = fmu_dir / "HRG.fmu"
    res = {}
    s = FmuSlave(fmu, "hrg_seed001", {"scale_factor": SCALE, "bias": BIAS, "bandwidth_hz": BW})
    res["seed001"] = _record(s, 10000, 0.1)
    s.close()

    # constant external rate switched on at t = 1 s: analytic first-order step response
    s = FmuSlave(fmu, "hrg_step", {"profile": 0, "scale_factor": SCALE, "bias": BIAS,
                                   "bandwidth_hz": 1.0})
    before = _record(s, 100, 0.01)
    s.set("rate_in", 0.2)
    res["step"] = np.vstack([before, _record(s, 300, 0.01)[1:]])
    s.close()

    for tag, seed in (("noise", 5), ("noise_same", 5), ("noise_other", 6)):
        s = FmuSlave(fmu, f"hrg_{tag}", {"profile": 2, "rate_const": 0.3, "noise_std": 0.01,
                                         "seed": seed})
        res[tag] = _record(s, 2000, 0.05)
        s.close()

    s = FmuSlave(fmu, "hrg_state", {"noise_std": 0.02, "seed": 9, "bandwidth_hz": BW})
    _record(s, 30, 0.1)
    t_saved, state = s.time, s.fmu.getFMUstate()
    first = _record(s, 30, 0.1)
    s.fmu.setFMUstate(state)
    s.time = t_saved
    second = _record(s, 30, 0.1)
    s.close()
    res["state_first"], res["state_second"] = first, second
    np.savez(out, **res)


# ---------------------------------------------------------------------------------------
# tests
# ---------------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def rec(run_fmu_script) -> dict[str, np.ndarray]:
    return run_fmu_script(Path(__file__).resolve())


def test_voltage_is_filtered_scale_rate_plus_bias(rec):
    t, v, rate = rec["seed001"].T
    h = np.diff(t)
    u = SCALE * rate + BIAS
    ref = np.empty_like(v)
    ref[0] = u[0]  # the filter starts in steady state
    for k in range(len(v) - 1):
        a = math.exp(-2.0 * math.pi * BW * h[k])
        ref[k + 1] = u[k] + a * (ref[k] - u[k])
    np.testing.assert_allclose(v, ref, rtol=1e-12, atol=1e-12)
    # the filter lags: at 0.2 Hz and 0.1 s steps the output is not the instantaneous value
    assert np.abs(v - u).max() > 1e-3


def test_seed001_profile_is_a_few_volts_and_flat_after_825s(rec):
    t, v, rate = rec["seed001"].T
    assert t[-1] == pytest.approx(1000.0)
    early = t < 825.0
    assert 1.0 < v[early].min() < v[early].max() < 4.5
    assert np.ptp(v[early]) > 1.5  # really varies (over hundreds of seconds)
    late_rate = rate[t >= 825.0 + 1e-6]
    assert np.all(late_rate == 0.25)
    # 0.2 Hz filter: the residual lag shrinks by e^(-2π·0.2·0.1) per step and is rounded
    # away completely after ~25 s
    flat = t >= 850.0
    assert np.all(v[flat] == SCALE * 0.25 + BIAS)  # exactly constant, not just close


def test_step_response_is_the_analytic_first_order_response(rec):
    t, v, rate = rec["step"].T
    on = t > 1.0 + 1e-9
    assert np.all(v[~on] == BIAS) and np.all(rate[~on] == 0.0)
    tau_t = t[on] - 1.0
    expected = BIAS + SCALE * 0.2 * (1.0 - np.exp(-2.0 * np.pi * 1.0 * tau_t))
    np.testing.assert_allclose(v[on], expected, rtol=0, atol=1e-12)


def test_noise_is_seeded_white_with_the_set_std(rec):
    v = rec["noise"][:, 1]
    draws = np.random.default_rng(5).standard_normal(len(v))
    np.testing.assert_allclose(v, SCALE_DEFAULT_V + 0.01 * draws, rtol=0, atol=1e-12)
    np.testing.assert_array_equal(rec["noise"], rec["noise_same"])
    assert np.all(rec["noise"][:, 1] != rec["noise_other"][:, 1])
    assert np.std(v - SCALE_DEFAULT_V) == pytest.approx(0.01, rel=0.1)


SCALE_DEFAULT_V = 10.0 * 0.3  # default scale factor 10 V/(rad/s), bias 0, rate 0.3 rad/s


def test_fmu_state_round_trip(rec):
    np.testing.assert_array_equal(rec["state_first"], rec["state_second"])


if __name__ == "__main__":
    _scenarios(Path(sys.argv[1]), Path(sys.argv[2]))
