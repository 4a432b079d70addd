"""Diagnoser.fmu scenarios, run in a fresh process (docs/methods.md §6.11) by test_diagnoser_fmu.

``python _diagnoser_runner.py FMU_DIR OUT.npz IN.npz`` reads the input records from
IN.npz, runs every scenario below through fmpy and writes all outputs to OUT.npz.

This module must not import ``gyrodiag``: the FMU loads the copy shipped in its
resources into this interpreter, and the first imported copy would win (docs/methods.md §6.3).
The parameter sets live here so that the test module (which builds the library
references) and this process share them.
"""

from __future__ import annotations

import math
import shutil
import sys
from pathlib import Path
from typing import Any

import numpy as np

#: Input columns of every record (channels that are disabled ignore theirs).
IN_NAMES = (
    ["dtg.Utx", "dtg.Uty", "dtg.Ux", "dtg.Uy", "grey.y", "df.u[1]", "df.u[2]"]
    + [f"df.y[{i}]" for i in range(1, 7)]
)
SIGNATURE_TABLE = {1: [0, 0, 0, 0, -1], 2: [-3, -1, 1, 1, 2]}


def _signature_params(table: dict[int, list[int]]) -> dict[str, Any]:
    out: dict[str, Any] = {"dtg.n_signatures": len(table)}
    for j, sig in table.items():
        for i, c in enumerate(sig, start=1):
            out[f"dtg.signature[{j},{i}]"] = c
    return out


#: DTG channel alone at 1 kHz, experiment start 2.5 s.
DTG_H, DTG_START = 1e-3, 2.5
DTG_PARAMS: dict[str, Any] = {
    "sample_period_s": DTG_H, "grey.enabled": False, "df.enabled": False,
    "dtg.classifier": "paper",
    "dtg.p0": 1e8, "dtg.forgetting": 0.99, "dtg.learn_start_s": 0.5, "dtg.learn_end_s": 2.0,
    "dtg.persistence_k": 3, "dtg.persistence_n": 5, **_signature_params(SIGNATURE_TABLE),
}
#: DTG with a given θ0 and the signature library from a file (set as a String).
SIGFILE_PARAMS: dict[str, Any] = {
    "sample_period_s": DTG_H, "grey.enabled": False, "df.enabled": False,
    "dtg.classifier": "paper", "dtg.forgetting": 0.99,
    "dtg.p0": 1e8, "dtg.prefilter_enabled": False, "dtg.learn_theta0": False,
}
#: DTG with the (default) pattern classifier at 1 kHz; the library file is set at run
#: time (``dtg.signature_file`` = the input's ``patterns_1khz_path``).
PATTERN_PARAMS: dict[str, Any] = {
    "sample_period_s": DTG_H, "grey.enabled": False, "df.enabled": False,
    "dtg.p0": 1e8, "dtg.learn_start_s": 0.5, "dtg.learn_end_s": 2.0,
}
#: Save point of the pattern scenario: inside the learning window (learner state).
K_PATTERN_SAVE = 1200
K_PATTERN_RERUN = 2000
#: NaN sample of the pattern scenario, inside the learning window.
K_PATTERN_NAN = 900
#: Grey channel alone at 10 Hz (improved and classic models).
GREY_H = 0.1
GREY_PARAMS: dict[str, Any] = {
    "sample_period_s": GREY_H, "dtg.enabled": False, "df.enabled": False,
    "grey.decision": 0, "grey.model": 1, "grey.window": 10, "grey.threshold": 0.02,
    "grey.clear_after_s": 5.0, "grey.a_min": 1e-6,
}
GREY_CLASSIC_PARAMS = {**GREY_PARAMS, "grey.model": 0, "grey.window": 8,
                       "grey.clear_after_s": 0.0}
#: Detection filter alone at 100 Hz with online calibration.
DF_H = 0.01
DF_PARAMS: dict[str, Any] = {
    "sample_period_s": DF_H, "dtg.enabled": False, "grey.enabled": False,
    "df.calibrate_s": 8.0, "df.burn_in_s": 2.0, "df.k_sigma": 6.0,
}
#: All three channels at 100 Hz, experiment start 1 s.
ALL_H, ALL_START = 0.01, 1.0
ALL_PARAMS: dict[str, Any] = {
    "sample_period_s": ALL_H,
    "dtg.prefilter_cutoff_hz": 20.0, "dtg.p0": 1e8, "dtg.forgetting": 0.99,
    "dtg.learn_start_s": 0.5, "dtg.learn_end_s": 2.0, "dtg.persistence_k": 3,
    "dtg.persistence_n": 5,
    "grey.decision": 0, "grey.window": 10, "grey.threshold": 0.01, "grey.clear_after_s": 3.0,
    "df.calibrate_s": 5.0, "df.burn_in_s": 1.0,
}
#: Save points of the state scenario (step indices of the "all" record).
K_SAVE_1, K_SAVE_2 = 400, 1100  # DF calibrating / DF calibrated and in alarm
K_RERUN_1 = 400                  # steps re-run after restoring the first save point
K_RERUN_2 = 400                  # steps re-run after restoring the second one
K_RERUN_OTHER = 800              # steps run by a fresh instance from the first one
#: Steps with a non-finite input in the NaN scenario: {step: (input, value)}.
NAN_STEPS: dict[int, tuple[str, float]] = {
    250: ("df.y[2]", float("nan")),    # during the DF calibration
    300: ("dtg.Utx", float("nan")),    # DTG learned, before its alarm
    700: ("grey.y", float("inf")),
    1050: ("df.y[3]", float("nan")),   # DF in alarm
}
N_RESET = 300
#: Tunable changes: applied from sample K_TUNE on; at K_BAD two refused changes (one
#: outside the declared range, one the library refuses), then the run goes on.
K_TUNE, K_BAD = 1000, 1500
TUNED: dict[str, Any] = {"dtg.low": 0.8, "dtg.high": 1.25, "dtg.persistence_k": 2,
                         "dtg.level_threshold": 1.5, "dtg.var_threshold": 1.3,
                         "grey.threshold": 0.03, "grey.clear_after_s": 1.0}
REFUSED_TUNES: tuple[tuple[str, Any], ...] = (("dtg.high", 0.9), ("dtg.persistence_k", 9))
#: Multi-sample steps: samples per doStep, cycled over the "all" record, and the
#: relative jitter put on each step size (inside the 1e-6 tolerance).
MULTI_STEPS = (1, 3, 2, 5, 1, 4, 7, 2)
MULTI_JITTER = (0.0, 4e-7, -4e-7, 9e-7)
#: Refused steps at sample_period_s = 0.1 s: not a multiple, beyond the tolerance, zero,
#: negative, non-finite.
BAD_STEPS = (0.0, -0.1, float("nan"), float("inf"))
#: Steps that are no whole number of GREY_H: half, one and a half, 0.3 s a little long.
OFF_GRID_STEPS = (0.5, 1.5, 3.0 * (1 + 5e-6))
N_INTERLEAVE = 600
#: Invalid parameter sets: label → (parameters, strings).
INVALID: dict[str, tuple[dict[str, Any], dict[str, str]]] = {
    "dtg.forgetting": ({"dtg.forgetting": 1.5}, {}),
    "dtg.estimator": ({"dtg.estimator": 7}, {}),
    "dtg.prefilter_cutoff_hz": ({"dtg.prefilter_cutoff_hz": 600.0}, {}),
    "dtg.window": ({"dtg.estimator": 0, "dtg.window": 3}, {}),
    "dtg.classifier": ({}, {"dtg.classifier": "nearest"}),
    "dtg.long_window_s": ({"dtg.long_window_s": 0.1}, {}),
    "dtg.var_threshold": ({"dtg.var_threshold": 0.5}, {}),
    "dtg.signature_file (paper signatures, pattern classifier)": (
        {}, {"dtg.signature_file": "@PAPER_FILE@"}),
    "dtg.n_signatures": ({"dtg.n_signatures": 9}, {}),
    "dtg.n_signatures (pattern classifier)": ({"dtg.n_signatures": 1}, {}),
    "dtg.signature_file": ({}, {"dtg.signature_file": "/nonexistent/gyrodiag/sigs.json"}),
    "dtg.signature_file (bad JSON)": ({}, {"dtg.signature_file": "@BAD_JSON@"}),
    "grey.window": ({"grey.window": 2}, {}),
    "grey.threshold": ({"grey.threshold": 0.0}, {}),
    "df.eigenvalue (unstable)": ({"df.eigenvalue[1]": 1.0}, {}),
    "df.eigenvalue (repeated)": ({"df.eigenvalue[2]": -1.0}, {}),
    "df.persistence_k": ({"df.persistence_k": 6}, {}),
    "df.calibrate_s": ({"df.calibrate_s": -1.0}, {}),
    "df.decision": ({"df.decision": 3}, {}),
    "df.cusum_k": ({"df.cusum_k": 0.0}, {}),
    "df.false_alarm_rate": ({"df.false_alarm_rate": -1.0}, {}),
    "df.max_faults": ({"df.max_faults": 3}, {}),
    "df.isolation_window_s": ({"df.isolation_window_s": 3601.0}, {}),
    "df.isolation_baseline_s": ({"df.isolation_baseline_s": -1.0}, {}),
    "df.align_auto (no window)": ({"df.calibrate_s": 0.0, "df.noise_std[1]": 0.05,
                                   "df.noise_std[2]": 1e-3, "df.noise_std[3]": 1e-3,
                                   "df.noise_std[4]": 1e-3, "df.noise_std[5]": 1e-3,
                                   "df.noise_std[6]": 0.2}, {}),
    "sample_period_s (zero)": ({"sample_period_s": 0.0}, {}),
    "sample_period_s (negative)": ({"sample_period_s": -1e-3}, {}),
}


def _off_grid_runs(unzipdir: str, md: Any, record: np.ndarray) -> dict[str, np.ndarray]:
    """The grey record stepped by OFF_GRID_STEPS (in periods) from t = 0, with a new
    input set before every step (the record's next value, every other one a decoy
    1000 × larger); and the reference: one step per sample, fed the input of the step
    each sample instant k·GREY_H falls in."""
    res: dict[str, np.ndarray] = {}
    for m in OFF_GRID_STEPS:
        inputs = np.array([x if j % 2 == 0 else 1e3 * x for j, x in enumerate(record)])
        d = Diag(unzipdir, md, f"off_grid_{m}", GREY_PARAMS, h=GREY_H)
        rows, statuses = [], []
        for j, x in enumerate(inputs):
            d.fmu.setReal(d._in_vr, [float(v) for v in x])
            statuses.append(d.call(d.fmu.doStep, j * m * GREY_H, m * GREY_H))
            rows.append(d.outputs())
        d.close()
        starts = np.arange(len(inputs)) * m  # step starts, in periods
        k = np.arange(math.ceil(starts[-1] + m - 1e-6))
        owner = np.searchsorted(starts, k + 1e-9, side="right") - 1
        ref = Diag(unzipdir, md, f"off_grid_ref_{m}", GREY_PARAMS, h=GREY_H)
        res[f"off_grid_{m}_ref"] = ref.run(inputs[owner])
        ref.close()
        res[f"off_grid_{m}"], res[f"off_grid_{m}_status"] = np.array(rows), np.array(statuses)
        res[f"off_grid_{m}_counts"] = np.bincount(owner, minlength=len(inputs))
    return res


class Diag:
    """One Diagnoser instance through fmpy, with the log captured and statuses recorded.

    fmpy raises ``FMICallException`` for a status worse than warning; ``call`` turns
    that back into the status code so that scenarios can record it.
    """

    def __init__(self, unzipdir: str, md: Any, name: str, params: dict[str, Any],
                 strings: dict[str, str] | None = None, start: float = 0.0,
                 h: float = 1e-3, initialise: bool = True) -> None:
        from ctypes import byref

        from fmpy.fmi2 import (
            FMU2Slave,
            calloc,
            fmi2CallbackAllocateMemoryTYPE,
            fmi2CallbackFreeMemoryTYPE,
            fmi2CallbackFunctions,
            fmi2CallbackLoggerTYPE,
            free,
        )
        from fmpy.logging import addLoggerProxy

        self.vars = {v.name: v for v in md.modelVariables}
        self.log: list[tuple[int, str]] = []

        def logger(_env, _inst, status, _cat, message):
            self.log.append((int(status), message.decode("utf-8", "replace")))

        cb = fmi2CallbackFunctions()
        cb.logger = fmi2CallbackLoggerTYPE(logger)
        cb.allocateMemory = fmi2CallbackAllocateMemoryTYPE(calloc)
        cb.freeMemory = fmi2CallbackFreeMemoryTYPE(free)
        addLoggerProxy(byref(cb))
        self._callbacks = cb  # keep the ctypes objects alive
        self.fmu = FMU2Slave(guid=md.guid, unzipDirectory=unzipdir,
                             modelIdentifier=md.coSimulation.modelIdentifier,
                             instanceName=name)
        self.fmu.instantiate(callbacks=cb, loggingOn=False)
        self.start, self.h, self.k = start, h, 0
        outputs = [v for v in md.modelVariables if v.causality == "output"]
        self.out_names = [v.name for v in outputs]
        self._out = {kind: [(i, v.valueReference) for i, v in enumerate(outputs)
                            if v.type == kind] for kind in ("Real", "Integer", "Boolean")}
        self._in_vr = [self.vars[n].valueReference for n in IN_NAMES]
        self.init_status = self.initialise(params, strings) if initialise else None

    def call(self, fn, *args) -> int:
        from fmpy.fmi1 import FMICallException

        try:
            fn(*args)
        except FMICallException as exc:
            return int(exc.status)
        return 0

    def set(self, name: str, value: Any) -> None:
        v = self.vars[name]
        if v.type == "Real":
            self.fmu.setReal([v.valueReference], [float(value)])
        elif v.type == "Integer":
            self.fmu.setInteger([v.valueReference], [int(value)])
        elif v.type == "Boolean":
            self.fmu.setBoolean([v.valueReference], [bool(value)])
        else:
            self.fmu.setString([v.valueReference], [str(value)])

    def get(self, name: str) -> Any:
        v = self.vars[name]
        getter = {"Real": self.fmu.getReal, "Integer": self.fmu.getInteger,
                  "Boolean": self.fmu.getBoolean, "String": self.fmu.getString}[v.type]
        return getter([v.valueReference])[0]

    def initialise(self, params: dict[str, Any], strings: dict[str, str] | None = None) -> int:
        """setupExperiment, parameters, enter/exit initialisation; the exit status."""
        self.fmu.setupExperiment(startTime=self.start)
        for name, value in {**params, **(strings or {})}.items():
            self.set(name, value)
        self.fmu.enterInitializationMode()
        self.k = 0
        return self.call(self.fmu.exitInitializationMode)

    def step(self, inputs: np.ndarray | None = None) -> int:
        """One doStep at t = start + k·h (exact, no accumulated rounding)."""
        if inputs is not None:
            self.fmu.setReal(self._in_vr, [float(x) for x in inputs])
        status = self.call(self.fmu.doStep, self.start + self.k * self.h, self.h)
        self.k += 1
        return status

    def outputs(self) -> np.ndarray:
        row = np.zeros(len(self.out_names))  # String outputs stay 0
        for kind, getter in (("Real", self.fmu.getReal), ("Integer", self.fmu.getInteger),
                             ("Boolean", self.fmu.getBoolean)):
            items = self._out[kind]
            if items:
                row[[i for i, _ in items]] = getter([vr for _, vr in items])
        return row

    def run(self, record: np.ndarray) -> np.ndarray:
        rows = []
        for x in record:
            status = self.step(x)
            if status != 0:
                raise RuntimeError(f"doStep at k={self.k - 1} returned {status}: {self.log}")
            rows.append(self.outputs())
        return np.array(rows)

    def close(self) -> None:
        """Free the instance but keep the shared library loaded (docs/methods.md §6.11)."""
        self.call(self.fmu.terminate)
        self.fmu.fmi2FreeInstance(self.fmu.component)


def run_scenarios(fmu_dir: Path, out: Path, inp: Path) -> None:
    from fmpy import extract, read_model_description

    unzipdir = extract(str(fmu_dir / "Diagnoser.fmu"))
    md = read_model_description(unzipdir)
    data = dict(np.load(inp))
    res: dict[str, Any] = {}
    all_params = {**ALL_PARAMS, "dtg.signature_file": str(data["patterns_100hz_path"])}

    def new(name: str, params: dict[str, Any], **kw: Any) -> Diag:
        return Diag(unzipdir, md, name, params, **kw)

    # -- each channel alone, and all three together ------------------------------------
    for tag, params, h, start in (("dtg", DTG_PARAMS, DTG_H, DTG_START),
                                  ("grey", GREY_PARAMS, GREY_H, 0.0),
                                  ("grey_classic", GREY_CLASSIC_PARAMS, GREY_H, 0.0),
                                  ("df", DF_PARAMS, DF_H, 0.0)):
        d = new(tag, params, h=h, start=start)
        assert d.init_status == 0, d.log
        res[tag] = d.run(data[tag.split("_")[0]])
        d.close()
    res["columns"] = np.array(d.out_names)

    # -- DTG pattern classifier: a NaN sample and a save point inside the learning -----
    pattern_params = {**PATTERN_PARAMS, "dtg.signature_file": str(data["patterns_1khz_path"])}
    d = new("pattern", pattern_params, h=DTG_H, start=DTG_START)
    assert d.init_status == 0, d.log
    rec_p = data["dtg"].copy()
    rec_p[K_PATTERN_NAN, 0] = np.nan
    first = d.run(rec_p[:K_PATTERN_SAVE])
    saved = d.fmu.serializeFMUstate(d.fmu.getFMUstate())
    res["pattern"] = np.vstack([first, d.run(rec_p[K_PATTERN_SAVE:])])
    d.close()
    other = new("pattern_other", {}, h=DTG_H, start=DTG_START)
    other.fmu.setFMUstate(other.fmu.deSerializeFMUstate(saved))
    other.k = K_PATTERN_SAVE
    res["pattern_restored"] = other.run(rec_p[K_PATTERN_SAVE:K_PATTERN_SAVE + K_PATTERN_RERUN])
    other.close()

    # -- all channels, with FMU state saved, restored and (de)serialised ---------------
    rec = data["all"]
    d = new("all", all_params, h=ALL_H, start=ALL_START)
    first = d.run(rec[:K_SAVE_1])
    s1 = d.fmu.getFMUstate()
    b1 = d.fmu.serializeFMUstate(s1)
    first = np.vstack([first, d.run(rec[K_SAVE_1:K_SAVE_2])])
    s2 = d.fmu.getFMUstate()
    b2 = d.fmu.serializeFMUstate(s2)
    res["all"] = np.vstack([first, d.run(rec[K_SAVE_2:])])
    d.fmu.setFMUstate(s1)                                 # get/set, same instance
    d.k = K_SAVE_1
    res["restore_1"] = d.run(rec[K_SAVE_1:K_SAVE_1 + K_RERUN_1])
    d.fmu.setFMUstate(d.fmu.deSerializeFMUstate(b2))      # deserialised, same instance
    d.k = K_SAVE_2
    res["restore_2"] = d.run(rec[K_SAVE_2:K_SAVE_2 + K_RERUN_2])
    d.fmu.freeFMUstate(s1)
    d.fmu.freeFMUstate(s2)
    d.close()
    # a fresh instance with default parameters takes over from the serialised state
    other = new("all_other", {}, h=ALL_H, start=ALL_START)
    res["other_period_before"] = np.array(other.get("sample_period_s"))
    other.fmu.setFMUstate(other.fmu.deSerializeFMUstate(b1))
    res["other_period_after"] = np.array(other.get("sample_period_s"))
    other.k = K_SAVE_1
    res["restore_other"] = other.run(rec[K_SAVE_1:K_SAVE_1 + K_RERUN_OTHER])
    other.close()

    # -- non-finite inputs ---------------------------------------------------------------
    d = new("nan", all_params, h=ALL_H, start=ALL_START)
    bad = rec.copy()
    for k, (name, value) in NAN_STEPS.items():
        bad[k, IN_NAMES.index(name)] = value
    res["nan"] = d.run(bad)
    res["nan_log"] = np.array([m for _, m in d.log] or [""])
    d.close()

    # -- fmi2Reset, and two instances interleaved ---------------------------------------
    d = new("reset", all_params, h=ALL_H, start=ALL_START)
    d.run(data["all2"][:N_RESET])  # other data, so that leftovers would show
    res["reset_status"] = np.array(d.call(d.fmu.reset))
    res["reset_period"] = np.array(d.get("sample_period_s"))
    res["reset_init_status"] = np.array(d.initialise(all_params))
    res["reset_run"] = d.run(rec[:N_RESET])
    d.close()
    a = new("inter_a", all_params, h=ALL_H, start=ALL_START)
    b = new("inter_b", all_params, h=ALL_H, start=ALL_START)
    rows_a, rows_b = [], []
    for k in range(N_INTERLEAVE):
        rows_a.append(a.run(rec[k:k + 1])[0])
        rows_b.append(b.run(data["all2"][k:k + 1])[0])
    res["inter_a"], res["inter_b"] = np.array(rows_a), np.array(rows_b)
    a.close()
    b.close()
    alone = new("alone_b", all_params, h=ALL_H, start=ALL_START)
    res["alone_b"] = alone.run(data["all2"][:N_INTERLEAVE])
    alone.close()

    # -- signature library from a file: absolute path, and relative to the resources ----
    abs_path = Path(str(data["sigfile_path"]))
    shutil.copy(abs_path, Path(unzipdir) / "resources" / "gd_test_signatures.json")
    theta0 = {f"dtg.theta0[{i + 1}]": float(t) for i, t in enumerate(data["sigfile_theta0"])}
    for tag, ref in (("sigfile_abs", str(abs_path)), ("sigfile_rel", "gd_test_signatures.json")):
        d = new(tag, {**SIGFILE_PARAMS, **theta0}, strings={"dtg.signature_file": ref})
        assert d.init_status == 0, (tag, d.log)
        res[tag] = d.run(data["sigfile"])
        d.close()

    # -- invalid parameters, doStep after a failed initialisation, wrong step ----------
    bad_json = Path(unzipdir) / "resources" / "gd_bad.json"
    bad_json.write_text('{"signatures": [1, 2', encoding="utf-8")
    labels, exit_status, exit_log, step_status, step_log = [], [], [], [], []
    substitute = {"@BAD_JSON@": str(bad_json), "@PAPER_FILE@": str(data["sigfile_path"])}
    for label, (params, strings) in {"valid defaults": ({}, {}), **INVALID}.items():
        strings = {k: substitute.get(v, v) for k, v in strings.items()}
        d = new(f"bad_{len(labels)}", params, strings=strings)
        labels.append(label)
        exit_status.append(d.init_status)
        exit_log.append("\n".join(f"[{s}] {m}" for s, m in d.log))
        d.log.clear()
        step_status.append(d.step(np.zeros(len(IN_NAMES))))
        step_log.append("\n".join(f"[{s}] {m}" for s, m in d.log))
        d.close()
    res["invalid_labels"] = np.array(labels)
    res["invalid_exit_status"] = np.array(exit_status)
    res["invalid_exit_log"] = np.array(exit_log)
    res["invalid_step_status"] = np.array(step_status)
    res["invalid_step_log"] = np.array(step_log)

    # -- tunable parameters changed during the run --------------------------------------
    d = new("tune", all_params, h=ALL_H, start=ALL_START)
    parts = [d.run(rec[:K_TUNE])]
    for name, value in TUNED.items():
        d.set(name, value)
    parts.append(d.run(rec[K_TUNE:K_BAD]))
    statuses, logs, kept = [], [], []
    for name, value in REFUSED_TUNES:
        d.log.clear()
        d.set(name, value)
        statuses.append(d.step(rec[K_BAD]))
        d.k -= 1  # a refused step consumed no sample
        logs.append("\n".join(m for _, m in d.log))
        kept.append(d.get(name))
    d.log.clear()
    parts.append(d.run(rec[K_BAD:]))
    res["tune"] = np.vstack(parts)
    res["tune_refused_status"] = np.array(statuses)
    res["tune_refused_log"] = np.array(logs)
    res["tune_refused_kept"] = np.array(kept, dtype=float)
    res["tune_after_log"] = np.array(len(d.log))
    d.close()

    # -- communication steps of several samples, and refused steps ---------------------
    d = new("multi", all_params, h=ALL_H, start=ALL_START)
    rows, counts, k, j = [], [], 0, 0
    while k < len(rec):
        n = min(MULTI_STEPS[j % len(MULTI_STEPS)], len(rec) - k)
        h = n * ALL_H * (1.0 + MULTI_JITTER[j % len(MULTI_JITTER)])
        d.fmu.setReal(d._in_vr, [float(x) for x in rec[k]])
        status = d.call(d.fmu.doStep, ALL_START + k * ALL_H, h)
        if status != 0:
            raise RuntimeError(f"multi-sample doStep at k={k}, n={n}: {status} {d.log}")
        rows.append(d.outputs())
        counts.append(n)
        k, j = k + n, j + 1
    res["multi"], res["multi_n"] = np.array(rows), np.array(counts)
    d.close()

    d = new("wrong_step", GREY_PARAMS, h=GREY_H)
    statuses, logs = [], []
    for h in BAD_STEPS:
        d.log.clear()
        d.fmu.setReal(d._in_vr, [float(x) for x in data["grey"][0]])
        statuses.append(d.call(d.fmu.doStep, 0.0, h))
        logs.append("\n".join(m for _, m in d.log))
    res["wrong_step_status"] = np.array(statuses)
    res["wrong_step_log"] = np.array(logs)
    d.k = 0
    d.log.clear()
    res["after_wrong_step"] = d.run(data["grey"][:20])
    res["after_wrong_step_log"] = np.array(len(d.log))
    d.close()
    res.update(_off_grid_runs(unzipdir, md, data["grey"][:40]))

    np.savez(out, **res)
    shutil.rmtree(unzipdir, ignore_errors=True)


if __name__ == "__main__":
    run_scenarios(Path(sys.argv[1]), Path(sys.argv[2]), Path(sys.argv[3]))
