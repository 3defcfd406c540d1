"""Tests of crs_core.estimation.factory: estimators built by kind, input mode and settings."""

import numpy as np
import pytest

from crs_core.estimation import (
    EkfSettings,
    EstimatorNoise,
    MheSettings,
    make_estimator,
)
from tests.crs_core.estimation.conftest import KINDS, _run, _yaw_error


@pytest.mark.parametrize("kind", KINDS)
def test_estimated_inputs_beat_silent_zero_inputs(drive, kind):
    """Without commands, the input-free model (inputs as random-walk states) tracks the yaw far
    better than the commanded model fed nothing (u = 0, the old behaviour)."""
    queries = np.arange(1, 480) / 60.0
    rms = {}
    for mode in ("commanded", "estimated"):
        xs, _ = _run(make_estimator(kind, "lh+imu+we", inputs=mode), drive, queries, False)
        rms[mode] = float(np.sqrt(np.mean(_yaw_error(drive, queries, xs)[queries > 2] ** 2)))
    assert rms["estimated"] < 0.5 * rms["commanded"], rms


def test_settings_are_validated_by_name():
    with pytest.raises(ValueError, match="process_std: needs 6 values"):
        EstimatorNoise(process_std=(0.02,) * 7)
    with pytest.raises(ValueError, match=r"extra_process_std: \['tau'\] are not effect states"):
        make_estimator(
            "ekf", "lh", settings=EkfSettings(noise=EstimatorNoise(extra_process_std={"tau": 1.0}))
        )
    # one setting serves both models of the auto mode (the commanded one lacks these states)
    noise = EstimatorNoise(extra_process_std={"steer_estimated": 0.5})
    bounds = {"steer_estimated": (-0.4, 0.4)}
    make_estimator("mhe", "lh", settings=MheSettings(noise=noise, extra_state_bounds=bounds))
    with pytest.raises(ValueError, match="process_bound: needs 6 values"):
        MheSettings(process_bound=(0.1,) * 8)
    with pytest.raises(ValueError, match="time_offsets: 'lidar' is neither"):
        EkfSettings(time_offsets={"lidar": 0.01})
    with pytest.raises(TypeError, match="settings: a mhe needs MheSettings"):
        make_estimator("mhe", "lh", settings=EkfSettings())
    with pytest.raises(ValueError, match="inputs: must be one of"):
        make_estimator("ekf", "lh", inputs="maybe")
