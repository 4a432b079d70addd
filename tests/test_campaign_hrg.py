"""Grey (HRG) campaigns: two decision rules judged side by side on one run.

* a grey class judges every Diagnoser in ``witnesses`` on its own ``grey.alarm`` from its
  own first ready sample; the summary splits each record per rule;
* the paper's fixed-threshold rule is replayed for the threshold sweep, and the replay
  at its own threshold reproduces the FMU's alarm exactly;
* ``condition_seeds = "disjoint"`` gives every condition (noise level) its own seeds;
* the grey channel names no fault kind: isolation is "n/a", there is no confusion matrix.

The tiny campaign runs real FMUs (build/fmus): three short runs of the seed-001 HRG chain.
"""

from __future__ import annotations

from pathlib import Path

import pytest
from pydantic import ValidationError

from gyrodiag_harness.campaigns.campaign import (
    CampaignSpec,
    expand_runs,
    load_campaign,
    run_campaign,
)
from gyrodiag_harness.campaigns.campaign_report import markdown_summary, summarize

ROOT = Path(__file__).resolve().parents[1]
BASE = ROOT / "scenarios" / "hrg_seed001_noise20mv.toml"
PERIOD_S = 0.5  # the seed scenario's sample period


def spec(**extra) -> CampaignSpec:
    data = {
        "name": "hrg_tiny",
        "base_seed": 16,
        "classes": {"hrg": {"scenario": str(BASE), "channel": "grey",
                            "diagnoser": "calibrated", "injector": "inj_bias",
                            "witnesses": ["paper", "calibrated"],
                            "seed_parameters": ["hrg.seed"],
                            "condition_seeds": "disjoint",
                            "thresholds": [0.5, 1.0, 2.0, 20.0]}},
        "conditions": {"quiet": {"group": "0 mV",
                                 "parameters": {"hrg": {"noise_std": 0.0}}},
                       "noisy": {"group": "20 mV",
                                 "parameters": {"hrg": {"noise_std": 0.02}}}},
        # 0.5 V: ten times the paper's threshold, ~25 sigma of the calibrated one
        "sweeps": [{"class": "hrg", "type": "bias", "magnitudes": [-0.5], "onsets_s": [30.0],
                    "channels": [1], "post_onset_s": 5.0, "conditions": ["quiet"]}],
        "nominal": [{"class": "hrg", "duration_s": 40.0, "runs": 1,
                     "conditions": ["quiet", "noisy"]}],
    }
    data.update(extra)
    return CampaignSpec.model_validate(data)


def test_disjoint_condition_seeds_and_witnesses_in_the_run() -> None:
    runs = expand_runs(spec(), ROOT)
    assert len(runs) == 3
    assert len({r.seed for r in runs}) == 3
    nominal = {r.condition: r for r in runs if r.kind == "nominal"}
    assert nominal["quiet"].seed != nominal["noisy"].seed
    assert all(r.witnesses == ["paper", "calibrated"] and r.channel == "grey" for r in runs)
    fault = next(r for r in runs if r.kind == "fault")
    assert fault.injected == "bias" and fault.duration_s == 35.0
    # paired (the default): one seed for the same run under both conditions
    paired = spec(classes={"hrg": {"scenario": str(BASE), "channel": "grey",
                                   "witnesses": ["paper"]}})
    seeds = {r.condition: r.seed for r in expand_runs(paired, ROOT) if r.kind == "nominal"}
    assert seeds["quiet"] == seeds["noisy"]


def test_shipped_hrg_campaign_covers_issue_16() -> None:
    """campaigns/hrg.toml: 5 noise levels, >= 3 onsets, >= 10 nominal hours, own seeds."""
    spec_, base = load_campaign(ROOT / "campaigns" / "hrg.toml")
    runs = expand_runs(spec_, base)
    assert len(runs) == 640 and len({r.seed for r in runs}) == 640
    assert not {r.seed for r in runs} & set(range(1, 53))  # the benchmark seeds
    noise = {r.parameters["hrg"]["noise_std"] for r in runs}
    assert noise == {0.0, 0.005, 0.01, 0.015, 0.02}
    fault = [r for r in runs if r.kind == "fault"]
    assert {r.fault_type for r in fault} == {"bias", "stuck", "scale", "failure"}
    assert len({r.onset_s for r in fault}) >= 3
    nominal_h = sum(r.duration_s for r in runs if r.kind == "nominal") / 3600.0
    assert nominal_h >= 10.0
    assert all(r.witnesses == ["paper", "calibrated"] for r in runs)


def test_witnesses_only_for_the_grey_df_and_dtg_channels() -> None:
    # df and dtg judge witnesses too (tests/test_campaign_sidebyside.py); system runs
    # have their own two witnesses in one Diagnoser
    with pytest.raises(ValidationError, match="only the grey, df, dtg channels"):
        spec(classes={"hrg": {"scenario": str(BASE), "channel": "system",
                              "witnesses": ["paper"]}})
    with pytest.raises(ValidationError, match="names an instance twice"):
        spec(classes={"hrg": {"scenario": str(BASE), "channel": "grey",
                              "witnesses": ["paper", "paper"]}})


def test_tiny_hrg_campaign(tmp_path: Path, fmu_dir: Path) -> None:
    # the session fixture builds the FMUs when they are missing or stale (a skip here
    # would never run on a fresh CI clone)
    outcome = run_campaign(spec(fmu_dir=str(fmu_dir)), ROOT, tmp_path, workers=2,
                           progress=False)
    assert outcome.failed == [] and outcome.n_executed == 3
    recs = {(r["run"]["kind"], r["run"]["condition"]): r for r in outcome.records}

    fault = recs[("fault", "quiet")]["witnesses"]
    for rule in ("paper", "calibrated"):
        w = fault[rule]
        assert w["detected"] and 0.0 < w["delay_s"] <= PERIOD_S  # the next sample
        assert w["false_alarms"] == 0 and not w["alarm_at_onset"]
    # the paper's rule is ready after its 10-sample window, the calibrated one after
    # learning sigma_e (5-25 s)
    assert fault["paper"]["t_ready_s"] == pytest.approx(5.5)
    assert 25.0 <= fault["calibrated"]["t_ready_s"] <= 26.0
    assert fault["paper"]["fault_free_s"] == pytest.approx(30.0 - 5.5)
    # the replay of the paper's rule at its own threshold is the FMU's alarm
    assert fault["paper"]["sweep_replayed"] and fault["paper"]["sweep_mismatch"] == 0.0
    assert not fault["calibrated"]["sweep_replayed"]
    # 0.5 V is 10x the paper's 0.05 V: found up to 2x, missed at 20x
    assert fault["paper"]["sweep"]["detected"] == [True, True, True, False]

    quiet = recs[("nominal", "quiet")]["witnesses"]
    assert quiet["paper"]["false_alarms"] == 0 and quiet["calibrated"]["false_alarms"] == 0
    assert quiet["paper"]["fault_free_s"] == pytest.approx(40.0 - 5.5)
    noisy = recs[("nominal", "noisy")]["witnesses"]
    # 20 mV rms: the one-step error of the paper's predictor is ~32 mV rms, so |e| > 50 mV
    # happens every few samples; the calibrated rule learned the noise and stays quiet
    assert noisy["paper"]["false_alarms"] >= 1
    assert noisy["calibrated"]["false_alarms"] == 0
    assert noisy["paper"]["sweep_mismatch"] == 0.0
    assert noisy["paper"]["sweep"]["false_alarms"][1] == noisy["paper"]["false_alarms"]

    summary = summarize(outcome.records, outcome.n_total)
    assert summary["n_fault_runs"] == 1 and summary["n_nominal_runs"] == 2
    assert summary["confusion"] == {}  # no fault kind named: nothing to confuse
    grey = summary["grey"]
    assert grey["rules"] == ["paper", "calibrated"] and grey["groups"] == ["0 mV", "20 mV"]
    rows = {(r["rule"], r["group"]): r for r in grey["detection"]}
    assert set(rows) == {("paper", "0 mV"), ("calibrated", "0 mV")}
    for row in rows.values():
        assert (row["n"], row["detected"], row["within_target"], row["standing"]) == (1, 1, 1, 0)
        assert row["delay"]["max_s"] == row["delay"]["median_s"] <= PERIOD_S
    fa = grey["false_alarms"]
    assert fa["calibrated/all"]["count"] == 0
    assert fa["paper/20 mV"]["count"] == noisy["paper"]["false_alarms"]
    assert fa["paper/0 mV"]["count"] == 0
    hours = (30.0 - 5.5 + 40.0 - 5.5) / 3600.0
    assert fa["paper/0 mV"]["hours"] == pytest.approx(hours)
    assert fa["paper/0 mV"]["upper_95"] == pytest.approx(3.6889 / hours, rel=1e-3)
    det = {r["class"]: r for r in summary["detection"]}
    assert det["hrg/paper"]["isolated"] is None and det["hrg/calibrated"]["detected"] == 1
    md = markdown_summary(summary, "hrg_tiny")
    assert "| grey/paper |" in md and "n/a (names no fault kind)" in md
    assert "Grey channel, rule calibrated" in md
    assert "| bias | -0.5 | 1/1 (1) · 0.5 / 0.5 / 0.5 | – |" in md
