"""Tests of crs_core.track.yaml_file: loading the CRS YAML file and naming what is wrong in it."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import yaml

from crs_core.errors import FieldError
from crs_core.track import DEMO_TRACK_PATH, Track, read_track

DEMO_LENGTH = 11.568


def _circle_document(n: int = 40, radius: float = 1.0) -> dict:
    theta = np.arange(n) * 2.0 * np.pi / n
    return {
        "track": {
            "xCoords": (radius * np.cos(theta)).tolist(),
            "yCoords": (radius * np.sin(theta)).tolist(),
            "tangentAngle": (theta + 0.5 * np.pi).tolist(),
            "arcLength": (radius * theta).tolist(),
            "curvature": [1.0 / radius] * n,
            "trackLength": 2.0 * np.pi * radius,
            "trackWidth": 0.5,
            "width_of_track": 0.4,
            "x_init": radius,
            "y_init": 0.0,
            "yaw_init": 0.5 * np.pi,
        }
    }


def _write(tmp_path: Path, document: dict) -> Path:
    path = tmp_path / "track.yaml"
    path.write_text(yaml.safe_dump(document), encoding="utf-8")
    return path


def test_packaged_track_loads(demo: Track) -> None:
    assert DEMO_TRACK_PATH.is_file()
    assert (DEMO_TRACK_PATH.parent / "LICENSE-data.txt").is_file()
    assert demo.num_points == 347  # every 10th of the 3466 samples of one lap
    assert demo.length == pytest.approx(DEMO_LENGTH, abs=1e-3)
    assert demo.width == pytest.approx(0.46)
    assert (demo.start_x, demo.start_y, demo.start_yaw) == pytest.approx((0.15, -1.05, 0.0))
    assert demo.arc_length[0] == 0.0
    assert demo.arc_length[-1] < demo.length
    assert np.all(np.abs(demo.heading) <= np.pi)


def test_original_loads_one_lap_and_matches_compact(demo: Track, original: Track) -> None:
    # The original file holds two laps (6932 samples); one lap is kept.
    assert original.num_points == 3466
    assert original.length == pytest.approx(DEMO_LENGTH, abs=1e-3)
    assert abs(demo.length - original.length) < 1e-3
    np.testing.assert_allclose(demo.x, original.x[::10], atol=1e-6)
    np.testing.assert_allclose(demo.y, original.y[::10], atol=1e-6)
    np.testing.assert_allclose(demo.arc_length, original.arc_length[::10], atol=1e-6)


def test_circle_track_loads(tmp_path: Path) -> None:
    track = read_track(_write(tmp_path, _circle_document()))
    assert track.length == pytest.approx(2.0 * np.pi)
    # Inside the circle, i.e. left of a counter-clockwise loop; the closest point of the
    # 40-gon is on a chord next to the sample at s = pi / 2.
    p = track.project(0.0, 0.5)
    assert p.s == pytest.approx(0.5 * np.pi, abs=0.1)
    assert p.lateral_error == pytest.approx(0.5, abs=1e-2)


@pytest.mark.parametrize(
    ("mutate", "field"),
    [
        (lambda t: t.pop("curvature"), "curvature"),
        (lambda t: t.pop("trackLength"), "trackLength"),
        (lambda t: t.__setitem__("yCoords", t["yCoords"][:-1]), "yCoords"),
        (lambda t: t["tangentAngle"].__setitem__(5, float("nan")), "tangentAngle"),
        (lambda t: t["xCoords"].__setitem__(2, "a"), "xCoords"),
        (lambda t: t.__setitem__("width_of_track", float("inf")), "width_of_track"),
        (lambda t: t.__setitem__("x_init", "left"), "x_init"),
        (lambda t: t["arcLength"].__setitem__(3, 0.0), "arcLength"),
        (lambda t: t.__setitem__("trackLength", 7.0), "trackLength"),
        (lambda t: t.__setitem__("width_of_track", -0.1), "width_of_track"),
    ],
)
def test_validation_names_the_field(tmp_path: Path, mutate, field: str) -> None:
    document = _circle_document()
    mutate(document["track"])
    with pytest.raises(ValueError, match=field):
        read_track(_write(tmp_path, document))


def test_too_few_points_is_rejected(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="at least 10"):
        read_track(_write(tmp_path, _circle_document(n=8)))


def test_open_centerline_is_rejected(tmp_path: Path) -> None:
    document = _circle_document()
    for key in ("xCoords", "yCoords", "tangentAngle", "arcLength", "curvature"):
        document["track"][key] = document["track"][key][:30]  # three quarters of the circle
    with pytest.raises(ValueError, match="not closed"):
        read_track(_write(tmp_path, document))


def test_missing_track_mapping_is_rejected(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="track"):
        read_track(_write(tmp_path, {"something": 1}))


def test_a_track_file_names_the_yaml_key(tmp_path) -> None:
    path = tmp_path / "track.yaml"
    path.write_text("track:\n  xCoords: [0, 1]\n")
    with pytest.raises(FieldError) as caught:
        read_track(path)
    assert caught.value.field == f"{path}: track.yCoords"
    assert caught.value.reason == "required key missing"
