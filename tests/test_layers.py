"""The layer rule of DESIGN.md ("nothing imports upward") and no import circle, read from the
source of every module (imports inside functions too)."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]

#: Each package and what it may import besides itself (DESIGN.md, "Layers"); the benchmarks sit
#: on top (they may launch the stack), and only the command line imports them.
ALLOWED = {
    "crs_core": set(),
    "sim": {"crs_core"},
    "chronos_bridge": {"sim", "crs_core"},
    "ros4crs": {"chronos_msgs", "chronos_bridge", "sim", "crs_core"},
    "launch_scripts": {"ros4crs", "chronos_msgs", "chronos_bridge", "sim", "crs_core"},
    "benchmarks": {
        "launch_scripts",
        "ros4crs",
        "chronos_msgs",
        "chronos_bridge",
        "sim",
        "crs_core",
    },
}
#: Modules of a lower layer allowed to import a higher one: the command line dispatches to the
#: benchmarks.
EXCEPTIONS = {"launch_scripts.commands": {"benchmarks"}}


def module_name(path: Path) -> str:
    parts = path.relative_to(ROOT).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def modules() -> dict[str, Path]:
    return {module_name(p): p for package in ALLOWED for p in (ROOT / package).rglob("*.py")}


def imports(path: Path, known: set[str]) -> list[tuple[int, str]]:
    """``(line, module)`` of each project module ``path`` imports (``from a.b import c`` gives
    ``a.b.c`` when that is a module, else ``a.b``)."""
    found = []
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            found += [(node.lineno, alias.name) for alias in node.names]
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            for alias in node.names:
                submodule = f"{node.module}.{alias.name}"
                found.append((node.lineno, submodule if submodule in known else node.module))
    return [(line, name) for line, name in found if name.split(".")[0] in ALLOWED]


def upward(importer: str, imported: str) -> bool:
    package, target = importer.split(".")[0], imported.split(".")[0]
    if target == package or target in ALLOWED[package]:
        return False
    return not any(
        importer.startswith(prefix) and target in allowed for prefix, allowed in EXCEPTIONS.items()
    )


def cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components of more than one module (Tarjan)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    found = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        for w in graph.get(v, ()):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while True:
                w = stack.pop()
                component.append(w)
                if w == v:
                    break
            if len(component) > 1:
                found.append(sorted(component))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return found


def graph() -> dict[str, set[str]]:
    known = modules()
    return {
        name: {
            imported
            for _, imported in imports(path, set(known))
            if imported in known and imported != name and not name.startswith(imported + ".")
        }
        for name, path in known.items()
    }


def test_nothing_imports_upward() -> None:
    known = modules()
    wrong = [
        f"{path.relative_to(ROOT)}:{line}: {name} imports {imported}"
        for name, path in known.items()
        for line, imported in imports(path, set(known))
        if upward(name, imported)
    ]
    assert not wrong, "\n".join(wrong)


def test_no_import_circle() -> None:
    assert cycles(graph()) == []


@pytest.mark.parametrize(
    ("importer", "imported", "wrong"),
    [
        ("crs_core.estimation.mhe", "ros4crs.conversions", True),
        ("sim.simulator", "chronos_bridge.link", True),
        ("ros4crs.estimator_node", "launch_scripts.launcher", True),
        ("launch_scripts.sim_stack", "benchmarks.stack", True),
        ("launch_scripts.commands.bench", "benchmarks.stack", False),
        ("benchmarks.link", "launch_scripts.car_stack", False),
        ("ros4crs.bridge_node", "chronos_bridge.link", False),
    ],
)
def test_the_rule_catches_a_planted_upward_import(importer: str, imported: str, wrong: bool):
    assert upward(importer, imported) is wrong


def test_a_planted_circle_is_found() -> None:
    planted = graph()
    planted["crs_core.measurements"] = planted["crs_core.measurements"] | {"crs_core.dataset"}
    assert any({"crs_core.dataset", "crs_core.measurements"} <= set(c) for c in cycles(planted))
