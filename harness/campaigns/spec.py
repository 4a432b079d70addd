"""Campaign specs: the TOML format (:class:`CampaignSpec` and its parts), loading it
(:func:`load_campaign`) and one run's spec (:class:`RunSpec`, what travels to the run
process).  The format and what a run records: :mod:`gyrodiag_harness.campaigns.campaign`."""

from __future__ import annotations

import math
import re
import tomllib
from pathlib import Path
from typing import Any, Literal

from pydantic import ConfigDict, Field, ValidationError, model_validator

from gyrodiag_harness.cosim.scenario import FAULT_TYPE_PARAMETERS, ScenarioError
from gyrodiag_harness.verification.strict_model import StrictModel

#: The per-run function used unless the spec or the caller names another.
DEFAULT_RUNNER = "gyrodiag_harness.campaigns.campaign:simulate_run"
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
#: Channels whose classes may judge several Diagnoser instances (``witnesses``).
WITNESS_CHANNELS = ("grey", "df", "dtg")


class WitnessCopy(StrictModel):
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


class FaultClass(StrictModel):
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


class Condition(StrictModel):
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


class Sweep(StrictModel):
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

    model_config = ConfigDict(populate_by_name=True)

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


class Nominal(StrictModel):
    """Fault-free runs of a class: ``runs`` seeds of ``duration_s`` each, per condition."""

    cls: str = Field(alias="class")
    duration_s: float = Field(gt=0)
    runs: int = Field(ge=1)
    conditions: list[str] = Field(default_factory=list)

    model_config = ConfigDict(populate_by_name=True)


class CampaignSpec(StrictModel):
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
class RunSpec(StrictModel):
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


#: Grey-channel outputs recorded per witness.
GREY_SIGNALS = ("grey.alarm", "grey.statistic", "grey.calibrating", "grey.prediction_valid",
                "grey.y")

