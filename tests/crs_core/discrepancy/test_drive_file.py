"""Tests of drive.yaml and the drive's controller (crs_core.discrepancy.drive_file)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import yaml

from crs_core.discrepancy.drive_file import (
    Drive,
    DriveController,
    DriveLimits,
    drive_from_dict,
    load_drive,
)
from crs_core.errors import FieldError
from crs_core.track import load_demo_track


def _drive(**changes) -> Drive:
    fields = {
        "duration_s": 2.0,
        "segment_s": 0.5,
        "v_ref": 1.0,
        "steer_offset": (0.1, -0.1, 0.2, 0.0),
        "torque_offset": (0.0, 0.3, -0.2, 0.0),
        "open": ("Dr", "Br"),
        "start": (0.15, -1.05, 0.0, 1.0),
    }
    return Drive(**{**fields, **changes})


def test_a_drive_file_reads_back_as_written(tmp_path: Path) -> None:
    drive = _drive()
    assert load_drive(drive.save(tmp_path / "drive.yaml")) == drive


def test_offsets_are_held_per_segment_and_end_with_the_drive() -> None:
    drive = _drive()
    assert drive.offsets(0.6) == (-0.1, 0.3)
    assert drive.offsets(1.99) == (0.0, 0.0)
    assert drive.offsets(2.0) == (0.0, 0.0) and drive.offsets(-0.1) == (0.0, 0.0)


@pytest.mark.parametrize(
    ("change", "field"),
    [
        ({"format": "other"}, "format"),
        ({"v_ref": "fast"}, "v_ref"),
        ({"steer_offset": [0.1, 0.2]}, "steer_offset"),
        ({"torque_offset": [0.0, 0.1, float("nan"), 0.0]}, "torque_offset[2]"),
        ({"start": {"x": 0.0, "y": 0.0, "yaw": 0.0}}, "start.vx"),
        ({"limits": {"steer_max": 2.0}}, "limits.steer_max"),
        ({"limits": {"brake": 1.0}}, "limits.brake"),
        ({"kind": "random"}, "kind"),
    ],
)
def test_a_bad_drive_file_names_the_field(tmp_path: Path, change, field) -> None:
    document = {**_drive().to_dict(), **change}
    path = tmp_path / "drive.yaml"
    path.write_text(yaml.safe_dump(document))
    with pytest.raises(FieldError) as caught:
        load_drive(path)
    assert caught.value.field == f"{path}: {field}"


def test_a_file_that_is_no_drive_is_refused(tmp_path: Path) -> None:
    with pytest.raises(FieldError, match="expected a mapping"):
        drive_from_dict([1, 2])
    path = tmp_path / "bad.yaml"
    path.write_text("a: [1, 2\n")
    with pytest.raises(FieldError, match="not valid YAML"):
        load_drive(path)


def test_the_controller_adds_the_offsets_to_the_follower_and_clips() -> None:
    track = load_demo_track()
    drive = _drive(limits=DriveLimits(steer_max=0.3, torque_min=-0.2, torque_max=0.8))
    plain = DriveController(_drive(steer_offset=(0.0,) * 4, torque_offset=(0.0,) * 4), track, 0.09)
    excited = DriveController(drive, track, 0.09, t_start=10.0)
    x = track.start_state(1.0)
    follower = plain(10.6, x)
    command = excited(10.6, x)
    assert command[0] == pytest.approx(np.clip(follower[0] - 0.1, -0.3, 0.3))
    assert command[1] == pytest.approx(np.clip(follower[1] + 0.3, -0.2, 0.8))
    assert not excited.done(11.9) and excited.done(12.0)
    assert abs(excited.lateral_error) < 1e-6


def test_a_drive_begins_at_speed_and_stops_the_car_off_the_track() -> None:
    track = load_demo_track()
    drive = _drive()
    controller = DriveController(drive, track, 0.09, t_start=None)
    controller(0.0, track.start_state(0.2))
    assert controller.t_start is None  # getting up to speed behind the follower
    elsewhere = track.start_state(1.0)
    elsewhere[0] += 0.5  # half a metre down the straight from where the drive begins
    controller(0.5, elsewhere)
    assert controller.t_start is None
    controller(1.0, track.start_state(0.95))
    assert controller.t_start == 1.0
    off = track.start_state(1.0)
    off[1] += 0.3  # 0.3 m left of the centreline, the track is 0.46 m wide
    assert np.all(controller(1.1, off) == 0.0) and controller.stopped
    assert np.all(controller(1.2, track.start_state(1.0)) == 0.0)


def test_a_lead_in_races_before_the_drive() -> None:
    track = load_demo_track()
    controller = DriveController(_drive(), track, 0.09, t_start=None, lead_in_s=5.0)
    at_speed = track.start_state(1.0)
    controller(10.0, at_speed)
    controller(14.9, at_speed)
    assert controller.t_start is None
    controller(15.0, at_speed)
    assert controller.t_start == 15.0
    with pytest.raises(FieldError, match="lead_in_s"):
        DriveController(_drive(), track, 0.09, lead_in_s=-1.0)
