"""Scenario files: plain TOML validated by pydantic models (unknown keys are errors).

A scenario names the FMU instances, their parameters, the connections between them, a
fault schedule, what to record and what to expect (see the harness contract for the full
format).  Errors always name the file and the key path, e.g.::

    scenarios/x.toml: fmus.aircraft.step_ratio: Input should be greater than or equal to 1

List entries are addressed with 0-based indices: ``connections[2].from``.  Checks run in
three stages: TOML syntax, structure and values (pydantic), cross references inside the
file (:func:`load_scenario`), and — when a run starts and the FMUs are known — variable
names, causalities and types against each FMU's modelDescription
(:func:`check_against_models`), with the closest existing names as suggestions.

Scenario files cannot run code: TOML is data only, nothing is evaluated or imported.
"""

from __future__ import annotations

import difflib
import math
import os
import re
import tomllib
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Any, Literal

from pydantic import (
    BaseModel,
    ConfigDict,
    Discriminator,
    Field,
    PrivateAttr,
    Tag,
    ValidationError,
    field_validator,
    model_validator,
)

from gyrodiag_harness.verification import expectations
from gyrodiag_harness.verification.strict_model import StrictModel

#: FaultInjector fault codes (parameter ``fault_type_<channel>``), copied from the
#: FaultInjector FMU's documentation (``FaultType`` in models/fault_injector); a test
#: checks that this table matches the built FMU.  The harness never imports models/.
FAULT_TYPE_CODES: dict[str, int] = {
    "none": 0,
    "bias": 1,
    "gain": 2,
    "stuck_value": 3,
    "stuck_last": 4,
    "failure": 5,
    "step": 6,
    "ramp": 7,
    "noise": 8,
    "signal_loss": 9,
    "intermittent": 10,
    "saturation": 11,
    "nan_dropout": 12,
}
#: Extra spellings accepted for ``type`` (mapped to the canonical name).
FAULT_TYPE_ALIASES: dict[str, str] = {"stuck": "stuck_value"}

#: Channel parameters each fault type needs (all required, others must be left out).
FAULT_TYPE_PARAMETERS: dict[str, tuple[str, ...]] = {
    "none": (),
    "bias": ("magnitude",),
    "gain": ("gain",),
    "stuck_value": ("stuck_value",),
    "stuck_last": (),
    "failure": (),
    "step": ("magnitude",),
    "ramp": ("magnitude",),
    "noise": ("noise_std",),
    "signal_loss": ("noise_std",),
    "intermittent": ("magnitude", "period", "duty"),
    "saturation": ("sat_min", "sat_max"),
    "nan_dropout": (),
}
_CHANNEL_PARAMETERS = ("magnitude", "gain", "stuck_value", "noise_std", "period", "duty",
                       "sat_min", "sat_max")

#: PitchController ``command_source`` codes of the command manoeuvres, copied from the
#: PitchController FMU's documentation (``KIND_NAMES`` in models/pitch_controller); a test
#: checks that this table matches the built FMU.  The harness never imports models/.
MANOEUVRE_COMMAND_CODES: dict[str, int] = {
    "square_wave": 1,
    "step": 2,
    "doublet": 3,
    "sine_sweep": 4,
}
#: Manoeuvre kinds: the command shapes plus a start off trim (initial state of an
#: Aircraft-like instance: ``x0_theta``, ``x0_q``, ``x0_alpha``).
MANOEUVRE_KINDS = (*MANOEUVRE_COMMAND_CODES, "off_trim")
#: Fields each manoeuvre kind needs (all required) and may take (optional).
MANOEUVRE_REQUIRED: dict[str, tuple[str, ...]] = {
    "square_wave": ("amplitude_rad", "period_s"),
    "step": ("amplitude_rad",),
    "doublet": ("amplitude_rad", "pulse_s"),
    "sine_sweep": ("amplitude_rad", "f0_hz", "f1_hz", "duration_s"),
    "off_trim": ("duration_s",),
}
MANOEUVRE_OPTIONAL: dict[str, tuple[str, ...]] = {
    "square_wave": ("duration_s",),
    "step": ("duration_s",),
    "doublet": ("period_s", "duration_s"),
    "sine_sweep": (),
    "off_trim": ("theta0_rad", "q0_rad_s", "alpha0_rad"),
}
_MANOEUVRE_FIELDS = ("amplitude_rad", "period_s", "pulse_s", "f0_hz", "f1_hz", "duration_s",
                     "theta0_rad", "q0_rad_s", "alpha0_rad")
#: FMU parameter of each command-manoeuvre field (PitchController) and off-trim field
#: (Aircraft).
_COMMAND_PARAMETER = {"amplitude_rad": "cmd_amplitude", "period_s": "cmd_period",
                      "pulse_s": "cmd_pulse_s", "f0_hz": "cmd_f0_hz", "f1_hz": "cmd_f1_hz",
                      "duration_s": "cmd_duration_s"}
_OFF_TRIM_PARAMETER = {"theta0_rad": "x0_theta", "q0_rad_s": "x0_q", "alpha0_rad": "x0_alpha"}

DEFAULT_FMU_DIR = "build/fmus"
#: Environment variable that overrides the scenario's ``fmu_dir`` (CI, test sessions).
FMU_DIR_ENV = "GYRODIAG_FMU_DIR"

_INSTANCE_RE = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*$")

ParameterValue = bool | int | float | str


class ScenarioError(ValueError):
    """A scenario file is invalid; ``problems`` holds ``(key path, message)`` pairs.

    ``str(error)`` is one line per problem: ``<source>: <key path>: <message>``.
    """

    def __init__(self, source: str, problems: list[tuple[str, str]]) -> None:
        self.source = source
        self.problems = list(problems)
        lines = [f"{source}: {key}: {msg}" if key else f"{source}: {msg}"
                 for key, msg in self.problems]
        super().__init__("\n".join(lines))


class _Strict(StrictModel):
    # attribute docstrings are the field descriptions of the JSON Schema and of
    # docs/scenarios.md (python -m gyrodiag_harness schema); extra="forbid" from StrictModel
    model_config = ConfigDict(populate_by_name=True, use_attribute_docstrings=True)


class FmuInstance(_Strict):
    """One FMU instance: which FMU, its rate and its start values.

    ``files`` holds String parameters that name a file (parameter name → path), e.g.
    ``files = { "dtg.signature_file" = "${out}/dtg_signatures.json" }``.  The harness
    resolves each path before the run and hands the FMU an absolute path: a path that
    starts with ``${out}/`` is taken in the results folder of the command (``--out``),
    or, if it is not there, in the folder above it (``results/`` when the command writes
    into ``results/verify-<time>/``), so that a file produced at run time (``gyrodiag
    learn-signatures ... --out results/dtg_signatures.json``) can be named; any
    other relative path is taken relative to the scenario file's folder.  The file must
    exist when the run starts (see :func:`resolve_file_parameters`).
    """

    fmu: str = Field(min_length=1)
    """FMU name in the FMU folder (``"Aircraft"`` → ``Aircraft.fmu``), or a path ending
    in ``.fmu`` (relative to the scenario file's folder, then its parents)."""
    step_ratio: int = Field(default=1, ge=1)
    """The instance steps every ``step_ratio`` base steps, with ``step_ratio * step_s``."""
    parameters: dict[str, ParameterValue] = Field(default_factory=dict)
    """Start values of parameters, by FMU variable name (Real, Integer, Boolean, String;
    the FMU's type decides)."""
    files: dict[str, str] = Field(default_factory=dict)
    """String parameters that name a file: parameter name → path (see above)."""

    @field_validator("files")
    @classmethod
    def _file_specs(cls, value: dict[str, str]) -> dict[str, str]:
        for name, spec in value.items():
            _check_file_spec(name, spec)
        return value


class Connection(_Strict):
    """``from`` output → ``to`` input, both ``"instance.variable"``."""

    from_: str = Field(alias="from")
    """Output, ``"instance.variable"``."""
    to: str
    """Input, ``"instance.variable"``; at most one connection per input."""

    @field_validator("from_", "to")
    @classmethod
    def _qualified(cls, value: str) -> str:
        return _check_qualified(value)


class InjectorFault(_Strict):
    """A fault on one FaultInjector channel, set as the injector's parameters."""

    name: str = Field(min_length=1)
    """Fault name, unique in the scenario (expectations and reports refer to it)."""
    injector: str
    """The FaultInjector instance."""
    channel: int = Field(ge=1)
    """Injector channel (``in_<channel>`` → ``out_<channel>``); one fault per channel."""
    type: str
    """Fault type (table below; ``stuck`` is accepted for ``stuck_value``)."""
    start_s: float = Field(ge=0.0, allow_inf_nan=False)
    """Onset, s."""
    end_s: float = math.inf
    """End, s (default: never; a ``step`` never ends)."""
    magnitude: float | None = Field(default=None, allow_inf_nan=False)
    """Bias, step or intermittent amplitude, ramp slope (signal units, per s for a ramp)."""
    gain: float | None = Field(default=None, allow_inf_nan=False)
    """Gain factor of a ``gain`` fault."""
    stuck_value: float | None = None
    """Value held by a ``stuck_value`` fault."""
    noise_std: float | None = Field(default=None, ge=0.0, allow_inf_nan=False)
    """Standard deviation of added (``noise``) or remaining (``signal_loss``) noise."""
    period: float | None = Field(default=None, gt=0.0, allow_inf_nan=False)
    """Period of an ``intermittent`` fault, s."""
    duty: float | None = Field(default=None, ge=0.0, le=1.0)
    """Fraction of each period an ``intermittent`` fault is on."""
    sat_min: float | None = None
    """Lower limit of a ``saturation`` fault."""
    sat_max: float | None = None
    """Upper limit of a ``saturation`` fault."""

    @field_validator("type")
    @classmethod
    def _known_type(cls, value: str) -> str:
        name = FAULT_TYPE_ALIASES.get(value.lower(), value.lower())
        if name not in FAULT_TYPE_CODES or name == "none":
            names = [n for n in FAULT_TYPE_CODES if n != "none"]
            raise ValueError(f"unknown fault type {value!r}{_suggest(value.lower(), names)}"
                             f" (known: {', '.join(names)})")
        return name

    @model_validator(mode="after")
    def _parameters_match_type(self) -> InjectorFault:
        needed = FAULT_TYPE_PARAMETERS[self.type]
        missing = [p for p in needed if getattr(self, p) is None]
        unused = [p for p in _CHANNEL_PARAMETERS
                  if p not in needed and getattr(self, p) is not None]
        if missing:
            raise ValueError(f"fault type {self.type!r} needs {', '.join(missing)}")
        if unused:
            raise ValueError(f"fault type {self.type!r} does not use {', '.join(unused)} "
                             f"(it uses: {', '.join(needed) or 'no parameters'})")
        if not self.end_s > self.start_s:
            raise ValueError(f"end_s ({self.end_s}) must be > start_s ({self.start_s})")
        if self.type == "step" and not math.isinf(self.end_s):
            raise ValueError("a 'step' fault latches and never ends: leave out end_s")
        if self.type == "saturation" and not self.sat_min <= self.sat_max:
            raise ValueError(f"sat_min ({self.sat_min}) must be <= sat_max ({self.sat_max})")
        return self

    @property
    def code(self) -> int:
        """FaultInjector ``fault_type`` code."""
        return FAULT_TYPE_CODES[self.type]

    @property
    def target(self) -> str:
        """The faulty signal, ``"injector.out_<channel>"``."""
        return f"{self.injector}.out_{self.channel}"

    def injector_parameters(self) -> dict[str, float | int]:
        """Channel parameters of the FaultInjector FMU that realise this fault."""
        c = self.channel
        params: dict[str, float | int] = {f"fault_type_{c}": self.code,
                                          f"t_start_{c}": float(self.start_s),
                                          f"t_end_{c}": float(self.end_s)}
        for key in FAULT_TYPE_PARAMETERS[self.type]:
            params[f"{key}_{c}"] = float(getattr(self, key))
        return params


class PhysicalFault(_Strict):
    """A tunable parameter set to ``value`` at ``start_s`` (restored at ``end_s``)."""

    name: str = Field(min_length=1)
    """Fault name, unique in the scenario."""
    set: str
    """Tunable parameter, ``"instance.variable"``."""
    value: ParameterValue
    """Value from ``start_s`` on."""
    start_s: float = Field(ge=0.0, allow_inf_nan=False)
    """Onset, s."""
    end_s: float = math.inf
    """When the original value is restored, s (default: never)."""

    @field_validator("set")
    @classmethod
    def _qualified(cls, value: str) -> str:
        return _check_qualified(value)

    @model_validator(mode="after")
    def _window(self) -> PhysicalFault:
        if not self.end_s > self.start_s:
            raise ValueError(f"end_s ({self.end_s}) must be > start_s ({self.start_s})")
        return self

    @property
    def target(self) -> str:
        return self.set


class Manoeuvre(_Strict):
    """``[[manoeuvres]]``: a pilot input or an off-trim start — not a fault.

    A command manoeuvre (``square_wave``, ``step``, ``doublet``, ``sine_sweep``) becomes
    start values of the command generator ``instance`` (a PitchController: its
    ``command_source`` and ``cmd_*`` parameters), which flies the shape from ``start_s``
    for ``duration_s`` (0 or left out: to the end of the run; required for a sweep) and
    commands trim outside that window.  ``off_trim`` sets the initial state of an
    Aircraft-like ``instance`` (``x0_theta``, ``x0_q``, ``x0_alpha``); its window is
    [0, ``duration_s``], the time given to return to trim.

    Manoeuvre windows are fault-free time for the expectations: an alarm inside one is a
    false alarm for ``no_alarm_outside_faults`` (and ``no_alarm_during_manoeuvres``).
    """

    name: str = Field(min_length=1)
    """Manoeuvre name, unique in the scenario."""
    kind: str
    """``square_wave``, ``step``, ``doublet``, ``sine_sweep`` or ``off_trim``."""
    instance: str = Field(min_length=1)
    """The PitchController (commands) or Aircraft (``off_trim``) instance."""
    start_s: float = Field(default=0.0, ge=0.0, allow_inf_nan=False)
    """Start, s."""
    duration_s: float | None = Field(default=None, ge=0.0, allow_inf_nan=False)
    """Length, s (commands: default to the end; ``off_trim``: time to return to trim)."""
    amplitude_rad: float | None = Field(default=None, allow_inf_nan=False)
    """Command amplitude, rad."""
    period_s: float | None = Field(default=None, gt=0.0, allow_inf_nan=False)
    """Square-wave period, s."""
    pulse_s: float | None = Field(default=None, gt=0.0, allow_inf_nan=False)
    """Doublet pulse length, s."""
    f0_hz: float | None = Field(default=None, gt=0.0, allow_inf_nan=False)
    """Sweep start frequency, Hz."""
    f1_hz: float | None = Field(default=None, gt=0.0, allow_inf_nan=False)
    """Sweep end frequency, Hz."""
    theta0_rad: float | None = Field(default=None, allow_inf_nan=False)
    """``off_trim``: initial pitch angle, rad."""
    q0_rad_s: float | None = Field(default=None, allow_inf_nan=False)
    """``off_trim``: initial pitch rate, rad/s."""
    alpha0_rad: float | None = Field(default=None, allow_inf_nan=False)
    """``off_trim``: initial angle of attack, rad."""

    @field_validator("kind")
    @classmethod
    def _known_kind(cls, value: str) -> str:
        if value not in MANOEUVRE_KINDS:
            raise ValueError(f"unknown manoeuvre kind {value!r}"
                             f"{_suggest(value, list(MANOEUVRE_KINDS))} "
                             f"(known: {', '.join(MANOEUVRE_KINDS)})")
        return value

    @model_validator(mode="after")
    def _fields_match_kind(self) -> Manoeuvre:
        need, may = MANOEUVRE_REQUIRED[self.kind], MANOEUVRE_OPTIONAL[self.kind]
        missing = [f for f in need if getattr(self, f) is None]
        unused = [f for f in _MANOEUVRE_FIELDS
                  if f not in need and f not in may and getattr(self, f) is not None]
        if missing:
            raise ValueError(f"manoeuvre kind {self.kind!r} needs {', '.join(missing)}")
        if unused:
            raise ValueError(f"manoeuvre kind {self.kind!r} does not use {', '.join(unused)} "
                             f"(it uses: {', '.join(need + may)})")
        if self.kind == "sine_sweep" and not self.duration_s:
            raise ValueError("a sine sweep needs duration_s > 0")
        if self.kind == "off_trim":
            if self.start_s != 0.0:
                raise ValueError("an off_trim start begins at t = 0: leave out start_s")
            if all(getattr(self, f) is None for f in _OFF_TRIM_PARAMETER):
                raise ValueError("off_trim needs at least one of theta0_rad, q0_rad_s, "
                                 "alpha0_rad")
            if not self.duration_s:
                raise ValueError("off_trim needs duration_s > 0 (the time to return to trim)")
        if (self.kind == "doublet" and self.period_s is not None
                and self.period_s < 2.0 * self.pulse_s):
            raise ValueError(f"period_s ({self.period_s}) must be >= 2 * pulse_s "
                             f"({2.0 * self.pulse_s}) for a repeated doublet")
        return self

    @property
    def end_s(self) -> float:
        """End of the manoeuvre window (``math.inf``: to the end of the run)."""
        return self.start_s + self.duration_s if self.duration_s else math.inf

    def instance_parameters(self) -> dict[str, float | int]:
        """Start values of ``instance`` that realise this manoeuvre."""
        if self.kind == "off_trim":
            return {_OFF_TRIM_PARAMETER[f]: float(getattr(self, f))
                    for f in _OFF_TRIM_PARAMETER if getattr(self, f) is not None}
        params: dict[str, float | int] = {"command_source": MANOEUVRE_COMMAND_CODES[self.kind],
                                          "cmd_start_s": float(self.start_s),
                                          "cmd_duration_s": float(self.duration_s or 0.0)}
        for f, pname in _COMMAND_PARAMETER.items():
            if f != "duration_s" and getattr(self, f) is not None:
                params[pname] = float(getattr(self, f))
        if self.kind == "doublet" and self.period_s is None:
            params["cmd_period"] = 0.0  # once
        return params


def _fault_tag(value: Any) -> str:
    if isinstance(value, dict):
        return "physical_fault" if "set" in value else "injector_fault"
    return "physical_fault" if isinstance(value, PhysicalFault) else "injector_fault"


Fault = Annotated[
    Annotated[InjectorFault, Tag("injector_fault")]
    | Annotated[PhysicalFault, Tag("physical_fault")],
    Discriminator(_fault_tag),
]
_TAGS = ("injector_fault", "physical_fault")


class Record(_Strict):
    """What to record: ``variables`` (default: every output of every FMU), every
    ``decimation`` base steps (the first and the last sample are always recorded)."""

    variables: list[str] | None = None
    """Signals to record, ``"instance.variable"`` (default: every non-String output of
    every FMU); what an expectation reads is always recorded too."""
    decimation: int = Field(default=1, ge=1)
    """Record every ``decimation`` base steps."""
    precision: Literal["compact", "float32", "float64"] = "compact"
    """How ``signals.npz`` stores a Real signal that no exact compact form fits:
    ``"compact"`` rounds the signals an expectation reads (in a training scenario:
    every signal, the learners read them) to float32 (relative error at most 2**-24,
    about 6e-8) and the others, kept for plots and inspection, to 13 significant bits
    (at most 2**-13, about 1.2e-4); ``"float32"`` rounds every one to
    float32; ``"float64"`` keeps every bit.  Time, Integer, Boolean, integer-valued,
    constant and float32-exact signals are stored exactly in any case; ``run.json``
    lists the rounded signals with their bounds.  Verdicts of ``verify`` and ``all`` are
    computed from the full-precision run before it is stored; ``report`` reads the
    stored values."""

    @field_validator("variables")
    @classmethod
    def _qualified(cls, value: list[str] | None) -> list[str] | None:
        if value is not None:
            for v in value:
                _check_qualified(v)
        return value


class Expectation(BaseModel):
    """One ``[[expect]]`` entry.  Its arguments belong to
    ``gyrodiag_harness.verification.expectations``, which validates them; here only the references
    (``signal``, ``fault``, ``manoeuvre``) are checked."""

    model_config = ConfigDict(extra="allow")

    kind: str = Field(min_length=1)
    """What is checked (see the kinds below)."""
    name: str | None = None
    """Label in reports."""
    signal: str | None = None
    """Recorded signal the check reads, ``"instance.variable"``."""
    fault: str | None = None
    """A fault of this scenario, by name."""
    manoeuvre: str | None = None
    """A manoeuvre of this scenario, by name."""

    def arguments(self) -> dict[str, Any]:
        """All keys of the entry except ``kind`` (extra keys included)."""
        return self.model_dump(exclude={"kind"}, exclude_none=True)


class Training(_Strict):
    """``[training]``: the run is a training example of one DTG fault class.

    Read by ``gyrodiag learn-signatures`` (:mod:`gyrodiag_harness.campaigns.signatures`),
    ignored by the other commands.  ``signature`` names the fault class, ``code`` is its fault code
    (1-based position in the learned library, i.e. the ``dtg.fault_code`` the Diagnoser
    reports for it), ``diagnoser`` the Diagnoser instance whose outputs are read.

    ``classifier = "paper"`` (default): decade signatures from ``dtg.eta_x``/``dtg.eta_y``.
    ``classifier = "pattern"``: response patterns
    (:mod:`gyrodiag_harness.campaigns.pattern_learning`);
    then ``type`` (step, drift, noise, loss, spin, torquer or nominal), ``signal`` (Utx,
    Uty, Ux, Uy; signal faults) and ``fault`` (the ``[[faults]]`` entry giving the size
    and the onset; default the only one) describe the example. A ``nominal`` run (code
    0) only feeds the noise model and the nominal prior.
    """

    signature: str = Field(pattern=r"^[A-Za-z_][A-Za-z0-9_]*$")
    """Fault class name (an identifier; ``nominal`` for a nominal pattern run)."""
    code: int = Field(ge=0)
    """Its fault code: position in the learned library (``dtg.fault_code``); 0 for a
    nominal pattern training run."""
    diagnoser: str = "diag"
    """Diagnoser instance whose outputs are read."""
    classifier: Literal["paper", "pattern"] = "paper"
    """Which classifier the run trains: decade signatures or response patterns."""
    type: Literal["step", "drift", "noise", "loss", "spin", "torquer", "nominal"] | None = None
    """Pattern training: the fault type of the example."""
    signal: Literal["Utx", "Uty", "Ux", "Uy"] | None = None
    """Pattern training: the faulty signal (signal faults)."""
    fault: str | None = None
    """Pattern training: the ``[[faults]]`` entry giving the size and the onset (default:
    the only one)."""

    @model_validator(mode="after")
    def _pattern_fields(self) -> Training:
        if (self.code == 0) != (self.type == "nominal"):
            raise ValueError("code must be >= 1 for a fault class, and 0 for a nominal "
                             "(type = 'nominal') pattern training run")
        if self.classifier == "paper":
            if self.type is not None or self.signal is not None or self.fault is not None:
                raise ValueError("type, signal and fault describe pattern training "
                                 "(classifier = 'pattern')")
            return self
        if self.type is None:
            raise ValueError("classifier 'pattern' needs type (step, drift, noise, loss, "
                             "spin, torquer or nominal)")
        if self.type in ("step", "drift", "noise", "loss") and self.signal is None:
            raise ValueError(f"type {self.type!r} needs signal (Utx, Uty, Ux or Uy)")
        if self.type in ("spin", "torquer", "nominal") and self.signal is not None:
            raise ValueError(f"type {self.type!r} takes no signal")
        return self


class Scenario(_Strict):
    """A validated scenario; see the module docstring and the harness contract."""

    name: str = Field(min_length=1)
    """Scenario name (default: the file name without ``.toml``); names the results
    folder, so it must be unique among the scenarios of a command."""
    description: str = ""
    """One line for people: shown in reports and as the pytest item's doc."""
    duration_s: float = Field(gt=0.0, allow_inf_nan=False)
    """Simulated time, s; a whole number of base steps."""
    step_s: float = Field(gt=0.0, allow_inf_nan=False)
    """Base communication step, s."""
    coupling: Literal["gauss-seidel", "jacobi"] = "gauss-seidel"
    """Gauss-Seidel (instances in coupling order, no latency except to break a cycle) or
    Jacobi (all from the outputs at t_k: one step of latency per FMU boundary)."""
    fmu_dir: str | None = None
    """Folder of the FMUs (default ``build/fmus``, looked for from the scenario's folder
    upwards; ``--fmu-dir`` and ``$GYRODIAG_FMU_DIR`` take precedence)."""
    fmus: dict[str, FmuInstance] = Field(min_length=1)
    """FMU instances by instance name (an identifier), in this order when a coupling
    cycle has to be broken."""
    connections: list[Connection] = Field(default_factory=list)
    """Output → input connections."""
    faults: list[Fault] = Field(default_factory=list)
    """Fault schedule: injector faults (``injector`` key) and physical faults (``set``
    key)."""
    manoeuvres: list[Manoeuvre] = Field(default_factory=list)
    """Manoeuvres flown during the run (``[[manoeuvres]]``): not faults; an alarm during one
    is a false alarm."""
    record: Record = Field(default_factory=Record)
    """What to record."""
    expect: list[Expectation] = Field(default_factory=list)
    """What must hold in the run (``[[expect]]`` tables, kinds below)."""
    training: Training | None = None
    """Marks a DTG signature training run (``learn-signatures``)."""

    _source: str = PrivateAttr(default="<scenario>")
    _path: Path | None = PrivateAttr(default=None)

    @property
    def source(self) -> str:
        """File name (or a label) used in error messages."""
        return self._source

    @property
    def path(self) -> Path | None:
        """The TOML file, if the scenario was loaded from one."""
        return self._path

    @property
    def n_steps(self) -> int:
        """Number of base steps (``duration_s / step_s``, an integer by validation)."""
        return round(self.duration_s / self.step_s)

    @property
    def injector_faults(self) -> list[InjectorFault]:
        return [f for f in self.faults if isinstance(f, InjectorFault)]

    @property
    def physical_faults(self) -> list[PhysicalFault]:
        return [f for f in self.faults if isinstance(f, PhysicalFault)]


# --------------------------------------------------------------------------- loading
def load_scenario(path: Path | str) -> Scenario:
    """Read and validate a scenario TOML file.

    Parameters
    ----------
    path : path
        The ``.toml`` file; ``name`` defaults to its stem.

    Raises
    ------
    ScenarioError
        Syntax, structure, value or cross-reference problems, each naming the file and
        the key path.
    FileNotFoundError
        If the file does not exist.
    """
    path = Path(path)
    source = _display_path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{source}: scenario file not found")
    try:
        with open(path, "rb") as fh:
            data = tomllib.load(fh)
    except tomllib.TOMLDecodeError as exc:
        raise ScenarioError(source, [("", f"invalid TOML: {exc}")]) from None
    return parse_scenario(data, source=source, default_name=path.stem, path=path)


def parse_scenario(data: Mapping[str, Any], source: str = "<scenario>",
                   default_name: str | None = None, path: Path | None = None) -> Scenario:
    """Validate a scenario given as a dict (the parsed TOML); see :func:`load_scenario`."""
    data = dict(data)
    if "name" not in data and default_name is not None:
        data["name"] = default_name
    try:
        scenario = Scenario.model_validate(data)
    except ValidationError as exc:
        raise ScenarioError(source, _pydantic_problems(exc)) from None
    scenario._source = source
    scenario._path = Path(path).resolve() if path is not None else None
    problems = _cross_reference_problems(scenario)
    if problems:
        raise ScenarioError(source, problems)
    return scenario


def _display_path(path: Path) -> str:
    try:
        rel = os.path.relpath(path)
    except ValueError:  # other drive on Windows
        return str(path)
    return str(path.resolve()) if rel.startswith("..") else rel


def key_path(loc: tuple[int | str, ...]) -> str:
    """Pydantic ``loc`` → ``fmus.aircraft.step_ratio`` / ``connections[2].from``."""
    out = ""
    previous: int | str | None = None
    for i, part in enumerate(loc):
        if isinstance(part, int):
            out += f"[{part}]"
        elif part in _TAGS and isinstance(previous, int) and i >= 2 and loc[i - 2] == "faults":
            pass  # discriminator tag, not a key of the file
        else:
            out += ("." if out else "") + str(part)
        previous = part
    return out


def _pydantic_problems(exc: ValidationError) -> list[tuple[str, str]]:
    problems = []
    for err in exc.errors():
        msg = err["msg"]
        if err["type"] == "extra_forbidden":
            msg = "unknown key (not allowed here)"
        elif msg.startswith("Value error, "):
            msg = msg[len("Value error, "):]
        problems.append((key_path(tuple(err["loc"])), msg))
    return problems


def _check_qualified(value: str) -> str:
    instance, dot, variable = value.partition(".")
    if not dot or not instance or not variable:
        raise ValueError(f"{value!r} must be 'instance.variable'")
    return value


def split_name(qualified: str) -> tuple[str, str]:
    """``"diag.df.detected"`` → ``("diag", "df.detected")`` (instances hold no dots)."""
    instance, _, variable = qualified.partition(".")
    return instance, variable


def _suggest(name: str, candidates: list[str], n: int = 3) -> str:
    close = difflib.get_close_matches(name, candidates, n=n, cutoff=0.5)
    if close:
        return f"; did you mean {', '.join(repr(c) for c in close)}?"
    if 0 < len(candidates) <= 10:
        return f" (known: {', '.join(repr(c) for c in candidates)})"
    return ""


def _cross_reference_problems(s: Scenario) -> list[tuple[str, str]]:
    """Every reference between parts of the scenario that does not resolve (instances,
    faults, manoeuvres), duplicate names and inconsistent steps, in file order."""
    problems = _instance_problems(s) + _connection_problems(s)
    fault_problems, fault_names = _fault_problems(s)
    manoeuvre_problems, manoeuvre_names = _manoeuvre_problems(s, fault_names)
    problems += fault_problems + manoeuvre_problems
    for i, v in enumerate(s.record.variables or []):
        problems += _unknown_instance(s, f"record.variables[{i}]", v)
    return problems + _expect_problems(s, fault_names, manoeuvre_names)


def _unknown_instance(s: Scenario, key: str, qualified: str) -> list[tuple[str, str]]:
    """The problem of a qualified name whose instance the scenario does not declare."""
    inst, _ = split_name(qualified)
    if inst in s.fmus:
        return []
    instances = list(s.fmus)
    return [(key, f"unknown instance {inst!r} in {qualified!r}{_suggest(inst, instances)} "
                  f"(instances: {', '.join(instances)})")]


def _instance_problems(s: Scenario) -> list[tuple[str, str]]:
    """Instances: files also set as parameters, the training diagnoser, names, steps."""
    problems: list[tuple[str, str]] = []
    instances = list(s.fmus)
    for name, inst in s.fmus.items():
        for pname in inst.files:
            if pname in inst.parameters:
                problems.append((f"fmus.{name}.files.{pname}",
                                 "also set in parameters: set it in one place only"))
    if s.training is not None and s.training.diagnoser not in s.fmus:
        problems.append(("training.diagnoser", f"unknown instance {s.training.diagnoser!r}"
                                               f"{_suggest(s.training.diagnoser, instances)}"))
    for name in instances:
        if not _INSTANCE_RE.match(name):
            problems.append((f"fmus.{name}", "instance names must be identifiers "
                                             "(letters, digits, '_'; no dots)"))
    n = s.n_steps
    if abs(n * s.step_s - s.duration_s) > 1e-9 * max(1.0, s.duration_s) or n < 1:
        problems.append(("duration_s", f"must be a whole number of steps step_s = {s.step_s} "
                                       f"(got {s.duration_s})"))
    else:
        for name, inst in s.fmus.items():
            if n % inst.step_ratio:
                problems.append((f"fmus.{name}.step_ratio",
                                 f"the run has {n} base steps, not a multiple of step_ratio "
                                 f"{inst.step_ratio}: the instance's last step would overshoot"))
    return problems


def _connection_problems(s: Scenario) -> list[tuple[str, str]]:
    """Connections: unknown instances, an input connected twice."""
    problems: list[tuple[str, str]] = []
    for i, c in enumerate(s.connections):
        problems += _unknown_instance(s, f"connections[{i}].from", c.from_)
        problems += _unknown_instance(s, f"connections[{i}].to", c.to)
    seen: dict[str, int] = {}
    for i, c in enumerate(s.connections):
        if c.to in seen:
            problems.append((f"connections[{i}].to", f"input {c.to!r} is already connected "
                                                     f"by connections[{seen[c.to]}]"))
        seen.setdefault(c.to, i)
    return problems


def _fault_problems(s: Scenario) -> tuple[list[tuple[str, str]], dict[str, int]]:
    """Faults: duplicate names, unknown instances, one fault per injector channel, a start
    after the run; and the index of every fault name."""
    problems: list[tuple[str, str]] = []
    fault_names: dict[str, int] = {}
    channels: dict[tuple[str, int], int] = {}
    for i, f in enumerate(s.faults):
        if f.name in fault_names:
            problems.append((f"faults[{i}].name", f"duplicate fault name {f.name!r} "
                                                  f"(also faults[{fault_names[f.name]}])"))
        fault_names.setdefault(f.name, i)
        if isinstance(f, InjectorFault):
            if f.injector not in s.fmus:
                problems.append((f"faults[{i}].injector", f"unknown instance {f.injector!r}"
                                                          f"{_suggest(f.injector, list(s.fmus))}"))
            key = (f.injector, f.channel)
            if key in channels:
                problems.append((f"faults[{i}].channel",
                                 f"channel {f.channel} of {f.injector!r} already carries "
                                 f"faults[{channels[key]}]: one fault per channel"))
            channels.setdefault(key, i)
        else:
            problems += _unknown_instance(s, f"faults[{i}].set", f.set)
        if f.start_s > s.duration_s:
            problems.append((f"faults[{i}].start_s", f"{f.start_s} s is after the end of the "
                                                     f"run ({s.duration_s} s)"))
    return problems, fault_names


def _manoeuvre_problems(s: Scenario, fault_names: Mapping[str, int]
                        ) -> tuple[list[tuple[str, str]], dict[str, int]]:
    """Manoeuvres: names shared with faults or manoeuvres, unknown instances, one command
    manoeuvre per generator, a start after the run, parameters also set by the instance;
    and the index of every manoeuvre name."""
    problems: list[tuple[str, str]] = []
    manoeuvre_names: dict[str, int] = {}
    commanded: dict[str, int] = {}
    for i, m in enumerate(s.manoeuvres):
        if m.name in manoeuvre_names or m.name in fault_names:
            other = (f"manoeuvres[{manoeuvre_names[m.name]}]" if m.name in manoeuvre_names
                     else f"faults[{fault_names[m.name]}]")
            problems.append((f"manoeuvres[{i}].name", f"duplicate name {m.name!r} (also "
                                                      f"{other})"))
        manoeuvre_names.setdefault(m.name, i)
        if m.instance not in s.fmus:
            problems.append((f"manoeuvres[{i}].instance", f"unknown instance {m.instance!r}"
                                                          f"{_suggest(m.instance, list(s.fmus))}"))
            continue
        if m.kind != "off_trim":
            if m.instance in commanded:
                problems.append((f"manoeuvres[{i}].instance",
                                 f"{m.instance!r} already flies "
                                 f"manoeuvres[{commanded[m.instance]}]: one command "
                                 "manoeuvre per command generator"))
            commanded.setdefault(m.instance, i)
        if m.start_s > s.duration_s:
            problems.append((f"manoeuvres[{i}].start_s", f"{m.start_s} s is after the end of "
                                                         f"the run ({s.duration_s} s)"))
        own = s.fmus[m.instance].parameters
        clash = [p for p in m.instance_parameters() if p in own]
        if clash:
            problems.append((f"fmus.{m.instance}.parameters.{clash[0]}",
                             f"also set by manoeuvre {m.name!r} (manoeuvres[{i}]): set it in "
                             "one place only"))
    return problems, manoeuvre_names


def _expect_problems(s: Scenario, fault_names: Mapping[str, int],
                     manoeuvre_names: Mapping[str, int]) -> list[tuple[str, str]]:
    """Expectations: their own schema, the signals they read, the fault or manoeuvre they
    name."""
    problems: list[tuple[str, str]] = []
    expectations = _expectations_module()
    for i, e in enumerate(s.expect):
        if expectations is not None:
            try:
                expectations.parse_expectation(e)
            except ValidationError as exc:
                problems += _expectation_problems(i, e.kind, exc)
                continue
        for signal in expected_signals(e):
            key = f"expect[{i}].signal" if signal == e.signal else f"expect[{i}].args"
            if "." in signal:
                problems += _unknown_instance(s, key, signal)
            else:
                problems.append((key, f"{signal!r} must be 'instance.variable'"))
        if e.fault is not None and e.fault not in fault_names:
            problems.append((f"expect[{i}].fault", f"unknown fault {e.fault!r}"
                                                   f"{_suggest(e.fault, list(fault_names))}"))
        if e.manoeuvre is not None and e.manoeuvre not in manoeuvre_names:
            problems.append((f"expect[{i}].manoeuvre",
                             f"unknown manoeuvre {e.manoeuvre!r}"
                             f"{_suggest(e.manoeuvre, list(manoeuvre_names))}"))
    return problems


def _expectations_module() -> Any:
    # gyrodiag_harness.verification.expectations owns the [[expect]] schema (a layer below)
    return expectations


def expected_signals(e: Expectation) -> list[str]:
    """Signals an ``[[expect]]`` entry reads (``signal`` and signal arguments of metrics,
    as reported by ``gyrodiag_harness.verification.expectations.referenced_signals``)."""
    expectations = _expectations_module()
    if expectations is not None:
        try:
            return list(expectations.referenced_signals(e))
        except (ValidationError, KeyError, ValueError):
            pass
    return [e.signal] if e.signal is not None else []


def _expectation_problems(i: int, kind: str, exc: ValidationError) -> list[tuple[str, str]]:
    problems = []
    for err in exc.errors():
        loc = tuple(err["loc"])
        if loc and loc[0] == kind:
            loc = loc[1:]  # discriminator tag, not a key of the file
        key = f"expect[{i}]" + ("." + key_path(loc) if loc else "")
        if err["type"] == "union_tag_invalid":
            key = f"expect[{i}].kind"
        msg = err["msg"]
        if err["type"] == "extra_forbidden":
            msg = f"unknown key for kind {kind!r}"
        elif msg.startswith("Value error, "):
            msg = msg[len("Value error, "):]
        problems.append((key, msg))
    return problems


# --------------------------------------------------------------------------- FMU files
def resolve_fmu_dir(scenario: Scenario, fmu_dir: Path | str | None = None) -> Path:
    """Directory of the FMUs: ``fmu_dir`` argument, else ``$GYRODIAG_FMU_DIR``, else the
    scenario's ``fmu_dir``, else ``build/fmus``.  A relative scenario/default path is
    looked up from the scenario file's folder upwards (so ``build/fmus`` in
    ``scenarios/x.toml`` finds the repository's), then in the working directory."""
    if fmu_dir is not None:
        return Path(fmu_dir).resolve()
    env = os.environ.get(FMU_DIR_ENV)
    if env:
        return Path(env).resolve()
    return _find_upwards(scenario, scenario.fmu_dir or DEFAULT_FMU_DIR, want_dir=True)


def resolve_fmu_file(scenario: Scenario, instance: str, fmu_dir: Path) -> Path:
    """The ``.fmu`` file of ``instance`` (a name in ``fmu_dir`` or a path ending .fmu)."""
    spec = scenario.fmus[instance].fmu
    if spec.endswith(".fmu"):
        return _find_upwards(scenario, spec, want_dir=False)
    return fmu_dir / f"{spec}.fmu"


def _find_upwards(scenario: Scenario, spec: str, want_dir: bool) -> Path:
    p = Path(spec)
    if p.is_absolute():
        return p
    bases: list[Path] = []
    if scenario.path is not None:
        bases += [scenario.path.parent, *scenario.path.parent.parents]
    bases.append(Path.cwd())
    for base in bases:
        candidate = base / p
        if (candidate.is_dir() if want_dir else candidate.is_file()):
            return candidate.resolve()
    return (bases[0] / p).resolve()


# --------------------------------------------------------------------------- file parameters
#: Prefix of a ``files`` path taken in the results folder of the command (``--out``).
RESULTS_PREFIX = "${out}/"


def _check_file_spec(name: str, spec: str) -> None:
    if not spec.strip():
        raise ValueError(f"{name}: the path must not be empty")
    rest = spec[len(RESULTS_PREFIX):] if spec.startswith(RESULTS_PREFIX) else spec
    if "${" in rest:
        raise ValueError(f"{name}: {spec!r}: the only placeholder is a leading "
                         f"{RESULTS_PREFIX!r} (the results folder)")
    if spec.startswith(RESULTS_PREFIX) and (not rest or Path(rest).is_absolute()):
        raise ValueError(f"{name}: {spec!r}: {RESULTS_PREFIX!r} must be followed by a "
                         "relative path")


def resolve_file_parameters(scenario: Scenario, results_dir: Path | str | None = None,
                            must_exist: bool = True) -> dict[str, dict[str, str]]:
    """Absolute paths of every instance's ``files`` parameters.

    Parameters
    ----------
    scenario : Scenario
        The scenario.
    results_dir : path, optional
        Results folder of the command (what ``${out}/`` stands for; a file not found
        there is looked for in its parent folder).  Required if a path uses it.
    must_exist : bool
        Check that every file exists.

    Returns
    -------
    dict
        Instance → {parameter name → absolute path}.

    Raises
    ------
    ScenarioError
        Naming ``fmus.<instance>.files.<parameter>``: ``${out}/`` without a results
        folder, or a missing file.
    """
    resolved: dict[str, dict[str, str]] = {}
    problems: list[tuple[str, str]] = []
    base = scenario.path.parent if scenario.path is not None else Path.cwd()
    for name, inst in scenario.fmus.items():
        for pname, spec in inst.files.items():
            key = f"fmus.{name}.files.{pname}"
            if spec.startswith(RESULTS_PREFIX):
                if results_dir is None:
                    problems.append((key, f"{spec!r} names the results folder, but none was "
                                          "given (pass results_dir / --out)"))
                    continue
                rest = spec[len(RESULTS_PREFIX):]
                path = Path(results_dir) / rest
                above = Path(results_dir).parent / rest
                if must_exist and not path.is_file():
                    if not above.is_file():
                        problems.append((key, f"{rest} not found in {path.parent.resolve()} "
                                              f"nor in {above.parent.resolve()} (produce it "
                                              "first, e.g. with 'python -m gyrodiag_harness "
                                              f"learn-signatures ... --out {above}')"))
                        continue
                    path = above
            else:
                path = Path(spec) if Path(spec).is_absolute() else base / spec
            path = path.resolve()
            if must_exist and not path.is_file():
                problems.append((key, f"file {path} not found (produce it first, e.g. with "
                                      "'python -m gyrodiag_harness learn-signatures ... --out "
                                      f"{path}')"))
                continue
            resolved.setdefault(name, {})[pname] = str(path)
    if problems:
        raise ScenarioError(scenario.source, problems)
    return resolved


# --------------------------------------------------------------------------- FMU names
@dataclass(frozen=True)
class VariableInfo:
    """What the harness needs to know about one FMU variable."""

    name: str
    type: str          # "Real", "Integer", "Boolean", "String", "Enumeration"
    causality: str     # "parameter", "calculatedParameter", "input", "output", "local", ...
    variability: str   # "constant", "fixed", "tunable", "discrete", "continuous"
    value_reference: int


@dataclass(frozen=True)
class ModelInfo:
    """Variables of one FMU (from its modelDescription)."""

    fmu_name: str
    variables: Mapping[str, VariableInfo]


_NUMERIC = ("Real", "Integer", "Boolean", "Enumeration")


def check_against_models(scenario: Scenario, models: Mapping[str, ModelInfo]) -> None:
    """Check every variable name of ``scenario`` against the instances' FMUs.

    Parameters
    ----------
    scenario : Scenario
        A scenario whose instance references were already checked.
    models : mapping of str to ModelInfo
        Instance name → the variables of its FMU.

    Raises
    ------
    ScenarioError
        Listing every unknown name (with the closest existing names), wrong causality
        (e.g. a connection into an output) and type mismatch.
    """
    lookup = _Lookup(models)
    _parameter_model_problems(scenario, lookup)
    _connection_model_problems(scenario, lookup)
    _fault_model_problems(scenario, lookup)
    _manoeuvre_model_problems(scenario, lookup)
    _signal_model_problems(scenario, lookup)
    if lookup.problems:
        raise ScenarioError(scenario.source, lookup.problems)


class _Lookup:
    """Qualified names looked up in the models; what does not fit lands in ``problems``."""

    def __init__(self, models: Mapping[str, ModelInfo]) -> None:
        self.models = models
        self.problems: list[tuple[str, str]] = []

    def __call__(self, key: str, qualified: str, causalities: tuple[str, ...] | None,
                 role: str) -> VariableInfo | None:
        """The variable, or None after noting an unknown name or a wrong causality."""
        inst, var = split_name(qualified)
        model = self.models[inst]
        info = model.variables.get(var)
        if info is None:
            pool = [v.name for v in model.variables.values()
                    if causalities is None or v.causality in causalities]
            self.problems.append((key, f"instance {inst!r} (FMU {model.fmu_name}) has no "
                                       f"variable {var!r}{_suggest(var, pool)}"))
            return None
        if causalities is not None and info.causality not in causalities:
            article = "an" if info.causality[0] in "aeiou" else "a"
            self.problems.append((key, f"{qualified!r} is {article} {info.causality}, {role} "
                                       f"must be {' or '.join(causalities)}"))
            return None
        return info


def _parameter_model_problems(scenario: Scenario, lookup: _Lookup) -> None:
    """Instance parameters (names, causality, value types) and ``files`` (String)."""
    for name, inst in scenario.fmus.items():
        for pname, value in inst.parameters.items():
            key = f"fmus.{name}.parameters.{pname}"
            info = lookup(key, f"{name}.{pname}", ("parameter", "input"), "a parameter")
            if info is not None:
                msg = _value_type_problem(info, value)
                if msg:
                    lookup.problems.append((key, msg))
        for pname in inst.files:
            key = f"fmus.{name}.files.{pname}"
            info = lookup(key, f"{name}.{pname}", ("parameter",), "a file parameter")
            if info is not None and info.type != "String":
                lookup.problems.append((key, f"{pname} is {info.type}: only String parameters "
                                             "can name a file"))


def _connection_model_problems(scenario: Scenario, lookup: _Lookup) -> None:
    """Connections: an output or local into an input, of compatible types."""
    for i, c in enumerate(scenario.connections):
        src = lookup(f"connections[{i}].from", c.from_, ("output", "local"), "a source")
        dst = lookup(f"connections[{i}].to", c.to, ("input",), "a destination")
        if src is not None and dst is not None:
            ok = (src.type in _NUMERIC and dst.type == "Real") or src.type == dst.type or (
                src.type == "Boolean" and dst.type == "Integer")
            if not ok:
                lookup.problems.append((f"connections[{i}]", f"cannot connect {src.type} "
                                                             f"{c.from_!r} to {dst.type} "
                                                             f"{c.to!r}"))


def _fault_model_problems(scenario: Scenario, lookup: _Lookup) -> None:
    """Injector faults: the injector has the channel's parameters, not also set by the
    instance; physical faults: a tunable parameter of the value's type."""
    for i, f in enumerate(scenario.faults):
        if isinstance(f, InjectorFault):
            model = lookup.models[f.injector]
            missing = [p for p in f.injector_parameters() if p not in model.variables]
            if missing:
                lookup.problems.append((f"faults[{i}]", f"instance {f.injector!r} (FMU "
                                                        f"{model.fmu_name}) has no parameter "
                                                        f"{missing[0]!r}: not a FaultInjector, "
                                                        f"or it has fewer than {f.channel} "
                                                        "channels"))
            own = scenario.fmus[f.injector].parameters
            clash = [p for p in f.injector_parameters() if p in own]
            if clash:
                lookup.problems.append((f"fmus.{f.injector}.parameters.{clash[0]}",
                                        f"also set by fault {f.name!r} (faults[{i}]): set it "
                                        "in one place only"))
            continue
        info = lookup(f"faults[{i}].set", f.set, ("parameter",), "a physical fault target")
        if info is not None:
            if info.variability != "tunable":
                lookup.problems.append((f"faults[{i}].set", f"{f.set!r} is "
                                                            f"{info.variability}, not tunable: "
                                                            "it cannot change during the run"))
            msg = _value_type_problem(info, f.value)
            if msg:
                lookup.problems.append((f"faults[{i}].value", msg))


def _manoeuvre_model_problems(scenario: Scenario, lookup: _Lookup) -> None:
    """Manoeuvres: the instance has the parameters its kind sets."""
    for i, m in enumerate(scenario.manoeuvres):
        model = lookup.models[m.instance]
        missing = [p for p in m.instance_parameters() if p not in model.variables]
        if missing:
            what = "an Aircraft" if m.kind == "off_trim" else "a PitchController"
            lookup.problems.append((f"manoeuvres[{i}].instance",
                                    f"instance {m.instance!r} (FMU {model.fmu_name}) has no "
                                    f"parameter {missing[0]!r}: not {what}"))


def _signal_model_problems(scenario: Scenario, lookup: _Lookup) -> None:
    """Recorded signals (numbers only) and the signals the expectations read."""
    for i, v in enumerate(scenario.record.variables or []):
        info = lookup(f"record.variables[{i}]", v, None, "")
        if info is not None and info.type not in _NUMERIC:
            lookup.problems.append((f"record.variables[{i}]", f"{v!r} is a {info.type}: only "
                                                              "numbers can be recorded"))
    for i, e in enumerate(scenario.expect):
        for signal in expected_signals(e):
            if "." in signal:
                key = f"expect[{i}].signal" if signal == e.signal else f"expect[{i}].args"
                lookup(key, signal, None, "")


def _value_type_problem(info: VariableInfo, value: ParameterValue) -> str | None:
    t = info.type
    if t == "Real" and (isinstance(value, bool) or not isinstance(value, (int, float))):
        return f"{info.name} is Real, got {value!r}"
    if t in ("Integer", "Enumeration") and (isinstance(value, bool)
                                             or not isinstance(value, int)):
        return f"{info.name} is {t}, got {value!r} (write an integer)"
    if t == "Boolean" and not isinstance(value, bool):
        return f"{info.name} is Boolean, got {value!r} (write true or false)"
    if t == "String" and not isinstance(value, str):
        return f"{info.name} is String, got {value!r} (write a quoted string)"
    return None
