"""Moving Lighthouse calibration on a simulated recording with a 20 ms clock offset."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from crs_core.calibration.evaluation import moving_fixes
from crs_core.calibration.moving import calibrate_moving, read_recording
from crs_core.dataset import Dataset
from crs_core.model.lighthouse import RECORDED_BASE_STATION, RECORDED_PHOTODIODES
from sim.mocap_recording import simulate_mocap_recording

OFFSET = 0.02


@pytest.fixture(scope="module")
def recording(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """12 s on the demo track, Lighthouse and motion capture only, saved and reloadable."""
    folder = tmp_path_factory.mktemp("mocap") / "run"
    simulate_mocap_recording(duration=12.0, clock_offset=OFFSET, seed=4).save(folder)
    return folder


def test_recording_without_inputs_imu_or_encoders_loads(recording: Path):
    """No u.npy; NaN wheel and gyro rows; the stream holds only sweeps and poses."""
    assert not (recording / "u.npy").exists()
    dataset = Dataset.load(recording)
    assert dataset.u is None and np.all(np.isnan(dataset.y[:, 8:]))
    assert {m.sensor for m in dataset.measurements} == {"pose", "lighthouse/0/1", "lighthouse/0/2"}


def test_all_nan_inputs_count_as_no_inputs(recording: Path, tmp_path: Path):
    """u.npy filled with NaN (a recording without commands) loads as ``u is None``."""
    copy = tmp_path / "nan_inputs"
    Dataset.load(recording).save(copy)
    np.save(copy / "u.npy", np.full((2, np.load(copy / "t.npy").size), np.nan))
    assert Dataset.load(copy).u is None


def test_offset_and_station_recovered(recording: Path):
    """The 20 ms clock offset within 2 ms, the station within 5 mm and 5 mrad."""
    result = calibrate_moving(Dataset.load(recording), fit_offset=True)
    assert abs(result.offset - OFFSET) < 2e-3
    assert result.offset_std < 1e-3
    station = result.stations[0]
    assert np.linalg.norm(np.array(station.position) - RECORDED_BASE_STATION.position) < 5e-3
    assert np.abs(station.rotation - RECORDED_BASE_STATION.rotation).max() < 5e-3
    rms = float(np.sqrt(np.mean(result.fit.residuals**2)))
    assert 0.8e-3 < rms < 1.3e-3  # the simulated 1 mrad sweep noise
    fixes = moving_fixes(result, limit=200)
    assert fixes.errors.size > 150 and np.median(fixes.errors) < 0.02


def test_ignoring_the_offset_biases_the_station(recording: Path):
    """Without the offset (fixed at 0) the residuals grow: the offset matters."""
    with_offset = calibrate_moving(Dataset.load(recording), fit_offset=False, offset=OFFSET)
    without = calibrate_moving(Dataset.load(recording), fit_offset=False, offset=0.0)
    rms = [float(np.sqrt(np.mean(r.fit.residuals**2))) for r in (with_offset, without)]
    assert rms[1] > 1.5 * rms[0]


def test_photodiodes_fitted_with_a_known_offset(recording: Path):
    """With the offset given, the photodiode positions are recovered within 1.5 mm."""
    result = calibrate_moving(
        Dataset.load(recording), fit_offset=False, offset=OFFSET, fit_photodiodes=True
    )
    error = np.abs(np.array(result.fit.photodiodes) - np.array(RECORDED_PHOTODIODES))
    assert error.max() < 1.5e-3


def test_recording_without_pose_reference_is_refused(recording: Path):
    dataset = Dataset.load(recording)
    dataset.measurements = [m for m in dataset.measurements if m.sensor != "pose"]
    with pytest.raises(ValueError, match=r"^pose: the dataset has no motion-capture pose"):
        read_recording(dataset)
