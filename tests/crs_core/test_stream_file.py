"""Tests of crs_core.stream_file: the stream.npz of a dataset, written and read back, and every
malformed part of it named."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from crs_core.dataset import Dataset
from crs_core.errors import FieldError
from crs_core.measurements import InputSample, Measurement
from crs_core.stream_file import read_stream, write_stream
from tests.crs_core.conftest import write_user_recording


@pytest.mark.parametrize(
    ("change", "message"),
    [
        ({"meas:sonar:t": np.zeros(2), "meas:sonar:v": np.zeros((2, 1))}, "unknown sensor 'sonar'"),
        ({"meas:gyro:v": np.zeros((100, 2))}, r"meas:gyro:v expected shape \(100, 1\)"),
        ({"meas:gyro:t": np.zeros((100, 1))}, "meas:gyro:t must be a 1-D numeric array"),
        (
            {"meas:lighthouse__2__1:t": np.zeros(1), "meas:lighthouse__2__1:v": np.zeros((1, 4))},
            "is base station 2, but the geometry has 2",
        ),
        ({"meas:imu:t": np.zeros(3)}, "meas:imu:t has no values meas:imu:v"),
        ({"meas:imu:v": np.zeros((3, 3))}, "meas:imu:v has no stamps meas:imu:t"),
        ({"notes": np.zeros(1)}, "unknown array 'notes'"),
        ({"meas:gyro:v": np.full((100, 1), np.inf)}, "meas:gyro:v contains inf"),
        ({"inputs:u": np.zeros((13, 3))}, r"inputs:u expected shape \(13, 2\)"),
        ({"inputs:u": None}, "inputs:t and inputs:u must come together"),
    ],
)
def test_malformed_stream_is_rejected_naming_the_array(tmp_path: Path, change: dict, message):
    """Every malformed part of a user-written stream.npz is a one-line error naming it."""
    arrays = write_user_recording(tmp_path / "bad")
    for key, value in change.items():
        if value is None:
            del arrays[key]
        else:
            arrays[key] = value
    np.savez(tmp_path / "bad" / "stream.npz", **arrays)
    with pytest.raises(FieldError, match=rf"^stream\.npz: .*{message}") as excinfo:
        Dataset.load(tmp_path / "bad")
    assert "\n" not in str(excinfo.value)
    assert excinfo.value.field == "stream.npz"


def test_unreadable_stream_is_a_one_line_error(corruptible: Path):
    """A stream.npz that is not an archive is rejected naming stream.npz."""
    (corruptible / "stream.npz").write_bytes(b"not a zip file")
    with pytest.raises(FieldError, match=r"^stream\.npz: not a readable \.npz archive") as error:
        Dataset.load(corruptible)
    assert error.value.field == "stream.npz"


def test_truncated_stream_is_a_one_line_error(corruptible: Path):
    data = (corruptible / "stream.npz").read_bytes()
    (corruptible / "stream.npz").write_bytes(data[:1000])
    with pytest.raises(ValueError, match=r"^stream\.npz: not a readable \.npz archive"):
        Dataset.load(corruptible)


def test_measurements_inputs_and_truth_round_trip_sorted_with_missing_rows_skipped(
    tmp_path: Path,
):
    """Written out of order, read back sorted by stamp then sensor; a NaN row of a sensor is a
    missing sample; inputs come back in stamp order and truth as written."""
    measurements = [
        Measurement(0.30, "gyro", [0.3]),
        Measurement(0.10, "wheel_encoders", [1.0, 2.0, 3.0, 4.0]),
        Measurement(0.10, "gyro", [0.1]),
        Measurement(0.20, "lighthouse/1/2", [0.1, 0.2, 0.3, 0.4]),
        Measurement(0.25, "wheel_encoders", [5.0, 6.0, 7.0, 8.0]),
    ]
    inputs = [InputSample(0.2, [0.1, 0.5]), InputSample(0.0, [0.0, 0.4])]
    truth_t, truth_x = np.array([0.0, 0.1]), np.arange(12.0).reshape(2, 6)
    path = tmp_path / "stream.npz"
    write_stream(path, measurements, inputs, truth_t, truth_x)
    with np.load(path) as archive:
        stored = {key: archive[key] for key in archive.files}
    stored["meas:wheel_encoders:v"][1, 2] = np.nan
    np.savez(path, **stored)

    contents = read_stream(path, stations=2)
    assert [(m.stamp, m.sensor) for m in contents.measurements] == [
        (0.10, "gyro"),
        (0.10, "wheel_encoders"),
        (0.20, "lighthouse/1/2"),
        (0.30, "gyro"),
    ]
    np.testing.assert_array_equal(contents.measurements[2].values, [0.1, 0.2, 0.3, 0.4])
    assert contents.inputs is not None
    assert [s.stamp for s in contents.inputs] == [0.0, 0.2]
    np.testing.assert_array_equal(contents.inputs[1].u, [0.1, 0.5])
    np.testing.assert_array_equal(contents.truth_t, truth_t)
    np.testing.assert_array_equal(contents.truth_x, truth_x)


def test_an_empty_stream_has_no_inputs_or_truth(tmp_path: Path):
    path = tmp_path / "stream.npz"
    write_stream(path, None, None)
    contents = read_stream(path, stations=1)
    assert contents.measurements == []
    assert contents.inputs is None and contents.truth_t is None and contents.truth_x is None
