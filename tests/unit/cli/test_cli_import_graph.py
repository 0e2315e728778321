"""The ``mros`` CLI's modules import each other without a circle, and none passes the house's 600 lines.

Imports inside functions count too: the CLI defers most of its imports to keep start-up cheap, and a
deferred import that closes a circle still couples the two modules both ways (``bag.py`` and ``topic.py``
did, over ``split_topic`` and ``echo_bag``).
"""

from __future__ import annotations

import ast
from pathlib import Path

import mros_cli

PACKAGE = Path(mros_cli.__file__).parent
#: The house's bound on a module (docs/architecture.md, STYLE.md rule 11).
MAX_LINES = 600


def _imports(path: Path) -> set[str]:
    found: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.ImportFrom) and node.module and node.module.startswith("mros_cli"):
            found.add(node.module.split(".")[1] if "." in node.module else "")
            if node.module == "mros_cli":
                found.update(alias.name for alias in node.names)
        elif isinstance(node, ast.Import):
            found.update(a.name.split(".")[1] for a in node.names if a.name.startswith("mros_cli."))
    return found - {"", path.stem}


def _cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    cycles: list[list[str]] = []
    state: dict[str, int] = {}
    stack: list[str] = []

    def visit(node: str) -> None:
        state[node] = 1
        stack.append(node)
        for nxt in sorted(graph.get(node, ())):
            if state.get(nxt) == 1:
                cycles.append([*stack[stack.index(nxt) :], nxt])
            elif nxt not in state:
                visit(nxt)
        stack.pop()
        state[node] = 2

    for node in sorted(graph):
        if node not in state:
            visit(node)
    return cycles


def test_the_cli_modules_import_each_other_without_a_circle() -> None:
    graph = {p.stem: _imports(p) for p in PACKAGE.glob("*.py")}
    assert _cycles(graph) == []


def test_no_cli_module_passes_600_lines() -> None:
    sizes = {p.name: len(p.read_text().splitlines()) for p in PACKAGE.glob("*.py")}
    assert {name: n for name, n in sizes.items() if n > MAX_LINES} == {}
