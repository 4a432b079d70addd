"""Side by side (issue 16) on the df and dtg channels: two decision rules, one run.

* a class lists ``witnesses``; ``witness_copies`` adds a copy of the Diagnoser with the
  paper's settings and the same input connections, so both rules see the same signals;
* each witness is judged with its own rule (df: the paper's any-main-residual alarm
  against the sequential ``df.detected``; dtg: the paper's ratio band and decade code
  against the pattern classifier), with its own threshold grid;
* the seeds do not change when a witness is added, and the project's witness gives the
  same record as the single-Diagnoser run;
* the summary splits each record per rule: every table has a row per rule.

Tiny campaigns of real FMUs (build/fmus): aircraft closed loop (100 Hz, 11 s runs) and
the DTG chain (1 kHz, 7.5 s runs).
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import pytest
from pydantic import ValidationError

from gyrodiag_harness.campaigns.campaign import (
    CampaignSpec,
    build_scenario,
    expand_runs,
    load_campaign,
    run_campaign,
)
from gyrodiag_harness.campaigns.campaign_report import markdown_summary, summarize

ROOT = Path(__file__).resolve().parents[1]
# where the session fixture ``fmu_dir`` builds the FMUs (request it before running them)
FMUS = Path(os.environ.get("GYRODIAG_FMU_DIR", ROOT / "build" / "fmus")).resolve()
AIRCRAFT = ROOT / "scenarios" / "aircraft_alpha_small_bias.toml"
DTG = ROOT / "scenarios" / "dtg_fault_utx_step_s1.toml"
PAPER_DF_GRID = [3.0, 6.0, 9.0]


def df_spec(witnesses: bool = True, magnitudes=(0.002, 0.05)) -> CampaignSpec:
    cls = {"scenario": str(AIRCRAFT), "channel": "df", "seed_parameters": ["aircraft.seed"],
           "thresholds": [0.5, 1.0]}
    if witnesses:
        cls.update(witnesses=["diag", "paper"],
                   witness_copies={"paper": {"parameters": {"df.decision": 0},
                                             "thresholds": PAPER_DF_GRID}})
    # alpha biases of 2 sigma and 50 sigma from 8.5 s (calibration ends at 8 s), judged 3 s
    # after (the gust model takes about 1 s to isolate a 2 sigma alpha bias in calm air)
    return CampaignSpec.model_validate({
        "name": "side_df", "base_seed": 7, "fmu_dir": str(FMUS), "classes": {"air": cls},
        "sweeps": [{"class": "air", "type": "bias", "magnitudes": list(magnitudes),
                    "onsets_s": [8.5], "channels": [2], "post_onset_s": 3.0}]})


def test_expansion_keeps_the_seeds_and_the_copy_gets_the_same_inputs():
    with_, without = expand_runs(df_spec(), ROOT), expand_runs(df_spec(False), ROOT)
    assert [r.seed for r in with_] == [r.seed for r in without]
    assert not {r.run_id for r in with_} & {r.run_id for r in without}
    run = with_[0]
    assert run.witnesses == ["diag", "paper"] and list(run.witness_copies) == ["paper"]
    scenario = build_scenario(run)
    paper, diag = scenario.fmus["paper"], scenario.fmus["diag"]
    assert paper.parameters["df.decision"] == 0 and "df.decision" not in diag.parameters
    assert paper.parameters["df.calibrate_s"] == diag.parameters["df.calibrate_s"] == 8.0
    inputs = {c.to.partition(".")[2]: c.from_ for c in scenario.connections
              if c.to.startswith("diag.")}
    copied = {c.to.partition(".")[2]: c.from_ for c in scenario.connections
              if c.to.startswith("paper.")}
    assert len(inputs) == 8 and copied == inputs
    assert {"paper.df.alarm[6]", "diag.df.detected"} <= set(scenario.record.variables)


def test_witness_options_are_checked():
    base = {"scenario": str(AIRCRAFT), "channel": "df"}
    with pytest.raises(ValidationError, match="not among the witnesses"):
        CampaignSpec.model_validate({"name": "x", "classes": {"a": {
            **base, "witness_copies": {"paper": {}}}}})
    with pytest.raises(ValidationError, match="is the instance copied"):
        CampaignSpec.model_validate({"name": "x", "classes": {"a": {
            **base, "witnesses": ["diag"], "witness_copies": {"diag": {}}}}})
    with pytest.raises(ValidationError, match="only the grey, df, dtg"):
        CampaignSpec.model_validate({"name": "x", "classes": {"a": {
            **base, "channel": "system", "witnesses": ["diag"]}}})


@pytest.fixture(scope="module")
def df_campaign(tmp_path_factory, fmu_dir):
    assert fmu_dir == FMUS  # built (or rebuilt when stale) by the session fixture
    out = tmp_path_factory.mktemp("side_df")
    both = run_campaign(df_spec(), ROOT, out, workers=2, progress=False)
    assert not both.failed, [r.get("error") for r in both.records]
    return both.records


def test_df_each_rule_is_judged_on_its_own_alarm(df_campaign):
    records = df_campaign
    by_mag = {r["run"]["magnitude"]: r["witnesses"] for r in records}
    small, large = by_mag[0.002], by_mag[0.05]
    # 2 sigma: the CUSUM sees it and names it; 6 sigma with 3-of-5 never does
    assert small["diag"]["detected"] and small["diag"]["diagnosed"] == "alpha"
    assert small["diag"]["typed"] == "bias"
    assert not small["paper"]["detected"] and small["paper"]["diagnosed"] == "none"
    assert "typed" not in small["paper"]  # the paper's rule does not type faults
    # 50 sigma: both, and the paper's isolation names alpha from its own outputs
    assert large["paper"]["detected"] and large["paper"]["diagnosed"] == "alpha"
    assert 0.0 <= large["paper"]["delay_s"] <= 0.1
    for w in (small, large):
        # the paper's alarm is rebuilt exactly from its own residuals, on its own grid
        assert w["paper"]["sweep_mismatch"] == 0.0
        assert w["paper"]["thresholds"] == PAPER_DF_GRID
        assert w["paper"]["threshold_config"] == 6.0
        assert w["paper"]["sweep"]["detected"][1] == w["paper"]["detected"]
        assert w["diag"]["thresholds"] == [0.5, 1.0]
    # at 3 sigma the paper's rule would have seen the 2 sigma bias
    assert small["paper"]["sweep"]["detected"][0]


def test_df_the_copy_leaves_the_projects_rule_as_it_was(df_campaign, tmp_path):
    """The project's rule alone on the 2 sigma run (same seed): the same record."""
    alone = run_campaign(df_spec(False, magnitudes=(0.002,)), ROOT, tmp_path, workers=1,
                         progress=False)
    assert not alone.failed, alone.records[0].get("error")
    (solo,) = alone.records
    (small,) = [r["witnesses"]["diag"] for r in df_campaign if r["run"]["magnitude"] == 0.002]
    for key in ("detected", "delay_s", "false_alarms", "fault_free_s", "diagnosed", "typed",
                "size", "episodes", "sweep", "peak_before", "peak_after"):
        assert small[key] == solo[key], key


def test_df_paper_sweep_is_exact_under_jacobi_coupling(tmp_path, fmu_dir):
    """Jacobi: the channel aligns y one step after u, so the recorded calibration
    residuals are not the ones it calibrated on; the sweep uses its own statistic."""
    jacobi = ROOT / "scenarios" / "aircraft_dual_bias_jacobi.toml"
    spec = df_spec(magnitudes=(0.005,)).model_dump(by_alias=True)
    spec["classes"]["air"]["scenario"] = str(jacobi)
    outcome = run_campaign(CampaignSpec.model_validate(spec), ROOT, tmp_path, workers=1,
                           progress=False)
    assert not outcome.failed, outcome.records[0].get("error")
    (record,) = outcome.records
    paper, diag = record["witnesses"]["paper"], record["witnesses"]["diag"]
    assert diag["input_delay"] == 1                      # the alignment Jacobi needs
    assert paper["detected"] and paper["diagnosed"] == "alpha"
    assert paper["sweep_mismatch"] == 0.0
    det = paper["sweep"]["detected"]
    assert det[:2] == [True, True]           # 3 sigma and its own 6 sigma
    assert det[2] == (paper["peak_after"] > 9.0)
    assert paper["peak_after"] > 6.0 > paper["peak_before"]


def test_df_summary_has_a_row_per_rule_in_every_table(df_campaign):
    records = df_campaign
    s = summarize(records)
    assert s["n_fault_runs"] == 2  # runs, not rules
    assert set(s["false_alarms"]) == {"df/diag", "df/paper"}
    assert set(s["confusion"]) == {"df/diag", "df/paper"}
    assert s["confusion"]["df/diag"]["correct"] == 2
    assert s["confusion"]["df/paper"]["correct"] == 1
    rows = {(r["class"], r["magnitude"]): r for r in s["detection"]}
    assert rows[("air/diag", 0.002)]["detected"] == 1
    assert rows[("air/paper", 0.002)]["detected"] == 0
    assert rows[("air/diag", 0.002)]["typed"] == 1 and "typed" not in rows[("air/paper", 0.05)]
    assert {"all df/diag", "all df/paper"} <= set(s["delay"])
    assert s["delay"]["all df/paper"]["n"] == 1 and s["delay"]["all df/diag"]["n"] == 2
    assert s["threshold_sweep"]["df/paper"]["thresholds"] == PAPER_DF_GRID
    assert s["threshold_sweep"]["df/paper"]["detection_rate"] == [1.0, 0.5, 0.5]
    assert s["threshold_sweep"]["df/diag"]["thresholds"] == [0.5, 1.0]
    assert not s["witnesses"] and not s["grey"]  # no system or grey section
    md = markdown_summary(s)
    assert "| df/paper |" in md and "| air/paper | bias | 0.002 | 0 of 1 |" in md


# ------------------------------------------------------------------------------- DTG
#: Decade signatures of the paper's four classes (as learned from scenarios/training).
DECADES = {"utx_step": [0, 0, -2, -2, 0], "utx_noise": [0, 0, -3, -3, 0],
           "utx_loss": [0, 0, -1, -1, -1], "ux_drift": [0, 0, 0, 0, -1]}


@pytest.fixture(scope="module")
def dtg_campaign(tmp_path_factory, fmu_dir):
    assert fmu_dir == FMUS  # built (or rebuilt when stale) by the session fixture
    out = tmp_path_factory.mktemp("side_dtg")
    (out / "dtg_signatures.json").write_text(json.dumps({"signatures": DECADES}))
    # the base Diagnoser "diag" has the paper's rule; "pattern" is the project's
    # classifier with no library file: the Diagnoser's shipped one
    spec = CampaignSpec.model_validate({
        "name": "side_dtg", "base_seed": 3, "fmu_dir": str(FMUS), "results_dir": str(out),
        "classes": {"dtg": {
            "scenario": str(DTG), "channel": "dtg",
            "seed_parameters": ["dtg.seed", "injector.seed"],
            "witnesses": ["diag", "pattern"],
            "witness_copies": {"pattern": {"parameters": {
                "dtg.classifier": "pattern", "dtg.signature_file": ""},
                "thresholds": [1.0, 3.0]}}}},
        "sweeps": [{"class": "dtg", "type": "step", "label": "utx_step", "magnitudes": [1.0],
                    "onsets_s": [6.0], "channels": [1], "post_onset_s": 1.5}]})
    outcome = run_campaign(spec, ROOT, out / "camp", workers=1, progress=False)
    assert not outcome.failed, [r.get("error") for r in outcome.records]
    return outcome.records


def test_dtg_each_rule_reads_its_own_class(dtg_campaign):
    (record,) = dtg_campaign
    paper, pattern = record["witnesses"]["diag"], record["witnesses"]["pattern"]
    assert paper["detected"] and pattern["detected"]
    assert paper["diagnosed"] == "utx_step"      # nearest decade signature
    assert paper["diagnosed_axis"] is None       # the paper's codes name no axis
    assert pattern["diagnosed"] == "utx_step"    # the shipped library's class 1
    assert pattern["diagnosed_axis"] == 1
    assert paper["threshold_config"] == 0.5 and paper["sweep_mismatch"] == 0.0
    assert pattern["threshold_config"] == 1.0 and pattern["thresholds"] == [1.0, 3.0]
    assert paper["thresholds"] == [0.05, 0.1, 0.15, 0.2, 0.25, 0.3, 0.4, 0.5, 0.6, 0.8]
    assert paper["t_ready_s"] == pytest.approx(5.0, abs=0.01)
    s = summarize(dtg_campaign)
    assert s["confusion"]["dtg/diag"]["correct"] == 1
    assert s["confusion"]["dtg/pattern"]["correct"] == 1
    assert s["confusion"]["dtg/pattern"]["diagnosed"] == ["utx_step"]


def test_shipped_campaigns_carry_the_paper_witness():
    for name, rule in (("aircraft", {"df.decision": 0, "df.isolation_window_s": 0.0}),
                       ("dtg", {"dtg.classifier": "paper", "dtg.low": 0.5,
                                "dtg.high": 1.5})):
        spec, _ = load_campaign(ROOT / "campaigns" / f"{name}.toml")
        for c in spec.classes.values():
            assert c.witnesses == ["diag", "paper"]
            assert c.witness_copies["paper"].parameters == rule
    spec, _ = load_campaign(ROOT / "campaigns" / "dtg.toml")
    assert spec.libraries == {"dtg_signatures.json": "../scenarios/training"}
    assert spec.signatures_file == "dtg_patterns.json"


def test_system_paper_campaign_flies_the_system_campaigns_conditions():
    """campaigns/system_paper.toml: the paper's DTG rule (band 0.5/1.5, no case rate,
    decade signatures) beside the project's on the system chain, under every condition of
    campaigns/system.toml (the same flights), the detection filter off in both."""
    spec, _ = load_campaign(ROOT / "campaigns" / "system_paper.toml")
    system, _ = load_campaign(ROOT / "campaigns" / "system.toml")
    assert spec.conditions == system.conditions
    assert spec.libraries == {"dtg_signatures.json": "../scenarios/training"}
    for c in spec.classes.values():
        assert c.channel == "dtg" and c.witnesses == ["diag", "paper"]
        assert c.parameters == {"diag": {"df.enabled": False}}
        paper = c.witness_copies["paper"].parameters
        assert paper["dtg.classifier"] == "paper" and paper["dtg.case_rate"] == 0
        assert (paper["dtg.low"], paper["dtg.high"]) == (0.5, 1.5)
        assert paper["df.enabled"] is False
    runs = expand_runs(spec, ROOT / "campaigns")
    assert len(runs) == 98
    assert {r.condition for r in runs} == set(system.conditions)
