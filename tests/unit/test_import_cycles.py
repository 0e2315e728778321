"""No import circles inside mrosd/ and cli/: a circle means two modules each own part of one concept.

The graph is read from the source with ``ast``, not by importing: every import statement is an edge, those
under ``if TYPE_CHECKING:`` and those inside functions included. A type-only circle is still two modules
that each need the other's concept (a small protocol, as ``mrosd.tcpros.owner`` holds, breaks it), and a
lazy import is there for start-up time, not to hide a circle. As import-linter's grimp does,
``from package import name`` is an edge to ``package.name`` when that is a module and to the package's
``__init__`` otherwise.
"""

from __future__ import annotations

import ast
from collections.abc import Iterator
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]

#: Circles tolerated for now, each as the set of its modules (none: the last three were broken in issue 33).
#: A circle found must lie inside one of these.
KNOWN_CIRCLES: list[frozenset[str]] = []


def _modules() -> dict[str, Path]:
    found: dict[str, Path] = {}
    for base, package in ((ROOT, "mrosd"), (ROOT / "cli", "mros_cli")):
        for path in sorted((base / package).rglob("*.py")):
            parts = list(path.relative_to(base).with_suffix("").parts)
            if parts[-1] == "__init__":
                parts.pop()
            found[".".join(parts)] = path
    return found


def _imports(tree: ast.Module) -> Iterator[ast.Import | ast.ImportFrom]:
    for node in ast.walk(tree):
        if isinstance(node, ast.Import | ast.ImportFrom):
            yield node


def _graph(modules: dict[str, Path]) -> dict[str, set[str]]:
    graph: dict[str, set[str]] = {name: set() for name in modules}
    for name, path in modules.items():
        package = name if path.name == "__init__.py" else name.rpartition(".")[0]
        for stmt in _imports(ast.parse(path.read_text(), str(path))):
            if isinstance(stmt, ast.Import):
                targets = [alias.name for alias in stmt.names]
            else:
                base = stmt.module or ""
                if stmt.level:
                    anchor = package.split(".")
                    anchor = anchor[: len(anchor) - (stmt.level - 1)]
                    base = ".".join([*anchor, *([base] if base else [])])
                targets = [
                    f"{base}.{alias.name}" if f"{base}.{alias.name}" in modules else base for alias in stmt.names
                ]
            graph[name].update(t for t in targets if t in modules and t != name)
    return graph


def _circles(graph: dict[str, set[str]]) -> list[frozenset[str]]:
    """Strongly connected components of more than one module (Tarjan, iterative)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    on_stack: set[str] = set()
    stack: list[str] = []
    found: list[frozenset[str]] = []
    for root, succs in graph.items():
        if root in index:
            continue
        work: list[tuple[str, Iterator[str]]] = [(root, iter(sorted(succs)))]
        index[root] = low[root] = len(index)
        stack.append(root)
        on_stack.add(root)
        while work:
            node, edges = work[-1]
            for succ in edges:
                if succ not in index:
                    index[succ] = low[succ] = len(index)
                    stack.append(succ)
                    on_stack.add(succ)
                    work.append((succ, iter(sorted(graph[succ]))))
                    break
                if succ in on_stack:
                    low[node] = min(low[node], index[succ])
            else:
                work.pop()
                if work:
                    low[work[-1][0]] = min(low[work[-1][0]], low[node])
                if low[node] == index[node]:
                    component = set()
                    while True:
                        member = stack.pop()
                        on_stack.discard(member)
                        component.add(member)
                        if member == node:
                            break
                    if len(component) > 1:
                        found.append(frozenset(component))
    return found


def test_the_graph_sees_the_imports_it_must() -> None:
    graph = _graph(_modules())
    assert "mrosd.tcpros.node" in graph["mrosd.tcpros"]
    assert "mrosd.wire.header" in graph["mrosd.tcpros.publisher"]
    assert "mrosd.master.client" in graph["mrosd.tcpros.owner"]  # under ``if TYPE_CHECKING:``
    assert "mrosd.shm.loan" in graph["mrosd.tcpros.publisher"]  # inside a function


def test_the_cycle_finder_finds_a_circle_of_three() -> None:
    assert _circles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [frozenset({"a", "b", "c"})]


def test_no_new_import_circle_in_mrosd_or_the_cli() -> None:
    new = [
        sorted(circle) for circle in _circles(_graph(_modules())) if not any(circle <= known for known in KNOWN_CIRCLES)
    ]
    assert not new, f"import circles: {new}"
