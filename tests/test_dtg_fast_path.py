"""The DTG plant's float stepping and its SciPy-free design functions equal the numpy/SciPy
formulation they replaced.

* ``expm`` of gd_dtg_core equals ``scipy.linalg.expm`` (every Padé degree and the
  scaling branch, real and complex) and known closed forms; ``controller_matrices``
  equals ``scipy.signal.tf2ss`` + ``cont2discrete(method="bilinear")``;
* ``DTGSimulator`` (plain floats) equals a copy of the numpy formulation kept here
  (``_NumpyDTG``: numpy arrays, SciPy's expm and Tustin) to 1e-12 of each output's
  range: both sets, loop on and off, noise and dither, faults and noise switched during
  the run, steps of 1 ms, 0.7 ms, 2.5 ms and irregular ones, and a state saved by either
  implementation restored into the other;
* DTG.fmu in a host without SciPy (blocked) gives the library's outputs to 1e-12, also
  after an FMU state restore, and loads no SciPy module.
"""

from __future__ import annotations

import copy
import math
import sys
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "models" / "dtg"))
sys.path.insert(0, str(Path(__file__).resolve().parent))

import _dtg_fast_runner as runner  # noqa: E402
import gd_dtg_core as core  # noqa: E402
import gd_dtg_sets as sets  # noqa: E402
from gd_dtg_sim import NOMINAL_FAULTS, DTGSimulator  # noqa: E402

OUT = runner.OUT


# ---------------------------------------------------------------------------------------
# the numpy formulation the float stepping replaced (gd_dtg_sim before the speed work)
# ---------------------------------------------------------------------------------------

def _scipy_controller(p):
    from scipy.signal import cont2discrete, tf2ss

    num = p.kp * np.array([1.0, p.ki])
    den = np.array([1.0, 0.0])
    if p.lead_zero != p.lead_pole:
        num = np.polymul(num, [1.0 / p.lead_zero, 1.0])
        den = np.polymul(den, [1.0 / p.lead_pole, 1.0])
    wf = p.filter_corner
    den = np.polymul(den, [1.0 / wf**2, 2.0 * p.filter_damping / wf, 1.0])
    Ac, Bc, Cc, Dc, _ = cont2discrete(tf2ss(num, den), p.controller_sample_time,
                                      method="bilinear")
    return (np.asarray(Ac, dtype=float), np.asarray(Bc, dtype=float).reshape(-1),
            np.asarray(Cc, dtype=float).reshape(-1), np.asarray(Dc, dtype=float).reshape(()))


def _scipy_zoh(A, B, dt):
    from scipy.linalg import expm

    n, m = B.shape
    aug = np.zeros((n + m, n + m), dtype=np.result_type(A, B))
    aug[:n, :n] = A * dt
    aug[:n, n:] = B * dt
    e = expm(aug)
    return e[:n, :n], e[:n, n:]


class _NumpyDTG:
    """gd_dtg_sim.DTGSimulator as it was: numpy arrays, SciPy's expm and Tustin."""

    def __init__(self, params, *, rebalance=True, noise_std=1e-3, dither_std=0.0, seed=0):
        self.params, self.rebalance, self.seed = params, bool(rebalance), int(seed)
        self.noise_std, self.dither_std = float(noise_std), float(dither_std)
        self._faults = dict(NOMINAL_FAULTS)
        self._Tc = params.controller_sample_time
        self._eps = 1e-9 * self._Tc
        self._Ac, self._Bc, self._Cc, self._Dc = _scipy_controller(params)
        c, s = math.cos(params.loop_rotation), math.sin(params.loop_rotation)
        self._R = np.array([[c, -s], [s, c]])
        nominal = core.rotor_coefficients(params)
        self._readout_gain = params.Ku / nominal.L
        self._cache = {}
        self._coeffs = nominal
        self._A, self._B = core.rotor_state_space(nominal)
        self.reset()

    def set_faults(self, **faults):
        new = {**self._faults, **{k: float(v) for k, v in faults.items()}}
        if new != self._faults:
            self._faults = new
            self._coeffs = core.rotor_coefficients(self.params, **new)
            self._A, self._B = core.rotor_state_space(self._coeffs)
            self._cache.clear()

    def reset(self, start_time=0.0, omega_x=0.0, omega_y=0.0, ux_in=0.0, uy_in=0.0):
        noise_seq, dither_seq = np.random.SeedSequence(self.seed).spawn(2)
        self._rng = np.random.default_rng(noise_seq)
        self._rng_dither = np.random.default_rng(dither_seq)
        self._t0 = self._t = float(start_time)
        self._m = 0
        self._x = np.array([0.0, 0.0, float(omega_x), float(omega_y)])
        self._xc = np.zeros((self._Ac.shape[0], 2))
        self._noise, self._dither, self._u_ctrl = np.zeros(2), np.zeros(2), np.zeros(2)
        self._u_in = np.array([float(ux_in), float(uy_in)])
        self._tick()
        self._u_mean = self._u.copy()

    def get_state(self):
        return {"t0": self._t0, "t": self._t, "m": self._m, "x": self._x.tolist(),
                "xc": self._xc.tolist(), "noise": self._noise.tolist(),
                "dither": self._dither.tolist(), "u_ctrl": self._u_ctrl.tolist(),
                "u_in": self._u_in.tolist(), "u_mean": self._u_mean.tolist(),
                "rng": copy.deepcopy(self._rng.bit_generator.state),
                "rng_dither": copy.deepcopy(self._rng_dither.bit_generator.state),
                "faults": dict(self._faults), "noise_std": self.noise_std,
                "dither_std": self.dither_std}

    def set_state(self, state):
        self.set_faults(**state["faults"])
        self.noise_std, self.dither_std = state["noise_std"], state["dither_std"]
        self._t0, self._t, self._m = float(state["t0"]), float(state["t"]), int(state["m"])
        self._x = np.array(state["x"], dtype=float)
        self._xc = np.array(state["xc"], dtype=float).reshape(self._Ac.shape[0], 2)
        for name in ("noise", "dither", "u_ctrl", "u_in", "u_mean"):
            setattr(self, "_" + name, np.array(state[name], dtype=float))
        self._rng = np.random.default_rng()
        self._rng.bit_generator.state = copy.deepcopy(state["rng"])
        self._rng_dither = np.random.default_rng()
        self._rng_dither.bit_generator.state = copy.deepcopy(state["rng_dither"])

    @property
    def time(self):
        return self._t

    @property
    def rotor_state(self):
        return self._x.copy()

    @property
    def pickoff(self):
        kt = self._coeffs.KT
        return (self._x[0] / kt + self._noise[0], self._x[1] / kt + self._noise[1])

    @property
    def torquer_mean(self):
        return float(self._u_mean[0]), float(self._u_mean[1])

    @property
    def rate_readout(self):
        ux, uy = self._u_mean
        return (-self._readout_gain * uy, self._readout_gain * ux)

    def advance(self, t_end, omega_x, omega_y, ux_in=0.0, uy_in=0.0):
        self._u_in = np.array([float(ux_in), float(uy_in)])
        w = np.array([float(omega_x), float(omega_y)])
        u_integral = np.zeros(2)
        covered = 0.0
        while True:
            next_tick = self._t0 + (self._m + 1) * self._Tc
            at_tick = next_tick <= t_end + self._eps
            target = next_tick if at_tick else t_end
            dt = target - self._t
            if dt > self._eps:
                u = self._u
                Ad, Bd = self._matrices(dt)
                self._x = Ad @ self._x + Bd @ np.concatenate((w, u))
                u_integral += u * dt
                covered += dt
            self._t = target
            if at_tick:
                self._m += 1
                self._tick()
            if self._t >= t_end - self._eps:
                break
        self._t = t_end
        self._u_mean = u_integral / covered if covered > 0.0 else self._u

    @property
    def _u(self):
        return self._u_ctrl + self._u_in + self._dither

    def _tick(self):
        self._noise = (self.noise_std * self._rng.standard_normal(2) if self.noise_std > 0.0
                       else np.zeros(2))
        self._dither = (self.dither_std * self._rng_dither.standard_normal(2)
                        if self.dither_std > 0.0 else np.zeros(2))
        if self.rebalance:
            e = -self._R @ np.array(self.pickoff)
            self._u_ctrl = self._Cc @ self._xc + self._Dc * e
            self._xc = self._Ac @ self._xc + np.outer(self._Bc, e)

    def _matrices(self, dt):
        if abs(dt - self._Tc) <= self._eps:
            dt = self._Tc
        key = round(dt / self._eps)
        if key not in self._cache:
            self._cache[key] = _scipy_zoh(self._A, self._B, dt)
        return self._cache[key]


# ---------------------------------------------------------------------------------------
# design functions against SciPy and closed forms
# ---------------------------------------------------------------------------------------

def _designs():
    from dataclasses import replace

    paper, prod = sets.paper_set(), sets.production_set()
    return [paper, prod, replace(paper, ki=0.0, controller_sample_time=2.5e-4),
            replace(prod, lead_zero=50.0, lead_pole=900.0, filter_damping=0.3,
                    controller_sample_time=3e-4)]


@pytest.mark.parametrize("design", range(4))
def test_controller_matrices_equal_scipy_tustin(design):
    p = _designs()[design]
    for got, want in zip(core.controller_matrices(p), _scipy_controller(p), strict=True):
        assert got.shape == want.shape
        np.testing.assert_allclose(got, want, rtol=1e-13, atol=1e-13 * np.max(np.abs(want)))


@pytest.mark.parametrize("design", range(4))
def test_zoh_matrices_equal_scipy_expm(design):
    p = _designs()[design]
    Tc = p.controller_sample_time
    for faults in ({}, {"spin_fraction": 0.5, "k_offset": -3e-3},
                   {"damping_scale": 3.0, "torquer_scale": 0.2}):
        A, B = core.rotor_state_space(core.rotor_coefficients(p, **faults))
        for dt in (1e-4 * Tc, 0.013 * Tc, 0.37 * Tc, Tc):  # the stepping's intervals
            got = np.hstack(core.zoh_discretize(A, B, dt))
            want = np.hstack(_scipy_zoh(A, B, dt))
            assert np.max(np.abs(got - want)) <= 1e-14 * np.max(np.abs(want)), (faults, dt)


def test_expm_equals_scipy_at_every_pade_degree_real_and_complex():
    from scipy.linalg import expm

    rng = np.random.default_rng(2)
    for n in (2, 3, 8):
        base = rng.standard_normal((n, n)) + 1j * rng.standard_normal((n, n))
        for target in (1e-3, 0.1, 0.8, 2.0, 5.0, 40.0):  # degrees 3, 5, 7, 9, 13, scaled
            for a in (base.real, base):
                a = a * (target / np.max(np.sum(np.abs(a), axis=0)))
                got, want = core.expm(a), expm(a)
                assert got.dtype == want.dtype
                # rounding of either is ≈ u·‖a‖ of ‖exp(a)‖ (the condition of exp)
                tol = 1e-14 * max(1.0, target) * np.max(np.abs(want))
                np.testing.assert_allclose(got, want, rtol=0, atol=tol)


def test_expm_known_answers():
    theta = 2.7  # rotation generator → rotation matrix
    got = core.expm(np.array([[0.0, -theta], [theta, 0.0]]))
    want = np.array([[np.cos(theta), -np.sin(theta)], [np.sin(theta), np.cos(theta)]])
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-15)
    # nilpotent: exp(N) = I + N + N²/2
    N = np.array([[0.0, 3.0, -1.0], [0.0, 0.0, 2.0], [0.0, 0.0, 0.0]])
    np.testing.assert_allclose(core.expm(N), np.eye(3) + N + N @ N / 2, rtol=0, atol=1e-14)
    # diagonal with a large norm (scaling and squaring)
    np.testing.assert_allclose(core.expm(np.diag([-30.0, 0.5, 12.0])),
                               np.diag(np.exp([-30.0, 0.5, 12.0])), rtol=1e-13)
    with pytest.raises(ValueError, match="square"):
        core.expm(np.zeros((2, 3)))
    with pytest.raises(ValueError, match="finite"):
        core.expm(np.array([[np.nan, 0.0], [0.0, 1.0]]))


# ---------------------------------------------------------------------------------------
# float stepping against the numpy formulation
# ---------------------------------------------------------------------------------------

SIM_CASES = {  # name: (set, loop, steps, noise, dither)
    "paper_loop_1ms": (1, True, [1e-3] * 3000, 1e-3, 0.5),
    "paper_open_1ms": (1, False, [1e-3] * 3000, 1e-3, 0.5),
    "paper_loop_2p5ms": (1, True, [2.5e-3] * 1200, 1e-3, 0.5),
    "paper_loop_irregular": (1, True, list(np.random.default_rng(9).uniform(1e-5, 4e-3, 2000)),
                             2e-3, 0.0),
    "production_loop_1ms": (2, True, [1e-3] * 600, 1e-3, 1.0),
    "production_loop_0p7ms": (2, True, [0.7e-3] * 600, 0.0, 1.0),
    "production_open_irregular": (2, False,
                                  list(np.random.default_rng(3).uniform(1e-6, 3e-4, 2000)),
                                  1e-3, 0.2),
}


def _events(n: int) -> dict[int, tuple[dict, dict]]:
    """step → (faults, noise/dither changes) applied before that step."""
    return {n // 4: ({"spin_fraction": 0.9, "k_offset": 2e-4}, {}),
            n // 2: ({"torquer_scale": 1.1}, {"noise_std": 0.0}),
            (3 * n) // 4: ({"pickoff_scale": 0.95, "damping_scale": 2.0},
                           {"noise_std": 1.5e-3, "dither_std": 0.3})}


def _outputs(sim) -> list[float]:
    return [*sim.pickoff, *sim.torquer_mean, *sim.rate_readout, *sim.rotor_state]


def _run(sim, steps, inputs, events, first=0, last=None, saves=None):
    rows = []
    for k in range(first, len(steps) if last is None else last):
        if saves is not None and k in saves:
            saves[k] = sim.get_state()
        faults, stds = events.get(k, ({}, {}))
        sim.set_faults(**faults)
        for name, value in stds.items():
            setattr(sim, name, value)
        sim.advance(sim.time + steps[k], *inputs[k])
        rows.append(_outputs(sim))
    return np.array(rows)


def _assert_close(got: np.ndarray, want: np.ndarray, what: str, rtol: float = 1e-12) -> None:
    """Each column equal to ``rtol`` of its range."""
    assert got.shape == want.shape
    for j in range(want.shape[1]):
        scale = np.max(np.abs(want[:, j]))
        np.testing.assert_allclose(got[:, j], want[:, j], rtol=0, atol=rtol * scale,
                                   err_msg=f"{what}: column {j}")


@pytest.mark.parametrize("name", list(SIM_CASES))
def test_float_stepping_equals_numpy_formulation(name):
    pset, loop, steps, noise, dither = SIM_CASES[name]
    p = sets.parameter_set(pset)
    n = len(steps)
    rng = np.random.default_rng(len(name))
    inputs = np.column_stack([0.01 * rng.standard_normal((n, 2)),
                              (0.05 if loop else 0.5) * rng.standard_normal((n, 2))])
    events = _events(n)
    kwargs = {"rebalance": loop, "noise_std": noise, "dither_std": dither, "seed": 21}
    ref, fast = _NumpyDTG(p, **kwargs), DTGSimulator(p, **kwargs)
    ref.reset(0.0, *inputs[0]), fast.reset(0.0, *inputs[0])
    np.testing.assert_allclose(_outputs(fast), _outputs(ref), rtol=1e-15, atol=0)
    save_at = (2 * n) // 3
    saved_ref, saved_fast = {save_at: None}, {save_at: None}
    want = _run(ref, steps, inputs, events, saves=saved_ref)
    got = _run(fast, steps, inputs, events, saves=saved_fast)
    _assert_close(got, want, name)
    # the outputs moved: the comparison is not between two constants
    assert np.all(np.std(want[:, :4], axis=0) > 0)
    # a state saved by either implementation, restored into the other, same JSON layout.
    # Both cache the matrices of an interval length on a grid of 1e-9·Tc and reuse the
    # matrices of the first length seen in a grid cell; lengths of intervals that end
    # between ticks jitter by ulps of the time (≈1e-12 of the length), so after a restore
    # (the cache refilled) such intervals differ by that much. Intervals of one tick
    # are snapped to Tc: steps that are whole numbers of ticks restore exactly.
    ticks = [h / p.controller_sample_time for h in steps]
    aligned = all(abs(r - round(r)) < 1e-9 * r for r in ticks)
    rtol = 1e-12 if aligned else 1e-10
    assert set(saved_fast[save_at]) == set(saved_ref[save_at])
    fresh = DTGSimulator(p, **kwargs)
    fresh.set_state(saved_ref[save_at])
    _assert_close(_run(fresh, steps, inputs, events, first=save_at), want[save_at:],
                  name + " (fast restored from the reference's state)", rtol)
    back = _NumpyDTG(p, **kwargs)
    back.set_state(saved_fast[save_at])
    _assert_close(_run(back, steps, inputs, events, first=save_at), want[save_at:],
                  name + " (reference restored from the fast state)", rtol)
    fast.set_state(saved_fast[save_at])
    again = _run(fast, steps, inputs, events, first=save_at)
    if aligned:  # restoring its own state reproduces the run bit for bit
        np.testing.assert_array_equal(again, got[save_at:])
    else:
        _assert_close(again, got[save_at:], name + " (restored)", rtol)


def test_state_of_wrong_shape_is_refused_by_name():
    sim = DTGSimulator(sets.paper_set())
    state = sim.get_state()
    with pytest.raises(ValueError, match="reshape"):
        sim.set_state({**state, "xc": state["xc"][:-1]})
    with pytest.raises(ValueError, match="reshape"):
        sim.set_state({**state, "x": [0.0, 0.0, 0.0]})


# ---------------------------------------------------------------------------------------
# DTG.fmu, in a host without SciPy, against the library
# ---------------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def fmu_rec(run_fmu_script) -> dict[str, np.ndarray]:
    return run_fmu_script(Path(runner.__file__))


def _library_case(case: dict) -> np.ndarray:
    par = case["params"]
    sim = DTGSimulator(sets.parameter_set(par.get("parameter_set", 1)),
                       rebalance=par.get("rebalance_on", True), seed=par.get("seed", 0))
    tunables = {"noise_std": 1e-3, "dither_std": 0.0, **dict(NOMINAL_FAULTS)}
    tunables.update({k: v for k, v in par.items() if k in tunables})
    inputs = runner.inputs_of(case)
    rows = []

    def apply() -> None:  # what the facade does with its tunables
        sim.noise_std, sim.dither_std = tunables["noise_std"], tunables["dither_std"]
        sim.set_faults(**{f: tunables[f] for f in NOMINAL_FAULTS})

    apply()
    sim.reset(0.0)
    for k, h in enumerate(case["steps"]):
        tunables.update(case["events"].get(k, {}))
        apply()
        sim.advance(sim.time + h, *inputs[k])
        rows.append([*sim.pickoff, *sim.torquer_mean, *sim.rate_readout])
    return np.array(rows)


def test_fmu_loads_no_scipy(fmu_rec):
    assert fmu_rec["scipy_loaded"].tolist() == []


@pytest.mark.parametrize("name", list(runner.CASES))
def test_fmu_equals_library(fmu_rec, name):
    case = runner.CASES[name]
    want = _library_case(case)
    _assert_close(fmu_rec[name], want, name)
    assert np.all(np.std(want[:, :4], axis=0) > 0)
    k = case["restore_at"]
    if k is not None:
        np.testing.assert_array_equal(fmu_rec[name + "_restored"], fmu_rec[name][k:])
