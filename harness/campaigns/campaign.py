"""Monte Carlo fault-injection campaigns: ``python -m harness campaign SPEC.toml``.

A campaign spec (TOML, validated by :class:`CampaignSpec`) names, per *class*, a base
scenario (the chain of FMUs, e.g. ``scenarios/aircraft_q_bias.toml``) and sweeps over
fault type, magnitude, onset time, affected injector channel (sensor) and random seed,
plus nominal runs (no fault) for the false-alarm rate.  :func:`expand_runs` turns the
spec into :class:`RunSpec` entries, each with a deterministic id (hash of its content),
so that a campaign can be interrupted and resumed.

Execution
---------
Each run is simulated in **its own fresh process** (``python -m
harness.campaigns.campaign --child``): pythonfmu FMUs must not be loaded twice in one
process, a crash (abort, segfault) only kills that process, and a hung run can be killed
at its timeout.  The guard that starts the process, waits for it and writes the run's record
(:func:`execute_run`) is the task that a pool runs:

* default: a ``concurrent.futures.ProcessPoolExecutor`` (``spawn`` context);
* ``--dask local``: a ``dask.distributed`` ``LocalCluster``; ``--dask ADDRESS``: the
  scheduler of a real cluster (the workers need this package and the FMUs at the same
  paths).  No home-made job system: the pools do the scheduling.

Every finished run is written at once as ``<out>/runs/<run_id>.json`` (atomically: a
temporary file renamed), also when it failed: ``status`` is ``"ok"``, ``"error"`` (the
runner raised, the process died, the FMU failed) or ``"timeout"``.  A resumed campaign
skips every id that has a record (``--retry-failed`` re-runs the failed ones).

What a run records
------------------
Not the signals: a small record (:func:`simulate_run`) with, for the channel's alarm
``A(t)`` (detection filter with the paper's rule, ``df.decision = 0``: any main-residual
alarm ``diag.df.alarm[i]``, k-of-n, unlatched; with the sequential rule (the default):
``diag.df.detected``, a fault episode; DTG: ``diag.dtg.alarm``):

* ``detected`` / ``delay_s``: ``A`` on at some sample at or after the onset, delay from
  the onset to the first such sample;
* ``false_alarms`` / ``fault_free_s``: rising edges of ``A`` in the fault-free time from
  the end of calibration (DF) or learning (DTG) to the onset (the whole run if nominal);
* ``diagnosed``: isolated sensor (``diag.df.isolated_sensor``; several isolated sensors
  joined by "+", e.g. "alpha+q", from ``diag.df.isolated_mask``) or DTG fault code at the
  end of the run, and ``injected``, what it should be (a sweep's ``also`` faults make it
  a pair); sequential DF also ``typed`` (fault type at the end), ``expected_type``,
  ``size``, ``episodes`` and ``input_delay`` (the alignment it chose);
* the threshold sweep: the alarm statistic ``s(t)`` in threshold units is rebuilt from the
  recorded outputs, so that ``A_T(t) = s(t) > T`` reproduces the alarm at any threshold
  ``T``, and detection, delay and false alarms are evaluated on the class's threshold
  grid.  DF: ``s(t) = max_i kth_largest(|r_i - mu_i| / sigma_i over the last n
  samples)``, ``|r_i - mu_i| / sigma_i`` being ``k_sigma`` times the channel's own
  ``df.statistic[i]`` (its ``mu_i``, ``sigma_i`` and the alignment it chose; without that
  output ``mu_i``, ``sigma_i`` (ddof 1) are re-estimated from the recorded main residuals
  over the calibration window after the burn-in, exact with Gauss-Seidel coupling only);
  ``T`` is in standard deviations (the FMU uses ``df.k_sigma``); sequential DF: the
  recorded ``diag.df.statistic[i]`` (CUSUM over its threshold, capped at 1), so only
  ``T <= 1`` is meaningful and the alarm ``df.detected`` (episode logic) differs from
  ``s > 1`` after the first alarm (``sweep_mismatch`` shows how much).  DTG: ``s(t) =
  max |eta - 1|`` over the monitored ratios of both axes after learning; ``T`` is the
  half-width of a band symmetric about 1 (the paper's 0.5/1.5 is ``T = 0.5``).
  ``sweep_mismatch`` is the fraction of samples where ``s > T_config`` disagrees with the
  FMU's own alarm (0 when the reconstruction is exact).

Approximated in the sweep: the detection filter's isolation bank can also raise
``df.detected``; only the main residual alarms are swept.  Isolation and DTG
classification are not re-evaluated at other thresholds.

System runs (``channel = "system"``, the DTG as the aircraft's pitch gyro): one
Diagnoser runs both channels, and each is a witness of its own: the DTG channel's
``dtg.alarm`` (judged from the end of learning) and the detection filter's
``df.detected`` (from the end of calibration).  The record keeps both under
``witnesses`` (detected, delay, false alarms, fault-free time, the DTG class and the
isolated sensor, type and size of the detection filter); the top-level fields judge
"either witness" so the usual tables still apply; ``diagnosed`` is the detection
filter's isolated sensor.  No threshold sweep.  *Conditions* (``[conditions.NAME]``)
vary the flight of any class: manoeuvres (the scenario's ``[[manoeuvres]]`` entries)
and parameter overrides (e.g. turbulence), each with a ``group`` ("level",
"manoeuvre") that the summary compares.  A run is flown with the same seed under every
condition (a paired comparison) unless its class says ``condition_seeds = "disjoint"``.

Side by side, df and dtg (issue 16): a class may list ``witnesses``, Diagnoser instances
judged in the same run, each with its own rule, e.g. ``diag`` (the project's rule) and
``paper`` (the paper's).  ``witness_copies`` adds a witness to the base scenario as a copy
of ``diagnoser`` (same FMU, parameters and files, a copy of every connection into it, so
both see the same signals) with its own ``parameters``/``files`` (a setting replaces the
original's, in either table) and its own sweep grid ``thresholds`` in its rule's units.
The campaign adds the copy rather than shipping two-Diagnoser base scenarios: one base
scenario stays the single source of the chain (and of the seed scenarios' checks), the
two rules cannot drift apart in their connections, and the paper's settings are read in
the campaign file.  Each witness is judged exactly as a single Diagnoser of its rule
would be (:func:`judge_diagnoser`): DF paper rule (``df.decision = 0``): any main-residual
alarm, isolated sensor, sweep on the k-of-n statistic in sigma; DF sequential:
``df.detected`` episodes, isolated sensor, type, size, sweep on the CUSUM; DTG paper
(``dtg.classifier = "paper"``): the ratio band, the nearest decade signature's name, sweep
on ``|eta - 1|``; DTG pattern: class and axis, sweep on the residual tests.  The record
keeps each under ``witnesses`` (with its grid), the top level is the first witness's, and
the summary splits it into one record per witness (class ``<class>/<witness>``, channel
``df/<witness>``, ``dtg/<witness>``), so every table (detection, isolation/class right,
false alarms, delays, confusion matrix, threshold sweep) has a row per rule.  The seed
does not depend on the witnesses (the same noise with or without the copy, which does
not change the first Diagnoser's record); the run id does, so records of a single-rule
campaign are never mixed with two-rule ones.  A paper DTG witness needs the decade
signatures and the pattern witness its library: ``libraries`` names further files
learned first, like ``signatures_training`` (e.g. ``{ "dtg_signatures.json" =
"../scenarios/training" }`` next to ``dtg_patterns.json``).

Grey-prediction runs (``channel = "grey"``, the HRG): the class's ``witnesses`` are
Diagnoser instances that watch the same faulty signal with different decision rules
(e.g. the paper's fixed threshold and the project's calibrated detector), each judged
on its own ``grey.alarm`` from its first ready sample (``grey.prediction_valid`` and not
``grey.calibrating``: the window is full and, if calibrated, sigma is learned).  The
record keeps each under ``witnesses`` with its own threshold sweep; the summary splits a
grey record into one record per witness (class ``<class>/<witness>``, channel
``grey/<witness>``), so every table has a row per rule.  The grey channel names no
fault kind: ``diagnosed`` is None and isolation/classification does not apply.  Sweep
``T`` in multiples of the rule's threshold.  A fixed-threshold rule (the paper's,
``grey.calibrate_s = 0``) is *replayed*: the library's detector
(:class:`gyrodiag.grey.GreyFaultDetector`, the FMU's own code) is run on the recorded
input ``grey.y`` with threshold ``T · grey.threshold``, substitutions and clearing
included, so every point is exact; ``sweep_mismatch`` is the replay at ``T = 1``
against the FMU's alarm (0 when the replay is faithful).  A calibrated rule is rebuilt
from ``s(t) = grey.statistic`` (its CUSUM over its threshold and the lagged step test's
``|z|`` over its threshold), exact only up to the first alarm: in alarm the predictor is
fed substitutes and the CUSUM holds the alarm down to half its threshold.
"""

from __future__ import annotations

import hashlib
import importlib
import json
import logging
import math
import os
import re
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import time
import tomllib
import traceback
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, ValidationError, model_validator

from harness.cosim.scenario import FAULT_TYPE_PARAMETERS, FMU_DIR_ENV, ScenarioError

log = logging.getLogger(__name__)
REPO_ROOT = Path(__file__).resolve().parents[2]
#: The per-run function used unless the spec or the caller names another.
DEFAULT_RUNNER = "harness.campaigns.campaign:simulate_run"
#: Sensor names of the seed aircraft (injector channel i feeds sensor i).
AIRCRAFT_SENSORS = ("v", "alpha", "q", "theta", "gamma", "h")
DEFAULT_THRESHOLDS = {
    "df": [3.0, 4.0, 4.5, 5.0, 5.5, 6.0, 6.5, 7.0, 8.0, 10.0, 12.0, 15.0],
    "dtg": [0.05, 0.1, 0.15, 0.2, 0.25, 0.3, 0.4, 0.5, 0.6, 0.8],
    "system": [],
    # multiples of each grey rule's threshold (the paper's: of grey.threshold in V)
    "grey": [0.5, 0.75, 1.0, 1.25, 1.5, 2.0, 3.0],
}
Channel = Literal["df", "dtg", "system", "grey"]
#: Witnesses of a system run: name -> (alarm output, "not judged yet" output).
SYSTEM_WITNESSES = {"dtg": ("dtg.alarm", "dtg.learning"),
                    "df": ("df.detected", "df.calibrating")}
#: The fault parameter that ``magnitudes`` sets, per fault type (gain: the factor).
MAGNITUDE_PARAMETER = {
    "bias": "magnitude", "gain": "gain", "stuck_value": "stuck_value", "step": "magnitude",
    "ramp": "magnitude", "noise": "noise_std", "signal_loss": "noise_std",
    "intermittent": "magnitude",
}


# --------------------------------------------------------------------------- spec
class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid")


#: Channels whose classes may judge several Diagnoser instances (``witnesses``).
WITNESS_CHANNELS = ("grey", "df", "dtg")


class WitnessCopy(_Strict):
    """A witness added as a copy of the class's ``diagnoser`` instance (module docstring,
    "Side by side"): ``parameters`` and ``files`` override the copy's, e.g. the paper's
    rule ``{ "df.decision" = 0 }``; ``thresholds`` is its sweep grid (default: the
    channel's, :data:`DEFAULT_THRESHOLDS`), in its own rule's units."""

    parameters: dict[str, bool | int | float | str] = Field(default_factory=dict)
    files: dict[str, str] = Field(default_factory=dict)
    thresholds: list[float] | None = None


def _check_witness_copies(c: FaultClass) -> FaultClass:
    if not c.witness_copies:
        return c
    if c.channel not in WITNESS_CHANNELS:
        raise ValueError(f"witness_copies: only the {', '.join(WITNESS_CHANNELS)} channels "
                         f"judge several Diagnosers (channel is {c.channel!r})")
    if c.diagnoser in c.witness_copies:
        raise ValueError(f"witness_copies: {c.diagnoser!r} is the instance copied")
    missing = [w for w in c.witness_copies if w not in c.witnesses]
    if missing:
        raise ValueError(f"witness_copies: {missing[0]!r} is not among the witnesses "
                         f"{c.witnesses} (list every judged instance there, in order)")
    return c


class FaultClass(_Strict):
    """A base scenario and how to read its diagnosis.

    ``channel`` is the Diagnoser channel judged: ``"df"`` (aircraft detection filter),
    ``"dtg"``, ``"system"`` (both, as independent witnesses; module docstring) or
    ``"grey"`` (the grey-prediction channel of each Diagnoser in ``witnesses``).
    ``seed_parameters`` are ``instance.parameter`` names set to each run's seed (offset
    by their position, so two generators never share a seed).  ``condition_seeds``:
    ``"paired"`` flies a run with the same seed under every condition, ``"disjoint"``
    gives each condition its own seeds.
    """

    scenario: str
    channel: Channel
    diagnoser: str = "diag"
    injector: str = "injector"
    seed_parameters: list[str] = Field(default_factory=list)
    #: Parameter overrides per instance, e.g. ``{ diag = { "df.calibrate_s" = 2.0 } }``.
    parameters: dict[str, dict[str, bool | int | float | str]] = Field(default_factory=dict)
    thresholds: list[float] | None = None
    #: Grey, df, dtg: the Diagnoser instances judged side by side (grey default:
    #: diagnoser; df/dtg default: none, one Diagnoser judged as before).
    witnesses: list[str] = Field(default_factory=list)
    #: Witnesses the campaign adds to the base scenario as copies of ``diagnoser`` (same
    #: FMU, parameters, files and input connections) with their own rule's settings.
    witness_copies: dict[str, WitnessCopy] = Field(default_factory=dict)
    condition_seeds: Literal["paired", "disjoint"] = "paired"

    @model_validator(mode="after")
    def _witnesses_for_grey(self) -> FaultClass:
        if self.witnesses and self.channel not in WITNESS_CHANNELS:
            raise ValueError(f"witnesses: only the {', '.join(WITNESS_CHANNELS)} channels "
                             f"judge several Diagnosers (channel is {self.channel!r})")
        if len(set(self.witnesses)) != len(self.witnesses):
            raise ValueError(f"witnesses: {self.witnesses} names an instance twice")
        return _check_witness_copies(self)


class Condition(_Strict):
    """A flight condition: manoeuvres and parameter overrides applied to a run.

    ``manoeuvres`` are ``[[manoeuvres]]`` entries of the scenario format (they replace
    the base scenario's; a command generator that flew one in the base scenario and is
    given none flies trim, ``command_source = 0``, not its own default manoeuvre);
    ``parameters`` override instance parameters, e.g.
    ``{ aircraft = { turbulence_sigma_w = 1.5 } }``; ``group`` is what the summary
    compares (e.g. "level" against "manoeuvre").
    """

    group: str = Field(min_length=1)
    description: str = ""
    manoeuvres: list[dict[str, Any]] = Field(default_factory=list)
    parameters: dict[str, dict[str, bool | int | float | str]] = Field(default_factory=dict)


class Sweep(_Strict):
    """Fault runs: the product of magnitudes × onsets × channels × conditions × seeds.

    A fault is an injector fault (``type``, on the injector ``channels``) or a physical
    one (``set`` = ``instance.parameter``, tunable, set to each magnitude at the onset).
    ``post_onset_s`` sets each run's duration to onset + this; else ``duration_s``, else
    the base scenario's.  The diagnosis that counts as right: default the injected
    channel (``df``); for ``dtg`` the fault's signature name (``label``); for ``system``
    ``expected`` (the sensor the detection filter must isolate, default "q").
    """

    cls: str = Field(alias="class")
    type: str | None = None
    set: str | None = None
    label: str | None = None
    expected: str | None = None
    conditions: list[str] = Field(default_factory=list)
    magnitudes: list[float] = Field(default_factory=lambda: [math.nan])
    onsets_s: list[float] = Field(min_length=1)
    channels: list[int] = Field(default_factory=lambda: [0])
    seeds: int = Field(default=1, ge=1)
    duration_s: float | None = Field(default=None, gt=0)
    post_onset_s: float | None = Field(default=None, gt=0)
    extra: dict[str, float] = Field(default_factory=dict)
    #: Other diagnoses that count as right, for classes that cannot be told apart at
    #: these magnitudes (e.g. a DTG signal loss that leaves more noise than the signal
    #: had is a noise fault for every statistic: ``accept = ["utx_noise"]``).
    accept: list[str] = Field(default_factory=list)
    #: Further faults from the same onset in every run of the sweep (two faulty sensors at
    #: once): injector fault tables without ``name``/``injector``/``start_s``, e.g.
    #: ``{ channel = 2, type = "bias", magnitude = 0.005 }``.
    also: list[dict[str, float | int | str]] = Field(default_factory=list)

    model_config = ConfigDict(extra="forbid", populate_by_name=True)

    @model_validator(mode="after")
    def _known_type(self) -> Sweep:
        if (self.type is None) == (self.set is None):
            raise ValueError("give either type (an injector fault) or set (a physical "
                             "fault: instance.parameter)")
        if self.set is not None:
            if "." not in self.set:
                raise ValueError(f"set: {self.set!r} must be 'instance.parameter'")
            if all(math.isnan(m) for m in self.magnitudes):
                raise ValueError("magnitudes: a physical fault needs the values to set")
            return self
        if self.type not in FAULT_TYPE_PARAMETERS or self.type == "none":
            raise ValueError(f"type: unknown fault type {self.type!r}")
        if self.channels == [0]:
            raise ValueError("channels: an injector fault needs the injector channels")
        needs = MAGNITUDE_PARAMETER.get(self.type)
        has_mag = not all(math.isnan(m) for m in self.magnitudes)
        if needs is None and has_mag:
            raise ValueError(f"magnitudes: fault type {self.type!r} takes no magnitude")
        if needs is not None and not has_mag:
            raise ValueError(f"magnitudes: fault type {self.type!r} needs magnitudes "
                             f"(they set its {needs!r})")
        for i, other in enumerate(self.also):
            if other.get("type") not in FAULT_TYPE_PARAMETERS or "channel" not in other:
                raise ValueError(f"also[{i}]: needs a known 'type' and a 'channel'")
        return self


class Nominal(_Strict):
    """Fault-free runs of a class: ``runs`` seeds of ``duration_s`` each, per condition."""

    cls: str = Field(alias="class")
    duration_s: float = Field(gt=0)
    runs: int = Field(ge=1)
    conditions: list[str] = Field(default_factory=list)

    model_config = ConfigDict(extra="forbid", populate_by_name=True)


class CampaignSpec(_Strict):
    """A campaign file; relative paths are taken from the file's folder."""

    name: str = Field(min_length=1)
    description: str = ""
    base_seed: int = 1
    timeout_s: float = Field(default=600.0, gt=0)
    runner: str = DEFAULT_RUNNER
    fmu_dir: str | None = None
    #: What ``${out}/`` stands for in the base scenarios' ``files`` (default: the
    #: campaign's output folder).
    results_dir: str | None = None
    #: DTG training scenarios: learned into ``<results_dir>/<signatures_file>`` first
    #: when that file is missing (a pattern training set gives a pattern library).
    signatures_training: str | None = None
    signatures_file: str = Field(default="dtg_signatures.json", pattern=r"^[\w.-]+\.json$")
    #: Further learned files, file name -> training set (relative to the spec), learned
    #: into ``<results_dir>/<name>`` like ``signatures_training`` when missing: e.g. the
    #: paper's decade signatures next to the pattern library, for a paper witness.
    libraries: dict[str, str] = Field(default_factory=dict)
    classes: dict[str, FaultClass] = Field(min_length=1)
    conditions: dict[str, Condition] = Field(default_factory=dict)
    sweeps: list[Sweep] = Field(default_factory=list)
    nominal: list[Nominal] = Field(default_factory=list)

    @model_validator(mode="after")
    def _classes_exist(self) -> CampaignSpec:
        for name in self.libraries:
            if not re.fullmatch(r"[\w.-]+\.json", name) or name == self.signatures_file:
                raise ValueError(f"libraries: {name!r} must be a .json file name other "
                                 f"than signatures_file")
        for i, s in enumerate([*self.sweeps, *self.nominal]):
            if s.cls not in self.classes:
                raise ValueError(f"entry {i}: unknown class {s.cls!r} "
                                 f"(classes: {', '.join(self.classes)})")
            unknown = [c for c in s.conditions if c not in self.conditions]
            if unknown:
                raise ValueError(f"entry {i}: unknown condition {unknown[0]!r} (conditions: "
                                 f"{', '.join(self.conditions) or 'none'})")
        return self


def load_campaign(path: Path | str) -> tuple[CampaignSpec, Path]:
    """Read a campaign TOML; returns the spec and the folder relative paths start from.

    Raises
    ------
    ScenarioError
        Naming the file and the key of every problem.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: campaign file not found")
    try:
        data = tomllib.loads(path.read_text(encoding="utf-8"))
    except tomllib.TOMLDecodeError as exc:
        raise ScenarioError(str(path), [("", f"invalid TOML: {exc}")]) from None
    data.setdefault("name", path.stem)
    try:
        spec = CampaignSpec.model_validate(data)
    except ValidationError as exc:
        raise ScenarioError(str(path), [(".".join(str(x) for x in e["loc"]), e["msg"])
                                        for e in exc.errors()]) from None
    return spec, path.resolve().parent


# --------------------------------------------------------------------------- run specs
class RunSpec(_Strict):
    """Everything one run needs, JSON-serialisable (it travels to the worker)."""

    run_id: str
    campaign: str
    cls: str
    channel: Channel
    kind: Literal["fault", "nominal"]
    scenario: str                      # absolute path of the base scenario
    duration_s: float
    seed: int
    seed_parameters: list[str]
    parameters: dict[str, dict[str, bool | int | float | str]] = Field(default_factory=dict)
    diagnoser: str
    fault: dict[str, Any] | None       # a [[faults]] entry, None when nominal
    fault_type: str | None = None
    magnitude: float | None = None
    onset_s: float | None = None
    target: int | None = None          # injector channel
    injected: str | None = None        # diagnosis that counts as right
    condition: str | None = None       # flight condition name (None: the base scenario's)
    group: str | None = None           # its group ("level", "manoeuvre", ...)
    manoeuvres: list[dict[str, Any]] | None = None  # replace the base's when not None
    accepted: list[str] = Field(default_factory=list)  # also right (merged classes)
    also: list[dict[str, Any]] = Field(default_factory=list)  # further simultaneous faults
    thresholds: list[float]
    witnesses: list[str] = Field(default_factory=list)  # grey, df, dtg: Diagnosers judged
    witness_copies: dict[str, WitnessCopy] = Field(default_factory=dict)  # added ones
    fmu_dir: str | None = None
    results_dir: str | None = None


def _seed(base_seed: int, key: str) -> int:
    digest = hashlib.sha256(f"{base_seed}:{key}".encode()).digest()
    return int.from_bytes(digest[:4], "little") % 2_000_000_000 + 1


def _run_id(payload: dict[str, Any]) -> str:
    digest = hashlib.sha256(json.dumps(payload, sort_keys=True, default=str).encode())
    return digest.hexdigest()[:16]


def campaign_fmu_dir(spec: CampaignSpec, base_dir: Path,
                     fmu_dir: Path | str | None = None) -> str | None:
    """Folder of the FMUs the campaign's runs use: ``fmu_dir`` (the CLI's ``--fmu-dir``),
    else ``$GYRODIAG_FMU_DIR``, else the spec's ``fmu_dir`` (relative to ``base_dir``),
    else None (each base scenario's own, :func:`harness.cosim.scenario.resolve_fmu_dir`):
    the precedence of a scenario run, so one environment variable points every command
    at a folder of FMUs (a campaign resumed on the build it started with)."""
    if fmu_dir is not None:
        return str(Path(fmu_dir).resolve())
    env = os.environ.get(FMU_DIR_ENV)
    if env:
        return str(Path(env).resolve())
    return str((base_dir / spec.fmu_dir).resolve()) if spec.fmu_dir else None


def expand_runs(spec: CampaignSpec, base_dir: Path, out_dir: Path | None = None,
                fmu_dir: Path | str | None = None) -> list[RunSpec]:
    """Every run of the campaign, in a deterministic order with deterministic ids.

    The id hashes what the run computes (base scenario path relative to ``base_dir``,
    fault, seed, duration, thresholds), not where it is written or which folder the
    FMUs come from (:func:`campaign_fmu_dir`), so a spec edited by adding sweeps keeps
    the ids (and records) of the runs it had.
    """
    runs: list[RunSpec] = []
    fmu_dir = campaign_fmu_dir(spec, base_dir, fmu_dir)
    if spec.results_dir is not None:
        results_dir: str | None = str((base_dir / spec.results_dir).resolve())
    else:
        results_dir = str(out_dir.resolve()) if out_dir is not None else None

    def make(cls_name: str, kind: str, duration: float, replicate: str, fault: dict | None,
             condition: str | None = None, **meta: Any) -> RunSpec:
        c = spec.classes[cls_name]
        scenario = (base_dir / c.scenario).resolve()
        ident = {"class": cls_name, "scenario": os.path.relpath(scenario, base_dir),
                 "kind": kind, "duration_s": duration, "fault": fault,
                 "replicate": replicate, "base_seed": spec.base_seed}
        if meta.get("also"):
            ident["also"] = meta["also"]
        # the seed does not depend on the condition (unless the class says "disjoint"): a
        # fault under every condition is flown with the same noise (a paired comparison)
        seed = _seed(spec.base_seed, json.dumps(ident, sort_keys=True))
        parameters = {inst: dict(v) for inst, v in c.parameters.items()}
        manoeuvres = None
        group = None
        if condition is not None:  # only then: runs without conditions keep their ids
            cond = spec.conditions[condition]
            ident["condition"] = {"name": condition, **cond.model_dump()}
            for inst, values in cond.parameters.items():
                parameters.setdefault(inst, {}).update(values)
            manoeuvres = [dict(m) for m in cond.manoeuvres]
            group = cond.group
            if c.condition_seeds == "disjoint":
                seed = _seed(spec.base_seed, json.dumps(ident, sort_keys=True))
        thresholds = list(c.thresholds or DEFAULT_THRESHOLDS[c.channel])
        ident.update(seed_parameters=c.seed_parameters, thresholds=thresholds,
                     diagnoser=c.diagnoser, parameters=c.parameters)
        witnesses = (list(c.witnesses or [c.diagnoser]) if c.channel == "grey"
                     else list(c.witnesses))
        if witnesses:  # only then: the ids of the other channels' runs stay as they were
            ident["witnesses"] = witnesses
        if c.witness_copies:  # the seed (above) stays: same noise with or without them
            ident["witness_copies"] = {w: v.model_dump() for w, v in c.witness_copies.items()}
        tag = f"{meta.get('fault_type') or 'nominal'}" + (f"-{condition}" if condition else "")
        return RunSpec(run_id=f"{cls_name}-{tag}-{_run_id(ident)}",
                       campaign=spec.name, cls=cls_name, channel=c.channel, kind=kind,
                       scenario=str(scenario), duration_s=duration, seed=seed,
                       seed_parameters=c.seed_parameters, parameters=parameters,
                       diagnoser=c.diagnoser,
                       fault=fault, thresholds=thresholds, witnesses=witnesses,
                       witness_copies=dict(c.witness_copies),
                       fmu_dir=fmu_dir,
                       results_dir=results_dir, condition=condition, group=group,
                       manoeuvres=manoeuvres, **meta)

    for sw in spec.sweeps:
        c = spec.classes[sw.cls]
        for mag in sw.magnitudes:
            for onset in sw.onsets_s:
                for ch in sw.channels:
                    fault: dict[str, Any]
                    if sw.set is not None:
                        fault = {"name": "campaign_fault", "set": sw.set, "value": mag,
                                 "start_s": onset, **sw.extra}
                    else:
                        fault = {"name": "campaign_fault", "injector": c.injector,
                                 "channel": ch, "type": sw.type, "start_s": onset, **sw.extra}
                        if not math.isnan(mag):
                            fault[MAGNITUDE_PARAMETER[sw.type]] = mag
                    duration = (onset + sw.post_onset_s if sw.post_onset_s is not None
                                else sw.duration_s or _base_duration(base_dir / c.scenario))
                    label = sw.label or sw.type or sw.set.partition(".")[2]
                    also = [{"name": f"campaign_fault_{j + 2}", "injector": c.injector,
                             "start_s": onset, **other} for j, other in enumerate(sw.also)]
                    if c.channel == "system":
                        injected = sw.expected or "q"
                    elif c.channel == "df":
                        chans = sorted({ch, *(int(o["channel"]) for o in sw.also)})
                        injected = "+".join(AIRCRAFT_SENSORS[k - 1]
                                            if k <= len(AIRCRAFT_SENSORS) else str(k)
                                            for k in chans)
                    else:
                        injected = label
                    for cond in sw.conditions or [None]:
                        for r in range(sw.seeds):
                            runs.append(make(sw.cls, "fault", duration, str(r), fault, cond,
                                             fault_type=label,
                                             magnitude=None if math.isnan(mag) else mag,
                                             onset_s=onset,
                                             target=None if sw.set is not None else ch,
                                             injected=injected, accepted=list(sw.accept),
                                             also=also))
    for nom in spec.nominal:
        for cond in nom.conditions or [None]:
            for r in range(nom.runs):
                runs.append(make(nom.cls, "nominal", nom.duration_s, str(r), None, cond))
    ids = [r.run_id for r in runs]
    if len(set(ids)) != len(ids):
        dup = next(i for i in ids if ids.count(i) > 1)
        raise ValueError(f"campaign {spec.name!r}: two runs are identical ({dup}); "
                         "remove the duplicate sweep entry")
    return runs


def _base_duration(path: Path) -> float:
    return float(tomllib.loads(path.read_text(encoding="utf-8"))["duration_s"])


# --------------------------------------------------------------------------- one run
#: Grey-channel outputs recorded per witness.
GREY_SIGNALS = ("grey.alarm", "grey.statistic", "grey.calibrating", "grey.prediction_valid",
                "grey.y")


def _signals(run: RunSpec) -> list[str]:
    d = run.diagnoser
    if run.witnesses and run.channel in ("df", "dtg"):
        return _witness_signals(run)
    if run.channel == "grey":
        return [f"{w}.{name}" for w in run.witnesses for name in GREY_SIGNALS]
    if run.channel == "system":
        return [f"{d}.{alarm}" for alarm, _ in SYSTEM_WITNESSES.values()] + [
            f"{d}.{ready}" for _, ready in SYSTEM_WITNESSES.values()] + [
            f"{d}.dtg.fault_code", f"{d}.df.isolated_sensor", f"{d}.df.fault_type",
            f"{d}.df.fault_magnitude"]
    if run.channel == "df":
        return ([f"{d}.df.residual[{i}]" for i in range(1, 7)]
                + [f"{d}.df.alarm[{i}]" for i in range(1, 7)]
                + [f"{d}.df.statistic[{i}]" for i in range(1, 7)]
                + [f"{d}.df.detected", f"{d}.df.isolated_sensor", f"{d}.df.calibrating",
                   f"{d}.df.isolated_mask", f"{d}.df.fault_type", f"{d}.df.fault_magnitude",
                   f"{d}.df.episodes", f"{d}.df.input_delay_in_use"])
    return ([f"{d}.dtg.eta_{ax}[{i}]" for ax in "xy" for i in range(1, 6)]
            + [f"{d}.dtg.alarm", f"{d}.dtg.learning", f"{d}.dtg.fault_code",
               f"{d}.dtg.fault_axis", f"{d}.dtg.reference_status"]
            + [f"{d}.dtg.residual_{name}[{a}]" for name in
               ("level_z", "var_ratio", "long_var_ratio", "power_cusum") for a in (1, 2)])


def build_scenario(run: RunSpec) -> Any:
    """The base scenario with the run's fault, seed, duration and recorded signals (in
    memory, through :func:`harness.cosim.scenario.parse_scenario`); expectations dropped."""
    from harness.cosim.scenario import parse_scenario

    path = Path(run.scenario)
    data = tomllib.loads(path.read_text(encoding="utf-8"))
    data["name"] = run.run_id
    data["duration_s"] = run.duration_s
    data["faults"] = ([run.fault, *run.also] if run.fault is not None else [])
    if run.manoeuvres is not None:
        # A PitchController with no manoeuvre flies its built-in default (a 0.25 rad
        # square wave): one whose base manoeuvre is replaced by none is set to trim.
        from harness.cosim.scenario import MANOEUVRE_COMMAND_CODES

        def commanded(entries: list[dict[str, Any]]) -> set[str]:
            return {m["instance"] for m in entries if m.get("kind") in MANOEUVRE_COMMAND_CODES}

        for inst in commanded(data.get("manoeuvres", [])) - commanded(run.manoeuvres):
            params = data["fmus"][inst].setdefault("parameters", {})
            params.setdefault("command_source", 0)
        data["manoeuvres"] = run.manoeuvres
    data["expect"] = []
    data["record"] = {"variables": _signals(run)}
    data.pop("training", None)
    for inst, values in run.parameters.items():
        if inst not in data.get("fmus", {}) and inst not in run.witness_copies:
            raise ValueError(f"parameters: no instance {inst!r} in {path}")
        if inst in data.get("fmus", {}):
            data["fmus"][inst].setdefault("parameters", {}).update(values)
    add_witness_copies(data, run.diagnoser, run.witness_copies, str(path))
    for inst, values in run.parameters.items():
        if inst in run.witness_copies:  # overrides of an added witness itself
            data["fmus"][inst].setdefault("parameters", {}).update(values)
    for w in run.witnesses:
        if w not in data.get("fmus", {}):
            raise ValueError(f"witnesses: no instance {w!r} in {path}")
    for j, qualified in enumerate(run.seed_parameters):
        inst, _, par = qualified.partition(".")
        if inst not in data.get("fmus", {}):
            raise ValueError(f"seed_parameters: {qualified!r}: no instance {inst!r} in "
                             f"{path}")
        data["fmus"][inst].setdefault("parameters", {})[par] = run.seed + j
    return parse_scenario(data, source=f"{path} (run {run.run_id})", path=path)


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
    from harness.cosim.master import run_scenario

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


def add_witness_copies(data: dict[str, Any], diagnoser: str,
                       copies: dict[str, WitnessCopy], source: str = "scenario") -> None:
    """Add to scenario ``data`` (TOML as a dict, changed in place) each witness of
    ``copies`` as a copy of instance ``diagnoser``: same FMU, parameters and files, its
    own overrides on top, and a copy of every connection into ``diagnoser`` (its inputs;
    its outputs feed nothing new).  Side by side, both instances see the same signals."""
    fmus = data.get("fmus", {})
    if copies and diagnoser not in fmus:
        raise ValueError(f"witness_copies: no instance {diagnoser!r} to copy in {source}")
    for name, copy in copies.items():
        if name in fmus:
            raise ValueError(f"witness_copies: {source} has an instance {name!r} already")
        inst = json.loads(json.dumps(fmus[diagnoser]))
        # a setting of the copy replaces the original's, parameter or file alike (a
        # parameter "dtg.signature_file" = "" drops the original's library file)
        for key in copy.parameters:
            inst.get("files", {}).pop(key, None)
        for key in copy.files:
            inst.get("parameters", {}).pop(key, None)
        inst.setdefault("parameters", {}).update(copy.parameters)
        if copy.files:
            inst.setdefault("files", {}).update(copy.files)
        fmus[name] = inst
        prefix = f"{diagnoser}."
        data["connections"] = [*data.get("connections", []), *(
            {**conn, "to": name + "." + conn["to"][len(prefix):]}
            for conn in data.get("connections", []) if conn["to"].startswith(prefix))]


def _witness_signals(run: RunSpec) -> list[str]:
    """Recorded outputs of a df/dtg run with witnesses: each witness's channel outputs."""
    out: list[str] = []
    for w in run.witnesses:
        out += _signals(run.model_copy(update={"diagnoser": w, "witnesses": []}))
    return out


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
    """A function ``(t, y, valid, T) -> alarm`` replaying a fixed-threshold grey rule of
    ``witness`` at ``T`` times its ``grey.threshold``, or None for a calibrated rule
    (``grey.calibrate_s > 0``), which is swept on its statistic instead.

    The detector is built as the Diagnoser FMU builds it (its parameter defaults) and fed
    the recorded samples ``y`` (V) at times ``t`` (s).  Its first sample is the row that
    lies the predictor's window before the FMU's first ``grey.prediction_valid`` row
    (``valid``): with Gauss-Seidel coupling the Diagnoser steps after the plant, so row 0
    holds initial outputs that it never processed.
    """
    from gyrodiag.grey import ClassicGreyPredictor, GreyFaultDetector, ImprovedGreyPredictor

    def par(name: str, default: Any) -> Any:
        return _param(scenario, witness, name, default)

    if float(par("grey.calibrate_s", 0.0)) > 0.0:
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
    from harness.cosim.scenario import resolve_file_parameters

    files = resolve_file_parameters(scenario, run.results_dir, must_exist=False)
    path = files.get(run.diagnoser, {}).get("dtg.signature_file")
    if path is None or not Path(path).is_file():
        return []
    data = json.loads(Path(path).read_text(encoding="utf-8"))
    if "patterns" in data:
        return [c["name"] for c in data["patterns"]["classes"]]
    return list(data["signatures"])


# --------------------------------------------------------------------------- guard
def _write_json_atomic(path: Path, data: dict[str, Any]) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.stem}-", suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, "w", encoding="utf-8") as fh:
            json.dump(data, fh, indent=1, sort_keys=True, allow_nan=True)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def _child_env() -> dict[str, str]:
    env = dict(os.environ)
    paths = [str(REPO_ROOT), *[p for p in sys.path if p]]
    env["PYTHONPATH"] = os.pathsep.join(dict.fromkeys(paths))
    # the campaign is parallel across runs: BLAS threads inside a run only oversubscribe
    for var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
        env.setdefault(var, "1")
    return env


#: Prefix of the temporary folder of each run (input and output JSON of the run process).
RUN_TMP_PREFIX = "gd-campaign-"


def execute_run(run_dict: dict[str, Any], runner: str, timeout_s: float,
                records_dir: str) -> dict[str, Any]:
    """Run one campaign run in a fresh process and write its record; never raises.

    This is the task the pools execute.  ``runner`` is ``"module:function"``, called in
    the child with the run dict; what it returns is merged into the record.  A runner
    that raises, a process that dies, and a run longer than ``timeout_s`` (killed) are
    recorded with ``status`` ``"error"``/``"timeout"`` and the message.
    """
    t0 = time.perf_counter()
    record: dict[str, Any] = {"run": run_dict, "runner": runner}
    with tempfile.TemporaryDirectory(prefix=RUN_TMP_PREFIX) as tmp:
        inp, out = Path(tmp) / "run.json", Path(tmp) / "out.json"
        inp.write_text(json.dumps(run_dict), encoding="utf-8")
        cmd = [sys.executable, "-m", "harness.campaigns.campaign", "--child", runner, str(inp),
               str(out)]
        env = {**_child_env(), PARENT_PID_ENV: str(os.getpid())}
        proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                env=env, cwd=str(REPO_ROOT), text=True,
                                start_new_session=True)
        _LIVE_RUNS[proc] = tmp
        try:
            _, stderr = proc.communicate(timeout=timeout_s)
            _hold_if_stopping()
        except subprocess.TimeoutExpired:
            _hold_if_stopping()
            _LIVE_RUNS.pop(proc, None)
            _kill_group(proc)
            record.update(status="timeout",
                          error=f"timeout: run killed after {timeout_s:g} s")
        except BaseException:
            # interrupted: the run process lives in its own session, so nobody else will
            # stop it; the run is redone on resume
            _LIVE_RUNS.pop(proc, None)
            _kill_group(proc)
            raise
        else:
            _LIVE_RUNS.pop(proc, None)
            payload = json.loads(out.read_text(encoding="utf-8")) if out.is_file() else None
            if payload is not None and payload.get("error") is None:
                record.update(status="ok", error=None, **payload["result"])
            elif payload is not None:
                record.update(status="error", error=payload["error"])
            else:
                tail = "\n".join(stderr.strip().splitlines()[-20:])
                record.update(status="error", error=f"run process died with exit status "
                                                    f"{proc.returncode}: {tail}")
    record["wall_s"] = time.perf_counter() - t0
    _write_json_atomic(Path(records_dir) / f"{run_dict['run_id']}.json", record)
    return record


#: Run processes this process has started and not yet reaped, with their temporary
#: folders (for _worker_terminate and the orphan watch).
_LIVE_RUNS: dict[subprocess.Popen[str], str] = {}
#: Environment variable telling a run process the pid of the worker that started it.
PARENT_PID_ENV = "GYRODIAG_CAMPAIGN_PARENT_PID"


def _kill_group(proc: subprocess.Popen[str]) -> None:
    _killpg(proc.pid)
    proc.communicate()


def _killpg(pid: int) -> None:
    try:
        os.killpg(pid, signal.SIGKILL)
    except ProcessLookupError:
        pass


#: How often a run process checks that its parent (the pool or Dask worker) lives, s.
ORPHAN_POLL_S = 0.5


def _exit_when_orphaned(parent_pid: int) -> None:
    """Daemon thread of run processes and pool workers: when the process that started
    this one is gone (a killed pool worker, a closed Dask cluster, a SIGKILL of the
    campaign), kill the runs this process started and exit: a run process has its own
    session, so no signal of the campaign reaches it, and its result would have nobody
    to read it.  ``parent_pid`` is passed down by the parent (not read here), so a
    parent that died before this thread started is noticed too."""
    while True:
        if os.getppid() != parent_pid:
            _kill_live_runs()
            for folder in _ORPHAN_CLEANUP:
                shutil.rmtree(folder, ignore_errors=True)
            os._exit(3)
        time.sleep(ORPHAN_POLL_S)


#: Folders a run process removes when it finds itself orphaned: its own temporary
#: folder, which the worker that made it can no longer remove when it was killed
#: outright (SIGKILL, a closed Dask cluster).
_ORPHAN_CLEANUP: list[str] = []


#: Set when this worker is stopping: the runs it kills must not be recorded as failed.
_STOPPING = threading.Event()


def _hold_if_stopping() -> None:
    """Called where execute_run would record a run's end: if the run ended because this
    worker is stopping (orphan watch), wait for the watch to exit the process instead of
    writing an "exit status -9" record that a resume would take as a finished run."""
    if _STOPPING.is_set():
        while True:
            time.sleep(3600)


def _kill_live_runs() -> None:
    _STOPPING.set()
    for proc, tmp in list(_LIVE_RUNS.items()):
        _killpg(proc.pid)
        shutil.rmtree(tmp, ignore_errors=True)  # os._exit follows: no with-block cleanup


def _load_runner(runner: str) -> Callable[[dict[str, Any]], dict[str, Any]]:
    module, _, func = runner.partition(":")
    if not module or not func:
        raise ValueError(f"runner: {runner!r} must be 'module:function'")
    return getattr(importlib.import_module(module), func)


def _child_main(runner: str, inp: str, out: str) -> int:
    from harness.cosim.niceness import keep_niceness

    keep_niceness()  # its own session is its own autogroup (harness.cosim.niceness)
    parent = int(os.environ.get(PARENT_PID_ENV, os.getppid()))
    folder = Path(inp).parent
    if folder.name.startswith(RUN_TMP_PREFIX):  # only execute_run's own folders
        _ORPHAN_CLEANUP.append(str(folder))
    threading.Thread(target=_exit_when_orphaned, args=(parent,), daemon=True,
                     name="orphan-watch").start()
    run_dict = json.loads(Path(inp).read_text(encoding="utf-8"))
    try:
        result = _load_runner(runner)(run_dict)
        payload: dict[str, Any] = {"error": None, "result": result}
    except BaseException as exc:  # everything is recorded, even SystemExit
        payload = {"error": f"{type(exc).__name__}: {exc}\n{traceback.format_exc()}"}
    _write_json_atomic(Path(out), payload)
    return 0


# --------------------------------------------------------------------------- campaign
class CampaignInterrupted(KeyboardInterrupt):
    """A campaign stopped by Ctrl-C or SIGTERM; finished runs are saved (the message
    says where), runs in flight were killed."""


@dataclass
class CampaignOutcome:
    """What :func:`run_campaign` did: records of every finished run (old and new)."""

    records: list[dict[str, Any]]
    n_total: int
    n_skipped: int
    n_executed: int
    wall_s: float
    out_dir: Path
    failed: list[str] = field(default_factory=list)


def load_records(records_dir: Path) -> dict[str, dict[str, Any]]:
    """Run id → record of every record file in ``records_dir``."""
    out = {}
    if records_dir.is_dir():
        for p in sorted(records_dir.glob("*.json")):
            try:
                out[p.stem] = json.loads(p.read_text(encoding="utf-8"))
            except json.JSONDecodeError:
                continue  # cannot happen with atomic writes; re-run it if it does
    return out


@dataclass
class CampaignOutput:
    """One campaign's output folder as :func:`load_campaign_output` reads it."""

    name: str
    out_dir: Path
    n_planned: int
    fraction: float
    records: list[dict[str, Any]]
    # flight conditions the run was restricted to (``--group``/``--condition``), if any
    selection: dict[str, list[str] | None] = field(default_factory=dict)


def load_campaign_output(out_dir: Path | str) -> CampaignOutput:
    """The records of the runs a campaign output folder planned (its ``campaign.json``),
    for summarising several campaigns as one (``python -m harness campaign-summary``).

    Raises ValueError naming the folder when it holds no readable ``campaign.json``.
    """
    out_dir = Path(out_dir)
    path = out_dir / "campaign.json"
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
        name, ids = str(data["spec"]["name"]), list(data["run_ids"])
        fraction = float(data.get("fraction", 1.0))
        selection = {k: (None if v is None else [str(x) for x in v])
                     for k, v in dict(data.get("selection") or {}).items()}
    except FileNotFoundError:
        raise ValueError(f"{out_dir}: not a campaign output folder (no campaign.json; "
                         "run `python -m harness campaign SPEC --out DIR` first)") from None
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise ValueError(f"{path}: unreadable campaign record ({exc})") from None
    done = load_records(out_dir / "runs")
    return CampaignOutput(name=name, out_dir=out_dir, n_planned=len(ids), fraction=fraction,
                          records=[done[rid] for rid in ids if rid in done],
                          selection=selection)


def _iter_pool(runs: Sequence[RunSpec], runner: str, timeout_s: float, records_dir: Path,
               workers: int) -> Iterator[dict[str, Any]]:
    import multiprocessing

    ctx = multiprocessing.get_context("spawn")
    with ProcessPoolExecutor(max_workers=workers, mp_context=ctx,
                             initializer=_worker_init, initargs=(os.getpid(),)) as pool:
        futures: list[Any] = []
        try:
            # submitting is inside the try: an interrupt here must stop the pool too
            futures += [pool.submit(execute_run, r.model_dump(), runner, timeout_s,
                                    str(records_dir)) for r in runs]
            for f in as_completed(futures):
                yield f.result()
        except BaseException:
            # without this, leaving the with-block would wait for the runs in flight;
            # take the workers first: shutdown() forgets them (Python 3.11)
            procs = list((getattr(pool, "_processes", None) or {}).values())
            pool.shutdown(wait=False, cancel_futures=True)
            for proc in procs:
                proc.terminate()
            raise
        finally:
            for f in futures:
                f.cancel()


def _worker_init(campaign_pid: int) -> None:
    signal.signal(signal.SIGTERM, _worker_terminate)
    # Ctrl-C reaches the whole foreground process group: the campaign process decides
    # (it terminates the workers, see _iter_pool)
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    threading.Thread(target=_exit_when_orphaned, args=(campaign_pid,), daemon=True,
                     name="orphan-watch").start()


def _worker_terminate(signum: int, frame: Any) -> None:
    _kill_live_runs()
    os._exit(128 + signum)


def _raise_interrupt(signum: int, frame: Any) -> None:
    raise KeyboardInterrupt(f"signal {signum}")


def _iter_dask(runs: Sequence[RunSpec], runner: str, timeout_s: float, records_dir: Path,
               workers: int, address: str) -> Iterator[dict[str, Any]]:
    from distributed import Client, LocalCluster
    from distributed import as_completed as dask_as_completed

    cluster = None
    if address == "local":
        cluster = LocalCluster(n_workers=workers, threads_per_worker=1, processes=True,
                               dashboard_address=None)
        client = Client(cluster)
    else:
        client = Client(address)
    try:
        futures = [client.submit(execute_run, r.model_dump(), runner, timeout_s,
                                 str(records_dir), key=f"run-{r.run_id}", pure=False,
                                 retries=0) for r in runs]
        try:
            for f in dask_as_completed(futures):
                yield f.result()
        finally:
            client.cancel(futures)
    finally:
        client.close()
        if cluster is not None:
            cluster.close()


def prepare(spec: CampaignSpec, base_dir: Path, out_dir: Path,
            fmu_dir: Path | str | None = None) -> None:
    """Learn the DTG signatures first when the spec asks for them and they are missing
    (``signatures_training``, then every entry of ``libraries``), with the FMUs of
    :func:`campaign_fmu_dir`."""
    learned = ([(spec.signatures_file, spec.signatures_training)]
               if spec.signatures_training is not None else [])
    for name, training in [*learned, *spec.libraries.items()]:
        _learn_library(spec, base_dir, out_dir, name, training,
                       campaign_fmu_dir(spec, base_dir, fmu_dir))


def preflight_runs(runs: Sequence[RunSpec]) -> None:
    """Check one run of every class as a run process would before its first FMU call
    (``files`` parameters such as a library the spec does not learn, FMU files,
    variable names), so that a campaign whose chain cannot start stops at once
    instead of recording every run as failed.

    Raises
    ------
    ScenarioError, FileNotFoundError
        Naming the class's base scenario and what is missing.
    """
    from harness.cosim.master import preflight

    seen: set[str] = set()
    for run in runs:
        if run.cls in seen:
            continue
        seen.add(run.cls)
        try:
            scenario = build_scenario(run)
        except ScenarioError:
            raise
        except (ValueError, tomllib.TOMLDecodeError) as exc:  # the spec's or the base's
            raise ScenarioError(run.scenario, [(f"class {run.cls}", str(exc))]) from None
        preflight(scenario, fmu_dir=run.fmu_dir, results_dir=run.results_dir)


def _learn_library(spec: CampaignSpec, base_dir: Path, out_dir: Path, name: str,
                   training_set: str, fmu_dir: str | None) -> None:
    results = (base_dir / spec.results_dir).resolve() if spec.results_dir else out_dir
    target = results / name
    if target.is_file():
        return
    training = (base_dir / training_set).resolve()
    log.info("learning the DTG signatures from %s -> %s", training, target)
    cmd = [sys.executable, "-m", "harness", "learn-signatures", str(training), "--out",
           str(target)]
    if fmu_dir:
        cmd += ["--fmu-dir", fmu_dir]
    proc = subprocess.run(cmd, env=_child_env(), cwd=str(REPO_ROOT))
    if proc.returncode != 0 or not target.is_file():
        raise RuntimeError(f"learning the DTG signatures failed (exit {proc.returncode})")


def run_campaign(spec: CampaignSpec, base_dir: Path, out_dir: Path, *, workers: int = 2,
                 dask: str | None = None, runner: str | None = None,
                 timeout_s: float | None = None, max_runs: int | None = None,
                 retry_failed: bool = False, fraction: float = 1.0,
                 progress: bool = True, fmu_dir: Path | str | None = None,
                 groups: Sequence[str] | None = None,
                 conditions: Sequence[str] | None = None) -> CampaignOutcome:
    """Run (or resume) a campaign; every finished run is written as it finishes.

    Parameters
    ----------
    spec, base_dir : CampaignSpec, Path
        The spec and the folder its relative paths start from (:func:`load_campaign`).
    out_dir : Path
        Output folder: ``runs/<run_id>.json`` per run, ``campaign.json`` (the run list).
    workers : int
        Parallel runs (pool processes or LocalCluster workers).
    dask : str, optional
        None: local process pool; ``"local"``: a dask LocalCluster; else a scheduler
        address (``tcp://host:8786``).
    runner : str, optional
        ``"module:function"`` computing a run's record fields (default: the spec's,
        :func:`simulate_run`); it must be importable in the run process.
    timeout_s : float, optional
        Per-run wall time limit, s (default: the spec's).
    max_runs : int, optional
        Stop after starting this many pending runs (an interruption on purpose).
    retry_failed : bool
        Re-run runs whose record says error/timeout.
    fraction : float
        Run only a deterministic subset (run ids hashed below ``fraction``), in (0, 1].
    progress : bool
        tqdm progress bar with ETA on stderr.
    fmu_dir : path, optional
        Folder of the FMUs, before ``$GYRODIAG_FMU_DIR`` and the spec's
        (:func:`campaign_fmu_dir`); the run ids do not depend on it.
    groups, conditions : sequence of str, optional
        Run only these condition groups / flight conditions (:func:`select`).
    """
    if workers < 1:
        raise ValueError(f"workers must be >= 1, got {workers}")
    if not 0.0 < fraction <= 1.0:
        raise ValueError(f"fraction must be in (0, 1], got {fraction}")
    t0 = time.perf_counter()
    out_dir = Path(out_dir).resolve()
    records_dir = out_dir / "runs"
    if fmu_dir is not None and not Path(fmu_dir).is_dir():
        raise FileNotFoundError(f"fmu_dir {str(fmu_dir)!r} is not a folder")
    # selected before anything is written: a bad selection leaves no folder behind
    runs = select(expand_runs(spec, base_dir, out_dir, fmu_dir), fraction, groups=groups,
                  conditions=conditions)
    records_dir.mkdir(parents=True, exist_ok=True)
    prepare(spec, base_dir, out_dir, fmu_dir)
    runner = runner or spec.runner
    if runner == DEFAULT_RUNNER:  # another runner need not read the scenarios
        preflight_runs(runs)
    _write_json_atomic(out_dir / "campaign.json", {
        "spec": spec.model_dump(by_alias=True), "base_dir": str(base_dir),
        "fraction": fraction,
        "selection": {"groups": list(groups) if groups is not None else None,
                      "conditions": list(conditions) if conditions is not None else None},
        "run_ids": [r.run_id for r in runs]})
    for stale in records_dir.glob(".*.tmp"):  # atomic writes cut short by a kill
        if time.time() - stale.stat().st_mtime > 60.0:  # not one being written now
            stale.unlink(missing_ok=True)
    done = load_records(records_dir)
    keep = {rid for rid, rec in done.items()
            if not (retry_failed and rec.get("status") != "ok")}
    pending = [r for r in runs if r.run_id not in keep]
    n_skipped = len(runs) - len(pending)
    if max_runs is not None:
        pending = pending[:max(0, max_runs)]
    timeout = float(timeout_s if timeout_s is not None else spec.timeout_s)
    new: list[dict[str, Any]] = []
    if pending:
        it = (_iter_pool(pending, runner, timeout, records_dir, workers) if dask is None
              else _iter_dask(pending, runner, timeout, records_dir, workers, dask))
        bar = _bar(len(pending), n_skipped, progress)
        # a batch system's kill (SIGTERM) stops the campaign as cleanly as Ctrl-C
        main = threading.current_thread() is threading.main_thread()
        previous = signal.signal(signal.SIGTERM, _raise_interrupt) if main else None
        interrupted: KeyboardInterrupt | None = None
        try:
            try:
                for rec in it:
                    new.append(rec)
                    if bar is not None:
                        bar.update(1)
                        if rec.get("status") != "ok":
                            bar.write(f"{rec['run']['run_id']}: {rec['status']}: "
                                      f"{str(rec.get('error')).strip().splitlines()[0][:150]}")
            except KeyboardInterrupt as exc:
                interrupted = exc
            finally:
                try:
                    # the interrupt may land outside the generator: close it here, or
                    # its pool would wait for the runs in flight at interpreter exit
                    it.close()
                except KeyboardInterrupt as exc:  # a second interrupt while stopping
                    interrupted = interrupted or exc
        finally:
            if main:
                signal.signal(signal.SIGTERM,
                              previous if previous is not None else signal.SIG_DFL)
            if bar is not None:
                bar.close()
        if interrupted is not None:
            ids = {r.run_id for r in runs}
            saved = sum(1 for rid, rec in load_records(records_dir).items() if rid in ids)
            fate = ("were stopped and will be redone" if dask in (None, "local") else
                    "were cancelled (on a remote cluster a run already started may still "
                    "finish and be saved)")
            raise CampaignInterrupted(
                f"campaign {spec.name!r} interrupted: {saved} of {len(runs)} runs are saved "
                f"in {records_dir}; the runs in flight {fate}; run the same command again "
                "to resume") from interrupted
    ids = {r.run_id for r in runs}
    records = [rec for rid, rec in load_records(records_dir).items() if rid in ids]
    return CampaignOutcome(records=records, n_total=len(runs), n_skipped=n_skipped,
                           n_executed=len(new), wall_s=time.perf_counter() - t0,
                           out_dir=out_dir,
                           failed=[r["run"]["run_id"] for r in records
                                   if r.get("status") != "ok"])


def select(runs: list[RunSpec], fraction: float, *, groups: Sequence[str] | None = None,
           conditions: Sequence[str] | None = None) -> list[RunSpec]:
    """Deterministic subset, stratified: of every (class, kind, fault type) group the
    ``ceil(fraction * n)`` runs whose ids hash lowest (all runs when ``fraction`` is 1),
    so that a reduced campaign still has nominal runs of every class.

    ``groups`` / ``conditions`` keep only the runs of those condition groups / flight
    conditions (e.g. re-fly the ``level`` group after a change that only level flight
    sees); the run ids are the full campaign's, so the records serve both. An unknown
    name raises ValueError listing the spec's names.
    """
    for arg, values, field_name in (("groups", groups, "group"),
                                    ("conditions", conditions, "condition")):
        if values is None:
            continue
        known = sorted({getattr(r, field_name) for r in runs} - {None})
        unknown = [v for v in values if v not in known]
        if unknown or not values:
            raise ValueError(f"{arg}: {unknown or list(values)} not in this campaign "
                             f"(it has {known or 'none'})")
        runs = [r for r in runs if getattr(r, field_name) in values]
    if fraction >= 1.0:
        return runs
    strata: dict[tuple[str, str, str | None], list[RunSpec]] = {}
    for r in runs:
        strata.setdefault((r.cls, r.kind, r.fault_type), []).append(r)
    keep: set[str] = set()
    for members in strata.values():
        ranked = sorted(members, key=lambda r: hashlib.sha256(r.run_id.encode()).hexdigest())
        keep.update(r.run_id for r in ranked[:math.ceil(fraction * len(members))])
    return [r for r in runs if r.run_id in keep]


def _bar(total: int, initial: int, enabled: bool) -> Any:
    if not enabled:
        return None
    from tqdm import tqdm

    return tqdm(total=total + initial, initial=initial, unit="run", desc="campaign",
                file=sys.stderr, dynamic_ncols=True, smoothing=0.1)


if __name__ == "__main__":
    if len(sys.argv) == 5 and sys.argv[1] == "--child":
        code = _child_main(*sys.argv[2:])
        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(code)  # see harness/__main__.py: pythonfmu's exit-time destructors
    print("usage: python -m harness campaign SPEC.toml (this module's entry is internal)",
          file=sys.stderr)
    sys.exit(2)
