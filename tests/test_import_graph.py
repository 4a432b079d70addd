"""Layout of gyrodiag/: one package per method plus a shared one, imported in one
direction, no import cycles, no FMI or harness code, no build-time generators.

The graph is read from the source (``tests/_import_graph.py``): every executed import
counts, also deferred ones inside functions; relative imports are resolved. The
packages' lazy re-exports (``__getattr__`` in each ``__init__``) are not imports of the
graph: importing a package imports none of its modules.
"""

from __future__ import annotations

import ast
import importlib
import shutil
import tomllib
from pathlib import Path

import pytest
from _import_graph import find_cycle, import_graph, imports, module_name

ROOT = Path(__file__).resolve().parents[1]
GYRODIAG = ROOT / "fmu_src" / "gyrodiag"

#: The method packages and the one they share; a method package imports only itself
#: and ``common``, ``common`` only itself.
PACKAGES = ("common", "dtg", "grey", "df")

#: Top-level packages nothing under gyrodiag may import: the library knows neither the
#: FMI wrappers nor the harness that drives them.
FORBIDDEN = ("gyrodiag_harness", "harness", "fmpy", "pythonfmu")


def _all_imports(root: Path) -> dict[str, list[str]]:
    """Module → every module it imports (any package; executed imports)."""
    out: dict[str, list[str]] = {}
    for path in sorted(root.rglob("*.py")):
        name = module_name(path, root)
        tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
        out[name] = [target for target, _ in imports(tree, name, path.name == "__init__.py")]
    return out


def test_gyrodiag_has_no_import_cycle() -> None:
    graph = import_graph(GYRODIAG)
    assert "gyrodiag.df.channel" in graph and "gyrodiag.dtg.channel" in graph
    assert "gyrodiag.common._validation" in graph["gyrodiag.df.isolation"]  # absolute
    assert "gyrodiag.common._accel" in graph["gyrodiag.grey.predictor"]     # relative
    assert find_cycle(graph) is None


def test_the_check_finds_the_old_gain_table_cycle(tmp_path: Path) -> None:
    # the cycle this layout broke: channel -> isolation -> gains -> channel (the
    # generator of the shipped table, now fmu_src/tools/observer_gains.py)
    copy = tmp_path / "gyrodiag"
    shutil.copytree(GYRODIAG, copy, ignore=shutil.ignore_patterns("__pycache__", "*.so"))
    gains = copy / "df" / "gains.py"
    gains.write_text(gains.read_text(encoding="utf-8")
                     + "\n\ndef _designs():\n    from gyrodiag.df.channel import DFChannel\n",
                     encoding="utf-8")
    cycle = find_cycle(import_graph(copy))
    assert cycle is not None
    assert {"gyrodiag.df.channel", "gyrodiag.df.isolation", "gyrodiag.df.gains"} <= set(cycle)


def test_nothing_under_gyrodiag_imports_harness_or_fmi_code() -> None:
    found = sorted((name, target) for name, targets in _all_imports(GYRODIAG).items()
                   for target in targets if target.split(".")[0] in FORBIDDEN)
    assert found == []


def test_packages_import_in_one_direction() -> None:
    wrong = []
    for name, targets in import_graph(GYRODIAG).items():
        parts = name.split(".")
        if len(parts) < 3:
            continue  # gyrodiag, gyrodiag.demo and the package __init__s
        own = parts[1]
        allowed = {own} if own == "common" else {own, "common"}
        wrong += [(name, t) for t in targets
                  if len(t.split(".")) > 1 and t.split(".")[1] not in allowed]
    assert wrong == []


def test_one_package_per_method_and_nothing_loose() -> None:
    loose = sorted(p.name for p in GYRODIAG.glob("*.py"))
    assert loose == ["__init__.py", "demo.py"]
    found = sorted(p.parent.name for p in GYRODIAG.glob("*/__init__.py"))
    assert found == sorted(PACKAGES)
    assert not list(GYRODIAG.glob("*/*/__init__.py"))


def test_the_package_installs_every_gyrodiag_package() -> None:
    config = tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))
    listed = set(config["tool"]["setuptools"]["packages"])
    assert {"gyrodiag", *(f"gyrodiag.{p}" for p in PACKAGES)} <= listed


def test_no_runtime_module_parses_command_lines() -> None:
    # build-time generators live in fmu_src/tools/; only the demo has a command line
    users = sorted(name for name, targets in _all_imports(GYRODIAG).items()
                   if "argparse" in targets)
    assert users == ["gyrodiag.demo"]


@pytest.mark.parametrize("package", PACKAGES)
def test_each_package_reexports_its_modules_public_names(package: str) -> None:
    pkg = importlib.import_module(f"gyrodiag.{package}")
    assert pkg.__doc__ and "Modules\n-------\n" in pkg.__doc__
    assert sorted(pkg.__all__) == pkg.__all__
    for name, module in pkg._EXPORTS.items():
        mod = importlib.import_module(f"gyrodiag.{package}.{module}")
        assert name in mod.__all__, (module, name)
        assert getattr(pkg, name) is getattr(mod, name)
    for module in set(pkg._EXPORTS.values()):
        mod = importlib.import_module(f"gyrodiag.{package}.{module}")
        assert {n for n, m in pkg._EXPORTS.items() if m == module} == set(mod.__all__)
    with pytest.raises(AttributeError, match="no attribute 'no_such_name'"):
        pkg.no_such_name  # noqa: B018
