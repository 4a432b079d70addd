"""Shape of the code (issue 31): no class over 400 lines, no function over 80.

Measured on the source with ``ast`` (``end_lineno - lineno + 1``, docstrings included)
over the library, the FMU sources, the plant models, the harness and the build script.
Declaration tables are module-level data, not functions, and do not count.
"""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
FOLDERS = ("fmu_src", "models", "harness")
BOUND = {"class": 400, "function": 80}
#: "path:qualified name" still over its bound, with its size; each entry is work to do
KNOWN: dict[str, int] = {}


def sizes_of(tree: ast.AST, path: str) -> dict[str, tuple[str, int]]:
    """``"path:Qualified.name"`` → (kind, lines) of every class and function."""
    out: dict[str, tuple[str, int]] = {}

    def visit(node: ast.AST, prefix: str) -> None:
        for child in ast.iter_child_nodes(node):
            if isinstance(child, ast.ClassDef | ast.FunctionDef | ast.AsyncFunctionDef):
                kind = "class" if isinstance(child, ast.ClassDef) else "function"
                name = f"{prefix}{child.name}"
                out[f"{path}:{name}"] = (kind, (child.end_lineno or 0) - child.lineno + 1)
                visit(child, f"{name}.")
            else:
                visit(child, prefix)

    visit(tree, "")
    return out


def _project_sizes() -> dict[str, tuple[str, int]]:
    files = [p for f in FOLDERS for p in sorted((ROOT / f).rglob("*.py"))]
    files.append(ROOT / "build_fmu.py")
    out: dict[str, tuple[str, int]] = {}
    for p in files:
        out.update(sizes_of(ast.parse(p.read_text(encoding="utf-8")), str(p.relative_to(ROOT))))
    return out


def test_the_measure_counts_classes_methods_and_nested_functions() -> None:
    source = ("class A:\n    def f(self):\n        def g():\n            return 1\n"
              "        return g()\n\n\nif True:\n    def h():\n        pass\n")
    assert sizes_of(ast.parse(source), "m.py") == {
        "m.py:A": ("class", 5), "m.py:A.f": ("function", 4), "m.py:A.f.g": ("function", 2),
        "m.py:h": ("function", 2)}


def test_no_class_over_400_lines_and_no_function_over_80() -> None:
    sizes = _project_sizes()
    over = {k: n for k, (kind, n) in sizes.items() if n > BOUND[kind] and n > KNOWN.get(k, 0)}
    assert over == {}, f"over {BOUND}: {over}"
    stale = sorted(k for k in KNOWN if k not in sizes or sizes[k][1] <= BOUND[sizes[k][0]])
    assert stale == [], f"now within the bound: drop from KNOWN {stale}"
