"""SimulationResult.to_dataset: samples at the plane-2 sweeps with the exact truth, only where both
planes of a rotation were received."""

from __future__ import annotations

import numpy as np

from crs_core.dataset import Y_CHANNELS
from crs_core.measurements import lighthouse_sensor
from crs_core.model import CarModel
from crs_core.model.lighthouse import RECORDED_BASE_STATION
from sim import SimulationResult
from tests.sim.sim_runs import DRIVE_DURATION, model_outputs, truth_index


def test_to_dataset_samples_at_plane2_sweeps_with_exact_truth(
    ideal_drive: SimulationResult, base_model: CarModel
):
    """Samples sit at station-0 plane-2 stamps, pair both planes' angles and hold exact truth."""
    data = ideal_drive.to_dataset()
    t1, a1 = ideal_drive.measurements_of(lighthouse_sensor(0, 1))
    t2, a2 = ideal_drive.measurements_of(lighthouse_sensor(0, 2))
    assert t2.size == round(50 * DRIVE_DURATION)
    np.testing.assert_array_equal(data.t, t2)
    np.testing.assert_array_equal(data.y[:, 4:8], a2)
    np.testing.assert_array_equal(data.y[:, :4], a1)  # each plane-1 sweep precedes its plane 2
    np.testing.assert_allclose(t2 - t1, 0.01, rtol=0, atol=1e-12)
    assert data.y.shape == (t2.size, len(Y_CHANNELS))
    np.testing.assert_allclose(
        data.x, ideal_drive.truth_x[truth_index(ideal_drive, data.t)], rtol=0, atol=1e-12
    )
    u = np.array([0.1, 0.3])
    np.testing.assert_array_equal(data.u, np.tile(u, (t2.size, 1)))
    # plane 2 is swept at the stamp, plane 1 half a rotation (10 ms) earlier
    plane2 = model_outputs(base_model, data.x, u, lighthouse_sensor(0, 2))
    np.testing.assert_allclose(data.y[:, 4:8], plane2, rtol=0, atol=1e-9)
    x_plane1 = ideal_drive.truth_x[truth_index(ideal_drive, t1)]
    plane1 = model_outputs(base_model, x_plane1, u, lighthouse_sensor(0, 1))
    np.testing.assert_allclose(data.y[:, :4], plane1, rtol=0, atol=1e-9)
    # wheel speeds and yaw rate are the 250 Hz streams interpolated to the stamp
    wheels = model_outputs(base_model, data.x, u, "wheel_encoders")
    np.testing.assert_allclose(data.y[:, 8:12], wheels, rtol=0, atol=0.01)
    np.testing.assert_allclose(data.y[:, 12], data.x[:, 5], rtol=0, atol=1e-3)
    station = data.geometry.base_stations[0]
    np.testing.assert_allclose(station.angles, RECORDED_BASE_STATION.angles, atol=1e-12)
    assert data.meta["truth"]["effects"] == []
    assert data.meta["truth"]["parameters"]["r"] == base_model.parameters.value("r")
    assert data.measurements is ideal_drive.measurements


def test_to_dataset_keeps_only_rotations_with_both_planes(rest_run: SimulationResult):
    """With drop-outs, a sample exists exactly where plane 1 of the same rotation was received."""
    data = rest_run.to_dataset()
    t1, a1 = rest_run.measurements_of(lighthouse_sensor(0, 1))
    t2, a2 = rest_run.measurements_of(lighthouse_sensor(0, 2))
    partner = np.searchsorted(t1, t2) - 1
    complete = (partner >= 0) & (t2 - t1[np.maximum(partner, 0)] < 0.015)
    assert 0.85 * t2.size < complete.sum() < t2.size
    np.testing.assert_array_equal(data.t, t2[complete])
    np.testing.assert_array_equal(data.y[:, :4], a1[partner[complete]])
    np.testing.assert_array_equal(data.y[:, 4:8], a2[complete])
    assert np.all(np.isfinite(data.y))
