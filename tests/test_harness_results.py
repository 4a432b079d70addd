"""The run store (``signals.npz`` + ``run.json``, :mod:`gyrodiag_harness.cosim.results`): how much
it shrinks a real run, what it gives back, the formats of earlier versions, bad files.

Claims under test (docs/notes.md, Harness): Real signals rounded to float32 come back
within 2**-24 relative, the context signals of ``"compact"`` within 2**-13 (NaN, ±inf
and -0.0 kept); time, integer-valued, constant and float32-exact signals come back
bit-exactly; the DTG 1 kHz seed run ``dtg_nominal`` takes at least 3x less disk than as
float64 byte planes (format 2) with ``"float32"``, 4x with ``"compact"``; ``report`` on
every saved seed run measures what ``verify`` measured; a batch judges the
full-precision run, not the rounded file; ``harness all`` keeps only run.json of its
training runs.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from gyrodiag_harness.cosim.batch import run_all
from gyrodiag_harness.cosim.results import (
    CONTEXT_MAX_RELATIVE_ERROR,
    FLOAT32_MAX_RELATIVE_ERROR,
    META_FILE,
    SIGNALS_FILE,
    FaultWindow,
    RunResult,
    drop_signals,
    signals_dropped,
)
from gyrodiag_harness.cosim.scenario import expected_signals, load_scenario

ROOT = Path(__file__).resolve().parents[1]
DATA = Path(__file__).resolve().parent / "data" / "scenarios"
F32_MAX = float(np.finfo(np.float32).max)
F32_TINY = float(np.finfo(np.float32).tiny)


def _run(signals: dict[str, np.ndarray], n: int | None = None) -> RunResult:
    n = len(next(iter(signals.values()))) if n is None else n
    return RunResult(scenario="store", time=np.arange(n) * 1e-3, signals=signals,
                     fault_windows=[FaultWindow("f", "inj.out_1", "bias", 0.5)],
                     step_s=1e-3, stop_time_s=n * 1e-3, wall_time_s=0.25)


def _meta(directory: Path) -> dict:
    return json.loads((directory / META_FILE).read_text())


def _rel_err(stored: np.ndarray, value: np.ndarray) -> np.ndarray:
    finite = np.isfinite(value) & (value != 0)
    return np.abs(stored[finite] - value[finite]) / np.abs(value[finite])


def _write_format_2(run: RunResult, directory: Path) -> None:
    # what the harness wrote before format 3 (every column as float64 byte planes)
    directory.mkdir(parents=True)
    names = list(run.signals)

    def planes(col: np.ndarray) -> np.ndarray:
        return np.ascontiguousarray(np.asarray(col, "<f8").view(np.uint8).reshape(-1, 8).T)

    arrays = {"time": planes(run.time), **{n: planes(run.signals[n]) for n in names}}
    np.savez_compressed(directory / SIGNALS_FILE, **arrays)
    (directory / META_FILE).write_text(json.dumps({
        "format_version": 2, "scenario": run.scenario, "step_s": run.step_s,
        "stop_time_s": run.stop_time_s, "wall_time_s": run.wall_time_s, "error": None,
        "interrupted": False, "n_samples": len(run.time),
        "signals_encoding": "float64-byte-planes", "signals": names,
        "fault_windows": [w.to_json() for w in run.fault_windows],
        "manoeuvre_windows": []}))


# ------------------------------------------------------------------- what comes back
def test_each_kind_of_signal_comes_back_within_its_stated_precision(tmp_path):
    rng = np.random.default_rng(5)
    n = 5000
    noisy = 2.0 + 1e-3 * np.cumsum(rng.standard_normal(n))
    with_specials = rng.standard_normal(n) * 1e-3
    with_specials[[3, 10, 11, 400]] = [np.nan, np.inf, -np.inf, -0.0]
    signals = {
        "d.theta": noisy,                                    # Real: rounded
        "d.specials": with_specials,                         # Real with NaN, ±inf, -0.0
        "d.alarm": (rng.random(n) < 0.1).astype(float),      # Boolean
        "d.code": rng.integers(-3, 5, n).astype(float),      # Integer, int8
        "d.count": np.arange(n, dtype=float) * 7.0,          # int16 would overflow: int32
        "d.big_int": np.arange(n, dtype=float) + 2.0**40,    # beyond int32: int64
        "d.const": np.full(n, math.pi),                      # constant
        "d.nan_const": np.full(n, np.nan),                   # constant NaN
        "d.neg_zero": np.where(np.arange(n) % 2, 0.0, -0.0),  # zeros with signs
        "d.halves": np.round(rng.standard_normal(n) * 8) / 2 + 0.25,  # float32-exact
        "d.tiny": rng.standard_normal(n) * 1e-40,            # below float32's normals
        "d.huge": rng.standard_normal(n) * 1e300,            # beyond float32
    }
    r = _run(signals)
    r.save(tmp_path / "run", precision="float32")
    back = RunResult.load(tmp_path / "run")
    storage = _meta(tmp_path / "run")["signal_storage"]
    assert storage == {"time": "float64", "d.theta": "float32", "d.specials": "float32",
                       "d.alarm": "int8", "d.code": "int8", "d.count": "int32",
                       "d.big_int": "int64", "d.const": "constant",
                       "d.nan_const": "constant", "d.neg_zero": "float32",
                       "d.halves": "float32", "d.tiny": "float64", "d.huge": "float64"}
    assert back.rounded_signals == dict.fromkeys(["d.theta", "d.specials"], 2.0**-24)
    assert _meta(tmp_path / "run")["rounded_signals"] == back.rounded_signals
    np.testing.assert_array_equal(back.time, r.time)
    for name, value in signals.items():
        got = back.signal(name)
        assert got.dtype == np.float64 and got.shape == (n,), name
        assert np.array_equal(np.isnan(got), np.isnan(value)), name
        assert np.array_equal(np.signbit(got), np.signbit(value)), name
        if name in back.rounded_signals:
            err = _rel_err(got, value)
            assert err.max() <= FLOAT32_MAX_RELATIVE_ERROR, name
            assert err.max() > FLOAT32_MAX_RELATIVE_ERROR / 4, name  # rounded, not kept
            special = ~np.isfinite(value) | (value == 0)
            assert np.array_equal(got[special], value[special], equal_nan=True), name
        else:  # every bit (NaN payloads aside)
            assert np.array_equal(got, value, equal_nan=True), name


def test_compact_keeps_what_is_judged_to_float32_and_the_rest_to_13_bits(tmp_path):
    rng = np.random.default_rng(8)
    n = 4000
    judged = 1.0 + 1e-2 * np.cumsum(rng.standard_normal(n)) / np.sqrt(n)
    context = rng.standard_normal(n) * 1e-3
    context[[5, 6, 7, 8]] = [np.nan, np.inf, -np.inf, -0.0]
    r = _run({"d.eta": judged, "d.level": context, "d.alarm": (context > 0) * 1.0,
              # 13-bit rounding would carry these past float32's largest: float32 instead
              "d.big": F32_MAX * (1.0 - 1e-5 * rng.random(n))})
    r.save(tmp_path / "run", judged={"d.eta", "d.unrecorded"})
    back = RunResult.load(tmp_path / "run")
    meta = _meta(tmp_path / "run")
    assert meta["signals_precision"] == "compact"
    assert back.rounded_signals == {"d.eta": 2.0**-24, "d.level": 2.0**-13,
                                    "d.big": 2.0**-24}
    assert np.isfinite(back.signal("d.big")).all()
    assert meta["signal_storage"]["d.alarm"] == "int8"
    for name, bound in back.rounded_signals.items():
        value, got = r.signals[name], back.signal(name)
        err = _rel_err(got, value)
        assert bound / 4 < err.max() <= bound, name
        assert np.array_equal(np.isnan(got), np.isnan(value)), name
        assert np.array_equal(np.signbit(got), np.signbit(value)), name
        assert np.isinf(got).sum() == np.isinf(value).sum(), name
    # 13 significant bits: the 11 lowest of float32's 24 are zero
    stored = np.load(tmp_path / "run" / SIGNALS_FILE)["d.level"].T.copy().view("<u4")
    assert not np.any(stored.ravel() & np.uint32(0x7FF))
    assert CONTEXT_MAX_RELATIVE_ERROR == 2.0**-13
    with pytest.raises(TypeError, match="judged must be a collection of signal names"):
        r.save(tmp_path / "bad", judged="d.eta")


def test_float64_precision_keeps_every_bit_and_resaving_keeps_the_rounded_list(tmp_path):
    rng = np.random.default_rng(6)
    r = _run({"a.x": rng.standard_normal(300), "a.flag": np.ones(300)})
    r.save(tmp_path / "exact", precision="float64")
    exact = RunResult.load(tmp_path / "exact")
    assert not exact.rounded_signals
    assert _meta(tmp_path / "exact")["signals_precision"] == "float64"
    assert np.array_equal(exact.signal("a.x"), r.signals["a.x"])
    r.save(tmp_path / "rounded")
    rounded = RunResult.load(tmp_path / "rounded")
    assert rounded.rounded_signals == {"a.x": 2.0**-13}
    # saved again (even as float64, or judged) the samples are the rounded ones: the
    # bound stays
    rounded.save(tmp_path / "again", precision="float64", judged={"a.x"})
    again = RunResult.load(tmp_path / "again")
    assert again.rounded_signals == {"a.x": 2.0**-13}
    assert _meta(tmp_path / "again")["signal_storage"]["a.x"] == "float32"
    assert np.array_equal(again.signal("a.x"), rounded.signal("a.x"))
    with pytest.raises(ValueError, match=r"precision must be one of 'compact', 'float32', "
                                         r"'float64', got 'half'"):
        r.save(tmp_path / "bad", precision="half")


def test_a_run_without_its_signals_says_why(tmp_path):
    _run({"a.x": np.linspace(0, 1, 20)}).save(tmp_path / "run")
    assert signals_dropped(tmp_path / "run") is None
    drop_signals(tmp_path / "run", "kept elsewhere")
    assert not (tmp_path / "run" / SIGNALS_FILE).exists()
    assert signals_dropped(tmp_path / "run") == "kept elsewhere"
    with pytest.raises(FileNotFoundError, match=r"the signals of this run were not kept "
                                                r"\(kept elsewhere\); only run.json"):
        RunResult.load(tmp_path / "run")


def test_saved_files_get_the_permissions_of_ordinary_new_files(tmp_path):
    # not mkstemp's private 0600: colleagues sharing a results folder can read them
    import os

    mask = os.umask(0)
    os.umask(mask)
    _run({"a.x": np.ones(3)}).save(tmp_path / "run")
    for name in (SIGNALS_FILE, META_FILE):
        assert (tmp_path / "run" / name).stat().st_mode & 0o777 == 0o666 & ~mask, name


def test_an_empty_run_saves_and_loads(tmp_path):
    r = _run({"a.x": np.zeros(0)}, n=0)
    r.error = "the run process exited with status 1 before saving its run"
    r.save(tmp_path / "run")
    back = RunResult.load(tmp_path / "run")
    assert back.time.shape == (0,) and back.signal("a.x").shape == (0,)
    assert back.error == r.error


# --------------------------------------------------------------- earlier formats
def test_runs_saved_in_format_2_load_bit_exactly(tmp_path):
    rng = np.random.default_rng(7)
    r = _run({"a.x": rng.standard_normal(400), "a.flag": (rng.random(400) < 0.5) * 1.0})
    _write_format_2(r, tmp_path / "v2")
    back = RunResult.load(tmp_path / "v2")
    assert not back.rounded_signals and list(back.signals) == ["a.x", "a.flag"]
    np.testing.assert_array_equal(back.time, r.time)
    for name in r.signals:
        assert np.array_equal(back.signal(name), r.signals[name]), name
    assert back.fault_windows == r.fault_windows


def test_runs_saved_in_format_1_csv_load(tmp_path):
    folder = tmp_path / "v1"
    folder.mkdir()
    (folder / "signals.csv").write_text("time,a.x\n0.0,0.1\n0.5,nan\n1.0,-inf\n")
    (folder / META_FILE).write_text(json.dumps({"scenario": "old", "step_s": 0.5,
                                                "fault_windows": []}))
    back = RunResult.load(folder)
    np.testing.assert_array_equal(back.time, [0.0, 0.5, 1.0])
    np.testing.assert_array_equal(back.signal("a.x"), [0.1, np.nan, -np.inf])


# -------------------------------------------------------------------- bad files
def test_bad_files_are_named_with_what_is_wrong(tmp_path):
    r = _run({"a.x": np.linspace(0.1, 1.0, 50), "a.flag": np.ones(50) * (np.arange(50) > 9)})
    r.save(tmp_path / "run")
    meta = _meta(tmp_path / "run")

    def load_with(**changes: object) -> None:
        (tmp_path / "run" / META_FILE).write_text(json.dumps({**meta, **changes}))
        RunResult.load(tmp_path / "run")

    with pytest.raises(ValueError, match=r"format_version 9 is newer than this harness"):
        load_with(format_version=9)
    with pytest.raises(ValueError, match=r"unknown signals_encoding 'zstd'"):
        load_with(signals_encoding="zstd")
    with pytest.raises(ValueError, match=r"signal 'a.x' has an unknown storage 'bf16'"):
        load_with(signal_storage={**meta["signal_storage"], "a.x": "bf16"})
    with pytest.raises(ValueError, match=r"entry 'a.flag' stored as float64 should be uint8 "
                                         r"byte planes of shape \(8, N\) \(found dtype int8"):
        load_with(signal_storage={**meta["signal_storage"], "a.flag": "float64"})
    with pytest.raises(ValueError, match=r"run.json does not say how these are stored: a.x"):
        load_with(signal_storage={"time": "float64", "a.flag": "int8"})
    (tmp_path / "run" / META_FILE).write_text(json.dumps(meta))
    (tmp_path / "run" / SIGNALS_FILE).write_bytes(b"not a zip")
    with pytest.raises(ValueError, match=r"signals.npz: unreadable signals file"):
        RunResult.load(tmp_path / "run")


# ------------------------------------------------------ a real run: size, precision
def test_dtg_nominal_run_takes_4x_less_disk_and_comes_back_within_its_bounds(
        tmp_path, gyrodiag_run):
    # the main job's largest run (60 s, 20 θ/η signals at 1 kHz), as the session's run
    # cache holds it (bit-exact)
    from gyrodiag_harness.verification.expectations import verify_results

    scenario = load_scenario(ROOT / "scenarios" / "dtg_nominal.toml")
    judged = {q for e in scenario.expect for q in expected_signals(e)}
    run = gyrodiag_run(ROOT / "scenarios" / "dtg_nominal.toml")
    assert run.error is None and len(run.time) == 60001 and not run.rounded_signals
    _write_format_2(run, tmp_path / "v2")
    run.save(tmp_path / "float32", precision="float32")
    run.save(tmp_path / "compact", judged=judged)
    v2, f32, compact = ((tmp_path / d / SIGNALS_FILE).stat().st_size
                        for d in ("v2", "float32", "compact"))
    print(f"dtg_nominal signals.npz: float64 byte planes {v2 / 1e6:.2f} MB, float32 "
          f"{f32 / 1e6:.2f} MB ({v2 / f32:.2f}x smaller), compact {compact / 1e6:.2f} MB "
          f"({v2 / compact:.2f}x)")
    assert v2 / f32 >= 3.0 and v2 / compact >= 4.0
    back = RunResult.load(tmp_path / "compact")
    storage = _meta(tmp_path / "compact")["signal_storage"]
    thetas = {n for n in run.signals if "theta" in n}
    etas = {n for n in run.signals if n.split(".")[-1].startswith("eta_")}
    assert thetas <= judged and not etas & judged
    assert back.rounded_signals == {**dict.fromkeys(thetas, 2.0**-24),
                                    **dict.fromkeys(etas, 2.0**-13)}
    assert {storage[n] for n in ("diag.dtg.alarm", "diag_fine.dtg.alarm")} == {"constant"}
    assert storage["diag.dtg.learning"] == "int8"
    np.testing.assert_array_equal(back.time, run.time)
    for name, value in run.signals.items():
        if name in back.rounded_signals:
            bound = back.rounded_signals[name]
            assert bound / 4 < _rel_err(back.signal(name), value).max() <= bound, name
        else:
            assert np.array_equal(back.signal(name), value), name
    # what the scenario judges comes out the same from the stored values
    (full,), (stored,) = verify_results([run], [scenario]), verify_results([back], [scenario])
    assert full.passed and stored.passed
    for a, b in zip(full.expectations, stored.expectations, strict=True):
        if a.value is not None:
            assert b.value == pytest.approx(a.value, rel=1e-6, abs=1e-12), a.name


def test_a_batch_judges_the_full_precision_run_not_the_rounded_file(tmp_path, fmu_dir):
    scenario = load_scenario(DATA / "closed_loop.toml")
    (result,) = run_all([scenario], tmp_path, fmu_dir, progress=False)
    saved = RunResult.load(tmp_path / scenario.name)
    assert not result.rounded_signals and saved.rounded_signals
    # the q bias of 0.1 on the injector output: exact in the run held, rounded on disk
    after = result.time > 1.005
    diff = result.signal("injector.out_3") - result.signal("aircraft.y_q")
    np.testing.assert_allclose(diff[after], 0.1, atol=1e-12)
    stored = saved.signal("injector.out_3") - saved.signal("aircraft.y_q")
    assert np.abs(stored[after] - 0.1).max() > 1e-12
    for name, value in result.signals.items():
        if name in saved.rounded_signals:
            bound = saved.rounded_signals[name]
            assert _rel_err(saved.signal(name), value).max() <= bound, name
        else:
            assert np.array_equal(saved.signal(name), value), name


def test_report_on_the_saved_seed_runs_measures_what_verify_measured(tmp_path,
                                                                    gyrodiag_run):
    # every seed scenario of the main job, saved as `verify` saves it (its
    # record.precision) and judged again from the file, as `harness report` does
    from gyrodiag_harness.verification.expectations import verify_results

    files = sorted((ROOT / "scenarios").glob("*.toml"))
    scenarios = [load_scenario(f) for f in files]
    full_size = stored_size = 0
    for scenario, run in zip(scenarios, gyrodiag_run.many(files), strict=True):
        assert not run.rounded_signals, scenario.name
        run.save(tmp_path / scenario.name, scenario.record.precision,
                 judged={q for e in scenario.expect for q in expected_signals(e)})
        _write_format_2(run, tmp_path / "v2" / scenario.name)
        full_size += (tmp_path / "v2" / scenario.name / SIGNALS_FILE).stat().st_size
        stored_size += (tmp_path / scenario.name / SIGNALS_FILE).stat().st_size
        stored = RunResult.load(tmp_path / scenario.name)
        (a,), (b,) = verify_results([run], [scenario]), verify_results([stored], [scenario])
        assert (a.passed, a.error) == (b.passed, b.error), scenario.name
        for ea, eb in zip(a.expectations, b.expectations, strict=True):
            assert ea.passed == eb.passed, (scenario.name, ea.name)
            if ea.value is None or math.isnan(ea.value):
                assert eb.value is None or math.isnan(eb.value), (scenario.name, ea.name)
            else:
                assert eb.value == pytest.approx(ea.value, rel=1e-6, abs=1e-12), \
                    (scenario.name, ea.name, ea.message, eb.message)
    print(f"{len(files)} seed runs: {full_size / 1e6:.2f} MB as float64 byte planes, "
          f"{stored_size / 1e6:.2f} MB as saved, {full_size / stored_size:.2f}x smaller")
    assert full_size / stored_size >= 4.0
