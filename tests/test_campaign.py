"""Monte Carlo campaigns (harness/campaign.py, harness/campaign_report.py).

Crash/hang/resume tests use a fake per-run function (tests/_campaign_fake_runner.py)
run in the same per-run processes as real runs; the FMU tests run campaigns/smoke.toml
(6 aircraft runs of 4 s at 100 Hz) on the process pool and on a dask LocalCluster.
"""

from __future__ import annotations

import json
import math
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from gyrodiag_harness.campaigns.campaign import (
    RUN_TMP_PREFIX,
    CampaignSpec,
    _band_statistic,
    _kth_largest_window,
    build_scenario,
    expand_runs,
    judge,
    load_campaign,
    run_campaign,
)
from gyrodiag_harness.campaigns.campaign_report import (
    clopper_pearson,
    garwood_interval,
    markdown_summary,
    summarize,
)
from gyrodiag_harness.cosim.scenario import InjectorFault

ROOT = Path(__file__).resolve().parents[1]
SMOKE = ROOT / "campaigns" / "smoke.toml"
FAKE = "_campaign_fake_runner:fake"


def fake_spec(magnitudes: list[float], nominal_runs: int = 0, timeout_s: float = 60.0,
              seeds: int = 1) -> CampaignSpec:
    return CampaignSpec.model_validate({
        "name": "fake", "timeout_s": timeout_s, "runner": FAKE,
        "classes": {"air": {"scenario": "unused.toml", "channel": "df"}},
        "sweeps": [{"class": "air", "type": "bias", "magnitudes": magnitudes,
                    "onsets_s": [1.0], "channels": [3], "seeds": seeds, "duration_s": 2.0}],
        "nominal": ([{"class": "air", "duration_s": 60.0, "runs": nominal_runs}]
                    if nominal_runs else []),
    })


# --------------------------------------------------------------------------- statistics
def test_garwood_interval_matches_the_published_table():
    # Garwood (1936) 95 % limits: n=0 -> [0, 3.689], n=1 -> [0.0253, 5.572],
    # n=10 -> [4.795, 18.39]
    assert garwood_interval(0, 1.0) == pytest.approx((0.0, 3.689), abs=1e-3)
    assert garwood_interval(1, 1.0) == pytest.approx((0.0253, 5.572), abs=1e-3)
    assert garwood_interval(10, 2.0) == pytest.approx((4.795 / 2, 18.39 / 2), rel=1e-3)
    with pytest.raises(ValueError, match="hours"):
        garwood_interval(1, 0.0)


def test_clopper_pearson_edges():
    assert clopper_pearson(10, 10)[1] == 1.0
    # all n succeed: lower bound (alpha/2)^(1/n)
    assert clopper_pearson(10, 10)[0] == pytest.approx(0.025 ** (1 / 10))
    assert clopper_pearson(0, 5)[0] == 0.0


def test_kth_largest_window_matches_brute_force():
    rng = np.random.default_rng(0)
    z = rng.random(50)
    got = _kth_largest_window(z, 3, 5)
    padded = np.concatenate([np.zeros(4), z])
    want = [np.sort(padded[i:i + 5])[-3] for i in range(50)]
    np.testing.assert_array_equal(got, want)


def test_band_statistic_follows_the_channels_persistence():
    """The ratio band's sweep statistic decides as the channel does: per axis, k of the
    last n samples out of the band (a 6-sample excursion of one axis does not reach
    T = 1 with 10 of 20; a lasting one does, 10 samples in), in kept rows when the
    record is decimated; k = n = 1 is the per-sample deviation."""
    from types import SimpleNamespace

    def scenario(**params):
        return SimpleNamespace(step_s=1e-3, fmus={"diag": SimpleNamespace(
            parameters={"sample_period_s": 1e-3, **params})})

    t = np.arange(200) * 1e-3
    dev = np.full((200, 4), 0.01)          # 2 monitored parameters per axis
    dev[50:56, 1] = 0.1                    # x axis: 6 samples out
    dev[120:, 3] = 0.1                     # y axis: out for good from sample 120
    plain = _band_statistic(scenario(), "diag", t, dev, 2)
    np.testing.assert_array_equal(plain, dev.max(axis=1))
    held = _band_statistic(scenario(**{"dtg.persistence_k": 10, "dtg.persistence_n": 20}),
                           "diag", t, dev, 2)
    assert held[:120].max() == pytest.approx(0.01)      # the excursion is filtered
    assert np.flatnonzero(held > 0.05)[0] == 129         # the 10th sample out
    # kept every 5 samples: k = 2, n = 4 rows (the excursion's 2 kept rows then count as
    # 10 samples: approximate, as documented)
    kept = _band_statistic(scenario(**{"dtg.persistence_k": 10, "dtg.persistence_n": 20}),
                           "diag", t[::5], dev[::5], 2)
    assert np.flatnonzero(kept[20:] > 0.05)[0] + 20 == 25   # row 25 = sample 125


def test_judge_counts_false_alarms_before_onset_and_the_delay_after():
    t = np.arange(0, 10.01, 0.5)
    alarm = np.zeros_like(t, dtype=bool)
    alarm[[3, 4, 8, 15, 16]] = True          # 1.5-2.0 s, 4.0 s, 7.5-8.0 s
    det, delay, n_false, free = judge(t, alarm, t_ready=1.0, onset_s=7.0)
    assert (det, n_false) == (True, 2)
    assert delay == pytest.approx(0.5)
    assert free == pytest.approx(6.0)
    # nominal: the whole run after t_ready is fault-free, 3 rising edges
    assert judge(t, alarm, 1.0, None) == (False, None, 3, 9.0)


def test_summary_figures_from_synthetic_records():
    def rec(kind, ftype, mag, detected, delay, fa, free, injected, diagnosed):
        return {"status": "ok", "run": {"run_id": f"{ftype}{mag}{delay}{fa}", "kind": kind,
                                        "cls": "c", "channel": "df", "fault_type": ftype,
                                        "magnitude": mag, "injected": injected,
                                        "thresholds": [1.0, 2.0]},
                "detected": detected, "delay_s": delay, "false_alarms": fa,
                "fault_free_s": free, "diagnosed": diagnosed, "threshold_config": 1.0,
                "sweep": {"detected": [detected, False], "false_alarms": [fa, 0]},
                "sweep_mismatch": 0.0}
    records = [rec("fault", "bias", 0.1, True, 0.2, 0, 1800.0, "q", "q"),
               rec("fault", "bias", 0.1, False, None, 1, 1800.0, "q", "none"),
               rec("fault", "bias", 0.3, True, 0.4, 0, 0.0, "alpha", "q"),
               rec("nominal", None, None, False, None, 2, 3600.0, None, "none"),
               {"status": "timeout", "error": "timeout: killed", "run": {"run_id": "x"}}]
    records[3]["run"]["injected"] = None
    s = summarize(records, n_planned=6)
    assert (s["n_finished"], s["n_ok"], s["n_failed"], s["n_planned"]) == (5, 4, 1, 6)
    rows = {(r["fault_type"], r["magnitude"]): r for r in s["detection"]}
    assert rows[("bias", 0.1)]["rate"] == 0.5 and rows[("bias", 0.3)]["rate"] == 1.0
    assert rows[("bias", 0.1)]["isolated"] == 1 and rows[("bias", 0.1)]["isolation_rate"] == 0.5
    assert rows[("bias", 0.3)]["isolated"] == 0
    fa = s["false_alarms"]["df"]
    assert fa["count"] == 3 and fa["hours"] == pytest.approx(2.0)
    assert fa["rate_per_h"] == pytest.approx(1.5)
    assert fa["upper_95"] == pytest.approx(garwood_interval(3, 2.0)[1])
    assert s["delay"]["all df"]["median_s"] == pytest.approx(0.3)
    assert s["delay"]["all df"]["max_s"] == pytest.approx(0.4)
    c = s["confusion"]["df"]
    assert c["injected"] == ["alpha", "q"] and c["diagnosed"] == ["alpha", "none", "q"]
    assert c["matrix"] == [[0, 0, 1], [0, 1, 1]] and c["correct"] == 1
    sw = s["threshold_sweep"]["df"]
    assert sw["detection_rate"] == pytest.approx([2 / 3, 0.0])
    assert sw["false_alarms_per_h"] == pytest.approx([1.5, 0.0])
    md = markdown_summary(s, "t").splitlines()
    up = garwood_interval(3, 2.0)[1]
    assert f"| df | 3 in 2.00 h (≤ {up:.3g}) | 2 of 3 | 0.3 / 0.39 / 0.4 | 1 of 3 |" in md
    assert "| c | bias | 0.1 | 1 of 2 | 1 of 2 | – | – |" in md
    # a channel that types its faults (sequential detection filter) adds "typed right"
    for r, typed in zip(records[:3], ("bias", "ramp", "bias"), strict=True):
        r["typed"], r["expected_type"] = typed, "bias"
    md = markdown_summary(summarize(records, n_planned=6), "t").splitlines()
    assert "| c | bias | 0.1 | 1 of 2 | 1 of 2 | – | 1 of 2 |" in md
    assert "| 1 | 0.667 | 1.5 | " + f"{up:.3g} |" in md


def test_dtg_summary_counts_merged_classes_and_the_axis():
    """A sweep's ``accept`` labels count as right (classes merged where physics cannot tell
    them apart); the axis column compares dtg.fault_axis with the injected channel's axis
    (injector channels 1, 3 feed x; 2, 4 feed y)."""
    def rec(target, injected, diagnosed, axis, accepted=()):
        return {"status": "ok", "run": {"run_id": f"{target}{diagnosed}{axis}", "kind": "fault",
                                        "cls": "dtg", "channel": "dtg", "fault_type": injected,
                                        "magnitude": 0.1, "injected": injected,
                                        "accepted": list(accepted), "target": target,
                                        "thresholds": [1.0]},
                "detected": True, "delay_s": 0.1, "false_alarms": 0, "fault_free_s": 1.0,
                "diagnosed": diagnosed, "diagnosed_axis": axis, "threshold_config": 1.0,
                "sweep": {"detected": [True], "false_alarms": [0]}, "sweep_mismatch": 0.0}
    records = [rec(2, "uty_loss", "uty_noise", 2, accepted=["uty_noise"]),
               rec(2, "uty_loss", "uty_loss", 2, accepted=["uty_noise"]),
               rec(2, "uty_loss", "utx_noise", 1, accepted=["uty_noise"]),
               rec(3, "ux_drift", "ux_step", 1)]
    s = summarize(records)
    rows = {r["fault_type"]: r for r in s["detection"]}
    assert rows["uty_loss"]["isolated"] == 2 and rows["uty_loss"]["axis_right"] == 2
    assert rows["ux_drift"]["isolated"] == 0 and rows["ux_drift"]["axis_right"] == 1
    assert s["confusion"]["dtg"]["correct"] == 2
    md = markdown_summary(s, "t").splitlines()
    assert "| dtg | uty_loss | 0.1 | 3 of 3 | 2 of 3 | 2 of 3 | – |" in md


# --------------------------------------------------------------------------- expansion
def test_expansion_is_deterministic_and_applies_fault_seed_and_overrides(tmp_path):
    spec, base = load_campaign(SMOKE)
    runs = expand_runs(spec, base, tmp_path / "a")
    again = expand_runs(spec, base, tmp_path / "b")
    assert [r.run_id for r in runs] == [r.run_id for r in again]
    assert len(runs) == 6 and len({r.run_id for r in runs}) == 6
    assert [r.kind for r in runs].count("nominal") == 2
    assert len({r.seed for r in runs}) == 6
    bias = next(r for r in runs if r.fault_type == "bias" and r.magnitude == 0.2)
    sc = build_scenario(bias)
    (fault,) = sc.faults
    assert isinstance(fault, InjectorFault)
    assert (fault.type, fault.channel, fault.magnitude, fault.start_s) == ("bias", 3, 0.2, 3.0)
    assert sc.duration_s == 4.0 and sc.expect == []
    assert sc.fmus["aircraft"].parameters["seed"] == bias.seed
    assert sc.fmus["diag"].parameters["df.calibrate_s"] == 2.0
    assert sc.fmus["diag"].parameters["df.burn_in_s"] == 0.5
    nominal = next(r for r in runs if r.kind == "nominal")
    assert build_scenario(nominal).faults == []


def test_aircraft_campaign_has_dual_faults_both_couplings_and_40_nominal_hours(tmp_path):
    from gyrodiag_harness.campaigns.campaign import _df_sequential

    spec, base = load_campaign(ROOT / "campaigns" / "aircraft.toml")
    runs = expand_runs(spec, base, tmp_path)
    nominal_h = sum(r.duration_s - 8.0 for r in runs if r.kind == "nominal") / 3600.0
    assert nominal_h >= 40.0
    dual = [r for r in runs if r.also]
    assert {r.injected for r in dual} == {"alpha+q", "theta+gamma"}
    sc = build_scenario(next(r for r in dual if r.cls == "aircraft_jacobi"))
    assert sc.coupling == "jacobi"
    assert sorted((f.channel, f.type, f.magnitude) for f in sc.faults) == [
        (2, "bias", 0.005), (3, "bias", 0.005)]
    assert len({f.name for f in sc.faults}) == 2
    # the classes judge the Diagnoser's default, sequential decision
    assert _df_sequential(sc, "diag")
    assert not _df_sequential(build_scenario(expand_runs(*load_campaign(SMOKE))[0]), "diag")


def test_identical_sweep_entries_are_rejected():
    spec = fake_spec([0.7, 0.7])
    with pytest.raises(ValueError, match="identical"):
        expand_runs(spec, Path("/tmp"))


# --------------------------------------------------------------------------- execution
def test_raising_hanging_and_dying_runs_are_recorded_and_the_rest_complete(tmp_path):
    spec = fake_spec([0.7, 1.0, 2.0, 3.0, 0.9], timeout_s=4.0)
    out = run_campaign(spec, tmp_path, tmp_path / "out", workers=2, progress=False)
    assert out.n_total == out.n_executed == 5
    by_mag = {r["run"]["magnitude"]: r for r in out.records}
    assert by_mag[0.7]["status"] == by_mag[0.9]["status"] == "ok"
    assert by_mag[0.9]["delay_s"] == pytest.approx(0.1 / 0.9)
    assert by_mag[1.0]["status"] == "error"
    assert "ValueError: fake runner: magnitude 1 raises" in by_mag[1.0]["error"]
    assert by_mag[2.0]["status"] == "timeout" and "4 s" in by_mag[2.0]["error"]
    assert by_mag[3.0]["status"] == "error" and "exit status" in by_mag[3.0]["error"]
    assert sorted(out.failed) == sorted(by_mag[m]["run"]["run_id"] for m in (1.0, 2.0, 3.0))
    files = sorted((tmp_path / "out" / "runs").glob("*.json"))
    assert len(files) == 5
    s = summarize(out.records, out.n_total)
    assert s["n_failed"] == 3 and sum(r["n"] for r in s["detection"]) == 2


def test_resume_skips_finished_runs_and_leaves_their_records_untouched(tmp_path, monkeypatch):
    log = tmp_path / "log"
    log.mkdir()
    monkeypatch.setenv("GD_FAKE_LOG", str(log))
    spec = fake_spec([0.6, 0.7, 0.8], nominal_runs=3)
    out_dir = tmp_path / "out"
    first = run_campaign(spec, tmp_path, out_dir, workers=2, max_runs=2, progress=False)
    assert (first.n_total, first.n_executed, len(first.records)) == (6, 2, 2)
    files = {p: (p.stat().st_mtime_ns, p.read_bytes())
             for p in (out_dir / "runs").glob("*.json")}
    assert len(files) == 2
    second = run_campaign(spec, tmp_path, out_dir, workers=2, progress=False)
    assert (second.n_skipped, second.n_executed, len(second.records)) == (2, 4, 6)
    for p, (mtime, content) in files.items():
        assert p.stat().st_mtime_ns == mtime and p.read_bytes() == content
    executions = [p.name.split(".")[0] for p in log.iterdir()]
    assert sorted(executions) == sorted(r["run"]["run_id"] for r in second.records)
    third = run_campaign(spec, tmp_path, out_dir, workers=2, progress=False)
    assert (third.n_skipped, third.n_executed) == (6, 0)
    assert summarize(third.records, 6)["false_alarms"]["df"]["count"] == 3


def _alive(pid: int) -> bool:
    """pid runs (a zombie nobody reaps in a container counts as dead)."""
    try:
        status = Path(f"/proc/{pid}/status").read_text()
    except FileNotFoundError:
        return False
    return "\nState:\tZ" not in status


def _wait_for(predicate, timeout_s: float) -> bool:
    t_end = time.monotonic() + timeout_s
    while time.monotonic() < t_end:
        if predicate():
            return True
        time.sleep(0.1)
    return predicate()


DRIVER = """
import json, sys
sys.path.insert(0, {tests!r})
from gyrodiag_harness.campaigns.campaign import CampaignInterrupted, CampaignSpec, run_campaign
from pathlib import Path
spec = CampaignSpec.model_validate(json.loads({spec!r}))
try:
    run_campaign(spec, Path({tmp!r}), Path({out!r}), workers=2, progress=False, dask={dask!r})
except CampaignInterrupted as exc:
    print(exc, flush=True)
    sys.exit(130)
"""


@pytest.mark.skipif(not Path("/proc/self/status").is_file(), reason="needs /proc")
@pytest.mark.parametrize(("sig", "dask"), [(signal.SIGTERM, None), (signal.SIGKILL, None),
                                           (signal.SIGTERM, "local")])
def test_stopping_a_campaign_kills_its_runs_in_flight_and_keeps_finished_ones(
        tmp_path, sig, dask):
    """Two quick runs finish, two hang; the campaign process is stopped. SIGTERM: it
    says how many runs are saved and exits 130; SIGKILL: it just dies. Either way the
    hanging run processes (own sessions: no signal of the campaign reaches them) are
    gone within a few seconds, and the two finished records are intact. On Dask the
    runs die with their workers when the campaign closes its LocalCluster."""
    if dask:
        import distributed  # noqa: F401  (the test extra's; a missing one is an error)
    log = tmp_path / "log"
    log.mkdir()
    spec = fake_spec([0.6, 0.7, 2.0, 2.1], timeout_s=3600.0)
    hang = spec.model_dump(by_alias=True)
    script = DRIVER.format(tests=str(Path(__file__).parent), spec=json.dumps(hang),
                           tmp=str(tmp_path), out=str(tmp_path / "out"), dask=dask)
    run_tmp = tmp_path / "run_tmp"  # where the runs' temporary folders go
    run_tmp.mkdir()
    env = {**os.environ, "GD_FAKE_LOG": str(log), "TMPDIR": str(run_tmp)}
    proc = subprocess.Popen([sys.executable, "-c", script], env=env, cwd=str(ROOT),
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        assert _wait_for(lambda: len(list(log.iterdir())) == 4, 60.0), list(log.iterdir())
        assert _wait_for(lambda: len(list((tmp_path / "out" / "runs").glob("*.json"))) == 2,
                         30.0)
        pids = [int(p.suffix[1:]) for p in log.iterdir()]
        assert sum(_alive(pid) for pid in pids) == 2  # the hanging ones
        proc.send_signal(sig)
        out, err = proc.communicate(timeout=30)
    finally:
        if proc.poll() is None:
            proc.kill()
    if sig == signal.SIGTERM:
        assert proc.returncode == 130, err
        assert "2 of 4 runs are saved" in out and "resume" in out
    else:
        assert proc.returncode == -signal.SIGKILL
    # the poll period of the orphan watch (0.5 s), twice over for a killed worker
    assert _wait_for(lambda: not any(_alive(pid) for pid in pids), 10.0), \
        [pid for pid in pids if _alive(pid)]
    records = [json.loads(p.read_text()) for p in (tmp_path / "out" / "runs").glob("*")]
    assert sorted(r["run"]["magnitude"] for r in records) == [0.6, 0.7]
    assert all(r["status"] == "ok" for r in records)
    # nobody leaves the runs' temporary folders behind, not even a closed Dask cluster
    assert _wait_for(lambda: not list(run_tmp.glob(f"{RUN_TMP_PREFIX}*")), 10.0), \
        list(run_tmp.iterdir())


def test_smoke_campaign_pool_and_dask_give_the_same_figures(tmp_path, fmu_dir, monkeypatch):
    import distributed  # noqa: F401  (the test extra's; a missing one is an error)

    monkeypatch.setenv("GYRODIAG_FMU_DIR", str(fmu_dir))
    spec, base = load_campaign(SMOKE)
    pool = run_campaign(spec, base, tmp_path / "pool", workers=2, progress=False)
    dask = run_campaign(spec, base, tmp_path / "dask", workers=2, dask="local",
                        progress=False)
    assert pool.failed == [] and dask.failed == [], [r.get("error") for r in pool.records]
    s_pool, s_dask = summarize(pool.records, 6), summarize(dask.records, 6)
    assert json.dumps(s_pool, sort_keys=True) == json.dumps(s_dask, sort_keys=True)
    # what the figures say about the seed aircraft (calibration 0.5-2 s, 6 sigma, 3 of 5)
    assert s_pool["false_alarms"]["df"]["count"] == 0
    for r in pool.records:
        assert r["sweep_mismatch"] == 0.0  # offline statistic reproduces the FMU's alarm
        if r["run"]["kind"] == "fault":
            assert r["detected"] and 0 < r["delay_s"] < 0.5
            j = r["run"]["thresholds"].index(6.0)
            assert r["sweep"]["detected"][j] is True
            assert r["peak_after"] > 6.0 > r["peak_before"]
        if r["run"]["fault_type"] == "bias" and r["run"]["magnitude"] == 0.2:
            assert r["diagnosed"] == "q"
    sweep = s_pool["threshold_sweep"]["df"]
    assert all(np.diff(sweep["detection_rate"]) <= 0)
    assert not math.isnan(sweep["upper_95_per_h"][0])
    # the report writes figures and plots
    from gyrodiag_harness.cli import main

    assert main(["campaign", str(SMOKE), "--out", str(tmp_path / "pool"),
                 "--report-only"]) == 0
    assert (tmp_path / "pool" / "report.html").stat().st_size > 1000
    assert (tmp_path / "pool" / "threshold_sweep_df.png").is_file()
    assert os.path.getsize(tmp_path / "pool" / "summary.json") > 100
    assert "| df | 0 in " in (tmp_path / "pool" / "summary.md").read_text(encoding="utf-8")


def test_campaign_summary_pools_campaigns_and_counts_each_ones_runs(tmp_path):
    """`harness campaign-summary`: two campaigns (one stopped half way) as one summary:
    classes kept apart by campaign, a channel's false alarms pooled, the unfinished one
    counted as planned but not finished (exit 1); bad folders exit 2 naming them."""
    from gyrodiag_harness.cli.commands import main

    a = fake_spec([0.6, 0.7], nominal_runs=2)
    b = fake_spec([0.3, 0.8, 0.9], nominal_runs=3).model_copy(update={"name": "other"})
    run_campaign(a, tmp_path, tmp_path / "a", workers=2, progress=False)
    run_campaign(b, tmp_path, tmp_path / "b", workers=2, max_runs=4, progress=False)
    out = tmp_path / "all"
    assert main(["-q", "campaign-summary", str(tmp_path / "a"), str(tmp_path / "b"),
                 "--out", str(out)]) == 1  # b: 4 of 6 runs
    s = json.loads((out / "summary.json").read_text())
    rows = {c["campaign"]: c for c in s["campaigns"]}
    assert (rows["fake"]["n_finished"], rows["fake"]["n_planned"]) == (4, 4)
    assert (rows["other"]["n_finished"], rows["other"]["n_planned"]) == (4, 6)
    assert rows["fake"]["nominal_hours"] == pytest.approx(2 * 60 / 3600)
    walls = [json.loads(f.read_text())["wall_s"] for f in (tmp_path / "b" / "runs").glob("*.json")]
    assert rows["other"]["run_hours"] == pytest.approx(sum(walls) / 3600) and sum(walls) > 0
    assert (s["n_finished"], s["n_planned"]) == (8, 10)
    assert {r["class"] for r in s["detection"]} == {"fake/air", "other/air"}
    fa = s["false_alarms"]["df"]
    n_nominal = rows["fake"]["n_nominal_runs"] + rows["other"]["n_nominal_runs"]
    assert fa["count"] == n_nominal  # the fake runner: one false alarm per nominal run
    assert fa["hours"] == pytest.approx(8 * 60 / 3600)
    # ... and kept apart per campaign, which add up to the pooled row
    per = {name: rows[name]["false_alarms"]["df"] for name in ("fake", "other")}
    assert [per[n]["count"] for n in ("fake", "other")] == [
        rows["fake"]["n_nominal_runs"], rows["other"]["n_nominal_runs"]]
    assert per["fake"]["hours"] + per["other"]["hours"] == pytest.approx(fa["hours"])
    md = (out / "summary.md").read_text()
    assert f"| other | df | {per['other']['count']} (≤ " in md
    assert "| other | 4 / 6 |" in md and (out / "report.html").is_file()

    assert main(["-q", "campaign-summary", str(tmp_path / "a"), str(tmp_path / "nowhere"),
                 "--out", str(tmp_path / "x")]) == 2
    assert main(["-q", "campaign-summary", str(tmp_path / "a"), "--out",
                 str(tmp_path / "a")]) == 2  # would overwrite a's own summary
    assert main(["-q", "campaign-summary", str(tmp_path / "a"), str(tmp_path / "a"),
                 "--out", str(out)]) == 2  # the same campaign twice


def test_a_group_runs_alone_and_its_summary_says_so(tmp_path):
    """`--group`: only that flight condition group's runs (ids of the full campaign),
    recorded in campaign.json and named in campaign-summary's table; a bad name exits 2
    naming the spec's groups and writes nothing."""
    from gyrodiag_harness.cli.commands import main

    base = Path(__file__).resolve().parents[1] / "scenarios" / "system_pitch_gyro_nominal.toml"
    data = fake_spec([0.6, 0.7], nominal_runs=2).model_dump(by_alias=True)
    data["conditions"] = {"calm": {"group": "level"},
                          "rough": {"group": "manoeuvre",
                                    "parameters": {"aircraft": {"turbulence_sigma_w": 1.5}}}}
    for entry in data["sweeps"] + data["nominal"]:
        entry["conditions"] = ["calm", "rough"]
    spec = CampaignSpec.model_validate(data)
    everything = expand_runs(spec, tmp_path)
    assert len(everything) == 8
    out = run_campaign(spec, tmp_path, tmp_path / "level", workers=2, progress=False,
                       groups=["level"])
    calm = sorted(r.run_id for r in everything if r.condition == "calm")
    assert sorted(r["run"]["run_id"] for r in out.records) == calm and out.n_total == 4
    saved = json.loads((tmp_path / "level" / "campaign.json").read_text())
    assert saved["selection"] == {"groups": ["level"], "conditions": None}
    assert main(["-q", "campaign-summary", str(tmp_path / "level"),
                 "--out", str(tmp_path / "all")]) == 0  # 4 of the 4 selected
    assert "| fake | 4 / 4 (groups level) |" in (tmp_path / "all" / "summary.md").read_text()
    toml = tmp_path / "spec.toml"
    toml.write_text('name = "fake"\nrunner = "_campaign_fake_runner:fake"\n'
                    f'[classes.air]\nscenario = "{base.as_posix()}"\nchannel = "df"\n'
                    '[conditions.calm]\ngroup = "level"\n'
                    '[[sweeps]]\nclass = "air"\ntype = "bias"\nmagnitudes = [0.6]\n'
                    'onsets_s = [1.0]\nchannels = [3]\nconditions = ["calm"]\n',
                    encoding="utf-8")
    assert main(["-q", "campaign", str(toml), "--group", "cruise", "--out",
                 str(tmp_path / "bad"), "--no-progress"]) == 2
    assert not (tmp_path / "bad").exists()


@pytest.mark.skipif(not Path("/proc/self/autogroup").is_file(),
                    reason="needs Linux scheduler autogroups")
def test_run_processes_keep_the_campaigns_niceness_in_their_own_session(tmp_path):
    """A campaign started with `nice -n 7`: each run process (a session, so an autogroup,
    of its own) gives its autogroup nice 7, else `nice` would not lower its CPU share."""
    log = tmp_path / "log"
    log.mkdir()
    script = DRIVER.format(tests=str(Path(__file__).parent),
                           spec=json.dumps(fake_spec([0.6, 0.7]).model_dump(by_alias=True)),
                           tmp=str(tmp_path), out=str(tmp_path / "out"), dask=None)
    env = {**os.environ, "GD_FAKE_LOG": str(log)}
    done = subprocess.run(["nice", "-n", "7", sys.executable, "-c", script], env=env,
                          cwd=str(ROOT), capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    groups = [p.read_text().split() for p in log.iterdir()]
    assert len(groups) == 2
    want = str(min(os.nice(0) + 7, 19))  # `nice -n 7` adds to this process's own
    assert all(g[-2:] == ["nice", want] for g in groups), groups
    # A process in the root group reads an empty file (the kernel prints autogroups
    # only): then the run processes' named groups are their own by construction.
    mine = Path("/proc/self/autogroup").read_text().split()[:1]
    assert all(g[:1] != mine for g in groups)  # their own groups, not this session's


def test_every_shipped_campaign_learns_the_libraries_its_scenarios_read():
    """A base scenario (or witness copy) that reads ``${out}/NAME`` needs the spec to
    learn NAME first (``signatures_file`` with ``signatures_training``, or
    ``libraries``): campaigns/system.toml did not, and all 304 runs failed."""
    from gyrodiag_harness.cosim.scenario import load_scenario

    for path in sorted((ROOT / "campaigns").glob("*.toml")):
        spec, base = load_campaign(path)
        learned = set(spec.libraries)
        if spec.signatures_training is not None:
            learned.add(spec.signatures_file)
        for name, c in spec.classes.items():
            sc = load_scenario(base / c.scenario)
            files = [v for inst in sc.fmus.values() for v in inst.files.values()]
            files += [v for w in c.witness_copies.values() for v in w.files.values()]
            for value in files:
                if str(value).startswith("${out}/"):
                    assert str(value)[len("${out}/"):] in learned, (path.name, name, value)


def test_a_campaign_whose_chain_cannot_start_stops_before_any_run(tmp_path):
    from gyrodiag_harness.cosim.scenario import ScenarioError

    spec, base = load_campaign(ROOT / "campaigns" / "dtg.toml")
    spec = spec.model_copy(update={"signatures_training": None})  # the library is missing
    with pytest.raises(ScenarioError, match=r"dtg\.signature_file: dtg_patterns\.json not "
                                            r"found"):
        run_campaign(spec, base, tmp_path, workers=1, progress=False)
    assert not list((tmp_path / "runs").glob("*.json"))


def test_the_fmu_folder_of_a_campaign_follows_the_scenario_precedence(tmp_path, monkeypatch):
    """--fmu-dir, then $GYRODIAG_FMU_DIR, then the spec's fmu_dir (relative to the spec),
    then each scenario's own; the run ids do not depend on it (a resume on the build a
    campaign started with). campaigns/hrg.toml's fmu_dir hid the variable before."""
    from gyrodiag_harness.campaigns.campaign import campaign_fmu_dir

    spec, base = load_campaign(SMOKE)
    monkeypatch.delenv("GYRODIAG_FMU_DIR", raising=False)
    assert campaign_fmu_dir(spec, base) is None
    with_dir = spec.model_copy(update={"fmu_dir": "../somewhere"})
    assert campaign_fmu_dir(with_dir, base) == str((base / "../somewhere").resolve())
    monkeypatch.setenv("GYRODIAG_FMU_DIR", str(tmp_path / "env"))
    assert campaign_fmu_dir(with_dir, base) == str(tmp_path / "env")
    assert campaign_fmu_dir(with_dir, base, tmp_path / "cli") == str(tmp_path / "cli")
    ids = [r.run_id for r in expand_runs(with_dir, base, tmp_path)]
    runs = expand_runs(with_dir, base, tmp_path, fmu_dir=tmp_path / "cli")
    assert [r.run_id for r in runs] == ids
    assert {r.fmu_dir for r in runs} == {str(tmp_path / "cli")}


def test_campaign_command_names_a_missing_fmu_folder(tmp_path, capsys):
    from gyrodiag_harness.cli.commands import main

    missing = tmp_path / "no_fmus"
    assert main(["campaign", str(SMOKE), "--out", str(tmp_path / "out"), "--fmu-dir",
                 str(missing), "--no-progress"]) == 2
    assert str(missing) in capsys.readouterr().err
    assert not (tmp_path / "out" / "runs").exists() or not list(
        (tmp_path / "out" / "runs").glob("*.json"))


def test_the_judged_rule_reads_a_readout_model_given_as_a_file():
    """``df.sensor_dynamics_file`` in the instance's ``files`` (a path the harness
    resolves) makes the auto rule the paper's, as in the Diagnoser."""
    from gyrodiag_harness.campaigns.campaign import _df_sequential

    sc = build_scenario(expand_runs(*load_campaign(ROOT / "campaigns" / "aircraft.toml"))[0])
    assert _df_sequential(sc, "diag")
    diag = sc.fmus["diag"]
    with_file = diag.model_copy(update={"files": {**diag.files,
                                                  "df.sensor_dynamics_file": "readout.json"}})
    sc = sc.model_copy(update={"fmus": {**sc.fmus, "diag": with_file}})
    assert not _df_sequential(sc, "diag")


def test_a_spec_naming_an_unknown_instance_stops_with_its_class_named(tmp_path):
    from gyrodiag_harness.cosim.scenario import ScenarioError

    spec, base = load_campaign(SMOKE)
    cls = spec.classes["aircraft"].model_copy(update={"parameters": {"nope": {"x": 1.0}}})
    spec = spec.model_copy(update={"classes": {"aircraft": cls}})
    with pytest.raises(ScenarioError, match=r"class aircraft: parameters: no instance 'nope'"):
        run_campaign(spec, base, tmp_path, workers=1, progress=False)
    assert not list((tmp_path / "runs").glob("*.json"))
