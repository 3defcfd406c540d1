"""Every ROS parameter a node declares is documented in its section of docs/ros-interface.md
(read from the nodes' source: each ``declare(node, "name", default, description, ...)``)."""

from __future__ import annotations

import ast
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
INTERFACE = ROOT / "docs" / "ros-interface.md"
NODES = sorted((ROOT / "ros4crs").glob("*_node.py"))


def declared_parameters(source: Path) -> list[str]:
    """Names of the parameters ``source`` declares with ``declare(self, "name", ...)``."""
    names = []
    for call in ast.walk(ast.parse(source.read_text())):
        if (
            isinstance(call, ast.Call)
            and isinstance(call.func, ast.Name)
            and call.func.id == "declare"
            and len(call.args) >= 2
            and isinstance(call.args[1], ast.Constant)
        ):
            names.append(call.args[1].value)
    return names


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
