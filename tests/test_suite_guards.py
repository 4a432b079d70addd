"""The suite guards itself: no silent skips on CI, a time limit on every test and every
subprocess, and no import that turns a missing dependency into a skip."""

from __future__ import annotations

import ast
import os
import re
import tomllib
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
CONFTEST = Path(__file__).resolve().parent / "conftest.py"
#: Where the project starts processes.
SOURCES = [*sorted((ROOT / "tests").glob("*.py")), *sorted((ROOT / "harness").rglob("*.py")),
           *sorted((ROOT / "benchmarks").glob("*.py")), ROOT / "build_fmu.py"]
_BLOCKING = {"run", "call", "check_call", "check_output"}


def _pyproject() -> dict:
    return tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))


def _subprocess_calls_without_timeout(path: Path) -> list[str]:
    tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
    return [f"{path.relative_to(ROOT)}:{node.lineno}" for node in ast.walk(tree)
            if isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute)
            and node.func.attr in _BLOCKING and isinstance(node.func.value, ast.Name)
            and node.func.value.id == "subprocess"
            and not any(k.arg == "timeout" for k in node.keywords)]


def test_every_blocking_subprocess_call_has_a_timeout() -> None:
    missing = [where for path in SOURCES for where in _subprocess_calls_without_timeout(path)]
    assert missing == []


def test_the_timeout_check_sees_a_call_without_one(tmp_path: Path) -> None:
    bad = ROOT / "tests" / f"_guard_probe_{os.getpid()}.py"
    try:
        bad.write_text("import subprocess\nsubprocess.run(['true'], check=True)\n"
                       "subprocess.run(['true'], timeout=5)\n")
        assert _subprocess_calls_without_timeout(bad) == [f"tests/{bad.name}:2"]
    finally:
        bad.unlink()


def _declared_modules() -> set[str]:
    """Import names of the first-party packages and of every declared dependency."""
    project = _pyproject()["project"]
    reqs = list(project["dependencies"])
    for extra in project["optional-dependencies"].values():
        reqs += extra
    names = {re.split(r"[\[<>=~!; ]", r, maxsplit=1)[0].lower() for r in reqs}
    import_names = {"dask[distributed]": "distributed", "pyssp-standard": "pyssp_standard",
                    "pytest-xdist": "xdist", "pytest-timeout": "pytest_timeout",
                    "pillow": "PIL"}
    mods = {import_names.get(n, n.replace("-", "_")) for n in names} | {"distributed"}
    return mods | {"gyrodiag", "gyrodiag_harness"}


def test_no_importorskip_of_first_party_or_declared_dependencies() -> None:
    declared = _declared_modules()
    found = []
    for path in sorted((ROOT / "tests").glob("*.py")):
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if (isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute)
                    and node.func.attr == "importorskip" and node.args
                    and isinstance(node.args[0], ast.Constant)):
                top = str(node.args[0].value).split(".")[0]
                if top in declared:
                    found.append(f"{path.name}:{node.lineno} {node.args[0].value}")
    assert "control" in declared and "distributed" in declared and "gyrodiag_harness" in declared
    assert found == []


def test_every_test_has_a_time_limit_and_ci_forbids_unlisted_skips() -> None:
    options = _pyproject()["tool"]["pytest"]["ini_options"]
    assert 60 <= int(options["timeout"]) <= 3600
    assert any(r.startswith("pytest-timeout") for r in
               _pyproject()["project"]["optional-dependencies"]["test"])
    ci = (ROOT / ".ci" / "run").read_text(encoding="utf-8")
    assert "GYRODIAG_STRICT_SKIPS=1" in ci


_PROBE = """
import pytest

def test_runs():
    pass

def test_skips():
    pytest.skip("no frobnicator here")

@pytest.mark.xfail(strict=True, reason="a known limitation")
def test_known():
    assert False
"""


@pytest.mark.parametrize("strict", [False, True])
def test_a_skip_not_on_the_allow_list_fails_a_strict_run(pytester: pytest.Pytester,
                                                         monkeypatch, strict: bool) -> None:
    pytester.makeconftest(CONFTEST.read_text(encoding="utf-8"))
    pytester.makepyfile(test_probe=_PROBE)
    monkeypatch.setenv("GYRODIAG_STRICT_SKIPS", "1" if strict else "0")
    result = pytester.runpytest_subprocess("-p", "no:cacheprovider", "-p", "no:xdist",
                                           "-p", "no:gyrodiag", timeout=300)
    result.assert_outcomes(passed=1, skipped=1, xfailed=1)
    text = result.stdout.str()
    if strict:
        assert result.ret == pytest.ExitCode.TESTS_FAILED
        assert "skips not on the allow-list" in text
        assert "test_probe.py::test_skips: Skipped: no frobnicator here" in text
    else:
        assert result.ret == pytest.ExitCode.OK and "allow-list" not in text


_FOLDERS = ("fmu_src", "models", "harness")


def _third_party_imports(folder: Path) -> dict[str, str]:
    """Top-level imported module -> first file importing it, for modules outside the
    standard library and the project."""
    import sys

    local = {p.stem for f in _FOLDERS for p in (ROOT / f).rglob("*.py")}
    local |= {p.name for f in _FOLDERS for p in (ROOT / f).rglob("*") if p.is_dir()}
    found: dict[str, str] = {}
    for path in sorted(folder.rglob("*.py")):
        if ".venv" in path.parts or "build" in path.parts:
            continue
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            names = ([a.name for a in node.names] if isinstance(node, ast.Import) else
                     [node.module] if isinstance(node, ast.ImportFrom) and node.module
                     and node.level == 0 else [])
            for name in names:
                top = name.split(".")[0]
                if top not in sys.stdlib_module_names and top not in local:
                    found.setdefault(top, str(path.relative_to(ROOT)))
    return found


def test_every_runtime_import_is_a_declared_dependency() -> None:
    """The library, the plant models and the harness import only what pyproject.toml
    installs with `pip install -e .` (a dependency dropped from it fails here)."""
    project = _pyproject()["project"]
    runtime = {re.split(r"[\[<>=~!; ]", r, maxsplit=1)[0].lower().replace("-", "_")
               for r in project["dependencies"]}
    runtime = {"PIL" if n == "pillow" else n for n in runtime}
    optional = _declared_modules()
    allowed = runtime | {"gyrodiag", "gyrodiag_harness", "fmpy", "pythonfmu", "mpl_toolkits"}
    used = {}
    for folder in _FOLDERS:
        used.update(_third_party_imports(ROOT / folder))
    # optional features import their extra's packages lazily, inside functions
    missing = {m: f for m, f in used.items() if m not in allowed and m not in optional}
    assert missing == {}
    assert {"numpy", "scipy", "control"} <= set(used) <= allowed | optional
