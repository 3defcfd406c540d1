"""Argument types and texts shared by the ``crs`` commands (one-line errors naming the value)."""

from __future__ import annotations

import argparse
import math
from collections.abc import Callable
from typing import Any

OVERWRITE_HELP = (
    "replace an --out folder written by an earlier crs run (a folder holding other files is "
    "always refused)"
)


def argument_type(parse: Callable[[str], Any]) -> Callable[[str], Any]:
    """An argparse type from a parser raising ``ValueError`` (its message, one line)."""

    def parse_argument(text: str) -> Any:
        try:
            return parse(text)
        except ValueError as error:
            raise argparse.ArgumentTypeError(str(error)) from None

    parse_argument.__name__ = parse.__name__
    return parse_argument


def bounded_number(
    name: str,
    unit: str,
    low: float,
    high: float = math.inf,
    kind: type = float,
    *,
    include_low: bool = False,
) -> Callable[[str], Any]:
    """An argparse type: a finite ``kind`` in ``(low, high]`` (``[low, high]`` with
    ``include_low``), the error naming ``name``: ``'0': stations must be >= 1 and <= 8``."""

    def parse(text: str) -> Any:
        try:
            value = kind(text)
        except ValueError:
            what = "an integer" if kind is int else "a number"
            raise argparse.ArgumentTypeError(f"{text!r} is not {what}") from None
        above = value >= low if include_low else value > low
        if not (math.isfinite(value) and above and value <= high):
            bounds = f"{name} must be {'>=' if include_low else '>'} {low:g}"
            if math.isfinite(high):
                bounds += f" and <= {high:g}"
            raise argparse.ArgumentTypeError(f"{text!r}: {bounds} {unit}".rstrip())
        return value

    parse.__name__ = name
    return parse
