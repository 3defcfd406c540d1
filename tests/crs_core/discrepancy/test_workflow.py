"""Two effects hidden at once: the workflow names both, with each parameter near its truth,
and the held-out gap shrinks (a real run: about a minute)."""

from __future__ import annotations

import pytest

from crs_core.discrepancy.workflow import DiscrepancySettings, find_discrepancy
from crs_core.identification.problem import FieSettings
from crs_core.model import CarModel
from sim.scenarios import simulate_dataset

pytestmark = pytest.mark.slow

#: The hidden truth: a gyro bias (rad/s) and a steering offset (rad).
TRUTH = {"gyro_bias": {"gyro_bias": 0.06}, "steering_offset": {"steering_offset": 0.04}}


@pytest.fixture(scope="module")
def summary() -> dict:
    truth = CarModel(TRUTH)
    train = simulate_dataset(20, 11, truth, "joystick")
    validation = simulate_dataset(15, 12, truth, "joystick")
    settings = DiscrepancySettings(
        identification=FieSettings(fit=("Cm1", "Df", "Dr", "Iz"), process_scale=0.1),
        candidates=("gyro_bias", "steering_offset", "wheel_radius_error"),
        workers=1,
    )
    return find_discrepancy(train, CarModel(), validation, settings).summary()


def test_both_effects_are_named(summary):
    assert summary["verdict"] == "effect"
    assert sorted(summary["effects"]) == ["gyro_bias", "steering_offset"]


def test_each_parameter_is_within_15_percent(summary):
    for effect, values in TRUTH.items():
        for name, truth in values.items():
            entry = summary["parameters"][effect][name]
            assert entry["value"] == pytest.approx(truth, rel=0.15), (effect, entry)
            assert entry["std"] > 0 and entry["unit"] in ("rad", "rad/s")


def test_the_gap_shrinks(summary):
    assert summary["gap_after"] < 0.8 * summary["gap_before"]
