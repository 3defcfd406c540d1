"""The one error of every boundary: a bad value, and the field it came in.

Every boundary of the suite (a ROS message or parameter, a datagram from a car, a file, a YAML
key, a command-line option) rejects a bad value with a :class:`FieldError`: ``field`` names where
the value came from (a dotted path such as ``geometry.base_stations[0].position``, a parameter or
an option), ``reason`` says what is wrong with it, and the message is ``"<field>: <reason>"``. It
is a ``ValueError``, so callers that catch those keep working; a caller that knows the field by
another name (a YAML key for a dataclass field, a command-line option for a function argument)
renames it with :meth:`FieldError.renamed` instead of taking the message apart.
"""

from __future__ import annotations

__all__ = ["FieldError"]


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
