"""Settings whose bounds are declared once, on their fields.

A field of a settings dataclass states its bound where it states its default, and
:class:`Settings` checks every such field when the dataclass is built (and again whenever it is
rebuilt, e.g. by :func:`dataclasses.replace`)::

    @dataclass(frozen=True)
    class RealtimeSettings(Settings):
        rate_hz: float = positive(60.0)
        lag: float = non_negative(0.02)
        share: float = within(0.5, low=0, high=1, high_open=True)

The field constructors :func:`finite`, :func:`positive`, :func:`non_negative` and :func:`within`
are :func:`dataclasses.field` with a :class:`Bound` in the field's metadata; :func:`check_bounds`
checks each bounded field of a dataclass instance with the shared checks of
:mod:`crs_core.errors` (so the messages are theirs: ``"lag: must be a finite number >= 0, got
-1"``, a :class:`~crs_core.errors.FieldError` naming the field). A rule between fields
(``empty_voltage < full_voltage``) or on a field that is not a plain number goes in
:meth:`Settings._check_relations`, which runs after the bounds. Nested settings that name their
fields with a dotted path (``health.window_s``) say so once: ``class
HealthSettings(Settings, prefix="health")``; settings that store their bounded fields as
``float`` (an ``int`` or numpy number given is converted once checked) say ``floats=True``.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import MISSING, dataclass
from types import SimpleNamespace
from typing import Any, ClassVar

from crs_core.errors import (
    FieldError,
    require_finite,
    require_non_negative,
    require_positive,
    require_within,
)

__all__ = [
    "Bound",
    "Settings",
    "bound_of",
    "check_bounds",
    "finite",
    "non_negative",
    "positive",
    "within",
]

#: Key of a field's :class:`Bound` in its metadata.
BOUND_KEY = "crs_core.bound"

#: The kinds of :class:`Bound`, each checked by its helper of :mod:`crs_core.errors`.
KINDS = ("finite", "positive", "non_negative", "within")


@dataclass(frozen=True)
class Bound:
    """What a settings field's value must be: a finite real number (not a bool) in an interval.

    Attributes
    ----------
    kind : {"finite", "positive", "non_negative", "within"}
        Which check of :mod:`crs_core.errors` applies (and so the wording of its error).
    low, high : float
        Ends of the interval, in the field's unit (``-inf`` / ``inf``: open on that side).
    low_open, high_open : bool
        Whether ``low`` / ``high`` itself is excluded.
    unit : str
        Unit named in the message of a ``within`` bound (``"s"``; empty: none).
    """

    kind: str
    low: float = -math.inf
    high: float = math.inf
    low_open: bool = False
    high_open: bool = False
    unit: str = ""

    def __post_init__(self) -> None:
        if self.kind not in KINDS:
            raise ValueError(f"kind: one of {', '.join(KINDS)}, got {self.kind!r}")
        if not self.low < self.high:
            raise ValueError(f"low: must be below high ({self.high!r}), got {self.low!r}")

    def check(self, settings: object, name: str, prefix: str = "") -> None:
        """Attribute ``name`` of ``settings`` is within this bound, else
        :class:`~crs_core.errors.FieldError` naming it (``prefix.name`` with a ``prefix``)."""
        if self.kind == "finite":
            require_finite(settings, name, prefix=prefix)
        elif self.kind == "positive":
            require_positive(settings, name, prefix=prefix)
        elif self.kind == "non_negative":
            require_non_negative(settings, name, prefix=prefix)
        else:
            require_within(
                settings,
                name,
                self.low,
                self.high,
                low_open=self.low_open,
                high_open=self.high_open,
                unit=self.unit,
                prefix=prefix,
            )

    def requirement(self) -> str:
        """What the bound asks of a value, in the words of its error: ``"a finite number > 0"``,
        ``"within [0, 1) s"`` (e.g. a ROS parameter's constraints)."""
        try:  # None is outside every bound: the check words its reason
            self.check(SimpleNamespace(value=None), "value")
        except FieldError as error:
            return error.reason.removeprefix("must be ").removesuffix(", got None")
        raise AssertionError("None passed a bound")


def _bounded(default: Any, bound: Bound) -> Any:
    """A dataclass field with ``default`` (``MISSING``: none) and ``bound`` in its metadata."""
    return dataclasses.field(default=default, metadata={BOUND_KEY: bound})


def finite(default: Any = MISSING) -> Any:
    """A dataclass field (default ``default``, none if not given) that must be a finite number."""
    return _bounded(default, Bound("finite"))


def positive(default: Any = MISSING) -> Any:
    """A dataclass field (default ``default``, none if not given) that must be a finite
    number > 0."""
    return _bounded(default, Bound("positive", low=0.0, low_open=True))


def non_negative(default: Any = MISSING) -> Any:
    """A dataclass field (default ``default``, none if not given) that must be a finite
    number >= 0."""
    return _bounded(default, Bound("non_negative", low=0.0))


def within(
    default: Any = MISSING,
    *,
    low: float,
    high: float,
    low_open: bool = False,
    high_open: bool = False,
    unit: str = "",
) -> Any:
    """A dataclass field (default ``default``, none if not given) that must be a finite number
    from ``low`` to ``high`` (each end included unless ``low_open`` / ``high_open``); ``unit``
    is named in the error (``"share: must be within [0, 1) s, got 1.0"``)."""
    return _bounded(default, Bound("within", low, high, low_open, high_open, unit))


def bound_of(item: dataclasses.Field[Any]) -> Bound | None:
    """The :class:`Bound` declared on a dataclass field, ``None`` if it has none."""
    bound = item.metadata.get(BOUND_KEY)
    return bound if isinstance(bound, Bound) else None


def check_bounds(settings: object, prefix: str = "") -> None:
    """Check every bounded field of the dataclass instance ``settings``, in field order.

    Raises
    ------
    FieldError
        For the first field out of its bound, named ``prefix.name`` with a ``prefix``.
    """
    for item in dataclasses.fields(settings):  # type: ignore[arg-type]  # TypeError if not one
        bound = bound_of(item)
        if bound is not None:
            bound.check(settings, item.name, prefix)


class Settings:
    """Base of a settings dataclass whose fields declare their bounds (module docstring).

    Building the dataclass (its ``__init__``, hence :func:`dataclasses.replace` too) runs
    :meth:`validate`: :func:`check_bounds` over every field of the class and its bases, then
    :meth:`_check_relations`. Works with frozen and mutable dataclasses; a subclass that also
    needs ``__post_init__`` (to normalise a value) calls ``super().__post_init__()`` in it.
    The class keyword ``prefix`` names the fields ``prefix.name`` in the errors; ``floats=True``
    stores every bounded field as ``float`` once it passed its check (both inherited).
    """

    __slots__ = ()

    #: Prefix of the field names in the errors (``"health"``: ``health.window_s``).
    field_prefix: ClassVar[str] = ""
    #: Whether the bounded fields are stored as ``float`` once checked (``floats=True``).
    bounded_floats: ClassVar[bool] = False

    def __init_subclass__(
        cls, *, prefix: str | None = None, floats: bool | None = None, **kwargs: Any
    ) -> None:
        super().__init_subclass__(**kwargs)
        if prefix is not None:
            cls.field_prefix = prefix
        if floats is not None:
            cls.bounded_floats = floats

    def __post_init__(self) -> None:
        self.validate()
        if self.bounded_floats:
            for item in dataclasses.fields(self):  # type: ignore[arg-type]  # a dataclass
                if bound_of(item) is not None:  # checked: a finite real number
                    object.__setattr__(self, item.name, float(getattr(self, item.name)))

    def validate(self) -> None:
        """Check the declared bounds, then the rules between fields.

        Raises
        ------
        FieldError
            Naming the first field out of its bound, or the field a rule refuses.
        """
        check_bounds(self, self.field_prefix)
        self._check_relations()

    def _check_relations(self) -> None:
        """Rules the bounds cannot state (between fields, on counts, on choices); raise
        :class:`~crs_core.errors.FieldError` naming the field. Runs after the bounds, so each
        bounded field is a finite number here. A subclass calls ``super()._check_relations()``
        to keep its bases' rules."""
