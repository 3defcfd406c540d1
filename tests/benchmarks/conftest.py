"""Fixtures of the benchmark tests shared by more than one file."""

from __future__ import annotations

import pytest

from benchmarks.robust_estimation import timing_robustness_rows


@pytest.fixture(scope="session")
def timing_rows():
    return timing_robustness_rows((0,), duration=4.0)
