"""Settings written once: a node's ROS parameters derived from a settings dataclass.

A setting that is both a field of a settings dataclass (of ``crs_core``, ``sim``,
``chronos_bridge`` or ``ros4crs`` itself: ``SupervisorSettings.stale_timeout``)
and a ROS parameter of a node (the controller's ``stale_timeout``) is written once, in the
dataclass: the parameter's default is the field's, its description the field's entry in the
``Attributes`` section of the dataclass's numpydoc docstring (which gives the unit), and its
bounds are the dataclass's own checks (made when it is built, raising
:class:`~crs_core.errors.FieldError`). A node names the fields it takes as parameters in a
:class:`SettingsParameters` (with the parameter's name where it differs from the field's),
declares them with :func:`declare_fields` and builds the settings with
:meth:`SettingsParameters.build` (or both at once: :func:`declare_settings`); a bad value is a
:class:`~ros4crs.node_support.ParameterError` naming the parameter, with the dataclass's reason.

A bound declared on the field (:mod:`crs_core.settings`: ``rate_hz: float = positive(60.0)``)
is also the parameter's ``additional_constraints``, which ``ros2 param describe`` shows
(``a finite number > 0``). It is text, not a ``floating_point_range``: rclpy would enforce a
range itself, with its own error before the dataclass names the parameter, and a range has
neither open ends (``> 0``) nor "finite".

Each parameter is declared with the type of its default (:func:`~ros4crs.node_support.declare`:
an integer is accepted for a float), so a value of the wrong type is refused when it is declared,
and a value out of bounds when the settings are built.
"""

from __future__ import annotations

import dataclasses
import inspect
import re
from collections.abc import Callable, Mapping
from typing import Any, Generic, TypeVar

from rclpy.node import Node

from crs_core.errors import FieldError
from crs_core.settings import bound_of
from ros4crs.node_support import ParameterError, declare

__all__ = ["SettingsParameters", "attribute_docs", "declare_fields", "declare_settings"]

S = TypeVar("S")

#: The ``Attributes`` section of a numpydoc docstring, up to the next section or the end.
_ATTRIBUTES = re.compile(r"^Attributes\n-+\n(.*?)(?=^\S[^\n]*\n-+\n|\Z)", re.M | re.S)
#: Inline reST markup: ``literal``, `text`, :role:`text` (``~`` shortens a dotted name).
_MARKUP = re.compile(r"(?::[\w:]+:)?`{1,2}(~?)([^`]+?)`{1,2}")


def _plain(text: str) -> str:
    """``text`` without reST markup, on one line (a ROS parameter's description)."""

    def inner(match: re.Match[str]) -> str:
        return match.group(2).rsplit(".", 1)[-1] if match.group(1) else match.group(2)

    return _MARKUP.sub(inner, " ".join(text.split()))


def attribute_docs(cls: type) -> dict[str, str]:
    """Each documented attribute of ``cls`` with its ``Attributes`` entry, as plain text.

    Reads the numpydoc docstrings of ``cls`` and its bases (a subclass's entry wins); an entry
    for several names (``torque_min, torque_max : float``) gives each the same text.
    """
    docs: dict[str, str] = {}
    for klass in reversed(cls.__mro__):
        match = _ATTRIBUTES.search(inspect.cleandoc(klass.__dict__.get("__doc__") or ""))
        if match is None:
            continue
        names: list[str] = []
        lines: list[str] = []
        for line in [*match.group(1).splitlines(), "end"]:
            if line and not line[0].isspace():  # a new entry: "name[, name] : type"
                docs.update(dict.fromkeys(names, _plain(" ".join(lines))))
                names = [name.strip() for name in line.split(" : ")[0].split(",")]
                lines = []
            elif line.strip():
                lines.append(line.strip())
    return docs


@dataclasses.dataclass(frozen=True)
class SettingsParameters(Generic[S]):
    """Fields of the settings dataclass ``settings`` that a node takes as ROS parameters.

    Attributes
    ----------
    settings : type
        A dataclass that checks its fields when it is built (a
        :class:`~crs_core.settings.Settings`, or its own ``__post_init__``), raising
        :class:`~crs_core.errors.FieldError` naming the field.
    fields : tuple of str
        The fields that are parameters, in the order they are declared; each must have a
        default and an entry in the docstring's ``Attributes`` section.
    rename : mapping of str to str
        The parameter's name, by field, where the two differ.
    """

    settings: type[S]
    fields: tuple[str, ...]
    rename: Mapping[str, str] = dataclasses.field(default_factory=dict)

    def __post_init__(self) -> None:
        known = {item.name: item for item in dataclasses.fields(self.settings)}  # type: ignore[arg-type]
        docs = attribute_docs(self.settings)
        for name in (*self.fields, *self.rename):
            if name not in known:
                raise TypeError(f"{self.settings.__name__} has no field {name!r}")
            if name not in self.fields:
                raise TypeError(f"rename: {name!r} is not among the fields")
            if not docs.get(name):
                raise TypeError(f"{self.settings.__name__}.{name} is not documented")

    @property
    def parameters(self) -> tuple[str, ...]:
        """The parameters' names, in the order of :attr:`fields`."""
        return tuple(self.parameter(name) for name in self.fields)

    def parameter(self, field: str) -> str:
        """The name of the parameter ``field`` comes from."""
        return self.rename.get(field, field)

    def default(self, field: str) -> Any:
        """The dataclass's default of ``field`` (a float field's as a float)."""
        item = next(f for f in dataclasses.fields(self.settings) if f.name == field)  # type: ignore[arg-type]
        if item.default is not dataclasses.MISSING:
            value = item.default
        elif item.default_factory is not dataclasses.MISSING:
            value = item.default_factory()
        else:
            raise TypeError(f"{self.settings.__name__}.{field} has no default")
        if item.type in ("float", float) and type(value) is int:
            value = float(value)
        return value

    def description(self, field: str) -> str:
        """The ``Attributes`` entry of ``field`` in the dataclass's docstring, as plain text."""
        return attribute_docs(self.settings)[field]

    def constraints(self, field: str) -> str:
        """What the bound declared on ``field`` asks (``"a finite number > 0"``); empty if the
        field declares none."""
        item = next(f for f in dataclasses.fields(self.settings) if f.name == field)  # type: ignore[arg-type]
        bound = bound_of(item)
        return bound.requirement() if bound is not None else ""

    def build(self, values: Mapping[str, Any], **given: Any) -> S:
        """The settings from the parameters' ``values`` (by field) and the other fields
        ``given``; a :class:`ParameterError` naming the parameter when the dataclass refuses a
        value (a field that is not a parameter keeps its own name)."""
        try:
            return self.settings(**given, **values)
        except FieldError as error:
            field = self.parameter(error.field) if error.field in self.fields else error.field
            raise ParameterError(field, error.reason) from None


def declare_fields(
    node: Node,
    parameters: SettingsParameters[Any],
    defaults: Mapping[str, Any] | None = None,
    checks: Mapping[str, Callable[[Any], str | None]] | None = None,
) -> dict[str, Any]:
    """Declare each of ``parameters`` on ``node``; their values by field name.

    Each is declared with the dataclass's default (or the node's own in ``defaults``, by field:
    one that depends on another parameter, or where the dataclass has ``None``), its
    docstring entry as the description and its declared bound as the constraints; ``checks``
    (by field) are the node's own checks on top of the dataclass's, made at once. A tuple
    field's value is a tuple.
    """
    defaults = defaults or {}
    checks = checks or {}
    values = {}
    for field in parameters.fields:
        default = defaults[field] if field in defaults else parameters.default(field)
        if default is None:
            raise TypeError(f"{parameters.parameter(field)}: a parameter needs a default")
        value = declare(
            node,
            parameters.parameter(field),
            default,
            parameters.description(field),
            checks.get(field),
            parameters.constraints(field),
        )
        values[field] = tuple(value) if isinstance(default, tuple) else value
    return values


def declare_settings(
    node: Node,
    parameters: SettingsParameters[S],
    defaults: Mapping[str, Any] | None = None,
    checks: Mapping[str, Callable[[Any], str | None]] | None = None,
    **given: Any,
) -> S:
    """:func:`declare_fields`, then the settings built from their values and the other fields
    ``given`` (:meth:`SettingsParameters.build`)."""
    return parameters.build(declare_fields(node, parameters, defaults, checks), **given)
