"""Tests of crs_core.calibration.points: a bad points file names the field."""

from __future__ import annotations

import re

import pytest

from crs_core.calibration.points import points_from_dict
from crs_core.errors import FieldError


@pytest.mark.parametrize(
    ("change", "field"),
    [
        ({"stations": []}, "stations"),
        ({"stations": {"dt1": 0.0}}, "stations"),
        (
            {"points": [{"position": [0, 0], "sweeps": [{"station": -1, "plane1": [[0] * 4]}]}]},
            "points[0].sweeps[0].station",
        ),
        ({"stations": [{"dt1": "x"}]}, "stations[0].dt1"),
        ({"points": [{"position": [0.0]}]}, "points[0].position"),
        ({"points": [{"position": [0.0, 0.0], "sweeps": []}]}, "points[0].sweeps"),
        (
            {"points": [{"position": [0, 0], "sweeps": [{"station": 3, "plane1": [[0] * 4]}]}]},
            "points[0].sweeps[0].station",
        ),
    ],
)
def test_a_bad_points_file_names_the_field(change: dict, field: str):
    data = {"stations": [{}], "points": [{"position": [0.0, 0.0]}], **change}
    with pytest.raises(FieldError, match=rf"^{re.escape(field)}: ") as error:
        points_from_dict(data)
    assert error.value.field == field


def test_without_stations_the_sweeps_name_them():
    """No ``stations`` key: as many stations as the largest index the sweeps name, no tilts;
    and the file written back lists them without tilt offsets."""
    sweep = {"plane1": [[0.1] * 4], "plane2": [[0.2] * 4]}
    data = {
        "points": [
            {"position": [0.0, 0.0], "sweeps": [{"station": 0, **sweep}]},
            {"position": [1.0, 0.0], "sweeps": [{"station": 2, **sweep}]},
        ]
    }
    points = points_from_dict(data)
    assert points.n_stations == 3 and points.tilts == ((None, None),) * 3
    assert points_from_dict(points.to_dict()).tilts == points.tilts
