"""Fixtures of the simulator tests: the model compiles once and the runs are shared."""

from __future__ import annotations

import pytest

from crs_core.model import CarModel
from sim import SimulationResult, Simulator
from tests.sim.sim_runs import AT_REST, DRIVE, DRIVE_DURATION, IDEAL, NOISY, REST, REST_DURATION


@pytest.fixture(scope="session")
def base_model() -> CarModel:
    return CarModel()


@pytest.fixture(scope="session")
def rest_run(base_model: CarModel) -> SimulationResult:
    return Simulator(base_model, NOISY, seed=7).run(REST, REST_DURATION, AT_REST)


@pytest.fixture(scope="session")
def ideal_drive(base_model: CarModel) -> SimulationResult:
    return Simulator(base_model, IDEAL, seed=0).run(DRIVE, DRIVE_DURATION, AT_REST)
