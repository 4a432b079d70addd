"""Module-level import graph of a package, from its source (``ast``), for the layout tests.

Every import counts, also the ones inside functions (deferred imports hide cycles, they
do not remove them); only ``if TYPE_CHECKING:`` blocks are left out (never executed).
Relative imports are resolved; ``from pkg import name`` counts as an import of
``pkg.name`` when that is a module, else of ``pkg``.
"""

from __future__ import annotations

import ast
from pathlib import Path


def module_name(path: Path, root: Path, package: str | None = None) -> str:
    parts = list(path.relative_to(root.parent).with_suffix("").parts)
    parts[0] = package or parts[0]
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def _is_type_checking(test: ast.expr) -> bool:
    return (isinstance(test, ast.Name) and test.id == "TYPE_CHECKING") or (
        isinstance(test, ast.Attribute) and test.attr == "TYPE_CHECKING")


def imports(tree: ast.AST, module: str, is_package: bool) -> list[tuple[str, list[str]]]:
    """(imported module, names) of every executed import statement of a module."""
    found: list[tuple[str, list[str]]] = []

    def visit(node: ast.AST) -> None:
        if isinstance(node, ast.If) and _is_type_checking(node.test):
            for child in node.orelse:
                visit(child)
            return
        if isinstance(node, ast.Import):
            found.extend((a.name, []) for a in node.names)
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                package = module if is_package else module.rpartition(".")[0]
                for _ in range(node.level - 1):
                    package = package.rpartition(".")[0]
                base = f"{package}.{base}" if base else package
            found.append((base, [a.name for a in node.names]))
        for child in ast.iter_child_nodes(node):
            visit(child)

    visit(tree)
    return found


def import_graph(root: Path, package: str | None = None) -> dict[str, set[str]]:
    """Module → modules of the same top-level package it imports (executed imports).

    ``package`` is the import name where it differs from the folder's name.
    """
    files = {module_name(p, root, package): p for p in sorted(root.rglob("*.py"))}
    top = package or root.name
    graph: dict[str, set[str]] = {}
    for name, path in files.items():
        tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
        edges: set[str] = set()
        for target, names in imports(tree, name, path.name == "__init__.py"):
            if target != top and not target.startswith(top + "."):
                continue
            subs = [f"{target}.{n}" for n in names if f"{target}.{n}" in files]
            edges.update(subs or [target])
            if len(subs) < len(names):
                edges.add(target)
        edges.discard(name)
        graph[name] = {e for e in edges if e in files}
    return graph


def find_cycle(graph: dict[str, set[str]]) -> list[str] | None:
    """One cycle of the graph as a list of nodes (first = last), or None."""
    state: dict[str, int] = {}
    stack: list[str] = []

    def dfs(node: str) -> list[str] | None:
        state[node] = 1
        stack.append(node)
        for nxt in sorted(graph.get(node, ())):
            if state.get(nxt) == 1:
                return [*stack[stack.index(nxt):], nxt]
            if nxt not in state and (cycle := dfs(nxt)) is not None:
                return cycle
        stack.pop()
        state[node] = 2
        return None

    for node in sorted(graph):
        if node not in state and (cycle := dfs(node)) is not None:
            return cycle
    return None
