"""``FieldError``: the field and the reason travel with the error, not inside its text."""

from __future__ import annotations

import pytest

from chronos_bridge.packets import FieldError as BridgeFieldError
from crs_core.dataset import Geometry
from crs_core.errors import FieldError
from crs_core.track import read_track


def test_the_field_and_the_reason_are_attributes_and_make_the_message() -> None:
    error = FieldError("imu.angular_velocity", "contains NaN")
    assert isinstance(error, ValueError)
    assert (error.field, error.reason, str(error)) == (
        "imu.angular_velocity",
        "contains NaN",
        "imu.angular_velocity: contains NaN",
    )
    assert str(error.within("car_state")) == "car_state.imu.angular_velocity: contains NaN"
    assert error.renamed("--x0").field == "--x0" and error.renamed("--x0").reason == "contains NaN"


def test_the_bridge_and_the_core_share_one_error_type() -> None:
    assert BridgeFieldError is FieldError


def test_a_dataset_geometry_names_the_bad_field() -> None:
    station = {
        "rotation": [[1, 0, 0], [0, 1, 0], [0, 0, 1]],
        "position": [0, 0],
        "dt1": 0,
        "dt2": 0,
    }
    with pytest.raises(FieldError) as caught:
        Geometry.from_dict({"base_stations": [station], "photodiodes": [[0, 0]] * 4})
    assert caught.value.field == "geometry.base_stations[0].position"


def test_a_track_file_names_the_yaml_key(tmp_path) -> None:
    path = tmp_path / "track.yaml"
    path.write_text("track:\n  xCoords: [0, 1]\n")
    with pytest.raises(FieldError) as caught:
        read_track(path)
    assert caught.value.field == f"{path}: track.yCoords"
    assert caught.value.reason == "required key missing"
