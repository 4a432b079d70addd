"""System campaigns (gyrodiag_harness.campaigns): flight conditions, physical faults, two witnesses.

* conditions multiply sweeps and nominal runs, fly the same seed under every condition
  (a paired comparison), merge their manoeuvres and parameter overrides into the run,
  and leave the ids of runs without conditions as they were;
* a physical-fault sweep (``set``) becomes a ``[[faults]]`` entry with ``set``/``value``;
* a system run is judged per witness (each from its own readiness) and for "either";
* the summary compares each group's detection rate with level flight in points and
  counts false alarms per witness and group.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from pydantic import ValidationError

from gyrodiag_harness.campaigns.campaign import (
    CampaignSpec,
    RunSpec,
    _judge_system,
    build_scenario,
    expand_runs,
    select,
)
from gyrodiag_harness.campaigns.campaign_report import markdown_summary, summarize

ROOT = Path(__file__).resolve().parents[1]
BASE = ROOT / "scenarios" / "system_pitch_gyro_nominal.toml"

SQUARE = {"name": "m", "kind": "square_wave", "instance": "controller", "start_s": 12.0,
          "amplitude_rad": 0.05, "period_s": 8.0}


def spec(**extra) -> CampaignSpec:
    data = {
        "name": "sys",
        "classes": {"system": {"scenario": str(BASE), "channel": "system",
                               "diagnoser": "diag_fine", "seed_parameters": ["aircraft.seed"]},
                    "air": {"scenario": str(BASE), "channel": "df", "diagnoser": "diag_df"}},
        "conditions": {
            "level": {"group": "level"},
            "square": {"group": "manoeuvre", "manoeuvres": [SQUARE]},
            "rough": {"group": "manoeuvre", "manoeuvres": [SQUARE],
                      "parameters": {"aircraft": {"turbulence_sigma_w": 1.5}}},
        },
        "sweeps": [
            {"class": "system", "set": "dtg.spin_fraction", "label": "spin",
             "magnitudes": [0.9], "onsets_s": [20.0], "seeds": 2,
             "conditions": ["level", "square", "rough"]},
            {"class": "air", "type": "bias", "magnitudes": [0.01], "onsets_s": [20.0],
             "channels": [2]},
        ],
        "nominal": [{"class": "system", "duration_s": 60.0, "runs": 2,
                     "conditions": ["square"]}],
    }
    data.update(extra)
    return CampaignSpec.model_validate(data)


def test_conditions_multiply_runs_with_paired_seeds() -> None:
    runs = expand_runs(spec(), ROOT)
    spin = [r for r in runs if r.fault_type == "spin"]
    assert len(spin) == 6 and len({r.run_id for r in spin}) == 6
    by_cond = {c: sorted(r.seed for r in spin if r.condition == c)
               for c in ("level", "square", "rough")}
    assert by_cond["level"] == by_cond["square"] == by_cond["rough"]  # paired
    assert len(set(by_cond["level"])) == 2
    rough = next(r for r in spin if r.condition == "rough")
    assert rough.group == "manoeuvre" and rough.manoeuvres == [SQUARE]
    assert rough.parameters == {"aircraft": {"turbulence_sigma_w": 1.5}}
    assert rough.fault == {"name": "campaign_fault", "set": "dtg.spin_fraction", "value": 0.9,
                           "start_s": 20.0}
    assert rough.injected == "q" and rough.target is None and rough.channel == "system"
    assert next(r for r in spin if r.condition == "level").manoeuvres == []
    nominal = [r for r in runs if r.kind == "nominal"]
    assert len(nominal) == 2 and all(r.condition == "square" for r in nominal)
    # a run without conditions keeps the id it had before conditions existed
    plain = next(r for r in runs if r.cls == "air")
    assert plain.condition is None and plain.manoeuvres is None
    alone = CampaignSpec.model_validate({
        "name": "sys", "classes": {"air": {"scenario": str(BASE), "channel": "df",
                                           "diagnoser": "diag_df"}},
        "sweeps": [{"class": "air", "type": "bias", "magnitudes": [0.01], "onsets_s": [20.0],
                    "channels": [2]}]})
    assert expand_runs(alone, ROOT)[0].run_id == plain.run_id


def test_select_by_group_or_condition_keeps_the_full_campaigns_ids() -> None:
    runs = expand_runs(spec(), ROOT)
    level = select(runs, 1.0, groups=["level"])
    assert [r.run_id for r in level] == [r.run_id for r in runs if r.condition == "level"]
    assert len(level) == 2  # spin 0.9 at 20 s, 2 seeds: the nominal runs fly "square"
    both = select(runs, 1.0, conditions=["square", "rough"])
    assert {r.condition for r in both} == {"square", "rough"} and len(both) == 6
    assert [r.run_id for r in select(runs, 1.0, groups=["manoeuvre"])] == \
        [r.run_id for r in both]
    # group and fraction combine: half of each stratum of the manoeuvre group
    half = select(runs, 0.5, groups=["manoeuvre"])
    assert {r.kind for r in half} == {"fault", "nominal"} and len(half) == 3
    with pytest.raises(ValueError, match=r"groups: \['cruise'\] not in this campaign.*"
                                         r"'level', 'manoeuvre'"):
        select(runs, 1.0, groups=["cruise"])
    with pytest.raises(ValueError, match="conditions: "):
        select(runs, 1.0, conditions=[])


def test_condition_and_fault_reach_the_scenario() -> None:
    runs = expand_runs(spec(), ROOT)
    rough = next(r for r in runs if r.condition == "rough")
    s = build_scenario(rough)
    assert [m.name for m in s.manoeuvres] == ["m"]
    assert s.fmus["aircraft"].parameters["turbulence_sigma_w"] == 1.5
    assert s.fmus["aircraft"].parameters["seed"] == rough.seed
    assert s.physical_faults[0].set == "dtg.spin_fraction" and s.physical_faults[0].value == 0.9
    level = build_scenario(next(r for r in runs if r.condition == "level"))
    assert level.manoeuvres == []  # the base scenario's manoeuvre is replaced
    # ... and its controller flies trim, not the PitchController's default square wave
    assert level.fmus["controller"].parameters["command_source"] == 0
    assert "command_source" not in s.fmus["controller"].parameters


def test_invalid_entries_are_named() -> None:
    with pytest.raises(ValidationError, match="unknown condition 'wavy'"):
        spec(nominal=[{"class": "system", "duration_s": 60.0, "runs": 1,
                       "conditions": ["wavy"]}])
    with pytest.raises(ValidationError, match="either type"):
        spec(sweeps=[{"class": "system", "set": "dtg.spin_fraction", "type": "bias",
                      "magnitudes": [0.9], "onsets_s": [1.0]}])
    with pytest.raises(ValidationError, match="needs the injector channels"):
        spec(sweeps=[{"class": "air", "type": "bias", "magnitudes": [0.1],
                      "onsets_s": [1.0]}])


def test_system_run_is_judged_per_witness() -> None:
    run = RunSpec.model_validate({**expand_runs(spec(), ROOT)[0].model_dump()})
    t = np.arange(0, 30.001, 0.01)
    sig = {
        "diag_fine.dtg.alarm": ((t >= 5.0) & (t < 5.5) | (t >= 21.0)).astype(float),
        "diag_fine.dtg.learning": (t < 10.0).astype(float),  # the 5 s alarm is not judged
        "diag_fine.df.detected": (t >= 20.4).astype(float),
        "diag_fine.df.calibrating": (t < 12.0).astype(float),
        "diag_fine.dtg.fault_code": np.where(t >= 21.0, 4.0, 0.0),
        "diag_fine.df.isolated_sensor": np.where(t >= 20.6, 3.0, 0.0),
        "diag_fine.df.fault_type": np.where(t >= 20.6, 2.0, 0.0),
        "diag_fine.df.fault_magnitude": np.where(t >= 20.6, 0.9, 0.0),
    }
    rec = _judge_system(run, t, sig, 1.0)
    w = rec["witnesses"]
    assert w["dtg"]["detected"] and w["dtg"]["delay_s"] == pytest.approx(1.0)
    assert w["dtg"]["false_alarms"] == 0 and w["dtg"]["fault_free_s"] == pytest.approx(10.0)
    assert w["df"]["delay_s"] == pytest.approx(0.4) and w["df"]["t_ready_s"] == 12.0
    assert w["df"]["magnitude"] == 0.9 and w["dtg"]["diagnosed"] == 4
    assert rec["detected"] and rec["delay_s"] == pytest.approx(0.4)
    assert rec["diagnosed"] == "q" and rec["t_ready_s"] == 12.0


def _record(cond: str, group: str, kind: str, dtg: bool, df: bool, fa: int = 0) -> dict:
    run = {"run_id": f"{cond}-{kind}-{dtg}-{df}-{fa}", "kind": kind, "cls": "system",
           "channel": "system", "fault_type": "spin" if kind == "fault" else None,
           "magnitude": 0.9 if kind == "fault" else None, "condition": cond, "group": group,
           "injected": "q", "thresholds": []}
    wit = {"dtg": {"detected": dtg, "delay_s": 2.0 if dtg else None, "false_alarms": fa,
                   "fault_free_s": 3600.0},
           "df": {"detected": df, "delay_s": 0.1 if df else None, "false_alarms": 0,
                  "fault_free_s": 3600.0}}
    return {"status": "ok", "run": run, "detected": dtg or df, "delay_s": 0.1,
            "false_alarms": fa, "fault_free_s": 3600.0, "diagnosed": "q" if df else "none",
            "threshold_config": math.nan, "sweep": {"detected": [], "delay_s": [],
                                                    "false_alarms": []},
            "sweep_mismatch": 0.0, "witnesses": wit}


def test_summary_compares_groups_and_counts_false_alarms_per_witness() -> None:
    records = [_record("level", "level", "fault", True, True),
               _record("level", "level", "fault", True, False),
               _record("square", "manoeuvre", "fault", True, True),
               _record("square", "manoeuvre", "fault", False, True),
               _record("square", "manoeuvre", "nominal", False, False, fa=1)]
    s = summarize(records)
    w = s["witnesses"]
    assert w["names"] == ["df", "dtg"]
    comp = w["comparison"][0]
    assert comp["group"] == "manoeuvre"
    assert comp["dtg"]["points"] == pytest.approx(-50.0)
    assert comp["df"]["points"] == pytest.approx(50.0)
    assert comp["both"]["level"] == 0.5 and comp["both"]["group"] == 0.5
    assert comp["either"]["points"] == pytest.approx(0.0)  # any witness: 2 of 2 in each
    # a second fault type in the manoeuvre, missed by both: the pooled row counts it
    more = [*records, {**_record("square", "manoeuvre", "fault", False, False),
                       "run": {**_record("square", "manoeuvre", "fault", False, False)["run"],
                               "run_id": "torquer-miss", "fault_type": "torquer_scale"}}]
    pooled = [r for r in summarize(more)["witnesses"]["detection"] if r["fault_type"] == "all"]
    assert [(r["group"], r["n"], r["either"]["detected"], r["dtg"]["detected"])
            for r in pooled] == [("level", 2, 2, 2), ("manoeuvre", 3, 2, 1)]
    fa = w["false_alarms"]["dtg/manoeuvre"]
    assert fa["count"] == 1 and fa["hours"] == pytest.approx(3.0)
    assert fa["nominal_hours"] == pytest.approx(1.0)
    assert w["false_alarms"]["df/manoeuvre"]["count"] == 0
    assert s["threshold_sweep"] == {}
    md = markdown_summary(s, "sys")
    assert "Detection rate in each group against level flight" in md
    assert "1.00 → 0.50 (-50.0)" in md and "either: level → group" in md
