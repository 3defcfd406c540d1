"""The one error of every boundary: a bad value, and the field it came in.

Every boundary of the suite (a ROS message or parameter, a datagram from a car, a file, a YAML
key, a command-line option) rejects a bad value with a :class:`FieldError`: ``field`` names where
the value came from (a dotted path such as ``geometry.base_stations[0].position``, a parameter or
an option), ``reason`` says what is wrong with it, and the message is ``"<field>: <reason>"``. It
is a ``ValueError``, so callers that catch those keep working; a caller that knows the field by
another name (a YAML key for a dataclass field, a command-line option for a function argument)
renames it with :meth:`FieldError.renamed` instead of taking the message apart.

The checks that settings classes repeat (each of these fields a finite number, > 0, >= 0, within
an interval) are written once here: :func:`require_finite`, :func:`require_positive`,
:func:`require_non_negative` and :func:`require_within` check attributes of a settings object by
name, :func:`finite_number` one value, and each raises a :class:`FieldError` naming the field.
A settings dataclass declares them on its fields instead (:mod:`crs_core.settings`), which runs
these same checks.
Parsers of text that word their own errors read a number with :func:`parse_finite`.
"""

from __future__ import annotations

import math
from numbers import Real

__all__ = [
    "FieldError",
    "finite_number",
    "parse_finite",
    "require_finite",
    "require_non_negative",
    "require_positive",
    "require_within",
]


class FieldError(ValueError):
    """A malformed value; ``field`` is where it came from, ``reason`` what is wrong."""

    def __init__(self, field: str, reason: str) -> None:
        super().__init__(f"{field}: {reason}")
        self.field = field
        self.reason = reason

    def within(self, prefix: str) -> FieldError:
        """The same error with ``prefix.`` in front of the field path."""
        return FieldError(f"{prefix}.{self.field}", self.reason)

    def renamed(self, field: str) -> FieldError:
        """The same error naming ``field`` instead (e.g. the YAML key of a dataclass field)."""
        return FieldError(field, self.reason)


def _path(prefix: str, name: str) -> str:
    return f"{prefix}.{name}" if prefix else name


def _real(value: object) -> float | None:
    """``value`` as a float if it is a finite real number (not a bool), else ``None``."""
    if isinstance(value, bool) or not isinstance(value, Real):
        return None
    number = float(value)
    return number if math.isfinite(number) else None


def finite_number(field: str, value: object) -> float:
    """``value`` as a float: a finite real number (a bool is not one); else :class:`FieldError`
    ``"<field>: must be a finite number, got <value>"``."""
    number = _real(value)
    if number is None:
        raise FieldError(field, f"must be a finite number, got {value!r}")
    return number


def parse_finite(text: object) -> float | None:
    """``text`` as a float if it reads as a finite number (``float(text)``), else ``None`` (not a
    number, or nan or inf): the caller says what was wrong, in its own words."""
    try:
        number = float(text)  # type: ignore[arg-type]  # anything float() refuses is None
    except (TypeError, ValueError):
        return None
    return number if math.isfinite(number) else None


def require_finite(obj: object, *names: str, prefix: str = "") -> None:
    """Each attribute ``names`` of ``obj`` is a finite real number; else :class:`FieldError`
    naming the first that is not (``prefix.name`` with a ``prefix``, e.g. a settings block)."""
    for name in names:
        finite_number(_path(prefix, name), getattr(obj, name))


def require_positive(obj: object, *names: str, prefix: str = "") -> None:
    """Each attribute ``names`` of ``obj`` is a finite number > 0; else :class:`FieldError`
    ``"<name>: must be a finite number > 0, got <value>"`` for the first that is not."""
    for name in names:
        value = getattr(obj, name)
        number = _real(value)
        if number is None or not number > 0:
            raise FieldError(_path(prefix, name), f"must be a finite number > 0, got {value!r}")


def require_non_negative(obj: object, *names: str, prefix: str = "") -> None:
    """Each attribute ``names`` of ``obj`` is a finite number >= 0; else :class:`FieldError`
    ``"<name>: must be a finite number >= 0, got <value>"`` for the first that is not."""
    for name in names:
        value = getattr(obj, name)
        number = _real(value)
        if number is None or not number >= 0:
            raise FieldError(_path(prefix, name), f"must be a finite number >= 0, got {value!r}")


def require_within(
    obj: object,
    name: str,
    low: float,
    high: float,
    *,
    low_open: bool = False,
    high_open: bool = False,
    unit: str = "",
    prefix: str = "",
) -> None:
    """Attribute ``name`` of ``obj`` is a finite number in the interval from ``low`` to ``high``
    (closed unless ``low_open`` / ``high_open``); else :class:`FieldError`
    ``"<name>: must be within [low, high] <unit>, got <value>"``."""
    value = getattr(obj, name)
    number = _real(value)
    above = number is not None and (number > low if low_open else number >= low)
    below = number is not None and (number < high if high_open else number <= high)
    if not (above and below):
        interval = f"{'(' if low_open else '['}{low:g}, {high:g}{')' if high_open else ']'}"
        raise FieldError(
            _path(prefix, name),
            f"must be within {interval}{f' {unit}' if unit else ''}, got {value!r}",
        )
