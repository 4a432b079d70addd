"""Observer designs made once (gyrodiag.df.gains) and the calibration window run as
one stacked recursion (SensorFaultIsolator.calibrate).

Known answers: a remembered or shipped gain is bit-for-bit the gain scipy's pole
placement computes for the same inputs; the Diagnoser FMU with its shipped table
calibrates to the library's thresholds without importing ``scipy.signal``, and a model
the table does not hold is designed as before.  The stacked window equals streaming
every observer sample by sample to rounding.
"""

from __future__ import annotations

import importlib.util
import subprocess
import sys
import zipfile
from pathlib import Path
from types import ModuleType

import numpy as np
import pytest

from gyrodiag.df import gains, isolation
from gyrodiag.df.channel import DFChannel, DFChannelConfig
from gyrodiag.df.filter import design_detection_filter
from gyrodiag.df.isolation import SensorFaultIsolator, design_observer_bank, place_observer_gain
from gyrodiag.df.plant import seed_aircraft

ROOT = Path(__file__).resolve().parents[1]
RUNNER = Path(__file__).with_name("_gain_table_runner.py")


def _tool(name: str) -> ModuleType:
    """A build-time generator of fmu_src/tools/ (not part of the runtime package)."""
    spec = importlib.util.spec_from_file_location(name, ROOT / "fmu_src" / "tools" / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


observer_gains = _tool("observer_gains")


@pytest.fixture
def empty_memo(monkeypatch, tmp_path):
    """No table file, an empty memo; the process's memo is dropped afterwards."""
    monkeypatch.setattr(gains, "TABLE_FILE", tmp_path / "absent.npz")
    gains.forget()
    yield
    gains.forget()


def _counted(monkeypatch) -> list[int]:
    calls = [0]
    real = isolation._placed_gain

    def counting(*args):
        calls[0] += 1
        return real(*args)

    monkeypatch.setattr(isolation, "_placed_gain", counting)
    return calls


def test_a_design_is_computed_once_and_handed_out_as_a_copy(empty_memo, monkeypatch):
    ac = seed_aircraft()
    calls = _counted(monkeypatch)
    poles = np.exp(-np.arange(1.0, 6.0) * 0.01)
    first = place_observer_gain(np.eye(5) + 0.01 * ac.A, ac.C, poles)
    first[0, 0] = 1e9  # the caller's copy
    second = place_observer_gain(np.eye(5) + 0.01 * ac.A, ac.C, poles)
    assert calls[0] == 1
    assert second[0, 0] != 1e9
    # another pole set is another design
    place_observer_gain(np.eye(5) + 0.01 * ac.A, ac.C, poles ** 2)
    assert calls[0] == 2
    # a failed design is not remembered: it fails again, naming the cause
    for _ in range(2):
        with pytest.raises(ValueError, match="C must not be zero"):
            place_observer_gain(ac.A, np.zeros((2, 5)), -np.arange(1.0, 6.0))


def _bank_inputs(period: float = 0.01):
    ac = seed_aircraft()
    bank = design_observer_bank(ac.A, ac.B, ac.C, period)
    b = bank[2]
    poles = np.exp(-np.arange(1.0, b.n_observable + 1.0) * period)
    return b.observer._phi, b.observer._c, poles, b.observer._l


def _table_with(tmp_path, entry) -> Path:
    phi, c, poles, _ = _bank_inputs()
    return observer_gains.save(tmp_path / "t.npz", {gains.design_key(phi, c, poles): entry})


@pytest.mark.parametrize("damage", ["empty", "npy", "text", "other format",
                                    "wrong values", "wrong shape", "nan"])
def test_a_damaged_table_costs_speed_never_a_result(empty_memo, monkeypatch, tmp_path,
                                                    damage):
    phi, c, poles, right = _bank_inputs()
    path = tmp_path / "t.npz"
    if damage == "empty":
        path.write_bytes(b"")
    elif damage == "npy":
        with path.open("wb") as fh:
            np.save(fh, right)
    elif damage == "text":
        path.write_text("observer gains")
    elif damage == "other format":
        with path.open("wb") as fh:
            np.savez(fh, **{gains.FORMAT_KEY: np.array("gyrodiag observer designs 0"),
                            gains.design_key(phi, c, poles): right * 2.0})
    elif damage == "wrong values":
        _table_with(tmp_path, right * 2.0)
    elif damage == "wrong shape":
        _table_with(tmp_path, right[:, :2])
    else:
        _table_with(tmp_path, np.full_like(right, np.nan))
    monkeypatch.setattr(gains, "TABLE_FILE", path)
    gains.forget()  # read the table at the next design
    calls = _counted(monkeypatch)
    for _ in range(2):  # the same answer every time, designed once
        np.testing.assert_array_equal(place_observer_gain(phi, c, poles), right)
    assert calls[0] == 1


def test_a_sound_table_is_used_and_the_memo_is_bounded(empty_memo, monkeypatch, tmp_path):
    phi, c, poles, right = _bank_inputs()
    monkeypatch.setattr(gains, "TABLE_FILE", _table_with(tmp_path, right))
    gains.forget()
    calls = _counted(monkeypatch)
    np.testing.assert_array_equal(place_observer_gain(phi, c, poles), right)
    assert calls[0] == 0
    with pytest.raises(ValueError, match="__format__"):
        observer_gains.save(tmp_path / "x.npz", {gains.FORMAT_KEY: right})
    monkeypatch.setattr(gains, "MAX_REMEMBERED", 2)
    for k in range(3):
        place_observer_gain(phi, c, poles ** (k + 2))
    assert len(gains.designs()) == 2  # the table's and one more
    place_observer_gain(phi, c, poles ** 4)
    assert calls[0] == 4  # the third new design was not kept


def test_default_designs_hold_the_bank_of_either_rule(empty_memo):
    ac = seed_aircraft()
    table = observer_gains.default_designs([0.01])
    assert len(table) == 21  # 6 single-sensor observers and 15 sensor pairs
    assert gains.designs() == {}  # the process goes on with its own (no) table
    computed = design_observer_bank(ac.A, ac.B, ac.C, 0.01)
    for b in computed:
        o = b.observer
        key = gains.design_key(o._phi, o._c,
                                    np.exp(-np.arange(1.0, b.n_observable + 1.0) * 0.01))
        np.testing.assert_array_equal(table[key], o._l)


def _fresh_process_thresholds(table: Path, rule: str) -> tuple[bool, np.ndarray]:
    code = f"""
import sys
sys.path.insert(0, {str(ROOT / 'fmu_src')!r})
import numpy as np
from pathlib import Path
from gyrodiag.df import gains
gains.TABLE_FILE = Path({str(table)!r})
from gyrodiag.df.channel import DFChannel, DFChannelConfig
ch = DFChannel(DFChannelConfig(sample_period_s=0.01, decision={rule!r}, calibrate_s=2.0,
                               burn_in_s=0.2, align_auto=False))
rng = np.random.default_rng(3)
u, y = rng.normal(0, 0.01, (201, 2)), rng.normal(0, 1e-3, (201, 6))
for k in range(201):
    ch.update(u[k], y[k])
figures = ch.thresholds[0] if ch.thresholds is not None else ch.noise_std
print(int("scipy.signal" in sys.modules), *map(float.hex, map(float, figures)))
"""
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          check=True, timeout=600)
    flag, *values = proc.stdout.split()
    return flag == "1", np.array([float.fromhex(v) for v in values])


def _library_thresholds(rule: str) -> np.ndarray:
    ch = DFChannel(DFChannelConfig(sample_period_s=0.01, decision=rule, calibrate_s=2.0,
                                   burn_in_s=0.2, align_auto=False))
    rng = np.random.default_rng(3)
    u, y = rng.normal(0, 0.01, (201, 2)), rng.normal(0, 1e-3, (201, 6))
    for k in range(201):
        ch.update(u[k], y[k])
    return ch.thresholds[0] if ch.thresholds is not None else ch.noise_std


@pytest.mark.parametrize("rule", ["paper", "sequential"])
def test_a_process_with_the_table_never_imports_scipy_signal(empty_memo, tmp_path, rule):
    table = observer_gains.save(tmp_path / "observer_gains.npz",
                            observer_gains.default_designs([0.01]))
    gains.forget()
    imported, figures = _fresh_process_thresholds(table, rule)
    assert not imported
    np.testing.assert_array_equal(figures, _library_thresholds(rule))
    # without a table (or with a damaged one) the designs are computed: same figures
    damaged = tmp_path / "damaged.npz"
    damaged.write_bytes(b"not a zip file")
    for path in (tmp_path / "absent.npz", damaged):
        imported, again = _fresh_process_thresholds(path, rule)
        assert imported
        np.testing.assert_array_equal(again, figures)


def test_generator_command_writes_the_table(tmp_path):
    out = tmp_path / "gains.npz"
    proc = subprocess.run([sys.executable, str(ROOT / "fmu_src" / "tools" / "observer_gains.py"),
                           "--out", str(out), "--periods", "0.01", "0.001"],
                          capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr
    assert "42 observer designs" in proc.stdout
    with np.load(out) as table:
        assert len(table.files) == 42 + 1  # and the format entry
        assert str(table[gains.FORMAT_KEY]) == gains.FORMAT
    bad = subprocess.run([sys.executable, str(ROOT / "fmu_src" / "tools" / "observer_gains.py"),
                          "--out", str(out), "--periods", "0"], capture_output=True, text=True,
                         timeout=600)
    assert bad.returncode == 2 and "--periods must all be > 0" in bad.stderr


def test_fmu_ships_the_table_once(fmu_dir):
    with zipfile.ZipFile(fmu_dir / "Diagnoser.fmu") as zf:
        names = zf.namelist()
        assert names.count("resources/gyrodiag/df/observer_gains.npz") == 1
        assert len(names) == len(set(names))
        with zf.open("resources/gyrodiag/df/observer_gains.npz") as fh:
            table = np.load(fh)
            assert len(table.files) == 21 * len(observer_gains.DEFAULT_PERIODS_S) + 1


@pytest.mark.parametrize(("rule", "period", "a23_scale", "designed"), [
    (0, 0.001, None, False),   # the system chain's paper rule at 1 kHz: from the table
    (1, 0.01, None, False),    # the aircraft seeds' sequential rule at 100 Hz
    (0, 0.01, 1.01, True),     # another model: designed as before
])
def test_fmu_calibrates_to_the_library_with_or_without_the_table(
        run_fmu_script, rule, period, a23_scale, designed):
    ac = seed_aircraft()
    a = np.array(ac.A, dtype=float)
    a23 = "default" if a23_scale is None else repr(float(a[1, 2] * a23_scale))
    if a23_scale is not None:
        a[1, 2] *= a23_scale
    res = run_fmu_script(RUNNER, str(rule), repr(period), a23)
    assert not bool(res["signal_before"])
    assert bool(res["signal_after"]) == designed
    window_s = 50 * period
    ch = DFChannel(DFChannelConfig(A=a, sample_period_s=period,
                                   decision="paper" if rule == 0 else "sequential",
                                   calibrate_s=window_s, burn_in_s=0.1 * window_s,
                                   align_auto=False))
    for k in range(res["u"].shape[0]):
        ch.update(res["u"][k], res["y"][k])
    m = ch.m
    if rule == 0:
        np.testing.assert_array_equal(res["figures"][:m], ch.thresholds[0])
    np.testing.assert_array_equal(res["figures"][m:], ch.noise_std)


def _window(n: int = 400, seed: int = 5):
    ac = seed_aircraft()
    rng = np.random.default_rng(seed)
    return ac, rng.normal(0, 0.02, (n, 2)), rng.normal(0, 1e-3, (n, 6))


def test_calibration_window_equals_streaming_every_observer():
    ac, u, y = _window()
    K = design_detection_filter(ac.A, ac.C, np.eye(5), -np.arange(1.0, 6.0))
    x0 = np.array([1.0, 0.01, 0.02, 0.0, 5.0])
    iso = SensorFaultIsolator(ac.A, ac.B, ac.C, K, 0.01)
    iso.calibrate(u, y, k_sigma=5.0, burn_in=50, x0=x0, continue_after=True)
    ref = SensorFaultIsolator(ac.A, ac.B, ac.C, K, 0.01)
    observers = [(ref.main_filter, np.arange(6))] + [(b.observer, b.used) for b in ref.bank]
    residuals = []
    for obs, used in observers:
        obs.reset(x0)
        residuals.append(np.array([obs.update(u[k], y[k, used]) for k in range(len(u))]))
    # thresholds: k·std (+ mean) of the streamed residuals after the burn-in
    for thr, res in zip([iso.main_thresholds, *iso.bank_thresholds], residuals, strict=True):
        np.testing.assert_allclose(thr.std, res[50:].std(axis=0, ddof=1), rtol=1e-10)
    # continue_after: every observer where streaming left it
    got = [iso.main_filter] + [b.observer for b in iso.bank]
    for g, (obs, _) in zip(got, observers, strict=True):
        st_g, st_r = g.get_state(), obs.get_state()
        np.testing.assert_allclose(st_g["z"], st_r["z"], rtol=1e-10, atol=1e-14)
        np.testing.assert_allclose(st_g["residual"], st_r["residual"], rtol=1e-10,
                                   atol=1e-15)
        assert st_g["n_updates"] == st_r["n_updates"] == len(u)
    # by default every observer restarts from x0
    iso.calibrate(u, y, k_sigma=5.0, burn_in=50, x0=x0)
    np.testing.assert_allclose(iso.main_filter.state_estimate, x0, atol=1e-12)
    assert iso.main_filter.get_state()["n_updates"] == 0
