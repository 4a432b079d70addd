"""Expansion: a campaign spec into its runs (:func:`expand_runs`, deterministic ids and
seeds), a subset of them (:func:`select`: fraction, condition group, flight condition),
and one run into the scenario it simulates (:func:`build_scenario`)."""

from __future__ import annotations

import hashlib
import json
import math
import os
import tomllib
from collections.abc import Sequence
from pathlib import Path
from typing import Any, NamedTuple

from gyrodiag_harness.campaigns.spec import (
    AIRCRAFT_SENSORS,
    DEFAULT_THRESHOLDS,
    GREY_SIGNALS,
    MAGNITUDE_PARAMETER,
    SYSTEM_WITNESSES,
    CampaignSpec,
    FaultClass,
    RunSpec,
    Sweep,
    WitnessCopy,
)
from gyrodiag_harness.cosim.scenario import FMU_DIR_ENV


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
    else None (each base scenario's own, :func:`gyrodiag_harness.cosim.scenario.resolve_fmu_dir`):
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
    where = _Where(spec, base_dir, fmu_dir, results_dir)

    for sw in spec.sweeps:
        c = spec.classes[sw.cls]
        for mag in sw.magnitudes:
            for onset in sw.onsets_s:
                for ch in sw.channels:
                    fault = _sweep_fault(sw, c, mag, onset, ch)
                    duration = (onset + sw.post_onset_s if sw.post_onset_s is not None
                                else sw.duration_s or _base_duration(base_dir / c.scenario))
                    label = sw.label or sw.type or sw.set.partition(".")[2]
                    also = [{"name": f"campaign_fault_{j + 2}", "injector": c.injector,
                             "start_s": onset, **other} for j, other in enumerate(sw.also)]
                    injected = _injected(sw, c, ch, label)
                    for cond in sw.conditions or [None]:
                        for r in range(sw.seeds):
                            runs.append(_make_run(where, sw.cls, "fault", duration, str(r),
                                                  fault, cond, fault_type=label,
                                                  magnitude=None if math.isnan(mag) else mag,
                                                  onset_s=onset,
                                                  target=None if sw.set is not None else ch,
                                                  injected=injected,
                                                  accepted=list(sw.accept), also=also))
    for nom in spec.nominal:
        for cond in nom.conditions or [None]:
            for r in range(nom.runs):
                runs.append(_make_run(where, nom.cls, "nominal", nom.duration_s, str(r), None,
                                      cond))
    ids = [r.run_id for r in runs]
    if len(set(ids)) != len(ids):
        dup = next(i for i in ids if ids.count(i) > 1)
        raise ValueError(f"campaign {spec.name!r}: two runs are identical ({dup}); "
                         "remove the duplicate sweep entry")
    return runs


class _Where(NamedTuple):
    """What every run of one expansion shares (:func:`expand_runs`)."""

    spec: CampaignSpec
    base_dir: Path
    fmu_dir: str | None
    results_dir: str | None


def _sweep_fault(sw: Sweep, c: FaultClass, mag: float, onset: float, ch: int
                 ) -> dict[str, Any]:
    """The ``[[faults]]`` entry of one point of a sweep."""
    fault: dict[str, Any]
    if sw.set is not None:
        fault = {"name": "campaign_fault", "set": sw.set, "value": mag,
                 "start_s": onset, **sw.extra}
    else:
        fault = {"name": "campaign_fault", "injector": c.injector,
                 "channel": ch, "type": sw.type, "start_s": onset, **sw.extra}
        if not math.isnan(mag):
            fault[MAGNITUDE_PARAMETER[sw.type]] = mag
    return fault


def _injected(sw: Sweep, c: FaultClass, ch: int, label: str) -> str:
    """The diagnosis that counts as right for a sweep's runs on injector channel ``ch``."""
    if c.channel == "system":
        return sw.expected or "q"
    if c.channel == "df":
        chans = sorted({ch, *(int(o["channel"]) for o in sw.also)})
        return "+".join(AIRCRAFT_SENSORS[k - 1] if k <= len(AIRCRAFT_SENSORS) else str(k)
                        for k in chans)
    return label


def _make_run(where: _Where, cls_name: str, kind: str, duration: float, replicate: str,
              fault: dict | None, condition: str | None = None, **meta: Any) -> RunSpec:
    """One run of class ``cls_name``, its id and seed hashed from what it computes."""
    spec, base_dir = where.spec, where.base_dir
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
                   fmu_dir=where.fmu_dir,
                   results_dir=where.results_dir, condition=condition, group=group,
                   manoeuvres=manoeuvres, **meta)


def _base_duration(path: Path) -> float:
    return float(tomllib.loads(path.read_text(encoding="utf-8"))["duration_s"])


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
    memory, through :func:`gyrodiag_harness.cosim.scenario.parse_scenario`); expectations
    dropped."""
    from gyrodiag_harness.cosim.scenario import parse_scenario

    path = Path(run.scenario)
    data = tomllib.loads(path.read_text(encoding="utf-8"))
    data["name"] = run.run_id
    data["duration_s"] = run.duration_s
    data["faults"] = ([run.fault, *run.also] if run.fault is not None else [])
    if run.manoeuvres is not None:
        # A PitchController with no manoeuvre flies its built-in default (a 0.25 rad
        # square wave): one whose base manoeuvre is replaced by none is set to trim.
        from gyrodiag_harness.cosim.scenario import MANOEUVRE_COMMAND_CODES

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


