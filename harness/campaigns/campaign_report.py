"""Summary figures, plots and HTML/JSON report of a fault-injection campaign.

:func:`summarize` turns the run records of :mod:`gyrodiag_harness.campaigns.campaign` into figures:

* detection rate per class, fault type and magnitude, with a 95 % Clopper-Pearson
  interval, and in the same rows how many runs were isolated right (diagnosed class =
  injected class): the paper's DTG feature is a decade count of η, so fault size moves it
  as much as fault type, and only a per-magnitude view shows where classification holds;
* false alarms per hour per channel over all fault-free time (nominal runs and the
  pre-onset part of fault runs), with the exact Poisson (Garwood) 95 % interval
  ``[chi2(0.025; 2n) / 2, chi2(0.975; 2n + 2) / 2] / hours``;
* detection delay (median, p95, max) per class and fault type and per channel;
* isolation confusion matrix per channel (injected vs diagnosed at the end of the run);
* threshold sweep per channel: detection rate vs false alarms per hour at every
  threshold of the grid (recomputed offline from the alarm statistic, see
  :mod:`gyrodiag_harness.campaigns.campaign`);
* system runs (two witnesses, flight conditions): per fault, magnitude and condition
  group the detection rate of each witness and how often both saw it; each group's
  rate against the "level" group's (difference in percentage points); false alarms per
  hour per witness and group;
* grey runs (the HRG, several decision rules watching one signal): each rule (witness) is
  a class ``<class>/<rule>`` and a channel ``grey/<rule>`` of its own in every table
  above, and a grey section gives per rule, fault, magnitude and condition group (the
  output noise) detection and delay median / p95 / max, false alarms per hour per rule
  and group, and the threshold sweep per rule and group.  The grey channel names no
  fault kind: isolation/classification is "n/a" there, and it has no confusion matrix.

Only runs with status ``ok`` count; the others are listed with their error.  Nothing in
the summary depends on wall times or on the order in which runs finished, so the same
campaign gives the same summary on any executor.
"""

from __future__ import annotations

import html
import json
import math
from collections import defaultdict
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
from scipy import stats

SECONDS_PER_HOUR = 3600.0
#: Detection-delay target of the grey channel, s (issue 11: within 1.5 s, three samples).
GREY_TARGET_DELAY_S = 1.5


def garwood_interval(count: int, hours: float, confidence: float = 0.95) -> tuple[float, float]:
    """Exact Poisson (Garwood) interval of a rate, events per hour.

    Parameters
    ----------
    count : int
        Events observed (>= 0).
    hours : float
        Exposure, h (> 0).
    confidence : float
        Two-sided confidence level in (0, 1).

    Returns
    -------
    (float, float)
        Lower and upper bound, 1/h (lower 0 when ``count`` is 0).
    """
    if count < 0:
        raise ValueError(f"count must be >= 0, got {count}")
    if not hours > 0:
        raise ValueError(f"hours must be > 0, got {hours}")
    if not 0 < confidence < 1:
        raise ValueError(f"confidence must be in (0, 1), got {confidence}")
    a = 1.0 - confidence
    lo = 0.0 if count == 0 else stats.chi2.ppf(a / 2, 2 * count) / 2
    hi = stats.chi2.ppf(1 - a / 2, 2 * count + 2) / 2
    return float(lo / hours), float(hi / hours)


def clopper_pearson(k: int, n: int, confidence: float = 0.95) -> tuple[float, float]:
    """Exact binomial interval of a proportion ``k / n`` (NaN, NaN for ``n = 0``)."""
    if n == 0:
        return math.nan, math.nan
    a = 1.0 - confidence
    lo = 0.0 if k == 0 else stats.beta.ppf(a / 2, k, n - k + 1)
    hi = 1.0 if k == n else stats.beta.ppf(1 - a / 2, k + 1, n - k)
    return float(lo), float(hi)


def _delay_stats(delays: list[float]) -> dict[str, Any]:
    if not delays:
        return {"n": 0, "median_s": None, "p95_s": None, "max_s": None}
    d = np.asarray(delays, dtype=float)
    return {"n": int(d.size), "median_s": float(np.median(d)),
            "p95_s": float(np.percentile(d, 95)), "max_s": float(d.max())}


def _diagnosed_right(record: dict[str, Any]) -> bool:
    """The diagnosis is the injected class, or one the sweep accepts as merged with it."""
    run = record["run"]
    return record["diagnosed"] == run["injected"] or record["diagnosed"] in run.get(
        "accepted", [])


def _axis_right(record: dict[str, Any]) -> bool | None:
    """DTG pattern classifier: the reported axis (dtg.fault_axis) is the injected
    signal's (injector channels 1, 3 feed x; 2, 4 feed y); None when not recorded."""
    run = record["run"]
    axis = record.get("diagnosed_axis")
    if (str(run.get("channel")).split("/")[0] != "dtg" or axis is None
            or run.get("target") is None):
        return None
    return int(axis) == (1 if int(run["target"]) in (1, 3) else 2)


#: Channels whose records are split per witness (rule); system runs keep theirs whole.
SPLIT_CHANNELS = ("grey", "df", "dtg")


def split_grey(records: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """Records of runs with several witnesses (grey, df, dtg) split into one record per
    witness (rule); others unchanged.

    The witness's record has the run's class ``<class>/<rule>``, channel
    ``<channel>/<rule>``, ``rule`` set, the witness's fields at the top level and, when
    the witness has its own sweep grid, that grid as the run's ``thresholds``.  A grey
    witness names no fault kind (``diagnosed`` None); a df/dtg witness keeps its own
    diagnosis, so isolation, class and confusion are per rule too.
    """
    out = []
    for r in records:
        ch = r["run"].get("channel")
        if (r.get("status") != "ok" or ch not in SPLIT_CHANNELS
                or (ch != "grey" and not r["run"].get("witnesses"))):
            out.append(r)
            continue
        # the top level repeats the first witness's fields: none of them may leak into
        # another witness's record (e.g. "typed" of the sequential rule)
        judged = {k for fields in r["witnesses"].values() for k in fields}
        rest = {k: v for k, v in r.items() if k != "witnesses" and k not in judged}
        for w, fields in r["witnesses"].items():
            run = {**r["run"], "cls": f"{r['run']['cls']}/{w}", "channel": f"{ch}/{w}"}
            if "thresholds" in fields:
                run["thresholds"] = fields["thresholds"]
            split = {**rest, **fields, "run": run, "rule": w}
            if ch == "grey":
                split["diagnosed"] = None
            out.append(split)
    return out


#: The same split, by the name that says what it does now.
split_witnesses = split_grey


def _natural(key: str) -> tuple[float, str]:
    """Sort "5 mV" before "10 mV": the leading number, then the text."""
    head = key.split()[0] if key.split() else ""
    try:
        return float(head), key
    except ValueError:
        return math.inf, key


def _false_alarms(ok: list[dict[str, Any]]) -> dict[str, dict[str, Any]]:
    """False alarms per channel of (split) ok records: count, fault-free and nominal
    hours, rate and its 95 % Garwood interval, runs with a false alarm."""
    false_alarms: dict[str, dict[str, Any]] = {}
    for ch in sorted({r["run"]["channel"] for r in ok}):
        rs = [r for r in ok if r["run"]["channel"] == ch]
        count = sum(int(r["false_alarms"]) for r in rs)
        hours = sum(float(r["fault_free_s"]) for r in rs) / SECONDS_PER_HOUR
        nominal_h = sum(float(r["fault_free_s"]) for r in rs
                        if r["run"]["kind"] == "nominal") / SECONDS_PER_HOUR
        lo, hi = garwood_interval(count, hours) if hours > 0 else (math.nan, math.nan)
        false_alarms[ch] = {"count": count, "hours": hours, "nominal_hours": nominal_h,
                            "rate_per_h": count / hours if hours > 0 else math.nan,
                            "lower_95": lo, "upper_95": hi,
                            "runs_with_false_alarm": sum(int(r["false_alarms"]) > 0
                                                         for r in rs)}
    return false_alarms


def summarize(records: list[dict[str, Any]], n_planned: int | None = None) -> dict[str, Any]:
    """Campaign figures from run records (module docstring); a JSON-able dict."""
    n_records = len(records)
    n_fault_raw = sum(r.get("status") == "ok" and r["run"]["kind"] == "fault" for r in records)
    n_ok_raw = sum(r.get("status") == "ok" for r in records)
    records = split_grey(records)
    ok = sorted((r for r in records if r.get("status") == "ok"),
                key=lambda r: r["run"]["run_id"])
    failed = sorted((r for r in records if r.get("status") != "ok"),
                    key=lambda r: r["run"]["run_id"])
    fault = [r for r in ok if r["run"]["kind"] == "fault"]

    detection = _detection_rows(fault)
    false_alarms = _false_alarms(ok)
    delay = _delay_summary(fault)
    confusion = _confusion(fault)
    sweep = _threshold_sweep(ok)

    return {
        "n_planned": n_planned if n_planned is not None else n_records,
        "n_finished": n_records, "n_ok": len(ok), "n_failed": len(failed),
        # runs, not rules: a grey run judged by two rules counts once
        "n_fault_runs": n_fault_raw, "n_nominal_runs": n_ok_raw - n_fault_raw,
        "failures": [{"run_id": r["run"]["run_id"], "status": r["status"],
                      "error": str(r.get("error")).strip().splitlines()[0][:300]}
                     for r in failed],
        "class_channels": {r["run"]["cls"]: r["run"]["channel"] for r in ok},
        "detection": detection, "false_alarms": false_alarms, "delay": delay,
        "confusion": confusion, "threshold_sweep": sweep,
        "witnesses": _witness_summary(ok),
        "grey": _grey_summary(ok),
    }


def _detection_rows(fault: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """Detection and isolation per class, fault type and magnitude (:func:`summarize`)."""
    groups: dict[tuple, list[dict]] = defaultdict(list)
    for r in fault:
        run = r["run"]
        groups[(run["cls"], run["fault_type"], run["magnitude"])].append(r)
    detection = []
    for (cls, ftype, mag), rs in sorted(groups.items(),
                                        key=lambda kv: (kv[0][0], kv[0][1], kv[0][2] or 0.0)):
        k = sum(bool(r["detected"]) for r in rs)
        lo, hi = clopper_pearson(k, len(rs))
        # a channel that names no fault kind (grey) has no isolation: None, not 0
        classifies = any(r["diagnosed"] is not None for r in rs)
        right = sum(_diagnosed_right(r) for r in rs) if classifies else None
        row = {"class": cls, "fault_type": ftype, "magnitude": mag, "n": len(rs),
               "detected": k, "rate": k / len(rs), "ci_low": lo, "ci_high": hi,
               "isolated": right,
               "isolation_rate": right / len(rs) if right is not None else None}
        axes = [_axis_right(r) for r in rs]
        if all(a is not None for a in axes):
            row["axis_right"] = sum(bool(a) for a in axes)
        typed = [r for r in rs if r.get("expected_type")]
        if typed:  # channels that type the fault (sequential detection filter)
            row["typed"] = sum(r.get("typed") == r["expected_type"] for r in typed)
            row["n_typed"] = len(typed)
        detection.append(row)
    return detection


def _delay_summary(fault: list[dict[str, Any]]) -> dict[str, dict[str, Any]]:
    """Detection delay statistics per class and fault type, then per channel."""
    delay: dict[str, dict[str, Any]] = {}
    by_type: dict[str, list[float]] = defaultdict(list)
    by_channel: dict[str, list[float]] = defaultdict(list)
    for r in fault:
        if r["detected"] and r["delay_s"] is not None:
            by_type[f"{r['run']['cls']}/{r['run']['fault_type']}"].append(r["delay_s"])
            by_channel[f"all {r['run']['channel']}"].append(r["delay_s"])
    for key in sorted(by_type):
        delay[key] = _delay_stats(by_type[key])
    for key in sorted(by_channel):
        delay[key] = _delay_stats(by_channel[key])
    return delay


def _confusion(fault: list[dict[str, Any]]) -> dict[str, dict[str, Any]]:
    """Injected against diagnosed sensor per channel that classifies."""
    confusion: dict[str, dict[str, Any]] = {}
    for ch in sorted({r["run"]["channel"] for r in fault if r["diagnosed"] is not None}):
        rs = [r for r in fault if r["run"]["channel"] == ch]
        inj = sorted({r["run"]["injected"] for r in rs})
        diag = sorted({r["diagnosed"] for r in rs} | set(inj))
        m = np.zeros((len(inj), len(diag)), dtype=int)
        for r in rs:
            m[inj.index(r["run"]["injected"]), diag.index(r["diagnosed"])] += 1
        right = sum(_diagnosed_right(r) for r in rs)
        confusion[ch] = {"injected": inj, "diagnosed": diag, "matrix": m.tolist(),
                         "correct": int(right), "n": len(rs)}
    return confusion


def _threshold_sweep(ok: list[dict[str, Any]]) -> dict[str, dict[str, Any]]:
    """Detection rate and false alarms per hour over each channel's threshold grid (per
    class where the classes' grids differ)."""
    sweep: dict[str, dict[str, Any]] = {}
    for ch in sorted({r["run"]["channel"] for r in ok if r["run"]["thresholds"]}):
        rs = [r for r in ok if r["run"]["channel"] == ch]
        grids = {tuple(r["run"]["thresholds"]) for r in rs}
        keyed = [(ch, rs)] if len(grids) == 1 else [
            (f"{ch}:{c}", [r for r in rs if r["run"]["cls"] == c])
            for c in sorted({r["run"]["cls"] for r in rs})]
        for key, sub in keyed:
            thr = list(sub[0]["run"]["thresholds"])
            fr = [r for r in sub if r["run"]["kind"] == "fault"]
            hours = sum(float(r["fault_free_s"]) for r in sub) / SECONDS_PER_HOUR
            det, fa, up = [], [], []
            for j in range(len(thr)):
                k = sum(bool(r["sweep"]["detected"][j]) for r in fr)
                n_fa = sum(int(r["sweep"]["false_alarms"][j]) for r in sub)
                det.append(k / len(fr) if fr else math.nan)
                fa.append(n_fa / hours if hours > 0 else math.nan)
                up.append(garwood_interval(n_fa, hours)[1] if hours > 0 else math.nan)
            config = sorted({r["threshold_config"] for r in sub})
            sweep[key] = {"thresholds": thr, "detection_rate": det, "false_alarms_per_h": fa,
                          "upper_95_per_h": up, "n_fault_runs": len(fr), "hours": hours,
                          "configured_threshold": config,
                          "max_mismatch": max(float(r["sweep_mismatch"]) for r in sub)}
    return sweep


def summarize_campaigns(outputs: Sequence[Any]) -> dict[str, Any]:
    """One summary of several campaigns' records (e.g. every family of issue 16).

    ``outputs`` are :class:`gyrodiag_harness.campaigns.campaign.CampaignOutput` (name, planned run
    count, records).  Classes are renamed ``<campaign>/<class>`` so that families with
    the same class name stay apart; channels are kept, so the false-alarm and isolation
    tables pool a channel over the campaigns that judge it.  ``campaigns`` adds one row
    per campaign: runs finished / planned / failed, nominal hours judged, false alarms
    per channel and rule, and ``run_hours`` (the runs' wall times summed, h).
    """
    names = [o.name for o in outputs]
    if len(set(names)) != len(names):
        raise ValueError(f"campaigns: the same campaign given twice ({sorted(names)})")
    records, rows = [], []
    for o in outputs:
        for r in o.records:
            records.append({**r, "run": {**r["run"], "cls": f"{o.name}/{r['run']['cls']}"}})
        ok = [r for r in o.records if r.get("status") == "ok"]
        nominal = [r for r in ok if r["run"]["kind"] == "nominal"]
        selection = {k: v for k, v in getattr(o, "selection", {}).items() if v}
        rows.append({"campaign": o.name, "folder": str(o.out_dir), "fraction": o.fraction,
                     "selection": selection,
                     "n_planned": o.n_planned, "n_finished": len(o.records),
                     "n_failed": len(o.records) - len(ok),
                     "n_fault_runs": sum(r["run"]["kind"] == "fault" for r in ok),
                     "n_nominal_runs": len(nominal),
                     "nominal_hours": sum(float(r["fault_free_s"]) for r in nominal)
                     / SECONDS_PER_HOUR,
                     "channels": sorted({r["run"]["channel"] for r in ok}),
                     # the runs' own wall times summed: the campaign's cost on one
                     # worker, whatever pauses and resumptions its elapsed time had
                     "run_hours": sum(float(r.get("wall_s") or 0.0) for r in o.records)
                     / SECONDS_PER_HOUR,
                     # per campaign too: a channel pooled over families (the DTG bench
                     # and the system chain) would hide which family raised them
                     "false_alarms": _false_alarms(split_grey(ok))})
    summary = summarize(records, n_planned=sum(o.n_planned for o in outputs))
    summary["campaigns"] = rows
    return summary


def _grey_summary(ok: list[dict[str, Any]]) -> dict[str, Any]:
    """The grey section of :func:`summarize` from split records (empty without grey runs).

    Per rule, fault, magnitude and condition group: detection (95 % CI), how many within
    :data:`GREY_TARGET_DELAY_S`, delay median / p95 / max; per rule and group (and "all"):
    false alarms per hour with the Garwood 95 % interval; per rule and group the
    threshold sweep (detection rate and false alarms per hour at each multiple of the
    rule's threshold).
    """
    grey = [r for r in ok if "rule" in r and r["run"]["channel"].startswith("grey/")]
    if not grey:
        return {}
    # in the spec's order (the records' witness dicts are sorted by name)
    present = {r["rule"] for r in grey}
    rules = [w for w in dict.fromkeys(w for r in grey for w in r["run"].get("witnesses") or [])
             if w in present]
    groups = sorted({r["run"].get("group") or "base" for r in grey}, key=_natural)
    cells: dict[tuple, list[dict]] = defaultdict(list)
    for r in grey:
        run = r["run"]
        if run["kind"] == "fault":
            cells[(r["rule"], run["fault_type"], run["magnitude"],
                   run.get("group") or "base")].append(r)
    detection = []
    for (rule, ftype, mag, group), rs in sorted(
            cells.items(), key=lambda kv: (rules.index(kv[0][0]), kv[0][1],
                                           kv[0][2] if kv[0][2] is not None else 0.0,
                                           _natural(kv[0][3]))):
        k = sum(bool(r["detected"]) for r in rs)
        lo, hi = clopper_pearson(k, len(rs))
        delays = [float(r["delay_s"]) for r in rs if r["detected"]]
        detection.append({
            "rule": rule, "fault_type": ftype, "magnitude": mag, "group": group,
            "n": len(rs), "detected": k, "rate": k / len(rs), "ci_low": lo, "ci_high": hi,
            "within_target": sum(d <= GREY_TARGET_DELAY_S + 1e-9 for d in delays),
            # "detected" by an alarm already standing at the onset (a false alarm)
            "standing": sum(bool(r["detected"] and r.get("alarm_at_onset")) for r in rs),
            "delay": _delay_stats(delays)})
    false_alarms: dict[str, dict[str, Any]] = {}
    sweep: dict[str, dict[str, Any]] = {}
    for rule in rules:
        for group in [*groups, "all"]:
            rs = [r for r in grey if r["rule"] == rule
                  and group in ("all", r["run"].get("group") or "base")]
            count = sum(int(r["false_alarms"]) for r in rs)
            hours = sum(float(r["fault_free_s"]) for r in rs) / SECONDS_PER_HOUR
            nominal_h = sum(float(r["fault_free_s"]) for r in rs
                            if r["run"]["kind"] == "nominal") / SECONDS_PER_HOUR
            lo, hi = garwood_interval(count, hours) if hours > 0 else (math.nan, math.nan)
            false_alarms[f"{rule}/{group}"] = {
                "rule": rule, "group": group, "count": count, "hours": hours,
                "nominal_hours": nominal_h,
                "rate_per_h": count / hours if hours > 0 else math.nan,
                "lower_95": lo, "upper_95": hi,
                "runs_with_false_alarm": sum(int(r["false_alarms"]) > 0 for r in rs)}
            thr = list(rs[0]["run"]["thresholds"]) if rs else []
            fr = [r for r in rs if r["run"]["kind"] == "fault"]
            det, fa, up = [], [], []
            for j in range(len(thr)):
                n_fa = sum(int(r["sweep"]["false_alarms"][j]) for r in rs)
                det.append(sum(bool(r["sweep"]["detected"][j]) for r in fr) / len(fr)
                           if fr else math.nan)
                fa.append(n_fa / hours if hours > 0 else math.nan)
                up.append(garwood_interval(n_fa, hours)[1] if hours > 0 else math.nan)
            sweep[f"{rule}/{group}"] = {
                "rule": rule, "group": group, "thresholds": thr, "detection_rate": det,
                "false_alarms_per_h": fa, "upper_95_per_h": up, "n_fault_runs": len(fr),
                "hours": hours,
                "max_mismatch": max((float(r["sweep_mismatch"]) for r in rs), default=0.0)}
    return {"rules": rules, "groups": groups, "target_delay_s": GREY_TARGET_DELAY_S,
            "detection": detection, "false_alarms": false_alarms, "threshold_sweep": sweep}


def _witness_summary(ok: list[dict[str, Any]]) -> dict[str, Any]:
    """The system section of :func:`summarize` (empty without system runs)."""
    system = [r for r in ok if "witnesses" in r]
    if not system:
        return {}
    names = sorted(system[0]["witnesses"])
    groups: dict[tuple, list[dict]] = defaultdict(list)
    for r in system:
        run = r["run"]
        if run["kind"] == "fault":
            groups[(run["cls"], run["fault_type"], run["magnitude"],
                    run.get("group") or "base")].append(r)
    detection = []
    for (cls, ftype, mag, group), rs in sorted(
            groups.items(), key=lambda kv: (kv[0][0], kv[0][1], kv[0][2] or 0.0, kv[0][3])):
        row: dict[str, Any] = {"class": cls, "fault_type": ftype, "magnitude": mag,
                               "group": group, "n": len(rs),
                               "conditions": sorted({r["run"].get("condition") or "base"
                                                     for r in rs})}
        for w in names:
            k = sum(bool(r["witnesses"][w]["detected"]) for r in rs)
            lo, hi = clopper_pearson(k, len(rs))
            delays = [r["witnesses"][w]["delay_s"] for r in rs
                      if r["witnesses"][w]["detected"]]
            row[w] = {"detected": k, "rate": k / len(rs), "ci_low": lo, "ci_high": hi,
                      "delay": _delay_stats(delays)}
        both = sum(all(r["witnesses"][w]["detected"] for w in names) for r in rs)
        row["both"] = {"detected": both, "rate": both / len(rs)}
        either = sum(bool(r["detected"]) for r in rs)  # the run's top level: any witness
        row["either"] = {"detected": either, "rate": either / len(rs)}
        detection.append(row)
    # every fault of a class pooled per group: the one figure "as in level flight?"
    pooled: dict[tuple[str, str], list[dict]] = defaultdict(list)
    for (cls, _, _, group), rs in groups.items():
        pooled[(cls, group)] += rs
    for (cls, group), rs in sorted(pooled.items()):
        row = {"class": cls, "fault_type": "all", "magnitude": None, "group": group,
               "n": len(rs), "conditions": sorted({r["run"].get("condition") or "base"
                                                   for r in rs})}
        for w in names:
            k = sum(bool(r["witnesses"][w]["detected"]) for r in rs)
            lo, hi = clopper_pearson(k, len(rs))
            row[w] = {"detected": k, "rate": k / len(rs), "ci_low": lo, "ci_high": hi,
                      "delay": _delay_stats([r["witnesses"][w]["delay_s"] for r in rs
                                             if r["witnesses"][w]["detected"]])}
        k = sum(all(r["witnesses"][w]["detected"] for w in names) for r in rs)
        row["both"] = {"detected": k, "rate": k / len(rs)}
        k = sum(bool(r["detected"]) for r in rs)
        row["either"] = {"detected": k, "rate": k / len(rs)}
        detection.append(row)
    comparison = _group_comparison(detection, names)
    false_alarms = _witness_false_alarms(system, names)
    return {"names": names, "detection": detection, "comparison": comparison,
            "false_alarms": false_alarms}


def _group_comparison(detection: list[dict[str, Any]], names: list[str]
                      ) -> list[dict[str, Any]]:
    """Each group's detection rate per witness beside level flight's, in points."""
    comparison = []
    for row in detection:
        if row["group"] == "level":
            continue
        ref = next((x for x in detection if x["group"] == "level"
                    and (x["class"], x["fault_type"], x["magnitude"])
                    == (row["class"], row["fault_type"], row["magnitude"])), None)
        if ref is None:
            continue
        comparison.append({"class": row["class"], "fault_type": row["fault_type"],
                           "magnitude": row["magnitude"], "group": row["group"],
                           **{w: {"level": ref[w]["rate"], "group": row[w]["rate"],
                                  "points": 100.0 * (row[w]["rate"] - ref[w]["rate"])}
                              for w in [*names, "both", "either"]}})
    return comparison


def _witness_false_alarms(system: list[dict[str, Any]], names: list[str]
                          ) -> dict[str, dict[str, Any]]:
    """False alarms per witness and condition group, per hour with the 95 % interval."""
    false_alarms: dict[str, dict[str, Any]] = {}
    for w in names:
        for group in sorted({r["run"].get("group") or "base" for r in system}):
            rs = [r for r in system if (r["run"].get("group") or "base") == group]
            count = sum(int(r["witnesses"][w]["false_alarms"]) for r in rs)
            hours = sum(float(r["witnesses"][w]["fault_free_s"]) for r in rs) / SECONDS_PER_HOUR
            nominal_h = sum(float(r["witnesses"][w]["fault_free_s"]) for r in rs
                            if r["run"]["kind"] == "nominal") / SECONDS_PER_HOUR
            lo, hi = garwood_interval(count, hours) if hours > 0 else (math.nan, math.nan)
            false_alarms[f"{w}/{group}"] = {
                "witness": w, "group": group, "count": count, "hours": hours,
                "nominal_hours": nominal_h, "rate_per_h": count / hours if hours else math.nan,
                "lower_95": lo, "upper_95": hi,
                "runs_with_false_alarm": sum(int(r["witnesses"][w]["false_alarms"]) > 0
                                             for r in rs)}
    return false_alarms


# --------------------------------------------------------------------------- plots
def _plots(summary: dict[str, Any], records: list[dict[str, Any]], out: Path) -> list[Path]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    paths: list[Path] = []
    _detection_plot(summary["detection"], out, plt, paths)
    _delay_plot(records, out, plt, paths)
    if summary.get("grey"):
        paths.append(_grey_plot(summary["grey"], out, plt))
    _confusion_plots(summary["confusion"], out, plt, paths)
    _sweep_plots(summary["threshold_sweep"], out, plt, paths)
    return paths


def _detection_plot(rows: list[dict[str, Any]], out: Path, plt: Any,
                    paths: list[Path]) -> None:
    """detection_rate.png: the detection rate (95 % CI) against the magnitude, a panel per
    class; appended to ``paths``."""
    classes = sorted({r["class"] for r in rows})
    if rows:
        # one panel per class: magnitudes of different classes have different units
        fig, axes = plt.subplots(1, len(classes), figsize=(5.5 * len(classes), 4),
                                 squeeze=False)
        for ax, cls in zip(axes[0], classes, strict=True):
            fixed = []
            for ft in sorted({r["fault_type"] for r in rows if r["class"] == cls}):
                pts = [r for r in rows if r["class"] == cls and r["fault_type"] == ft]
                if all(p["magnitude"] is None for p in pts):
                    fixed.append(f"{ft}: {pts[0]['detected']}/{pts[0]['n']}")
                    continue
                pts = sorted(pts, key=lambda p: p["magnitude"])
                err = [[p["rate"] - p["ci_low"] for p in pts],
                       [p["ci_high"] - p["rate"] for p in pts]]
                ax.errorbar([p["magnitude"] for p in pts], [p["rate"] for p in pts],
                            yerr=err, marker="o", capsize=3, label=ft)
            mags = [r["magnitude"] for r in rows if r["class"] == cls
                    and r["magnitude"] is not None]
            ax.set_xscale("log" if all(m > 0 for m in mags) else "linear")
            ax.set_xlabel("fault magnitude (fault units)")
            ax.set_ylabel("detection rate (95 % CI)")
            ax.set_ylim(-0.05, 1.05)
            ax.set_title(cls + ("\n" + ", ".join(fixed) + " detected" if fixed else ""),
                         fontsize=9)
            ax.legend(fontsize=7)
            ax.grid(alpha=0.3)
        fig.tight_layout()
        paths.append(out / "detection_rate.png")
        fig.savefig(paths[-1], dpi=110)
        plt.close(fig)


def _delay_plot(records: list[dict[str, Any]], out: Path, plt: Any,
                paths: list[Path]) -> None:
    """delay_hist.png: the detection delays of the fault runs, a panel per channel."""
    delays = defaultdict(list)
    for r in records:
        if r.get("status") == "ok" and r["run"]["kind"] == "fault" and r["detected"]:
            delays[r["run"]["channel"]].append(r["delay_s"])
    if delays:
        fig, axes = plt.subplots(1, len(delays), figsize=(5 * len(delays), 3.5), squeeze=False)
        for ax, (ch, d) in zip(axes[0], sorted(delays.items()), strict=True):
            ax.hist(d, bins=30)
            ax.set_title(f"detection delay, {ch}")
            ax.set_xlabel("delay (s)")
            ax.set_ylabel("runs")
        fig.tight_layout()
        paths.append(out / "delay_hist.png")
        fig.savefig(paths[-1], dpi=110)
        plt.close(fig)


def _confusion_plots(confusion: dict[str, dict[str, Any]], out: Path, plt: Any,
                     paths: list[Path]) -> None:
    """confusion_<channel>.png: injected against diagnosed sensor."""
    for ch, c in confusion.items():
        m = np.asarray(c["matrix"])
        fig, ax = plt.subplots(figsize=(1.2 + 0.8 * m.shape[1], 1.2 + 0.6 * m.shape[0]))
        ax.imshow(m, cmap="Blues")
        for i in range(m.shape[0]):
            for j in range(m.shape[1]):
                ax.text(j, i, str(m[i, j]), ha="center", va="center", fontsize=8)
        ax.set_xticks(range(m.shape[1]), c["diagnosed"], rotation=45, ha="right", fontsize=8)
        ax.set_yticks(range(m.shape[0]), c["injected"], fontsize=8)
        ax.set_xlabel("diagnosed")
        ax.set_ylabel("injected")
        ax.set_title(f"isolation, {ch}")
        fig.tight_layout()
        paths.append(out / f"confusion_{ch.replace('/', '_')}.png")
        fig.savefig(paths[-1], dpi=110)
        plt.close(fig)


def _sweep_plots(sweeps: dict[str, dict[str, Any]], out: Path, plt: Any,
                 paths: list[Path]) -> None:
    """threshold_sweep_<key>.png: detection rate against false alarms per hour."""
    for key, s in sweeps.items():
        fig, ax = plt.subplots(figsize=(6, 4))
        fa = np.asarray(s["false_alarms_per_h"], dtype=float)
        ax.plot(fa, s["detection_rate"], "o-", label="false alarms/h")
        ax.plot(s["upper_95_per_h"], s["detection_rate"], "x--", alpha=0.6,
                label="95 % upper bound")
        for x, y, t in zip(fa, s["detection_rate"], s["thresholds"], strict=True):
            ax.annotate(f"{t:g}", (x, y), fontsize=7, xytext=(3, -8), textcoords="offset points")
        ax.set_xscale("symlog", linthresh=0.1)
        ax.set_xlabel("false alarms per hour")
        ax.set_ylabel("detection rate")
        ax.set_ylim(-0.05, 1.05)
        ax.set_title(f"threshold sweep, {key} (labels: threshold)")
        ax.legend(fontsize=7)
        ax.grid(alpha=0.3)
        fig.tight_layout()
        paths.append(out / f"threshold_sweep_{key.replace(':', '_').replace('/', '_')}.png")
        fig.savefig(paths[-1], dpi=110)
        plt.close(fig)


def _grey_plot(g: dict[str, Any], out: Path, plt: Any) -> Path:
    """Grey channel: per fault type the share detected within the delay target against
    the condition group (noise), a line per rule and magnitude; last panel the false
    alarms per hour (95 % upper bound as error bar) per rule and group."""
    groups = g["groups"]
    ftypes = list(dict.fromkeys(r["fault_type"] for r in g["detection"]))
    fig, axes = plt.subplots(1, len(ftypes) + 1, figsize=(3.6 * (len(ftypes) + 1), 3.6),
                             squeeze=False)
    x = np.arange(len(groups))
    styles = ["-", "--", ":", "-."]
    for ax, ft in zip(axes[0], ftypes, strict=False):
        for i, rule in enumerate(g["rules"]):
            rows = [r for r in g["detection"] if r["rule"] == rule and r["fault_type"] == ft]
            for j, mag in enumerate(dict.fromkeys(r["magnitude"] for r in rows)):
                # an alarm standing at the onset is no detection of the fault
                y = [next(((r["within_target"] - r["standing"]) / r["n"] for r in rows
                           if r["magnitude"] == mag and r["group"] == grp), math.nan)
                     for grp in groups]
                ax.plot(x, y, styles[i % len(styles)], marker="o", ms=3, color=f"C{j}",
                        label=f"{rule} {_fmt(mag)}")
        ax.set_xticks(x, groups, fontsize=8)
        ax.set_ylim(-0.05, 1.05)
        ax.set_title(f"{ft}: raised ≤ {g['target_delay_s']:g} s after onset", fontsize=9)
        ax.legend(fontsize=6)
        ax.grid(alpha=0.3)
    ax = axes[0][-1]
    for i, rule in enumerate(g["rules"]):
        fa = [g["false_alarms"][f"{rule}/{grp}"] for grp in groups]
        rate = np.array([f["rate_per_h"] for f in fa])
        upper = np.array([f["upper_95"] for f in fa])
        ax.errorbar(x + 0.08 * i, rate, yerr=[np.zeros_like(rate), upper - rate],
                    fmt=styles[i % len(styles)], marker="s", capsize=3, label=rule)
    ax.set_yscale("symlog", linthresh=0.1)
    ax.set_xticks(x, groups, fontsize=8)
    ax.set_title("false alarms per hour (bar: 95 % upper)", fontsize=9)
    ax.legend(fontsize=7)
    ax.grid(alpha=0.3)
    fig.tight_layout()
    path = out / "grey_by_noise.png"
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def _fmt(x: Any, digits: int = 3) -> str:
    if x is None or (isinstance(x, float) and math.isnan(x)):
        return "–"
    if isinstance(x, float):
        return f"{x:.{digits}g}"
    return html.escape(str(x))


def _table(header: list[str], rows: list[list[Any]]) -> str:
    head = "".join(f"<th>{html.escape(h)}</th>" for h in header)
    body = "".join("<tr>" + "".join(f"<td>{_fmt(c)}</td>" for c in r) + "</tr>" for r in rows)
    return f"<table><tr>{head}</tr>{body}</table>"


def _md_table(header: list[str], rows: list[list[Any]]) -> list[str]:
    def cell(x: Any) -> str:
        return html.unescape(_fmt(x)).replace("|", "\\|")

    return ["| " + " | ".join(header) + " |", "|" + " --- |" * len(header),
            *("| " + " | ".join(cell(c) for c in r) + " |" for r in rows), ""]


def markdown_summary(summary: dict[str, Any], title: str = "campaign") -> str:
    """The campaign's headline figures as Markdown tables (what README.md quotes).

    One row per channel (false alarms with the 95 % Garwood upper bound, delay median /
    p95 / max over all detected fault runs, isolation right), then detection and
    isolation per class, fault type and magnitude, then each threshold sweep.
    """
    lines = [f"## Campaign {title}", "",
             f"{summary['n_finished']} of {summary['n_planned']} runs finished: "
             f"{summary['n_fault_runs']} fault runs, {summary['n_nominal_runs']} nominal, "
             f"{summary['n_failed']} failed.", ""]
    if summary.get("campaigns"):
        lines += _md_table(["campaign", "runs finished / planned", "failed", "fault runs",
                            "nominal runs", "nominal h judged", "run time h (1 worker)",
                            "channels"],
                           [[c["campaign"], f"{c['n_finished']} / {c['n_planned']}"
                             + (f" (fraction {c['fraction']:g})" if c["fraction"] < 1 else "")
                             + "".join(f" ({k} {', '.join(v)})"
                                       for k, v in c.get("selection", {}).items()),
                             c["n_failed"], c["n_fault_runs"], c["n_nominal_runs"],
                             f"{c['nominal_hours']:.2f}", f"{c.get('run_hours', 0.0):.2f}",
                             ", ".join(c["channels"])]
                            for c in summary["campaigns"]])
        lines += ["False alarms per campaign and rule:", ""]
        lines += _md_table(["campaign", "channel", "false alarms (95 % upper / h)",
                            "fault-free h", "nominal h", "runs with a false alarm"],
                           [[c["campaign"], ch,
                             f"{fa['count']} (≤ {html.unescape(_fmt(fa['upper_95']))})",
                             f"{fa['hours']:.2f}", f"{fa['nominal_hours']:.2f}",
                             fa["runs_with_false_alarm"]]
                            for c in summary["campaigns"]
                            for ch, fa in c.get("false_alarms", {}).items()])
    rows = []
    for ch, fa in summary["false_alarms"].items():
        d = summary["delay"].get(f"all {ch}", {})
        c = summary["confusion"].get(ch, {})
        det = [r for r in summary["detection"] if _channel_of(summary, r) == ch]
        rows.append([ch, f"{fa['count']} in {fa['hours']:.2f} h (≤ "
                         f"{html.unescape(_fmt(fa['upper_95']))})",
                     f"{sum(r['detected'] for r in det)} of {sum(r['n'] for r in det)}",
                     " / ".join(_fmt(d.get(k)) for k in ("median_s", "p95_s", "max_s")),
                     f"{c.get('correct', 0)} of {c.get('n', 0)}" if c else
                     "n/a (names no fault kind)"])
    lines += _md_table(["channel", "false alarms / h (95 % upper)", "detected",
                        "delay median / p95 / max, s", "isolated right"], rows)
    lines += _md_table(["class", "fault", "magnitude", "detected", "isolated right",
                        "axis right", "typed right"],
                       [[r["class"], r["fault_type"], r["magnitude"],
                         f"{r['detected']} of {r['n']}",
                        f"{r['isolated']} of {r['n']}" if r.get("isolated") is not None
                        else "n/a",
                         f"{r['axis_right']} of {r['n']}" if "axis_right" in r else "–",
                         f"{r['typed']} of {r['n_typed']}" if "typed" in r else "–"]
                        for r in summary["detection"]])
    lines += _witness_markdown(summary.get("witnesses") or {})
    lines += _grey_markdown(summary.get("grey") or {})
    for key, sw in summary["threshold_sweep"].items():
        lines.append(f"Threshold sweep, {key} (configured {sw['configured_threshold']}):")
        lines.append("")
        lines += _md_table(["threshold", "detection rate", "false alarms / h", "95 % upper / h"],
                           [list(x) for x in zip(sw["thresholds"], sw["detection_rate"],
                                                 sw["false_alarms_per_h"], sw["upper_95_per_h"],
                                                 strict=True)])
    return "\n".join(lines)


def _witness_markdown(w: dict[str, Any]) -> list[str]:
    if not w:
        return []
    names = w["names"]
    lines = ["System runs: false alarms per witness and flight-condition group:", ""]
    lines += _md_table(["witness", "group", "false alarms (95 % upper / h)",
                        "fault-free h (nominal runs)", "runs with a false alarm"],
                       [[fa["witness"], fa["group"],
                         f"{fa['count']} (≤ {html.unescape(_fmt(fa['upper_95']))})",
                         f"{fa['hours']:.2f} ({fa['nominal_hours']:.2f})",
                         fa["runs_with_false_alarm"]] for fa in w["false_alarms"].values()])
    lines += ["System runs: detection per witness (delay median, s):", ""]
    lines += _md_table(["class", "fault", "magnitude", "group", "n", *names, "both",
                        "either"],
                       [[r["class"], r["fault_type"], r["magnitude"], r["group"], r["n"],
                         *(f"{r[n]['detected']} ({html.unescape(_fmt(r[n]['delay']['median_s']))})"
                           for n in names), r["both"]["detected"],
                         r.get("either", {}).get("detected", "–")]
                        for r in w["detection"]])
    if w["comparison"]:
        lines += ["Detection rate in each group against level flight (points):", ""]
        cols = [n for n in [*names, "both", "either"]
                if all(n in c for c in w["comparison"])]
        lines += _md_table(["class", "fault", "magnitude", "group",
                            *(f"{n}: level → group (points)" for n in cols)],
                           [[c["class"], c["fault_type"], c["magnitude"], c["group"],
                             *(f"{c[n]['level']:.2f} → {c[n]['group']:.2f} "
                               f"({c[n]['points']:+.1f})" for n in cols)]
                            for c in w["comparison"]])
    return lines


def _grey_tables(g: dict[str, Any]) -> list[tuple[str, list[str], list[list[Any]]]]:
    """Grey section as (caption, header, rows): false alarms per rule and group, per rule
    a fault × group table, per rule the threshold sweep by group."""
    if not g:
        return []
    groups, target = g["groups"], g["target_delay_s"]
    tables = [("Grey channel: false alarms per rule and condition group (fault-free time "
               "after warm-up/calibration: nominal runs and before each onset; count in "
               "hours, 95 % upper bound per hour):", ["rule", *groups, "all"],
               [[rule, *(f"{fa['count']} in {fa['hours']:.2f} h (≤ "
                         f"{html.unescape(_fmt(fa['upper_95']))})"
                         for fa in (g["false_alarms"][f"{rule}/{grp}"]
                                    for grp in [*groups, "all"]))]
                for rule in g["rules"]])]
    for rule in g["rules"]:
        rows = [r for r in g["detection"] if r["rule"] == rule]
        keys = list(dict.fromkeys((r["fault_type"], r["magnitude"]) for r in rows))
        table = []
        for ftype, mag in keys:
            cells = []
            for grp in groups:
                r = next((x for x in rows if (x["fault_type"], x["magnitude"], x["group"])
                          == (ftype, mag, grp)), None)
                if r is None:
                    cells.append("–")
                    continue
                d = r["delay"]
                cells.append(f"{r['detected']}/{r['n']} ({r['within_target']}) · "
                             + " / ".join(html.unescape(_fmt(d[k]))
                                          for k in ("median_s", "p95_s", "max_s"))
                             + (f" · +{r['standing']} st" if r["standing"] else ""))
            table.append([ftype, mag, *cells])
        tables.append((f"Grey channel, rule {rule}: detected of n (of them within {target:g} "
                       "s) · delay median / p95 / max, s; per condition group (\"+k st\": k "
                       "of the detections are an alarm already standing at the onset):",
                       ["fault", "magnitude", *groups], table))
    for rule in g["rules"]:
        sw = [g["threshold_sweep"][f"{rule}/{grp}"] for grp in [*groups, "all"]]
        tables.append((f"Threshold sweep, rule {rule} (× its threshold; detection rate / "
                       "false alarms per hour):", ["threshold", *groups, "all"],
                       [[t, *(f"{html.unescape(_fmt(x['detection_rate'][j]))} / "
                              f"{html.unescape(_fmt(x['false_alarms_per_h'][j]))}"
                              for x in sw)]
                        for j, t in enumerate(sw[-1]["thresholds"])]))
    return tables


def _grey_markdown(g: dict[str, Any]) -> list[str]:
    """Grey section of ``summary.md`` (:func:`_grey_tables`)."""
    lines: list[str] = []
    for caption, header, rows in _grey_tables(g):
        lines += [caption, "", *_md_table(header, rows)]
    return lines


def _channel_of(summary: dict[str, Any], row: dict[str, Any]) -> str:
    return summary.get("class_channels", {}).get(row["class"], row["class"])


def write_report(summary: dict[str, Any], records: list[dict[str, Any]], out_dir: Path,
                 title: str = "campaign") -> dict[str, Path]:
    """Write ``summary.json``, ``summary.md``, the plots and ``report.html`` into
    ``out_dir``."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    json_path = out_dir / "summary.json"
    json_path.write_text(json.dumps(summary, indent=1), encoding="utf-8")
    md_path = out_dir / "summary.md"
    md_path.write_text(markdown_summary(summary, title), encoding="utf-8")
    plots = _plots(summary, records, out_dir)
    parts = [f"<h1>Campaign {html.escape(title)}</h1>",
             f"<p>{summary['n_finished']} of {summary['n_planned']} runs finished: "
             f"{summary['n_fault_runs']} fault runs, {summary['n_nominal_runs']} nominal, "
             f"{summary['n_failed']} failed.</p>",
             *([_table(["campaign", "finished", "planned", "failed", "fault runs",
                        "nominal runs", "nominal h judged", "channels"],
                       [[c["campaign"], c["n_finished"], c["n_planned"], c["n_failed"],
                         c["n_fault_runs"], c["n_nominal_runs"], c["nominal_hours"],
                         ", ".join(c["channels"])] for c in summary["campaigns"]])]
               if summary.get("campaigns") else []),
             "<h2>False alarms</h2>",
             *([_table(["campaign", "channel", "count", "fault-free h", "nominal h",
                        "rate /h", "95 % high"],
                       [[c["campaign"], ch, f["count"], f["hours"], f["nominal_hours"],
                         f["rate_per_h"], f["upper_95"]]
                        for c in summary["campaigns"]
                        for ch, f in c.get("false_alarms", {}).items()])]
               if summary.get("campaigns") else []),
             _table(["channel", "count", "fault-free h", "nominal h", "rate /h",
                     "95 % low", "95 % high"],
                    [[ch, f["count"], f["hours"], f["nominal_hours"], f["rate_per_h"],
                      f["lower_95"], f["upper_95"]]
                     for ch, f in summary["false_alarms"].items()]),
             "<h2>Detection rate</h2>",
             _table(["class", "fault", "magnitude", "runs", "detected", "rate", "95 % CI",
                     "isolated right"],
                    [[r["class"], r["fault_type"], r["magnitude"], r["n"], r["detected"],
                      r["rate"], f"{_fmt(r['ci_low'])}–{_fmt(r['ci_high'])}",
                      r.get("isolated", "")]
                     for r in summary["detection"]]),
             "<h2>Detection delay (s)</h2>",
             _table(["group", "n", "median", "p95", "max"],
                    [[k, d["n"], d["median_s"], d["p95_s"], d["max_s"]]
                     for k, d in summary["delay"].items()])]
    for caption, header, rows in _grey_tables(summary.get("grey") or {}):
        parts += [f"<h2>{html.escape(caption.rstrip(':'))}</h2>", _table(header, rows)]
    for ch, c in summary["confusion"].items():
        parts.append(f"<h2>Isolation, {html.escape(ch)}: {c['correct']} of {c['n']} right</h2>")
        parts.append(_table(["injected \\ diagnosed", *c["diagnosed"]],
                            [[lab, *row] for lab, row in zip(c["injected"], c["matrix"],
                                                              strict=True)]))
    for key, s in summary["threshold_sweep"].items():
        parts.append(f"<h2>Threshold sweep, {html.escape(key)} (configured "
                     f"{s['configured_threshold']}, reconstruction mismatch "
                     f"{_fmt(s['max_mismatch'])})</h2>")
        parts.append(_table(["threshold", "detection rate", "false alarms /h", "95 % upper /h"],
                            [list(x) for x in zip(s["thresholds"], s["detection_rate"],
                                                  s["false_alarms_per_h"], s["upper_95_per_h"],
                                                  strict=True)]))
    if summary["failures"]:
        parts.append("<h2>Failed runs</h2>")
        parts.append(_table(["run", "status", "error"],
                            [[f["run_id"], f["status"], f["error"]]
                             for f in summary["failures"]]))
    parts += [f'<p><img src="{p.name}" alt="{p.stem}"></p>' for p in plots]
    style = ("<style>body{font-family:sans-serif;margin:2em}table{border-collapse:collapse;"
             "margin:0.5em 0}td,th{border:1px solid #bbb;padding:2px 6px;font-size:90%}"
             "</style>")
    html_path = out_dir / "report.html"
    html_path.write_text(f"<!doctype html><html><head><meta charset='utf-8'><title>"
                         f"{html.escape(title)}</title>{style}</head><body>"
                         + "\n".join(parts) + "</body></html>", encoding="utf-8")
    return {"json": json_path, "markdown": md_path, "html": html_path,
            **{p.stem: p for p in plots}}
