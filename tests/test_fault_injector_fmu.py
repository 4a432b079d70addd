"""FaultInjector.fmu acceptance tests: every fault formula, bit-exact idle, seeds, state.

The FMU runs through fmpy in a fresh process (this file executed as a script, see
``_scenarios``); the tests compare its records with the documented formulas
``out_i(t_{k+1}) = F_i(in_i(t_k), t_k)``.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

H = 0.125  # binary-exact step so fault windows fall exactly on samples
N_STEPS = 96  # 12 s
T_START, T_END = 2.0, 6.0
N_CH = 8

# channel -> (fault_type, extra parameters) for the two configurations
CONFIG_A = {1: (0, {}), 2: (1, {"magnitude": 0.5}), 3: (2, {"gain": 1.5}),
            4: (3, {"stuck_value": -2.25}), 5: (4, {}), 6: (5, {}),
            7: (6, {"magnitude": -0.75}), 8: (7, {"magnitude": 0.2})}
CONFIG_B = {1: (8, {"noise_std": 0.3}), 2: (9, {"noise_std": 0.7}),
            3: (10, {"magnitude": 1.0, "period": 1.0, "duty": 0.25}),
            4: (11, {"sat_min": -0.5, "sat_max": 0.8}), 5: (12, {}), 6: (0, {}),
            7: (1, {"magnitude": 3.0, "t_start": 10.0, "t_end": 4.0}),  # empty window
            8: (8, {"noise_std": 0.0})}


def input_signal(ch: int, t: float) -> float:
    """Known ramp + sine input of channel ``ch`` (1-based)."""
    return 0.3 * t + 2.0 * np.sin(0.7 * t + ch) - 0.1 * ch


def _parameters(config: dict, seed: int) -> dict:
    params: dict = {"seed": seed}
    for ch, (code, extra) in config.items():
        params[f"fault_type_{ch}"] = code
        params[f"t_start_{ch}"] = T_START
        params[f"t_end_{ch}"] = T_END
        for k, v in extra.items():
            params[f"{k}_{ch}"] = v
    return params


# ---------------------------------------------------------------------------------------
# scenario process
# ---------------------------------------------------------------------------------------

def _run(fmu: Path, config: dict, seed: int, name: str, FmuSlave) -> dict[str, np.ndarray]:
    s = FmuSlave(fmu, name, _parameters(config, seed))
    t_in, u_in, y_out, act = [], [], [], []
    y0 = [s.get(f"out_{c}") for c in range(1, N_CH + 1)]
    for _ in range(N_STEPS):
        t = s.time
        u = [input_signal(c, t) for c in range(1, N_CH + 1)]
        for c in range(1, N_CH + 1):
            s.set(f"in_{c}", u[c - 1])
        s.step(H)
        t_in.append(t)
        u_in.append(u)
        y_out.append([s.get(f"out_{c}") for c in range(1, N_CH + 1)])
        act.append([s.get(f"fault_active_{c}") for c in range(1, N_CH + 1)])
    s.close()
    return {"t": np.array(t_in), "u": np.array(u_in), "y": np.array(y_out),
            "active": np.array(act), "y0": np.array(y0)}


def _state_round_trip(fmu: Path, FmuSlave) -> dict[str, np.ndarray]:
    s = FmuSlave(fmu, "state", _parameters(CONFIG_B, 11))

    def advance(n: int) -> list[list[float]]:
        rows = []
        for _ in range(n):
            for c in range(1, N_CH + 1):
                s.set(f"in_{c}", input_signal(c, s.time))
            s.step(H)
            rows.append([s.get(f"out_{c}") for c in range(1, N_CH + 1)])
        return rows

    advance(20)  # into the fault window (t = 2.5 s)
    t_saved = s.time
    state = s.fmu.getFMUstate()
    first = advance(30)
    s.fmu.setFMUstate(state)
    s.time = t_saved
    second = advance(30)
    blob = s.fmu.serializeFMUstate(state)
    s.fmu.setFMUstate(s.fmu.deSerializeFMUstate(blob))
    s.time = t_saved
    third = advance(30)
    s.fmu.freeFMUstate(state)
    s.close()
    return {"first": np.array(first), "second": np.array(second), "third": np.array(third)}


def _scenarios(fmu_dir: Path, out: Path) -> None:
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from conftest import FmuSlave

    fmu = fmu_dir / "FaultInjector.fmu"
    results: dict[str, np.ndarray] = {}
    for tag, config, seed in [("A", CONFIG_A, 0), ("B", CONFIG_B, 7), ("B_same", CONFIG_B, 7),
                              ("B_other", CONFIG_B, 8)]:
        for k, v in _run(fmu, config, seed, f"fi_{tag}", FmuSlave).items():
            results[f"{tag}_{k}"] = v
    for k, v in _state_round_trip(fmu, FmuSlave).items():
        results[f"state_{k}"] = v
    np.savez(out, **results)


# ---------------------------------------------------------------------------------------
# tests
# ---------------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def rec(run_fmu_script) -> dict[str, np.ndarray]:
    return run_fmu_script(Path(__file__).resolve())


def _window(t: np.ndarray) -> np.ndarray:
    return (t >= T_START) & (t < T_END)


def test_idle_channels_are_bit_exact(rec):
    for tag, ch in (("A", 1), ("B", 6)):
        u, y = rec[f"{tag}_u"][:, ch - 1], rec[f"{tag}_y"][:, ch - 1]
        assert np.array_equal(y, u), f"config {tag} channel {ch} not bit-exact"
        assert not rec[f"{tag}_active"][:, ch - 1].any()
    # empty window (t_end < t_start): never active, bit-exact
    assert np.array_equal(rec["B_y"][:, 6], rec["B_u"][:, 6])
    assert not rec["B_active"][:, 6].any()
    # before the first step the outputs are the input start values (0.0)
    assert np.array_equal(rec["A_y0"], np.zeros(N_CH))


def test_deterministic_faults_follow_their_formulas(rec):
    t, u, y, act = rec["A_t"], rec["A_u"], rec["A_y"], rec["A_active"]
    w = _window(t)
    assert w.sum() == 32 and not w[0]
    expected = {
        2: np.where(w, u[:, 1] + 0.5, u[:, 1]),
        3: np.where(w, 1.5 * u[:, 2], u[:, 2]),
        4: np.where(w, -2.25, u[:, 3]),
        6: np.where(w, 0.0, u[:, 5]),
        7: np.where(t >= T_START, u[:, 6] - 0.75, u[:, 6]),  # STEP latches, ignores t_end
        8: np.where(w, u[:, 7] + 0.2 * (t - T_START), u[:, 7]),
    }
    first = int(np.argmax(w))
    expected[5] = np.where(w, u[first, 4], u[:, 4])  # STUCK_LAST holds u at onset
    for ch, exp in expected.items():
        np.testing.assert_array_equal(y[:, ch - 1], exp, err_msg=f"channel {ch}")
    for ch in (2, 3, 4, 5, 6, 8):
        np.testing.assert_array_equal(act[:, ch - 1], w, err_msg=f"active flag channel {ch}")
    np.testing.assert_array_equal(act[:, 6], t >= T_START)

    t, u, y, act = rec["B_t"], rec["B_u"], rec["B_y"], rec["B_active"]
    w = _window(t)
    phase_on = w & (((t - T_START) % 1.0) < 0.25)
    assert phase_on.sum() == 8  # 2 on-samples per 1 s period, 4 periods
    np.testing.assert_array_equal(y[:, 2], np.where(phase_on, u[:, 2] + 1.0, u[:, 2]))
    np.testing.assert_array_equal(act[:, 2], phase_on)
    np.testing.assert_array_equal(y[:, 3], np.where(w, np.clip(u[:, 3], -0.5, 0.8), u[:, 3]))
    assert np.any(w & ((u[:, 3] > 0.8) | (u[:, 3] < -0.5)))  # saturation really bites
    assert np.all(np.isnan(y[w, 4])) and np.array_equal(y[~w, 4], u[~w, 4])


def test_random_faults_use_documented_generators(rec):
    t, u, y = rec["B_t"], rec["B_u"], rec["B_y"]
    w = _window(t)
    seed = 7
    n1 = np.random.default_rng(seed + 0).standard_normal(int(w.sum()))
    n2 = np.random.default_rng(seed + 1).standard_normal(int(w.sum()))
    np.testing.assert_array_equal(y[w, 0], u[w, 0] + 0.3 * n1)
    np.testing.assert_array_equal(y[w, 1], 0.7 * n2)  # signal loss: zero-mean replacement
    np.testing.assert_array_equal(y[~w, :2], u[~w, :2])
    # noise_std 0 adds exactly nothing
    np.testing.assert_array_equal(y[:, 7], u[:, 7])


def test_same_seed_same_run_other_seed_differs(rec):
    np.testing.assert_array_equal(rec["B_y"], rec["B_same_y"])
    w = _window(rec["B_t"])
    other = rec["B_other_y"]
    assert np.all(rec["B_y"][w, 0] != other[w, 0])
    assert np.all(rec["B_y"][w, 1] != other[w, 1])
    # deterministic channels do not depend on the seed
    np.testing.assert_array_equal(rec["B_y"][:, 2:4], other[:, 2:4])


def test_fmu_state_round_trip_restores_rng_and_latches(rec):
    first, second, third = rec["state_first"], rec["state_second"], rec["state_third"]
    assert np.array_equal(first, second, equal_nan=True)
    assert np.array_equal(first, third, equal_nan=True)
    assert np.isnan(first[:, 4]).any()  # the replayed window includes NaN dropout


if __name__ == "__main__":
    _scenarios(Path(sys.argv[1]), Path(sys.argv[2]))
