"""Judging a run: its recorded signals into the record fields (detection, delay, false
alarms, diagnosis, threshold sweep) per channel and rule, the grey replay and witnesses,
and :func:`simulate_run`, the default runner.  What is judged how:
:mod:`gyrodiag_harness.campaigns.campaign` (module docstring)."""

from __future__ import annotations

import json
import math
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from gyrodiag_harness.campaigns.expand import build_scenario
from gyrodiag_harness.campaigns.spec import (
    AIRCRAFT_SENSORS,
    DEFAULT_THRESHOLDS,
    GREY_SIGNALS,
    SYSTEM_WITNESSES,
    RunSpec,
)


def _param(scenario: Any, instance: str, name: str, default: Any) -> Any:
    return scenario.fmus[instance].parameters.get(name, default)


def _kth_largest_window(z: np.ndarray, k: int, n: int) -> np.ndarray:
    """``out[t]`` = k-th largest of ``z[t-n+1 .. t]`` (zeros before the start)."""
    padded = np.concatenate([np.zeros(n - 1), z])
    windows = np.lib.stride_tricks.sliding_window_view(padded, n)
    return np.sort(windows, axis=1)[:, n - k]


def alarm_statistic(run: RunSpec, scenario: Any, t: np.ndarray,
                    sig: dict[str, np.ndarray]) -> tuple[np.ndarray, float, float]:
    """The alarm statistic ``s(t)`` in threshold units (module docstring), the time from
    which the channel judges (end of calibration / learning) and its configured
    threshold."""
    d = run.diagnoser
    if run.channel == "df" and _df_sequential(scenario, d):
        # the channel's own statistic: the largest CUSUM per sensor over its threshold
        # (capped at 1), so thresholds T <= 1 of the sweep are exact up to the first
        # alarm; the alarm itself is df.detected (an episode, cleared when the fault is)
        stat = np.column_stack([sig[f"{d}.df.statistic[{i}]"] for i in range(1, 7)])
        ready = np.flatnonzero(sig[f"{d}.df.calibrating"] < 0.5)
        ready = ready[ready > 0]
        t_ready = float(t[ready[0]]) if ready.size else float(t[-1])
        s = np.where(t >= t_ready, stat.max(axis=1), 0.0)
        return s, t_ready, 1.0
    if run.channel == "df":
        period = float(_param(scenario, d, "sample_period_s", scenario.step_s))
        cal_s = float(_param(scenario, d, "df.calibrate_s", 10.0))
        burn_s = float(_param(scenario, d, "df.burn_in_s", 2.0))
        k_sigma = float(_param(scenario, d, "df.k_sigma", 6.0))
        pk = int(_param(scenario, d, "df.persistence_k", 3))
        pn = int(_param(scenario, d, "df.persistence_n", 5))
        n_cal, n_burn = round(cal_s / period), round(burn_s / period)
        n_burn = min(n_burn, n_cal - 2)
        # row j (j >= 1) is the channel's j-th sample; rows 1..n_cal calibrate
        if f"{d}.df.statistic[1]" in sig:
            # the channel's own |r - mu| / (k sigma) per sample: its mu, sigma and the
            # alignment it chose (with Jacobi coupling the recorded residuals of the
            # calibration window are not those it calibrated on)
            z = k_sigma * np.column_stack([sig[f"{d}.df.statistic[{i}]"]
                                           for i in range(1, 7)])[n_cal + 1:]
        else:
            res = np.column_stack([sig[f"{d}.df.residual[{i}]"] for i in range(1, 7)])
            used = res[1 + n_burn:n_cal + 1]
            mu, sd = used.mean(axis=0), used.std(axis=0, ddof=1)
            sd = np.maximum(sd, 1e-12 / k_sigma)
            z = np.abs(res[n_cal + 1:] - mu) / sd
        s_after = np.max(np.column_stack([_kth_largest_window(z[:, i], pk, pn)
                                          for i in range(z.shape[1])]), axis=1)
        s = np.concatenate([np.zeros(n_cal + 1), s_after])
        t_ready = float(t[min(n_cal + 1, len(t) - 1)])
        return s, t_ready, k_sigma
    low = float(_param(scenario, d, "dtg.low", 0.5))
    high = float(_param(scenario, d, "dtg.high", 1.5))
    monitored = [bool(_param(scenario, d, f"dtg.monitored[{i}]", True)) for i in range(1, 6)]
    eta = np.column_stack([sig[f"{d}.dtg.eta_{ax}[{i}]"] for ax in "xy"
                           for i in range(1, 6) if monitored[i - 1]])
    learning = sig[f"{d}.dtg.learning"] > 0.5
    dev = np.abs(eta - 1.0)
    dev = np.where(np.isfinite(dev), dev, np.inf)
    if not math.isclose(1.0 - low, high - 1.0, rel_tol=1e-9):
        raise ValueError(f"{d}: dtg.low/dtg.high ({low}, {high}) are not symmetric about 1: "
                         "the threshold sweep needs a symmetric band")
    band = _band_statistic(scenario, d, t, dev, sum(monitored))
    if str(_param(scenario, d, "dtg.classifier", "pattern")) == "pattern":
        return _pattern_statistic(scenario, d, t, sig, band / (high - 1.0))
    s = np.where(learning, 0.0, band)
    ready = np.flatnonzero(~learning & (t > 0))
    t_ready = float(t[ready[0]]) if ready.size else float(t[-1])
    return s, t_ready, high - 1.0


def _band_statistic(scenario: Any, d: str, t: np.ndarray, dev: np.ndarray,
                    per_axis: int) -> np.ndarray:
    """|η − 1| of the ratio band as the channel decides it: per axis, the k-th largest
    of the largest deviation over the last n samples (``dtg.persistence_k``/``_n``; the
    axes alarm independently). Records kept every few samples count k and n in kept
    rows (rounded: approximate there)."""
    pk = int(_param(scenario, d, "dtg.persistence_k", 1))
    pn = int(_param(scenario, d, "dtg.persistence_n", 1))
    axes = [dev[:, :per_axis].max(axis=1), dev[:, per_axis:].max(axis=1)]
    if pn <= 1 or t.size < 2:
        return np.maximum(*axes)
    period = float(_param(scenario, d, "sample_period_s", scenario.step_s))
    rows = max(float(np.median(np.diff(t))) / period, 1.0)
    k = max(1, math.ceil(pk / rows - 1e-9))
    n = max(k, round(pn / rows))
    return np.maximum(*(_kth_largest_window(a, k, n) for a in axes))


def _pattern_statistic(scenario: Any, d: str, t: np.ndarray, sig: dict[str, np.ndarray],
                       band: np.ndarray) -> tuple[np.ndarray, float, float]:
    """Pattern classifier: the largest raise statistic in units of its threshold —
    residual level z / dtg.level_threshold, log variance ratios / log of their
    thresholds, the low-frequency power CUSUM / dtg.power_threshold (recorded that way;
    it is capped at 1, so only ``T <= 1`` is exact for it) and the ratio band's
    |η − 1| / (high − 1). ``T = 1`` is the configured setting; the FMU's alarm also holds
    below the raise thresholds (hold thresholds, ``dtg.clear_after_s``), which
    ``sweep_mismatch`` shows."""
    z_thr = float(_param(scenario, d, "dtg.level_threshold", 6.0))
    v_thr = float(_param(scenario, d, "dtg.var_threshold", 4.0))
    vl_thr = float(_param(scenario, d, "dtg.long_var_threshold", 2.0))
    parts = [band]
    for a in (1, 2):
        parts.append(sig[f"{d}.dtg.residual_level_z[{a}]"] / z_thr)
        parts.append(np.log10(np.maximum(sig[f"{d}.dtg.residual_var_ratio[{a}]"], 1e-12))
                     / math.log10(v_thr))
        parts.append(np.log10(np.maximum(sig[f"{d}.dtg.residual_long_var_ratio[{a}]"],
                                         1e-12)) / math.log10(vl_thr))
        power = sig.get(f"{d}.dtg.residual_power_cusum[{a}]")
        if power is not None:
            parts.append(power)
    s = np.max(np.column_stack(parts), axis=1)
    # judged from the first sample with a reference (status >= 1), as the channel
    ready_mask = (sig[f"{d}.dtg.reference_status"] > 0.5) & (t > 0)
    s = np.where(ready_mask, s, 0.0)
    ready = np.flatnonzero(ready_mask)
    t_ready = float(t[ready[0]]) if ready.size else float(t[-1])
    return s, t_ready, 1.0


def _df_sequential(scenario: Any, diagnoser: str) -> bool:
    """The detection-filter channel decides sequentially (``df.decision`` = 1, or 2 -
    auto, the default - without a read-out model) rather than by the paper's rule (0,
    or auto with ``df.sensor_dynamics_file``), as the Diagnoser chooses."""
    from gyrodiag.df.channel import DECISION_AUTO, decision_rule

    code = int(_param(scenario, diagnoser, "df.decision", DECISION_AUTO))
    name = "df.sensor_dynamics_file"  # a parameter, or (a path) in the instance's files
    given = _param(scenario, diagnoser, name, None) or scenario.fmus[diagnoser].files.get(name)
    return decision_rule(code, bool(str(given or "").strip())) == "sequential"


#: Fault type name the detection filter should report, per injector fault type.
EXPECTED_DF_TYPE = {"bias": "bias", "step": "bias", "gain": "gain", "stuck_last": "stuck",
                    "stuck_value": "stuck", "failure": "failure", "noise": "noise",
                    "ramp": "ramp", "intermittent": "intermittent"}
#: df.fault_type codes.
DF_TYPE_NAMES = {-1: "unknown", 0: "none", 1: "bias", 2: "gain", 3: "stuck", 4: "failure",
                 5: "noise", 6: "ramp", 7: "intermittent"}


def _rising_edges(on: np.ndarray) -> np.ndarray:
    prev = np.concatenate([[False], on[:-1]])
    return np.flatnonzero(on & ~prev)


def judge(t: np.ndarray, alarm: np.ndarray, t_ready: float,
          onset_s: float | None) -> tuple[bool, float | None, int, float]:
    """Detection and false alarms of one alarm signal (see the module docstring).

    Returns ``(detected, delay_s, false_alarms, fault_free_s)``; detection and delay are
    False/None for a nominal run (``onset_s`` None).
    """
    end = float(t[-1])
    free_end = end if onset_s is None else min(onset_s, end)
    edges = t[_rising_edges(alarm)]
    n_false = int(np.count_nonzero((edges >= t_ready) & (edges < free_end)))
    # an alarm standing at t_ready was raised in the judged time
    ready_idx = np.searchsorted(t, t_ready)
    if ready_idx < len(t) and alarm[ready_idx] and ready_idx > 0 and alarm[ready_idx - 1] \
            and t_ready < free_end:
        n_false += 1
    fault_free = max(free_end - t_ready, 0.0)
    if onset_s is None:
        return False, None, n_false, fault_free
    hit = np.flatnonzero((t >= onset_s - 1e-9) & alarm)
    if hit.size == 0:
        return False, None, n_false, fault_free
    return True, float(t[hit[0]] - onset_s), n_false, fault_free


def simulate_run(run_dict: dict[str, Any]) -> dict[str, Any]:
    """The default runner: simulate one run and return its record fields.

    Parameters
    ----------
    run_dict : dict
        A :class:`RunSpec` as a dict.

    Returns
    -------
    dict
        ``detected``, ``delay_s`` (s), ``false_alarms``, ``fault_free_s`` (s),
        ``diagnosed``, ``sweep`` and ``sweep_mismatch`` (module docstring).

    Raises
    ------
    RuntimeError
        If the co-simulation stopped on an FMU error (the message quotes it).
    """
    from gyrodiag_harness.cosim.master import run_scenario

    run = RunSpec.model_validate(run_dict)
    scenario = build_scenario(run)
    result = run_scenario(scenario, fmu_dir=run.fmu_dir, progress=False,
                          results_dir=run.results_dir)
    if result.error is not None:
        raise RuntimeError(f"co-simulation failed: {result.error}")
    t, sig = result.time, result.signals
    if run.channel == "system":
        return _judge_system(run, t, sig, result.wall_time_s)
    if run.channel == "grey":
        return _judge_grey(run, scenario, t, sig, result.wall_time_s)
    if run.witnesses:
        return _judge_witnesses(run, scenario, t, sig, result.wall_time_s)
    return {**judge_diagnoser(run, scenario, t, sig), "sim_wall_s": result.wall_time_s}


def judge_diagnoser(run: RunSpec, scenario: Any, t: np.ndarray,
                    sig: dict[str, np.ndarray]) -> dict[str, Any]:
    """The record fields of the ``df`` or ``dtg`` channel of Diagnoser ``run.diagnoser``
    with its own rule (read from its parameters in ``scenario``): alarm, detection,
    false alarms, diagnosis and threshold sweep (module docstring; no ``sim_wall_s``)."""
    d = run.diagnoser
    extra: dict[str, Any] = {}
    if run.channel == "df":
        sequential = _df_sequential(scenario, d)
        if sequential:
            alarm = sig[f"{d}.df.detected"] > 0.5
        else:
            alarm = np.any(np.column_stack([sig[f"{d}.df.alarm[{i}]"] > 0.5
                                            for i in range(1, 7)]), axis=1)
        diagnosed_value = int(np.rint(sig[f"{d}.df.isolated_sensor"][-1]))
        mask = int(np.rint(sig[f"{d}.df.isolated_mask"][-1]))
        if 1 <= diagnosed_value <= len(AIRCRAFT_SENSORS):
            diagnosed = AIRCRAFT_SENSORS[diagnosed_value - 1]
        elif diagnosed_value == -2:
            diagnosed = ("+".join(name for k, name in enumerate(AIRCRAFT_SENSORS)
                                  if mask >> k & 1) or "multiple")
        else:
            diagnosed = {0: "none", -1: "not isolated"}.get(diagnosed_value,
                                                             str(diagnosed_value))
        if sequential:
            code = int(np.rint(sig[f"{d}.df.fault_type"][-1]))
            extra = {"typed": DF_TYPE_NAMES.get(code, str(code)),
                     # a sweep's label names the row; the injected type says what to expect
                     "expected_type": (EXPECTED_DF_TYPE.get(run.fault_type or "")
                                       or EXPECTED_DF_TYPE.get((run.fault or {}).get("type", ""))
                                       if not run.also else None),
                     "size": float(sig[f"{d}.df.fault_magnitude"][-1]),
                     "episodes": int(np.rint(sig[f"{d}.df.episodes"][-1])),
                     "input_delay": int(np.rint(sig[f"{d}.df.input_delay_in_use"][-1]))}
    else:
        alarm = sig[f"{d}.dtg.alarm"] > 0.5
        code = int(np.rint(sig[f"{d}.dtg.fault_code"][-1]))
        names = _signature_names(scenario, run)
        diagnosed = (names[code - 1] if 1 <= code <= len(names)
                     else {0: "none", -1: "unknown"}.get(code, f"code {code}"))
        axis = f"{d}.dtg.fault_axis"
        # only the pattern classifier names an axis (the paper's codes are classes)
        extra["diagnosed_axis"] = (int(np.rint(sig[axis][-1])) if axis in sig
                                   and _dtg_classifier(scenario, d) == "pattern" else None)
    stat, t_ready, t_config = alarm_statistic(run, scenario, t, sig)
    detected, delay, n_false, free = judge(t, alarm, t_ready, run.onset_s)
    judged = t >= t_ready
    mismatch = float(np.mean((stat[judged] > t_config) != alarm[judged])) if judged.any() \
        else 0.0
    sweep: dict[str, list[Any]] = {"detected": [], "delay_s": [], "false_alarms": []}
    for thr in run.thresholds:
        det_t, del_t, fa_t, _ = judge(t, stat > thr, t_ready, run.onset_s)
        sweep["detected"].append(det_t)
        sweep["delay_s"].append(del_t)
        sweep["false_alarms"].append(fa_t)
    before = stat[judged & (t < (run.onset_s if run.onset_s is not None else math.inf))]
    after = stat[t >= run.onset_s] if run.onset_s is not None else np.zeros(0)
    return {
        "detected": detected, "delay_s": delay, "false_alarms": n_false,
        "fault_free_s": free, "t_ready_s": t_ready, "diagnosed": diagnosed,
        "threshold_config": t_config, "sweep": sweep, "sweep_mismatch": mismatch,
        "peak_before": float(before.max()) if before.size else None,
        "peak_after": float(after.max()) if after.size else None, **extra,
    }


def _dtg_classifier(scenario: Any, diagnoser: str) -> str:
    return str(_param(scenario, diagnoser, "dtg.classifier", "pattern"))


def _judge_witnesses(run: RunSpec, scenario: Any, t: np.ndarray, sig: dict[str, np.ndarray],
                     wall_s: float) -> dict[str, Any]:
    """Every witness of a df/dtg run judged with its own rule (:func:`judge_diagnoser`
    on that instance, its own sweep grid in ``thresholds``); the top-level fields are the
    first witness's (the summary splits the record per witness, module docstring)."""
    witnesses = {}
    for w in run.witnesses:
        copy = run.witness_copies.get(w)
        grid = (copy.thresholds if copy is not None and copy.thresholds is not None
                else run.thresholds if copy is None else DEFAULT_THRESHOLDS[run.channel])
        one = run.model_copy(update={"diagnoser": w, "witnesses": [], "thresholds": grid})
        witnesses[w] = {**judge_diagnoser(one, scenario, t, sig), "thresholds": list(grid)}
    first = witnesses[run.witnesses[0]]
    return {**first, "sim_wall_s": wall_s, "witnesses": witnesses}


def _ready_time(t: np.ndarray, not_ready: np.ndarray) -> float:
    ready = np.flatnonzero((not_ready < 0.5) & (t > 0))
    return float(t[ready[0]]) if ready.size else float(t[-1])


def _judge_system(run: RunSpec, t: np.ndarray, sig: dict[str, np.ndarray],
                  wall_s: float) -> dict[str, Any]:
    """Both witnesses of a system run and "either" at the top level (module docstring)."""
    d = run.diagnoser
    witnesses: dict[str, dict[str, Any]] = {}
    alarms = []
    readies = []
    for name, (alarm_name, ready_name) in SYSTEM_WITNESSES.items():
        alarm = sig[f"{d}.{alarm_name}"] > 0.5
        t_ready = _ready_time(t, sig[f"{d}.{ready_name}"])
        detected, delay, n_false, free = judge(t, alarm, t_ready, run.onset_s)
        witnesses[name] = {"detected": detected, "delay_s": delay, "false_alarms": n_false,
                           "fault_free_s": free, "t_ready_s": t_ready}
        alarms.append(alarm)
        readies.append(t_ready)
    witnesses["dtg"]["diagnosed"] = int(np.rint(sig[f"{d}.dtg.fault_code"][-1]))
    sensor = int(np.rint(sig[f"{d}.df.isolated_sensor"][-1]))
    witnesses["df"].update(
        diagnosed=sensor, fault_type_code=int(np.rint(sig[f"{d}.df.fault_type"][-1])),
        magnitude=float(sig[f"{d}.df.fault_magnitude"][-1]))
    t_ready = max(readies)
    either = np.logical_or.reduce(alarms)
    detected, delay, n_false, free = judge(t, either, t_ready, run.onset_s)
    diagnosed = (AIRCRAFT_SENSORS[sensor - 1] if 1 <= sensor <= len(AIRCRAFT_SENSORS)
                 else {0: "none", -1: "not isolated"}.get(sensor, str(sensor)))
    return {"detected": detected, "delay_s": delay, "false_alarms": n_false,
            "fault_free_s": free, "t_ready_s": t_ready, "diagnosed": diagnosed,
            "threshold_config": math.nan, "sweep": {"detected": [], "delay_s": [],
                                                   "false_alarms": []},
            "sweep_mismatch": 0.0, "peak_before": None, "peak_after": None,
            "sim_wall_s": wall_s, "witnesses": witnesses}


GreyReplay = Callable[[np.ndarray, np.ndarray, np.ndarray, float], np.ndarray]


def grey_replay(scenario: Any, witness: str) -> GreyReplay | None:
    """A function ``(t, y, valid, T) -> alarm`` replaying the paper's fixed-threshold grey
    rule of ``witness`` (``grey.decision = 0``) at ``T`` times its ``grey.threshold``, or
    None for a learned rule (``grey.decision`` 1 or 2, the default 1), which is swept on
    its statistic instead.

    The detector is built as the Diagnoser FMU builds it (its parameter defaults) and fed
    the recorded samples ``y`` (V) at times ``t`` (s).  Its first sample is the row that
    lies the predictor's window before the FMU's first ``grey.prediction_valid`` row
    (``valid``): with Gauss-Seidel coupling the Diagnoser steps after the plant, so row 0
    holds initial outputs that it never processed.
    """
    from gyrodiag.grey import ClassicGreyPredictor, GreyFaultDetector, ImprovedGreyPredictor

    def par(name: str, default: Any) -> Any:
        return _param(scenario, witness, name, default)

    if int(par("grey.decision", 1)) != 0:
        return None
    model, window = int(par("grey.model", 1)), int(par("grey.window", 10))
    threshold = float(par("grey.threshold", 0.05))
    clear = float(par("grey.clear_after_s", 20.0))
    period = float(par("sample_period_s", scenario.step_s))

    def replay(t: np.ndarray, y: np.ndarray, valid: np.ndarray, multiple: float
               ) -> np.ndarray:
        if model == 1:
            predictor: Any = ImprovedGreyPredictor(
                window, a_min=float(par("grey.a_min", 1e-6)),
                residual_order=int(par("grey.residual_order", 2)))
        else:
            evaluation = int(par("grey.classic_evaluation", 0))
            predictor = ClassicGreyPredictor(
                None if window == 0 else window,
                evaluation="textbook" if evaluation == 1 else "careful")
        det = GreyFaultDetector(predictor, multiple * threshold, period,
                                None if clear <= 0 else clear)
        first = np.flatnonzero(valid > 0.5)
        start = max(int(first[0]) - predictor.min_samples, 0) if first.size else len(t)
        alarm = np.zeros(len(t), dtype=bool)
        for i in range(start, len(t)):
            alarm[i] = det.update(float(y[i]), time_s=float(t[i])).alarm
        return alarm

    return replay


def judge_grey_witness(t: np.ndarray, sig: dict[str, np.ndarray], witness: str,
                       onset_s: float | None, thresholds: Sequence[float],
                       replay: GreyReplay | None = None) -> dict[str, Any]:
    """One grey-channel witness of a run: its alarm judged from its first ready sample,
    and its threshold sweep, replayed or on ``grey.statistic`` (module docstring).

    Parameters
    ----------
    t : ndarray
        Sample times, s.
    sig : dict
        Recorded signals; needs ``<witness>.<name>`` for every name in
        :data:`GREY_SIGNALS` (``grey.y`` in V).
    witness : str
        Diagnoser instance name.
    onset_s : float or None
        Fault onset, s (None: a nominal run).
    thresholds : sequence of float
        Sweep grid, multiples of the witness's threshold (1 = its own rule).
    replay : callable, optional
        :func:`grey_replay` of a fixed-threshold rule; None: sweep on the statistic.

    Returns
    -------
    dict
        ``detected``, ``delay_s`` (s), ``false_alarms``, ``fault_free_s`` (s),
        ``t_ready_s`` (s), ``sweep`` (lists per threshold), ``sweep_mismatch`` (share of
        the judged samples where the rebuilt alarm at 1x differs from the FMU's),
        ``sweep_replayed``, ``alarm_at_onset`` (the alarm was on at the last sample
        before the onset), ``peak_before`` / ``peak_after`` (largest statistic before /
        from the onset).
    """
    missing = [n for n in GREY_SIGNALS if f"{witness}.{n}" not in sig]
    if missing:
        raise ValueError(f"witness {witness!r}: {witness}.{missing[0]} was not recorded")
    alarm = sig[f"{witness}.grey.alarm"] > 0.5
    stat = np.asarray(sig[f"{witness}.grey.statistic"], dtype=float)
    not_ready = ((sig[f"{witness}.grey.calibrating"] > 0.5)
                 | (sig[f"{witness}.grey.prediction_valid"] < 0.5)).astype(float)
    t_ready = _ready_time(t, not_ready)
    detected, delay, n_false, free = judge(t, alarm, t_ready, onset_s)
    judged = t >= t_ready
    y = np.asarray(sig[f"{witness}.grey.y"], dtype=float)
    valid = sig[f"{witness}.grey.prediction_valid"]

    def rebuilt(multiple: float) -> np.ndarray:
        return (replay(t, y, valid, multiple) if replay is not None
                else judged & (stat > multiple))

    mismatch = float(np.mean(rebuilt(1.0)[judged] != alarm[judged])) if judged.any() else 0.0
    sweep: dict[str, list[Any]] = {"detected": [], "delay_s": [], "false_alarms": []}
    for thr in thresholds:
        det_t, del_t, fa_t, _ = judge(t, rebuilt(thr), t_ready, onset_s)
        sweep["detected"].append(det_t)
        sweep["delay_s"].append(del_t)
        sweep["false_alarms"].append(fa_t)
    end = onset_s if onset_s is not None else math.inf
    before = stat[judged & (t < end)]
    after = stat[t >= end]
    # an alarm already on at the last sample before the onset: a "detection" that the
    # fault did not raise (a false alarm still standing)
    k = int(np.searchsorted(t, onset_s - 1e-9)) - 1 if onset_s is not None else -1
    return {"detected": detected, "delay_s": delay, "false_alarms": n_false,
            "fault_free_s": free, "t_ready_s": t_ready, "sweep": sweep,
            "sweep_mismatch": mismatch, "sweep_replayed": replay is not None,
            "alarm_at_onset": bool(k >= 0 and alarm[k]),
            "peak_before": float(before.max()) if before.size else None,
            "peak_after": float(after.max()) if after.size else None}


def _judge_grey(run: RunSpec, scenario: Any, t: np.ndarray, sig: dict[str, np.ndarray],
                wall_s: float) -> dict[str, Any]:
    """Every witness of a grey run; the top-level fields are the first witness's (the
    summary splits the record per witness, module docstring)."""
    witnesses = {w: judge_grey_witness(t, sig, w, run.onset_s, run.thresholds,
                                       grey_replay(scenario, w))
                 for w in run.witnesses}
    first = witnesses[run.witnesses[0]]
    return {**first, "diagnosed": None, "threshold_config": 1.0, "sim_wall_s": wall_s,
            "witnesses": witnesses}


def _signature_names(scenario: Any, run: RunSpec) -> list[str]:
    """Class names in code order: of the decade signatures, or of a pattern library."""
    from gyrodiag_harness.cosim.scenario import resolve_file_parameters

    files = resolve_file_parameters(scenario, run.results_dir, must_exist=False)
    path = files.get(run.diagnoser, {}).get("dtg.signature_file")
    if path is None and _dtg_classifier(scenario, run.diagnoser) == "pattern":
        from gyrodiag.dtg.patterns import default_library

        return default_library().names  # no file: the Diagnoser's shipped library
    if path is None or not Path(path).is_file():
        return []
    data = json.loads(Path(path).read_text(encoding="utf-8"))
    if "patterns" in data:
        return [c["name"] for c in data["patterns"]["classes"]]
    return list(data["signatures"])


