"""The scenario format's reference, generated from the pydantic models that validate it.

* :func:`scenario_schema` — JSON Schema of a scenario file (``[[expect]]`` entries with
  every kind), for editors: ``python -m gyrodiag_harness schema > scenario.schema.json``.
* :func:`campaign_schema` — the same for campaign specs.
* :func:`markdown` — ``docs/scenarios.md`` (``python -m gyrodiag_harness schema --markdown``); a
  test fails when the committed file differs from what the models say.
"""

from __future__ import annotations

import json
import math
import re
from typing import Any

from pydantic import BaseModel, TypeAdapter

from gyrodiag_harness.campaigns.campaign import CampaignSpec
from gyrodiag_harness.cosim import scenario as sc
from gyrodiag_harness.verification import expectations as ex
from gyrodiag_harness.verification import metrics

__all__ = ["campaign_schema", "markdown", "scenario_schema"]

REGENERATE = "python -m gyrodiag_harness schema --markdown > docs/scenarios.md"
_ROLE = re.compile(r":\w+:`~?([^`]+)`")


def _finite(obj: Any) -> Any:
    # JSON has no infinity: an open end is "no default" (the description says "never")
    if isinstance(obj, dict):
        return {k: _finite(v) for k, v in obj.items()
                if not (k == "default" and isinstance(v, float) and math.isinf(v))}
    if isinstance(obj, list):
        return [_finite(v) for v in obj]
    return obj


def scenario_schema() -> dict[str, Any]:
    """JSON Schema (draft 2020-12) of a scenario file."""
    schema = sc.Scenario.model_json_schema(by_alias=True)
    expect = TypeAdapter(ex.Expectation).json_schema(ref_template="#/$defs/{model}")
    defs = schema.setdefault("$defs", {})
    defs.update(expect.pop("$defs", {}))
    defs.pop("Expectation", None)
    schema["properties"]["expect"]["items"] = expect
    schema["title"] = "gyrodiag scenario"
    schema["$schema"] = "https://json-schema.org/draft/2020-12/schema"
    return _finite(schema)


def campaign_schema() -> dict[str, Any]:
    """JSON Schema (draft 2020-12) of a campaign spec."""
    schema = CampaignSpec.model_json_schema(by_alias=True)
    schema["title"] = "gyrodiag campaign"
    schema["$schema"] = "https://json-schema.org/draft/2020-12/schema"
    return _finite(schema)


# ------------------------------------------------------------------------------ Markdown
def _type(prop: dict[str, Any]) -> str:
    if "const" in prop:
        return f'`"{prop["const"]}"`'
    if "enum" in prop:
        return " or ".join(f'`"{v}"`' for v in prop["enum"])
    if "anyOf" in prop:
        kinds = [_type(p) for p in prop["anyOf"] if p.get("type") != "null"]
        return " or ".join(dict.fromkeys(kinds))
    if "$ref" in prop:
        return "table"
    kind = prop.get("type", "any")
    if kind == "array":
        return f"list of {_type(prop.get('items', {}))}"
    if kind == "object":
        extra = prop.get("additionalProperties")
        return f"table of {_type(extra)}" if isinstance(extra, dict) else "table"
    return {"number": "float", "integer": "int", "boolean": "bool", "string": "str"}.get(
        kind, kind)


def _constraints(prop: dict[str, Any]) -> str:
    parts = []
    for p in [prop, *prop.get("anyOf", [])]:
        for key, text in (("minimum", "≥ {}"), ("exclusiveMinimum", "> {}"),
                          ("maximum", "≤ {}"), ("exclusiveMaximum", "< {}"),
                          ("minLength", "length ≥ {}"), ("minProperties", "≥ {} entries"),
                          ("pattern", "matches `{}`")):
            if key in p:
                parts.append(text.format(p[key]))
    return ", ".join(dict.fromkeys(parts))


def _default(name: str, prop: dict[str, Any], required: bool) -> str:
    if required:
        return "**required**"
    if "default" not in prop:
        return "—"
    value = prop["default"]
    if value is None:
        return "—"
    return f"`{json.dumps(value)}`"


def _cell(text: str) -> str:
    text = _ROLE.sub(r"`\1`", " ".join(text.split()))
    return text.replace("``", "`").replace("|", "\\|")


def _keys_table(model: type[BaseModel], skip: tuple[str, ...] = (),
                defaults: dict[str, str] | None = None) -> list[str]:
    schema = _finite(model.model_json_schema(by_alias=True))
    defaults = defaults or {}
    required = set(schema.get("required", []))
    rows = ["| key | type | default | constraints | meaning |", "| --- | --- | --- | --- | --- |"]
    for name, prop in schema["properties"].items():
        if name in skip:
            continue
        default = defaults.get(name) or _default(name, prop, name in required)
        rows.append(f"| `{name}` | {_type(prop)} | {default} | "
                    f"{_cell(_constraints(prop))} | {_cell(prop.get('description', ''))} |")
    return rows


def _doc(model: type[BaseModel]) -> str:
    return _cell(model.__doc__ or "")


_EXAMPLE = '''\
name = "pitch_q_bias"                         # default: the file name
description = "closed loop, q-sensor bias of 0.1 rad/s from 1 s"
duration_s = 2.0
step_s = 0.01

[fmus.aircraft]
fmu = "Aircraft"                              # <fmu folder>/Aircraft.fmu
parameters = { noise_std_q = 1e-3, seed = 3 }

[fmus.injector]
fmu = "FaultInjector"

[fmus.controller]
fmu = "PitchController"
parameters = { command_source = 1, cmd_amplitude = 0.1, cmd_period = 1.0 }

[[connections]]
from = "aircraft.y_q"
to = "injector.in_3"

[[connections]]
from = "injector.out_3"
to = "controller.q_meas"

[[connections]]
from = "aircraft.y_alpha"
to = "controller.alpha_meas"

[[connections]]
from = "aircraft.y_theta"
to = "controller.theta_meas"

[[connections]]
from = "controller.elevator"
to = "aircraft.elevator"

[[faults]]
name = "q_bias"
injector = "injector"
channel = 3
type = "bias"
start_s = 1.0
magnitude = 0.1

[record]
variables = ["aircraft.y_q", "injector.out_3", "controller.elevator"]

[[expect]]
kind = "value_at"
signal = "injector.fault_active_3"
t_s = 1.5
equals = 1

[[expect]]
kind = "metric"
metric = "absolute_errors"
args = { measured = "injector.out_3", predicted = "aircraft.y_q", t0_s = 1.1 }
field = "mean"
min = 0.099
max = 0.101
'''


def markdown() -> str:
    """The scenario reference as Markdown (``docs/scenarios.md``)."""
    out: list[str] = [
        "# Scenario files",
        "",
        f"<!-- Generated from the pydantic models by `{REGENERATE}`; do not edit by hand "
        "(tests/test_harness_reference.py fails when this file is stale). -->",
        "",
        "A scenario is a TOML file: the FMU instances and their parameters, the connections, "
        "the step, the fault schedule, what to record and what to expect. Unknown keys are "
        "errors; every error names the file and the key path, e.g. "
        "`scenarios/x.toml: fmus.aircraft.step_ratio: Input should be greater than or equal "
        "to 1` (list entries by 0-based index: `connections[2].from`). Variable names are "
        "checked against the FMUs' modelDescriptions before a run starts, with the closest "
        "names as suggestions. Signals are named `instance.variable`.",
        "",
        "Editors: `gyrodiag schema > scenario.schema.json` writes the JSON Schema "
        "(with the TOML extension of VS Code, *Even Better TOML*, put "
        "`#:schema ./scenario.schema.json` on the first line of a scenario).",
        "",
        "```toml",
        _EXAMPLE.rstrip("\n"),
        "```",
        "",
        "## Top level",
        "",
    ]
    out += _keys_table(sc.Scenario, defaults={"name": "the file name"})
    sections: list[tuple[str, type[BaseModel], str]] = [
        ("[fmus.NAME]", sc.FmuInstance, ""),
        ("[[connections]]", sc.Connection, ""),
        ("[[faults]]: injector faults", sc.InjectorFault,
         "A fault table with an `injector` key sets the FaultInjector channel's parameters "
         "(the injected signal is `INJECTOR.out_CHANNEL`)."),
        ("[[faults]]: physical faults", sc.PhysicalFault,
         "A fault table with a `set` key changes a tunable parameter of any FMU (e.g. "
         "`dtg.spin_fraction`)."),
        ("[[manoeuvres]]", sc.Manoeuvre, ""),
        ("[record]", sc.Record, ""),
        ("[training]", sc.Training, ""),
    ]
    for title, model, intro in sections:
        out += ["", f"## {title}", "", _doc(model)]
        if intro:
            out += ["", intro]
        out += ["", *_keys_table(model)]
        if model is sc.InjectorFault:
            out += ["", "Fault types, their FaultInjector code and the keys each needs "
                        "(and allows):", "", "| type | code | keys |", "| --- | --- | --- |"]
            for name, keys in sc.FAULT_TYPE_PARAMETERS.items():
                if name == "none":
                    continue
                shown = ", ".join(f"`{k}`" for k in keys) or "—"
                out.append(f"| `{name}` | {sc.FAULT_TYPE_CODES[name]} | {shown} |")
    out += ["", "## [[expect]]", "",
            "Each `[[expect]]` table is one check on the run, chosen by its `kind`. Every "
            "kind takes an optional `name` (label in reports). A failing check says what "
            "was expected, what was measured and where; when the run did not complete, its "
            "checks are not evaluated and the run's error is reported once."]
    for model in ex._MODELS:
        kind = model.model_json_schema()["properties"]["kind"]["const"]
        out += ["", f"### `kind = \"{kind}\"`", "", _doc(model), ""]
        out += _keys_table(model, skip=("kind", "name"))
    out += ["", "## Metrics (`kind = \"metric\"`)", "",
            "`metric` names one of these; `args` holds its arguments; `field` picks one "
            "value of a metric that returns several; `min`/`max` bound the value."]
    for spec in metrics.METRICS.values():
        fields = f" Fields: {', '.join(f'`{f}`' for f in spec.fields)}." if spec.fields else ""
        out += ["", f"### `{spec.name}`", "",
                f"{_cell(spec.doc)} Unit: {spec.unit or '—'}.{fields}", "",
                "| argument | kind | default | meaning |", "| --- | --- | --- | --- |"]
        for p in spec.params:
            default = "**required**" if p.required else (
                "—" if p.default is None else f"`{_plain(p.default)}`")
            choices = f" One of {', '.join(f'`{c}`' for c in p.choices)}." if p.choices else ""
            out.append(f"| `{p.name}` | {p.kind} | {default} | {_cell(p.doc)}{choices} |")
    return "\n".join(out) + "\n"


def _plain(value: Any) -> str:
    if isinstance(value, float) and math.isinf(value):
        return "inf"
    if isinstance(value, tuple):
        return json.dumps(list(value))
    return json.dumps(value)
