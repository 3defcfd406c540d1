"""Tests of crs_core.discrepancy.figures: the numbers of the report's tables and figures.

That the three figures are drawn and written is checked with the whole report
(test_report.py)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from crs_core.discrepancy.figures import format_number


@pytest.mark.parametrize(
    ("value", "form", "text"),
    [
        (0.012345, ".3g", "0.0123"),
        (12.5, "+.1f", "+12.5"),
        (-3.0, "+.1f", "-3.0"),
        (2.5e-7, ".2g", "2.5e-07"),
        (0.25, "g", "0.25"),
        (7, "d", "7"),
        (np.float64(0.5), ".2f", "0.50"),
    ],
)
def test_a_number_is_formatted_with_the_given_form(value, form: str, text: str) -> None:
    assert format_number(value, form) == text


@pytest.mark.parametrize("value", [None, math.nan, math.inf, -math.inf])
def test_a_missing_or_non_finite_number_reads_not_available(value) -> None:
    assert format_number(value, "+.1f") == "n/a"
