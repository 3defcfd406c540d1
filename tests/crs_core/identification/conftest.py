"""Fixtures of the identification tests: simulated drives."""

from __future__ import annotations

import pytest

from crs_core.dataset import Dataset
from sim.scenarios import simulate_dataset

DURATION = 15.0


@pytest.fixture(scope="package")
def drives() -> list[Dataset]:
    return [simulate_dataset(DURATION, seed) for seed in (11, 12)]


@pytest.fixture(scope="package")
def drive():
    return simulate_dataset(12.0, 21)
