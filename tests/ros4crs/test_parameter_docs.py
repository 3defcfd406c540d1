"""Every ROS parameter a node declares is documented in its section of docs/ros-interface.md
(read from the nodes' source: each ``declare(node, "name", default, description, ...)``, in the
node's module and in the ``declare_*`` helpers of ``ros4crs`` it calls)."""

from __future__ import annotations

import ast
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
INTERFACE = ROOT / "docs" / "ros-interface.md"
NODES = sorted((ROOT / "ros4crs").glob("*_node.py"))


def _calls(tree: ast.AST, name: str) -> list[ast.Call]:
    return [
        call
        for call in ast.walk(tree)
        if isinstance(call, ast.Call) and isinstance(call.func, ast.Name) and call.func.id == name
    ]


def _helpers() -> dict[str, ast.FunctionDef]:
    """The ``declare_*`` functions defined in ``ros4crs`` that declare parameters themselves."""
    found = {}
    for path in (ROOT / "ros4crs").glob("*.py"):
        for function in ast.parse(path.read_text()).body:
            if isinstance(function, ast.FunctionDef) and function.name.startswith("declare_"):
                if _calls(function, "declare"):
                    found[function.name] = function
    return found


def _names(tree: ast.AST) -> list[str]:
    return [
        call.args[1].value
        for call in _calls(tree, "declare")
        if len(call.args) >= 2 and isinstance(call.args[1], ast.Constant)
    ]


def declared_parameters(source: Path) -> list[str]:
    """Names of the parameters ``source`` declares with ``declare(self, "name", ...)``, and
    through the ``declare_*`` helpers it calls."""
    tree = ast.parse(source.read_text())
    names = _names(tree)
    for name, function in _helpers().items():
        if _calls(tree, name):
            names.extend(_names(function))
    return names


def test_the_helpers_are_found() -> None:
    assert "declare_sensor_output" in _helpers()
    bridge = declared_parameters(ROOT / "ros4crs" / "bridge_node.py")
    assert {"sensor_messages", "batch_period", "poll_hz"} <= set(bridge)


def section(node: str) -> str:
    """The text of ``### <node>`` in the interface page, up to the next heading."""
    match = re.search(rf"^### {node}\n(.*?)(?=^#{{1,3}} |\Z)", INTERFACE.read_text(), re.M | re.S)
    assert match is not None, f"docs/ros-interface.md has no section '### {node}'"
    return match.group(1)


@pytest.mark.parametrize("source", NODES, ids=[path.stem for path in NODES])
def test_every_declared_parameter_is_documented_with_its_node(source: Path) -> None:
    names = declared_parameters(source)
    assert names, f"{source.name}: no declare(...) found"
    text = section(source.stem)
    missing = [name for name in names if f"`{name}`" not in text]
    assert not missing, f"{source.stem}: not in docs/ros-interface.md: {missing}"
