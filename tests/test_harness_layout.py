"""Layout of harness/: subpackages by role, imported in one direction, no import cycles.

Every import counts, also the ones inside functions (deferred imports hide cycles, they
do not remove them); only ``if TYPE_CHECKING:`` blocks are left out (never executed).
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

from _import_graph import find_cycle, import_graph

ROOT = Path(__file__).resolve().parents[1]
HARNESS = ROOT / "harness"
#: what the folder installs as (pyproject package-dir; docs/harness.md says why)
PACKAGE = "gyrodiag_harness"

#: Subpackages, lowest first: a module may import its own subpackage and those before it.
LAYERS = ("verification", "cosim", "reporting", "campaigns", "testing", "cli")


def test_the_checker_finds_a_deferred_import_cycle(tmp_path: Path) -> None:
    pkg = tmp_path / "pkg"
    (pkg / "sub").mkdir(parents=True)
    (pkg / "__init__.py").write_text("")
    (pkg / "sub" / "__init__.py").write_text("")
    (pkg / "a.py").write_text("from pkg.sub import b\n")
    (pkg / "sub" / "b.py").write_text(
        "from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    from pkg import c\n"
        "def f():\n    from pkg import a\n")
    (pkg / "c.py").write_text("from . import a\n")
    graph = import_graph(pkg)
    assert graph["pkg.a"] == {"pkg.sub.b"}
    assert graph["pkg.sub.b"] == {"pkg.a"}          # deferred counted, TYPE_CHECKING not
    assert graph["pkg.c"] == {"pkg.a"}              # relative import resolved
    assert find_cycle(graph) == ["pkg.a", "pkg.sub.b", "pkg.a"]
    (pkg / "sub" / "b.py").write_text("def f():\n    import pkg.c\n")
    assert find_cycle(import_graph(pkg)) == ["pkg.a", "pkg.sub.b", "pkg.c", "pkg.a"]


def test_harness_has_no_import_cycle() -> None:
    graph = import_graph(HARNESS, PACKAGE)
    assert "gyrodiag_harness.cosim.master" in graph and "gyrodiag_harness.cli.commands" in graph
    assert find_cycle(graph) is None


def test_every_module_lives_in_a_role_subpackage() -> None:
    loose = sorted(p.name for p in HARNESS.glob("*.py")
                   if p.name not in ("__init__.py", "__main__.py"))
    assert loose == [], f"modules outside the role subpackages: {loose}"
    subpackages = sorted(p.name for p in HARNESS.iterdir()
                         if p.is_dir() and (p / "__init__.py").exists())
    assert subpackages == sorted(LAYERS)


def test_subpackages_import_only_their_own_layer_and_lower_ones() -> None:
    graph = import_graph(HARNESS, PACKAGE)
    wrong = []
    for module, targets in graph.items():
        parts = module.split(".")
        if len(parts) < 3:      # harness, gyrodiag_harness.__main__, harness.<sub> (package docs)
            continue
        rank = LAYERS.index(parts[1])
        for t in targets:
            t_parts = t.split(".")
            if len(t_parts) < 2 or t_parts[1] == "__main__":
                wrong.append(f"{module} -> {t} (the package's public API is the top)")
            elif LAYERS.index(t_parts[1]) > rank:
                wrong.append(f"{module} -> {t}")
    assert wrong == []


def test_the_package_installs_every_subpackage() -> None:
    import tomllib

    config = tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))
    listed = set(config["tool"]["setuptools"]["packages"])
    assert {PACKAGE, *(f"{PACKAGE}.{layer}" for layer in LAYERS)} <= listed
    assert config["tool"]["setuptools"]["package-dir"][PACKAGE] == "harness"


def test_only_the_cli_parses_command_lines() -> None:
    users = sorted(name for name, path in
                   ((n, ROOT / (n.replace(PACKAGE, "harness", 1).replace(".", "/") + ".py"))
                    for n in import_graph(HARNESS, PACKAGE))
                   if path.exists() and "import argparse" in path.read_text(encoding="utf-8"))
    assert users and all(u.startswith("gyrodiag_harness.cli.") for u in users), users


def test_every_module_imports_first() -> None:
    # each module imported first into an interpreter without harness modules: an
    # import-order cycle would show here as an ImportError
    modules = sorted(m for m in import_graph(HARNESS, PACKAGE) if m != "gyrodiag_harness.__main__")
    code = (
        "import importlib, sys\n"
        f"for name in {modules!r}:\n"
        "    for m in [m for m in sys.modules\n"
        "              if m == 'gyrodiag_harness' or m.startswith('gyrodiag_harness.')]:\n"
        "        del sys.modules[m]\n"
        "    importlib.import_module(name)\n"
        f"print('imported', {len(modules)})\n")
    proc = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True,
                          text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.strip() == f"imported {len(modules)}"


def test_public_api_is_unchanged() -> None:
    import gyrodiag_harness
    from gyrodiag_harness.cosim.master import run_scenario
    from gyrodiag_harness.cosim.scenario import load_scenario

    assert sorted(gyrodiag_harness.__all__) == ["FaultWindow", "RunResult", "Scenario",
                                       "ScenarioError", "load_scenario", "run_scenario"]
    assert gyrodiag_harness.load_scenario is load_scenario
    assert gyrodiag_harness.run_scenario is run_scenario


def test_command_line_offers_the_same_commands() -> None:
    proc = subprocess.run([sys.executable, "-m", "gyrodiag_harness", "--help"], cwd=ROOT,
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    for command in ("run", "verify", "report", "list", "isolability", "learn-signatures",
                    "all", "campaign"):
        assert f"    {command} " in proc.stdout or f"    {command}\n" in proc.stdout, command


def test_the_folder_refuses_its_folder_name_as_import_name() -> None:
    # from a checkout's root `import harness` finds the folder: one package under two
    # names would load every module twice, so it refuses and names the right one
    proc = subprocess.run([sys.executable, "-c", "import harness"], cwd=ROOT,
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode != 0
    assert "ImportError" in proc.stderr and "import gyrodiag_harness" in proc.stderr
