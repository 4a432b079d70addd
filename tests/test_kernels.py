"""Per-sample kernels: compiled vs plain-Python fallback vs the numpy reference.

The reference is the numpy implementation the kernels replaced (tests/reference/, a copy
of prefilter/estimators/dtg/grey before the change). Every comparison is to 1e−12 of the
signal's scale; the compiled and plain-Python kernels perform the same operations in the
same order and are compared for exact equality.
"""

from __future__ import annotations

import math
import os
import shutil
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
from reference import ref_dtg, ref_estimators, ref_grey, ref_prefilter
from scipy import signal

from gyrodiag import dtg, grey
from gyrodiag.common import _accel, _pykernels, estimators, prefilter
from gyrodiag.demo import NOMINAL, simulate

ROOT = Path(__file__).resolve().parents[1]
BACKENDS = ["python", "c"]


@pytest.fixture(params=BACKENDS)
def backend(request: pytest.FixtureRequest) -> Iterator[str]:
    if request.param == "c" and not _has_compiled():
        pytest.skip(f"compiled kernels not built: {_accel.IMPORT_ERROR}")
    previous = _accel.use(request.param)
    yield request.param
    _accel.use("c" if previous is not _pykernels else "python")


def _has_compiled() -> bool:
    try:
        from gyrodiag.common import _ckernels  # noqa: F401
    except ImportError:
        return False
    return True


def test_compiled_kernels_are_built_where_a_compiler_exists() -> None:
    # pip install (setup.py, optional extension) builds them when cc is there
    if shutil.which("cc") is None and shutil.which("gcc") is None:
        pytest.skip("no C compiler on this machine")
    assert _has_compiled(), _accel.IMPORT_ERROR


def test_environment_variable_forces_the_fallback() -> None:
    code = "import gyrodiag.common._accel as a; print(a.ACCELERATED, a.kernels.__name__)"
    env = {**os.environ, "GYRODIAG_KERNELS": "python"}
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True,
                         text=True, check=True, cwd=ROOT, timeout=600).stdout.split()
    assert out == ["False", "gyrodiag.common._pykernels"]


# ------------------------------------------------------------------ prefilter
@pytest.mark.parametrize("btype", ["low", "high"])
@pytest.mark.parametrize("order", range(1, 11))
def test_butterworth_design_equals_scipy(order: int, btype: str) -> None:
    for corner in (0.3, 2.0, 50.0, 123.4, 480.0):
        ref = signal.butter(order, corner, btype=btype, fs=1000.0, output="sos")
        got = np.array(prefilter.butterworth_sos(order, corner, 1000.0, btype))
        assert got.shape == ref.shape
        # per section, relative to the section's largest coefficient
        scale = np.max(np.abs(ref), axis=1, keepdims=True)
        np.testing.assert_array_less(np.abs(got - ref) / scale, 1e-13)


def _dtg_record(n: int = 4000, seed: int = 3) -> np.ndarray:
    return simulate(NOMINAL, n, seed, noise_v=1e-4)


@pytest.mark.parametrize("highpass", [None, 2.0])
def test_prefilter_streaming_equals_reference(backend: str, highpass: float | None) -> None:
    rec = _dtg_record()
    new = prefilter.ButterworthPrefilter(6, 50.0, 1000.0, 4, highpass_hz=highpass)
    ref = ref_prefilter.ButterworthPrefilter(6, 50.0, 1000.0, 4, highpass_hz=highpass)
    got = np.array([new.update(r) for r in rec])
    fast = prefilter.ButterworthPrefilter(6, 50.0, 1000.0, 4, highpass_hz=highpass)
    stepped = np.array([fast.step(r) for r in rec.tolist()])
    want = np.array([ref.update(r) for r in rec])
    scale = np.max(np.abs(want))
    assert np.max(np.abs(got - want)) <= 1e-12 * scale
    np.testing.assert_array_equal(stepped, got)
    np.testing.assert_allclose(new.get_state()["zi"], ref.get_state()["zi"], rtol=0,
                               atol=1e-12 * scale)
    # a record after streaming continues the same state (scipy's loop)
    np.testing.assert_allclose(new.update(rec[:50]), ref.update(rec[:50]), rtol=0,
                               atol=1e-12 * scale)


# ------------------------------------------------------------------ RLS family
def _dtg_rows() -> list[tuple]:
    filt = ref_prefilter.ButterworthPrefilter(6, 50.0, 1000.0, 4).update(_dtg_record())
    reg = dtg.DTGRegressor()
    rows = [reg.step(*s) for s in filt.tolist()]
    return [r for r in rows if r is not None]


ESTIMATORS = {
    "rls_p0_1e8": lambda m: m.RLS(5, p0=1e8),
    "forgetting_0.999": lambda m: m.ForgettingRLS(5, forgetting=0.999, p0=1e8),
    "forgetting_0.99_capped": lambda m: m.ForgettingRLS(5, forgetting=0.99, p0=1e4),
    "forgetting_1": lambda m: m.ForgettingRLS(5, forgetting=1.0, p0=1e10),
}


@pytest.mark.parametrize("kind", ESTIMATORS)
def test_rls_family_equals_reference_on_dtg_data(backend: str, kind: str) -> None:
    rows = _dtg_rows()
    new = [ESTIMATORS[kind](estimators) for _ in range(2)]
    ref = [ESTIMATORS[kind](ref_estimators) for _ in range(2)]
    worst = 0.0
    for k, (phi_x, y_x, phi_y, y_y) in enumerate(rows):
        if k % 2:
            new[0].update(np.array(phi_x), y_x)
            new[1].update(np.array(phi_y), y_y)
        else:  # the unchecked hot path is the same computation
            new[0].step(phi_x, y_x)
            new[1].step(phi_y, y_y)
        ref[0].update(np.array(phi_x), y_x)
        ref[1].update(np.array(phi_y), y_y)
        for a, b in zip(new, ref, strict=True):
            worst = max(worst, float(np.max(np.abs(a.theta - b.theta)) / np.max(np.abs(b.theta))))
    # relative to the largest parameter: two BLAS orderings of the numpy reference
    # itself differ by ~1e-14 here
    assert worst <= 1e-12
    for a, b in zip(new, ref, strict=True):
        assert (a.n_updates, a.converged_at, a.converged) == (b.n_updates, b.converged_at,
                                                               b.converged)
        np.testing.assert_allclose(a.P, b.P, rtol=0, atol=1e-12 * np.max(np.abs(b.P)))


def test_capped_forgetting_rls_stays_bounded_without_excitation(backend: str) -> None:
    est = estimators.ForgettingRLS(3, forgetting=0.9, p0=10.0)
    ref = ref_estimators.ForgettingRLS(3, forgetting=0.9, p0=10.0)
    for _ in range(2000):
        est.step((0.0, 0.0, 0.0), 0.0)
        ref.update(np.zeros(3), 0.0)
    # the cap is what keeps P finite: 0.9**-2000 would overflow
    assert np.trace(est.P) == pytest.approx(30.0, rel=1e-12)
    np.testing.assert_allclose(est.P, ref.P, rtol=1e-12)


@pytest.mark.parametrize("kind", ESTIMATORS)
def test_rls_state_round_trip_continues_identically(backend: str, kind: str) -> None:
    rows = _dtg_rows()[:600]
    a, b = ESTIMATORS[kind](estimators), ESTIMATORS[kind](estimators)
    for phi, y, *_ in rows[:300]:
        a.step(phi, y)
    b.set_state(a.get_state())
    for phi, y, *_ in rows[300:]:
        assert a.step(phi, y) == b.step(phi, y)


def test_regressor_equals_reference() -> None:
    rec = _dtg_record(200)
    new, ref = dtg.DTGRegressor(), ref_dtg.DTGRegressor()
    for k, sample in enumerate(rec):
        got, want = new.update(*sample), ref.update(*sample)
        if want is None:
            assert got is None
            continue
        for g, w in zip(got, want, strict=True):
            np.testing.assert_array_equal(g, w)
        if k == 100:
            np.testing.assert_array_equal(new.get_state()["hist"], ref.get_state()["hist"])


# ------------------------------------------------------------------ grey
def _grey_signals() -> dict[str, np.ndarray]:
    rng = np.random.default_rng(11)
    n = 1200
    t = np.arange(n) * 1e-2
    return {
        "sine_noise": 2.0 + 0.3 * np.sin(2 * np.pi * 0.5 * t) + 1e-3 * rng.standard_normal(n),
        "ramp_negative": 0.01 * np.arange(n) - 5.0,
        "flat_then_step": np.r_[np.full(n // 2, 3.0), np.full(n - n // 2, -1.5)],
        "random_steps": np.repeat(rng.standard_normal(n // 40), 40),
        "large_offset_noise": 1e5 + 1e3 * rng.standard_normal(n),
        "exp_approach": 4.0 - 3.0 * np.exp(-t / 3.0),
    }


PREDICTORS = {
    "improved_10": lambda m: m.ImprovedGreyPredictor(10),
    "improved_5_linear": lambda m: m.ImprovedGreyPredictor(5, residual_order=1),
    "improved_20_amin0": lambda m: m.ImprovedGreyPredictor(20, a_min=0.0),
    "classic_10": lambda m: m.ClassicGreyPredictor(10),
    "classic_7_ratio2": lambda m: m.ClassicGreyPredictor(7, level_ratio=2.0),
    "classic_record": lambda m: m.ClassicGreyPredictor(None),
    "classic_10_textbook": lambda m: m.ClassicGreyPredictor(10, evaluation="textbook"),
    "classic_record_textbook": lambda m: m.ClassicGreyPredictor(None, evaluation="textbook"),
}


@pytest.mark.parametrize("kind", PREDICTORS)
def test_grey_predictors_equal_reference(backend: str, kind: str) -> None:
    for name, x in _grey_signals().items():
        new, ref = PREDICTORS[kind](grey), PREDICTORS[kind](ref_grey)
        got = np.array([new.update(v) for v in x])
        want = np.array([ref.update(v) for v in x])
        np.testing.assert_array_equal(np.isfinite(got), np.isfinite(want), err_msg=name)
        ok = np.isfinite(want)
        scale = max(1.0, float(np.max(np.abs(x))))
        err = float(np.max(np.abs(got[ok] - want[ok])))
        assert err <= 1e-12 * scale, f"{name}: {err:.3g}"
        assert new.last_used_fallback == ref.last_used_fallback
        assert new.last_a == pytest.approx(ref.last_a, rel=1e-9, abs=1e-12)


def test_classic_record_running_sums_stay_exact_over_a_long_record() -> None:
    # the whole-record model refits on every sample; the reference is O(n) per sample
    rng = np.random.default_rng(5)
    t = np.arange(4000) * 0.5
    x = 2.0 + 0.3 * np.sin(2 * np.pi * 0.01 * t) + 1e-3 * rng.standard_normal(t.size)
    new, ref = grey.ClassicGreyPredictor(None), ref_grey.ClassicGreyPredictor(None)
    got = np.array([new.update(v) for v in x])
    want = np.array([ref.update(v) for v in x])
    ok = np.isfinite(want)
    assert np.max(np.abs(got[ok] - want[ok])) <= 1e-12 * np.max(np.abs(x))


@pytest.mark.parametrize("kind", ["improved_10", "classic_10", "classic_record"])
def test_grey_state_round_trip_continues_identically(backend: str, kind: str) -> None:
    x = _grey_signals()["sine_noise"]
    a, b = PREDICTORS[kind](grey), PREDICTORS[kind](grey)
    for v in x[:300]:
        a.update(v)
    b.set_state(a.get_state())
    for v in x[300:600]:
        pa, pb = a.update(v), b.update(v)
        assert pa == pytest.approx(pb, rel=0, abs=1e-12 * 2.5)


# ------------------------------------------------------------------ compiled vs fallback
def test_compiled_kernels_equal_the_fallback_exactly() -> None:
    if not _has_compiled():
        pytest.skip(f"compiled kernels not built: {_accel.IMPORT_ERROR}")
    from gyrodiag.common import _ckernels as ck

    rng = np.random.default_rng(2)
    sections = (prefilter.butterworth_sos(6, 50.0, 1000.0, "low")
                + prefilter.butterworth_sos(2, 2.0, 1000.0, "high"))
    coef = [v for s in sections for v in (s[0], s[1], s[2], s[4], s[5])]
    a, b = _pykernels.SosCascade(coef, 4, 4), ck.SosCascade(coef, 4, 4)
    for x in rng.standard_normal((3000, 4)).tolist():
        assert list(a.step(x)) == list(b.step(x))
    assert a.get_state() == b.get_state()
    for lam, cap in ((1.0, math.inf), (0.999, 5e8), (0.9, 50.0)):
        a, b = _pykernels.PotterRLS(5, lam, cap), ck.PotterRLS(5, lam, cap)
        s0 = np.diag(np.full(5, 10.0)).ravel().tolist()
        a.set([0.0] * 5, s0)
        b.set([0.0] * 5, s0)
        for row in rng.standard_normal((3000, 6)).tolist():
            assert a.step(row[:5], row[5]) == b.step(row[:5], row[5])
        assert list(a.theta) == list(b.theta) and a.get_S() == b.get_S()
    # generated straight-line code (m <= 256) and the loop version (longer windows)
    x = (2.0 + np.cumsum(rng.standard_normal(1500)) * 1e-3).tolist() + [3.0] * 320
    for m in (4, 10, 300):
        pred = grey.ImprovedGreyPredictor(m, residual_order=min(2, m - 2))
        for k in range(0, len(x) - m, 3):
            args = (x[k:k + m], 10.0, 1e-6, pred._poly_weights, pred._residual_weights)
            assert _pykernels.improved_grey_predict(*args) == ck.improved_grey_predict(*args)


def test_compiled_kernels_reject_wrong_lengths() -> None:
    if not _has_compiled():
        pytest.skip(f"compiled kernels not built: {_accel.IMPORT_ERROR}")
    from gyrodiag.common import _ckernels as ck

    rls = ck.PotterRLS(5, 1.0, math.inf)
    with pytest.raises(ValueError, match="phi must hold 5 values, got 4"):
        rls.step([1.0] * 4, 0.0)
    sos = ck.SosCascade([1.0, 0.0, 0.0, 0.0, 0.0], 1, 2)
    with pytest.raises(TypeError):
        sos.step(["a", 1.0])


# ------------------------------------------------------------------ observer
def test_linear_observer_kernel_equals_the_matrix_products(backend: str) -> None:
    rng = np.random.default_rng(8)
    n, p, m = 5, 2, 6
    phi = 0.3 * rng.standard_normal((n, n))
    phi[0, 3] = 0.0  # zero terms are left out of the generated code: still equal
    gamma = rng.standard_normal((n, p))
    c = rng.standard_normal((m, n))
    c[2] = 0.0
    gain = 0.05 * rng.standard_normal((n, m))
    kernel = _accel.kernels.LinearObserver(
        *(a.ravel().tolist() for a in (phi, gamma, c, gain)), n, p, m)
    z = np.zeros(n)
    for _ in range(3000):
        u, y = rng.standard_normal(p), rng.standard_normal(m)
        r = y - c @ z
        z = phi @ z + gamma @ u + gain @ r
        got = kernel.step(u.tolist(), y.tolist())
        np.testing.assert_allclose(got, r, rtol=0, atol=1e-12 * max(1.0, np.max(np.abs(r))))
    np.testing.assert_allclose(kernel.get_z(), z, rtol=0, atol=1e-12 * np.max(np.abs(z)))
    kernel.set_z([1.0] * n)
    assert kernel.get_z() == [1.0] * n
    with pytest.raises(ValueError, match="z must hold 5 values"):
        kernel.set_z([1.0] * 4)


def test_compiled_observer_equals_the_fallback_exactly() -> None:
    if not _has_compiled():
        pytest.skip(f"compiled kernels not built: {_accel.IMPORT_ERROR}")
    from gyrodiag.common import _ckernels as ck

    rng = np.random.default_rng(9)
    n, p, m = 4, 1, 3
    mats = [rng.standard_normal(s) * 0.2 for s in ((n, n), (n, p), (m, n), (n, m))]
    mats[2][1, 2] = 0.0
    args = [*(a.ravel().tolist() for a in mats), n, p, m]
    a, b = _pykernels.LinearObserver(*args), ck.LinearObserver(*args)
    for row in rng.standard_normal((2000, p + m)).tolist():
        assert list(a.step(row[:p], row[p:])) == list(b.step(row[:p], row[p:]))
    assert a.get_z() == b.get_z()


def test_sliding_window_step_equals_update() -> None:
    rows = _dtg_rows()[:400]
    a = estimators.SlidingWindowLS(5, window=50)
    b = estimators.SlidingWindowLS(5, window=50)
    for phi, y, *_ in rows:
        got = a.step(phi, y)
        want = b.update(np.array(phi), y)
        assert isinstance(got, tuple)
        np.testing.assert_array_equal(np.array(got), want)
