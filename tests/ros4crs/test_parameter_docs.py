"""The parameter table of each node in docs/ros-interface.md matches what the node declares: every
parameter it declares is in its section, every parameter of its table is declared, and the
documented default is the declared one.

The parameters are read from the nodes' source: each ``declare(node, "name", default, ...)`` and
each ``declare_fields`` / ``declare_settings`` of a module-level
:class:`~ros4crs.settings_parameters.SettingsParameters` (the defaults of a settings dataclass),
in the node's module and in the ``declare_*`` helpers of ``ros4crs`` it calls.
A default computed in the node (``rate_hz``: 30 Hz for the MPCC, 50 Hz for the path follower) is
not compared.
"""

from __future__ import annotations

import ast
import importlib
import math
import re
from pathlib import Path
from typing import Any

import pytest

from ros4crs.settings_parameters import SettingsParameters

ROOT = Path(__file__).resolve().parents[2]
INTERFACE = ROOT / "docs" / "ros-interface.md"
NODES = sorted((ROOT / "ros4crs").glob("*_node.py"))
#: A default that is not a value written in the source.
COMPUTED = object()


def _calls(tree: ast.AST, *names: str) -> list[ast.Call]:
    return [
        call
        for call in ast.walk(tree)
        if isinstance(call, ast.Call) and isinstance(call.func, ast.Name) and call.func.id in names
    ]


def _module(path: Path) -> Any:
    return importlib.import_module(f"ros4crs.{path.stem}")


def _value(node: ast.expr, module: Any) -> Any:
    """The value of a constant, or of a module-level name or attribute (``DEFAULT_PORT``,
    ``MheSettings.horizon``); else :data:`COMPUTED`."""
    if isinstance(node, ast.Constant):
        return node.value
    if isinstance(node, ast.Name):
        return getattr(module, node.id, COMPUTED)
    if isinstance(node, ast.Attribute):
        base = _value(node.value, module)
        return COMPUTED if base is COMPUTED else getattr(base, node.attr, COMPUTED)
    return COMPUTED


def _declared(tree: ast.AST, module: Any) -> dict[str, Any]:
    """The parameters ``tree`` declares itself, with their defaults."""
    found = {}
    for call in _calls(tree, "declare"):
        if len(call.args) >= 3 and isinstance(call.args[1], ast.Constant):
            found[call.args[1].value] = _value(call.args[2], module)
    for call in _calls(tree, "declare_fields", "declare_settings"):
        spec = _value(call.args[1], module)
        assert isinstance(spec, SettingsParameters), ast.unparse(call)
        overridden = {
            ast.literal_eval(key)
            for keyword in call.keywords
            if keyword.arg == "defaults" and isinstance(keyword.value, ast.Dict)
            for key in keyword.value.keys
            if key is not None
        }
        for field in spec.fields:
            default = COMPUTED if field in overridden else spec.default(field)
            found[spec.parameter(field)] = default
    return found


def _helpers() -> dict[str, dict[str, Any]]:
    """The ``declare_*`` functions of ``ros4crs`` that declare parameters themselves (by hand or
    from a settings dataclass), with their parameters and those of the helpers they call
    (``declare_initial_state`` calls ``declare_track``); not those of the machinery,
    :mod:`ros4crs.settings_parameters`."""
    found, functions = {}, {}
    for path in (ROOT / "ros4crs").glob("*.py"):
        if path.stem == "settings_parameters":
            continue
        for function in ast.parse(path.read_text()).body:
            if isinstance(function, ast.FunctionDef) and function.name.startswith("declare_"):
                if _calls(function, "declare", "declare_fields", "declare_settings"):
                    found[function.name] = _declared(function, _module(path))
                    functions[function.name] = function
    for name, function in functions.items():
        for helper in functions.keys() - {name}:
            if _calls(function, helper):
                found[name] = {**found[helper], **found[name]}
    return found


def declared_parameters(source: Path) -> dict[str, Any]:
    """The parameters ``source`` declares, itself and through the ``declare_*`` helpers it
    calls, with their defaults (:data:`COMPUTED`: not written in the source)."""
    tree = ast.parse(source.read_text())
    found = _declared(tree, _module(source))
    for name, parameters in _helpers().items():
        if _calls(tree, name):
            found.update(parameters)
    return found


def test_the_helpers_and_settings_are_found() -> None:
    assert _helpers()["declare_sensor_output"] == {"sensor_messages": "batch", "batch_period": 0.01}
    bridge = declared_parameters(ROOT / "ros4crs" / "bridge_node.py")
    assert {"sensor_messages", "batch_period", "poll_hz"} <= set(bridge)
    assert bridge["port"] == 20211
    assert bridge["command_repeat_period"] == 0.02 and bridge["car_ip"] == ""
    simulator = declared_parameters(ROOT / "ros4crs" / "simulator_node.py")
    assert {"sensor_messages", "batch_period", "tick_hz", "track_file"} <= set(simulator)
    controller = declared_parameters(ROOT / "ros4crs" / "controller_node.py")
    assert controller["speed_ramp"] == 1.5
    assert controller["command_delay"] == 0.02
    assert controller["rate_hz"] is COMPUTED
    estimator = declared_parameters(ROOT / "ros4crs" / "estimator_node.py")
    assert {"track_file", "initial_state"} <= set(estimator)
    assert estimator["max_lag"] is COMPUTED
    assert estimator["horizon"] == 40


def section(node: str) -> str:
    """The text of ``### <node>`` in the interface page, up to the next heading."""
    match = re.search(rf"^### {node}\n(.*?)(?=^#{{1,3}} |\Z)", INTERFACE.read_text(), re.M | re.S)
    assert match is not None, f"docs/ros-interface.md has no section '### {node}'"
    return match.group(1)


def table(node: str) -> dict[str, str]:
    """The parameters of the node's table, with their default cell."""
    rows = {}
    for line in section(node).splitlines():
        cells = [cell.strip() for cell in line.strip().strip("|").split("|")]
        if line.startswith("| `") and len(cells) >= 2:
            for name in re.findall(r"`([^`]+)`", cells[0]):
                rows[name] = cells[1]
    return rows


def documents(cell: str, value: Any) -> bool:
    """Whether a table's default ``cell`` says ``value`` (a number among those it names; a
    string, but an empty one, in backquotes; ``true`` / ``false``)."""
    if isinstance(value, bool):
        return ("true" if value else "false") in cell
    if isinstance(value, int | float):
        numbers = re.findall(r"-?\d+(?:\.\d+)?(?:e-?\d+)?", cell)
        return any(math.isclose(float(number), value) for number in numbers)
    if isinstance(value, str):
        return not value or f"`{value}`" in cell
    return True


@pytest.mark.parametrize("source", NODES, ids=[path.stem for path in NODES])
def test_every_declared_parameter_is_documented_with_its_node(source: Path) -> None:
    names = declared_parameters(source)
    assert names, f"{source.name}: no declare(...) found"
    text = section(source.stem)
    missing = [name for name in names if f"`{name}`" not in text]
    assert not missing, f"{source.stem}: not in docs/ros-interface.md: {missing}"


@pytest.mark.parametrize("source", NODES, ids=[path.stem for path in NODES])
def test_the_parameter_table_matches_the_node(source: Path) -> None:
    declared = declared_parameters(source)
    rows = table(source.stem)
    assert rows, f"{source.stem}: no parameter table"
    assert sorted(set(rows) - set(declared)) == [], f"{source.stem}: documented, not declared"
    assert sorted(set(declared) - set(rows)) == [], f"{source.stem}: declared, not in its table"
    wrong = {
        name: (rows[name], default)
        for name, default in declared.items()
        if default is not COMPUTED and not documents(rows[name], default)
    }
    assert not wrong, f"{source.stem}: documented default (cell, declared): {wrong}"
