"""A car that changes while it races: a schedule of changes to the simulated car's truth.

The schedule is YAML, times in seconds since the car applied its first command::

    drift:
      - {parameter: Cm1, from_s: 10, to_s: 100, factor: 0.8}
      - {parameter: Df, at_s: 60, factor: 0.85}
      - {effect: gyro_bias, at_s: 30, value: 0.05}

A change names a model ``parameter`` or an ``effect`` (its one parameter; with several, also
``parameter``), and either ``factor`` (multiplies the car's value at the start) or ``value``
(sets it). A step happens at ``at_s``; a ramp moves linearly from ``from_s`` to ``to_s``.
Changes of the same parameter apply in the order given, each to the value the ones before it
left. An effect the car lacks is switched on at 0 (where every effect is the base model).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import yaml

from crs_core.errors import FieldError
from crs_core.model import CarModel
from crs_core.model.effects import EFFECTS
from crs_core.yaml_io import load_yaml

#: The keys a change may have.
CHANGE_KEYS = ("parameter", "effect", "at_s", "from_s", "to_s", "factor", "value")


@dataclass(frozen=True)
class DriftChange:
    """One change: ``parameter`` (of the effect ``effect``, if named) moves from its value to
    ``factor`` times its value at the start, or to ``value``, between ``start_s`` and
    ``end_s`` (equal for a step)."""

    parameter: str
    effect: str | None
    start_s: float
    end_s: float
    factor: float | None
    value: float | None

    def apply(self, t: float, before: float, initial: float) -> float:
        """The parameter at ``t`` (s since the first command), ``before`` this change and
        ``initial`` at the start."""
        target = self.value if self.value is not None else initial * float(self.factor or 0.0)
        if t < self.start_s:
            return before
        if t >= self.end_s:
            return target
        share = (t - self.start_s) / (self.end_s - self.start_s)
        return before + share * (target - before)


class DriftSchedule:
    """Changes to a car's parameters over time (:func:`load_drift` reads one from YAML)."""

    def __init__(self, changes: tuple[DriftChange, ...]) -> None:
        self.changes = changes
        self.parameters = tuple(dict.fromkeys(c.parameter for c in changes))

    def model_for(self, model: CarModel) -> CarModel:
        """``model`` with the effects the schedule changes switched on (at 0) where it lacks
        them; a parameter the model does not have is refused, naming the change."""
        widened = model.with_effects_at_zero(c.effect for c in self.changes if c.effect)
        for k, change in enumerate(self.changes):
            if change.parameter not in widened.parameters.names:
                raise FieldError(
                    f"drift[{k}].parameter",
                    f"the car has no parameter {change.parameter!r}",
                )
        return widened

    def values_at(self, t: float, initial: Mapping[str, float]) -> dict[str, float]:
        """Every changed parameter at ``t`` (s since the first command), from its ``initial``
        value."""
        values = {name: float(initial[name]) for name in self.parameters}
        for change in self.changes:
            name = change.parameter
            values[name] = change.apply(t, values[name], float(initial[name]))
        return values


def load_drift(path: str | Path) -> DriftSchedule:
    """The schedule in YAML file ``path``; :class:`~crs_core.errors.FieldError` naming the
    entry and key (``drift[2].at_s``) for what is wrong, the file for what cannot be read."""
    try:
        document = load_yaml(Path(path).read_text())
    except OSError as error:
        raise FieldError("drift", f"cannot read {path} ({error.strerror})") from None
    except yaml.YAMLError as error:
        problem = str(error).splitlines()[0]
        raise FieldError("drift", f"{path} is not valid YAML ({problem})") from None
    return parse_drift(document)


def parse_drift(document: Any) -> DriftSchedule:
    """A schedule from its parsed YAML (``{"drift": [change, ...]}``)."""
    if not isinstance(document, dict) or set(document) != {"drift"}:
        raise FieldError("drift", "the file must hold one key, drift: a list of changes")
    entries = document["drift"]
    if not isinstance(entries, list) or not entries:
        raise FieldError("drift", "must be a non-empty list of changes")
    return DriftSchedule(tuple(_change(entry, f"drift[{k}]") for k, entry in enumerate(entries)))


def _change(entry: Any, where: str) -> DriftChange:
    if not isinstance(entry, dict):
        raise FieldError(where, f"must be a mapping of {', '.join(CHANGE_KEYS)}, got {entry!r}")
    unknown = sorted(set(entry) - set(CHANGE_KEYS))
    if unknown:
        raise FieldError(f"{where}.{unknown[0]}", f"unknown key (known: {', '.join(CHANGE_KEYS)})")
    numbers = {key: _number(entry, key, where) for key in CHANGE_KEYS[2:] if key in entry}
    effect = entry.get("effect")
    parameter = entry.get("parameter")
    if effect is not None:
        if effect not in EFFECTS:
            raise FieldError(f"{where}.effect", f"unknown effect {effect!r}")
        names = [p.name for p in EFFECTS[effect].parameters]
        if parameter is None and len(names) != 1:
            raise FieldError(f"{where}.parameter", f"{effect} has {', '.join(names)}: name one")
        parameter = parameter if parameter is not None else names[0]
        if parameter not in names:
            raise FieldError(f"{where}.parameter", f"{effect} has {', '.join(names)}")
    elif not isinstance(parameter, str) or not parameter:
        raise FieldError(f"{where}.parameter", "name a parameter (or an effect)")
    if ("factor" in numbers) == ("value" in numbers):
        raise FieldError(f"{where}.factor", "give exactly one of factor and value")
    if "at_s" in numbers:
        if "from_s" in numbers or "to_s" in numbers:
            raise FieldError(f"{where}.at_s", "a step (at_s) or a ramp (from_s, to_s), not both")
        start = end = numbers["at_s"]
    elif "from_s" in numbers and "to_s" in numbers:
        start, end = numbers["from_s"], numbers["to_s"]
        if not end > start:
            raise FieldError(f"{where}.to_s", f"must be after from_s ({start} s), got {end} s")
    else:
        raise FieldError(f"{where}.at_s", "give at_s (a step) or from_s and to_s (a ramp)")
    if start < 0:
        raise FieldError(f"{where}.{'at_s' if 'at_s' in numbers else 'from_s'}", "must be >= 0")
    return DriftChange(
        str(parameter), effect, start, end, numbers.get("factor"), numbers.get("value")
    )


def _number(entry: Mapping[str, Any], key: str, where: str) -> float:
    value = entry[key]
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        raise FieldError(f"{where}.{key}", f"must be a finite number, got {value!r}")
    return float(value)
