"""Tests of ``crs bench models``' pieces (the whole run takes minutes: not here)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from benchmarks.models import RAMP_STEER, departure, plot
from crs_core.model import CarModel


def test_the_departure_drive_shows_the_kinematic_model_turning_by_its_geometry(tmp_path: Path):
    """On the ramp drive the kinematic model's yaw rate is tan(delta)/L per unit speed at every
    sample; the dynamic one's agrees at walking pace, follows the linear single track's
    understeer while the tyres are linear, and falls far below the kinematic one's at speed."""
    result = departure()
    P = CarModel().parameters.value
    length = P("lf") + P("lr")
    kinematic, dynamic = result["kinematic"], result["dynamic"]
    speed, rate = np.asarray(kinematic["speed"]), np.asarray(kinematic["yaw_rate"])
    beta = np.arctan(P("lr") * np.tan(RAMP_STEER) / length)
    np.testing.assert_allclose(rate, speed * np.cos(beta) * np.tan(RAMP_STEER) / length, rtol=1e-3)
    d_speed, d_rate = np.asarray(dynamic["speed"]), np.asarray(dynamic["yaw_rate"])
    linear = np.asarray(result["linear_single_track"]["yaw_rate"])
    slow = d_speed < 0.6
    kinematic_there = d_speed * np.cos(beta) * np.tan(RAMP_STEER) / length
    assert np.all(np.abs(d_rate[slow][2:] / kinematic_there[slow][2:] - 1) < 0.1)
    assert np.all(np.abs(d_rate[slow][2:] / linear[slow][2:] - 1) < 0.05)
    fast = d_speed > 1.8
    assert fast.any() and np.all(d_rate[fast] < 0.6 * kinematic_there[fast])
    plot({"departure": result}, tmp_path / "models.png")
    assert (tmp_path / "models.png").stat().st_size > 10_000
