"""The scenario reference: docs/scenarios.md and ``python -m gyrodiag_harness schema`` come from the
pydantic models that validate scenario files, and stay true to them."""

from __future__ import annotations

import json
import subprocess
import sys
import tomllib
from pathlib import Path

import jsonschema
import pytest

from gyrodiag_harness.cli import reference
from gyrodiag_harness.cosim.batch import scenario_files
from gyrodiag_harness.cosim.master import preflight
from gyrodiag_harness.cosim.scenario import ScenarioError, parse_scenario
from gyrodiag_harness.verification import expectations, metrics

ROOT = Path(__file__).resolve().parents[1]
SEED_FILES = scenario_files([ROOT / "scenarios", ROOT / "scenarios" / "training"])


def test_docs_scenarios_md_is_generated_from_the_models() -> None:
    committed = (ROOT / "docs" / "scenarios.md").read_text(encoding="utf-8")
    assert committed == reference.markdown(), (
        f"docs/scenarios.md is stale: regenerate it with `{reference.REGENERATE}`")


def test_reference_names_every_key_kind_fault_type_and_metric() -> None:
    text = reference.markdown()
    for model in expectations._MODELS:
        kind = model.model_json_schema()["properties"]["kind"]["const"]
        assert f'### `kind = "{kind}"`' in text
        for key in model.model_fields:
            assert f"| `{key}` |" in text or key in ("kind", "name"), (kind, key)
    for name in metrics.METRICS:
        assert f"### `{name}`" in text
    for fault_type in ("bias", "intermittent", "nan_dropout"):
        assert f"| `{fault_type}` |" in text
    # descriptions come from the models' attribute docstrings
    assert "| `step_ratio` | int | `1` | ≥ 1 | The instance steps every" in text
    assert "| `end_s` | float | — |  | End, s (default: never" in text


def test_reference_example_is_a_valid_scenario(fmu_dir: Path) -> None:
    example = reference._EXAMPLE
    assert example in reference.markdown()
    scenario = parse_scenario(tomllib.loads(example), source="<reference example>")
    assert scenario.name == "pitch_q_bias" and len(scenario.expect) == 2
    preflight(scenario, fmu_dir)  # every variable name exists in the built FMUs


def test_json_schema_accepts_every_seed_scenario_and_rejects_what_the_loader_rejects() -> None:
    schema = reference.scenario_schema()
    json.dumps(schema, allow_nan=False)  # strict JSON: no Infinity defaults
    validator = jsonschema.Draft202012Validator(schema)
    assert len(SEED_FILES) >= 19
    for path in SEED_FILES:
        data = tomllib.loads(path.read_text(encoding="utf-8"))
        data.setdefault("name", path.stem)
        errors = [e.message for e in validator.iter_errors(data)]
        assert errors == [], f"{path.name}: {errors}"
    base = tomllib.loads(SEED_FILES[0].read_text(encoding="utf-8"))
    base.setdefault("name", "x")
    for broken in ({**base, "duraton_s": 1.0},                       # unknown key
                   {**base, "step_s": 0.0},                          # out of range
                   {**base, "expect": [{"kind": "detected_within", "signal": "a.b"}]},
                   {**base, "expect": [{"kind": "no_such_kind", "signal": "a.b"}]}):
        assert not validator.is_valid(broken)
        with pytest.raises(ScenarioError):
            parse_scenario(broken)


def test_schema_command_prints_the_json_schemas() -> None:
    def run(*args: str) -> dict:
        proc = subprocess.run([sys.executable, "-m", "gyrodiag_harness", "schema", *args], cwd=ROOT,
                              capture_output=True, text=True, timeout=120)
        assert proc.returncode == 0, proc.stderr
        return json.loads(proc.stdout)

    scenario = run()
    assert scenario["title"] == "gyrodiag scenario"
    kinds = {d["properties"]["kind"]["const"] for d in scenario["$defs"].values()
             if "kind" in d.get("properties", {}) and "const" in d["properties"]["kind"]}
    model_kinds = {m.model_json_schema()["properties"]["kind"]["const"]
                   for m in expectations._MODELS}
    assert kinds == model_kinds and {"detected_within", "metric", "value_at"} <= kinds
    campaign = run("--campaign")
    assert campaign["title"] == "gyrodiag campaign" and "classes" in campaign["properties"]
