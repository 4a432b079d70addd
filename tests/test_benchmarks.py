"""Every benchmark runs with no arguments: what each needs beyond the built FMUs it
prepares itself.  (The benchmarks print figures; they are run by hand, not here.)"""

from __future__ import annotations

import ast
import importlib.util
import sys
from pathlib import Path

import pytest

from gyrodiag_harness.cosim.batch import scenario_files
from gyrodiag_harness.cosim.master import preflight
from gyrodiag_harness.cosim.scenario import ScenarioError, load_scenario

ROOT = Path(__file__).resolve().parents[1]
BENCHMARKS = sorted((ROOT / "benchmarks").glob("*.py"))


def _load(path: Path):
    spec = importlib.util.spec_from_file_location(f"bench_{path.stem}", path)
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module
    spec.loader.exec_module(module)
    return module


@pytest.mark.parametrize("path", BENCHMARKS, ids=[p.stem for p in BENCHMARKS])
def test_no_benchmark_requires_an_argument(path: Path) -> None:
    tree = ast.parse(path.read_text(encoding="utf-8"))
    for node in ast.walk(tree):
        if isinstance(node, ast.Call) and getattr(node.func, "attr", "") == "add_argument":
            names = [a.value for a in node.args if isinstance(a, ast.Constant)]
            keywords = {k.arg: k.value for k in node.keywords}
            required = keywords.get("required")
            assert not (isinstance(required, ast.Constant) and required.value), names
            positional = [n for n in names if isinstance(n, str) and not n.startswith("-")]
            nargs = keywords.get("nargs")
            optional_nargs = isinstance(nargs, ast.Constant) and nargs.value in ("?", "*")
            assert not positional or optional_nargs or "default" in keywords, names


def test_bench_harness_provides_the_files_the_seed_scenarios_need(tmp_path, fmu_dir):
    bench = _load(ROOT / "benchmarks" / "bench_harness.py")
    paths = [str(p) for p in sorted((ROOT / "scenarios").glob("*.toml"))]
    needing = [p for p in paths if any(
        spec.startswith("${out}/") for inst in load_scenario(p).fmus.values()
        for spec in inst.files.values())]
    assert needing, "no seed scenario reads a run-time file any more: drop this test"
    # without preparation, those scenarios cannot start (the crash of issue 15)
    with pytest.raises(ScenarioError, match=r"dtg_signatures\.json"):
        preflight(load_scenario(needing[0]), fmu_dir, tmp_path)
    learned = []

    def learn(results: Path, name: str) -> None:  # stands for the learn-signatures run
        learned.append((results, name))
        (results / name).write_text("{}")

    bench.prepare_results(paths, tmp_path, learn=learn)
    assert learned == [(tmp_path, "dtg_patterns.json"), (tmp_path, "dtg_signatures.json")]
    for p in scenario_files([Path(x) for x in paths]):
        preflight(load_scenario(p), fmu_dir, tmp_path)
