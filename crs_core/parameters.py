"""Named model parameters with units, bounds and a Gaussian prior; YAML in and out.

A :class:`ParameterSet` is an ordered collection of :class:`Parameter`. The order defines the
layout of the parameter vector ``p`` that every CasADi function of the model takes, so code
addresses parameters by name and never by index.
"""

from __future__ import annotations

import math
from collections.abc import Iterator, Mapping
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from crs_core.errors import FieldError
from crs_core.yaml_io import load_yaml


@dataclass(frozen=True)
class Parameter:
    """One scalar model parameter.

    Attributes
    ----------
    name : str
        Identifier used in code and YAML (e.g. ``"Cm1"``).
    value : float
        Current value, in ``unit``.
    unit : str
        SI unit (``"-"`` for dimensionless).
    lower, upper : float
        Physically admissible bounds (used by identification and validation).
    prior_std : float
        Standard deviation of the Gaussian prior around the default value, in ``unit``.
    description : str
        One line saying what the parameter is.
    group : str
        Family in the paper's notation: ``tire``, ``car``, ``friction``, ``motor``, ``encoder``,
        ``lighthouse`` or ``effect:<name>``.
    period : float or None
        For an angle whose every value is physically valid (a base-station rotation angle):
        its period (``2 pi``). Values are wrapped into ``[-period/2, period/2)`` when set
        (:meth:`ParameterSet.updated`, YAML), and the bounds are ``+-period``, so a bound is
        about the physics, never about where the Euler chart happens to be.
    """

    name: str
    value: float
    unit: str
    lower: float
    upper: float
    prior_std: float
    description: str
    group: str
    period: float | None = None

    def __post_init__(self) -> None:
        if self.period is not None:
            if not (math.isfinite(self.period) and self.period > 0):
                raise ValueError(f"parameter {self.name!r}: period must be finite and > 0")
            object.__setattr__(self, "value", wrap_periodic(self.value, self.period))
        for field in ("value", "lower", "upper", "prior_std"):
            if not math.isfinite(getattr(self, field)):
                raise ValueError(f"parameter {self.name!r}: {field} must be finite")
        if not self.lower <= self.upper:
            raise ValueError(f"parameter {self.name!r}: lower bound exceeds upper bound")
        if not self.lower <= self.value <= self.upper:
            raise ValueError(
                f"parameter {self.name!r}: value {self.value} outside [{self.lower}, {self.upper}]"
            )
        if self.prior_std < 0:
            raise ValueError(f"parameter {self.name!r}: prior_std must be >= 0")


class ParameterSet(Mapping[str, Parameter]):
    """Ordered, immutable set of named parameters.

    ``params["m"]`` returns the :class:`Parameter`; ``params.value("m")`` its value;
    ``params.vector()`` the values in order (the layout of the model's ``p``).
    """

    def __init__(self, parameters: list[Parameter] | tuple[Parameter, ...]) -> None:
        self._items: dict[str, Parameter] = {}
        for parameter in parameters:
            if parameter.name in self._items:
                raise ValueError(f"duplicate parameter name {parameter.name!r}")
            self._items[parameter.name] = parameter

    def __getitem__(self, name: str) -> Parameter:
        try:
            return self._items[name]
        except KeyError:
            raise KeyError(f"unknown parameter {name!r}") from None

    def __iter__(self) -> Iterator[str]:
        return iter(self._items)

    def __len__(self) -> int:
        return len(self._items)

    def __repr__(self) -> str:
        inner = ", ".join(f"{p.name}={p.value:g}" for p in self._items.values())
        return f"ParameterSet({inner})"

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(self._items)

    def value(self, name: str) -> float:
        return self[name].value

    def vector(self) -> np.ndarray:
        """Values in set order, shape ``(n,)``."""
        return np.array([p.value for p in self._items.values()], dtype=float)

    def index(self, name: str) -> int:
        return self.names.index(self[name].name)

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """Lower and upper bounds in set order."""
        return (
            np.array([p.lower for p in self._items.values()]),
            np.array([p.upper for p in self._items.values()]),
        )

    def updated(self, values: Mapping[str, float]) -> ParameterSet:
        """Copy with some values replaced; validates names, finiteness and bounds."""
        for name in values:
            if name not in self._items:
                raise KeyError(f"unknown parameter {name!r}; known: {', '.join(self.names)}")
        return ParameterSet(
            [
                replace(p, value=_as_float(values[p.name], p.name)) if p.name in values else p
                for p in self._items.values()
            ]
        )

    def merged(self, other: ParameterSet) -> ParameterSet:
        """Union of two sets with disjoint names (order: self, then other)."""
        return ParameterSet(list(self._items.values()) + list(other.values()))

    # --- YAML ---------------------------------------------------------------------------
    def to_dict(self) -> dict[str, dict[str, Any]]:
        return {
            p.name: {
                "value": p.value,
                "unit": p.unit,
                "lower": p.lower,
                "upper": p.upper,
                "prior_std": p.prior_std,
                "group": p.group,
                "description": p.description,
            }
            for p in self._items.values()
        }

    def to_yaml(self, path: str | Path) -> None:
        Path(path).write_text(yaml.safe_dump({"parameters": self.to_dict()}, sort_keys=False))

    def updated_from_yaml(self, path: str | Path) -> ParameterSet:
        """Apply a YAML file onto this set.

        The file holds a mapping ``parameters:`` whose entries are either a plain number
        (``m: 0.25``) or a full entry (``m: {value: 0.25, lower: ..., ...}``). Names not in
        this set are rejected.
        """
        path = Path(path)
        if path.is_dir():
            raise FieldError(str(path), "is a folder, not a parameter YAML file")
        try:
            document = load_yaml(path.read_text())
        except yaml.YAMLError as error:
            mark = getattr(error, "problem_mark", None)
            where = f" at line {mark.line + 1}" if mark is not None else ""
            problem = getattr(error, "problem", None) or str(error).splitlines()[0]
            raise FieldError(str(path), f"not valid YAML{where} ({problem})") from None
        except OSError as error:
            raise FieldError(str(path), f"cannot read it ({error.strerror or error})") from None
        if not isinstance(document, dict) or not isinstance(document.get("parameters"), dict):
            raise FieldError(str(path), "expected a mapping with key 'parameters'")
        return self.updated_from_mapping(document["parameters"], source=str(path))

    def updated_from_mapping(self, entries: Mapping[str, Any], source: str = "") -> ParameterSet:
        """Apply ``{name: number | {value, lower, upper, prior_std, ...}}`` onto this set."""
        where = f"{source}: " if source else ""
        out = []
        for p in self._items.values():
            if p.name not in entries:
                out.append(p)
                continue
            entry = entries[p.name]
            if entry is None:
                raise ValueError(f"{where}parameter {p.name!r}: has no value")
            if isinstance(entry, Mapping):
                extra = set(entry) - {*_ENTRY_FIELDS, "unit", "group", "description"}
                if extra or not set(entry) & set(_ENTRY_FIELDS):
                    raise ValueError(
                        f"{where}parameter {p.name!r}: unknown field(s) {sorted(map(str, extra))} "
                        f"(known: {', '.join(_ENTRY_FIELDS)}, unit, group, description)"
                    )
                fields: dict[str, Any] = {}  # float values of the numeric fields only
                for key in _ENTRY_FIELDS:
                    if key in entry:
                        fields[key] = _as_float(entry[key], f"{p.name}.{key}", source)
                out.append(replace(p, **fields))
            else:
                out.append(replace(p, value=_as_float(entry, p.name, source)))
        unknown = set(entries) - set(self._items)
        if unknown:
            raise KeyError(f"{where}unknown parameter(s) {sorted(unknown)}")
        return ParameterSet(out)


#: Numeric fields of a full parameter entry in YAML.
_ENTRY_FIELDS = ("value", "lower", "upper", "prior_std")


def wrap_periodic(value: float, period: float) -> float:
    """``value`` moved by whole periods into ``[-period/2, period/2)``."""
    if not math.isfinite(value):
        return value
    return (value + 0.5 * period) % period - 0.5 * period


def _as_float(value: Any, field: str, source: str = "") -> float:
    where = f"{source}: " if source else ""
    if isinstance(value, bool):
        raise ValueError(f"{where}parameter {field!r}: expected a number, got {value!r}")
    try:
        number = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{where}parameter {field!r}: expected a number, got {value!r}") from None
    if not math.isfinite(number):
        raise ValueError(f"{where}parameter {field!r}: must be finite, got {value!r}")
    return number
