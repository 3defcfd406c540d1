"""Tests of crs_core.track: loading the CRS YAML file, closure, projection, interpolation."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import yaml

from crs_core.analysis.angles import wrap_angle
from crs_core.track import DEMO_TRACK_PATH, Track, load_demo_track, read_track

ORIGINAL_PATH = (
    Path(__file__).resolve().parents[2] / ".." / "shared" / "data" / "tracks" / "DEMO_TRACK.yaml"
)
DEMO_LENGTH = 11.568


@pytest.fixture(scope="module")
def demo() -> Track:
    return load_demo_track()


@pytest.fixture(scope="module")
def original() -> Track:
    if not ORIGINAL_PATH.is_file():
        pytest.skip(f"original track file not found: {ORIGINAL_PATH}")
    return read_track(ORIGINAL_PATH)


@pytest.fixture(params=["compact", "original"])
def track(request: pytest.FixtureRequest) -> Track:
    return request.getfixturevalue("demo" if request.param == "compact" else "original")


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


def test_track_is_closed(track: Track) -> None:
    spacing = float(np.max(np.diff(track.arc_length)))
    gap = math.hypot(track.x[-1] - track.x[0], track.y[-1] - track.y[0])
    assert gap <= 1.01 * spacing
    polyline = float(np.sum(np.hypot(np.diff(track.x), np.diff(track.y)))) + gap
    assert polyline == pytest.approx(track.length, abs=5e-3)
    # Extent from the data README: x within +-1.5 m, y within +-1.05 m.
    assert np.max(np.abs(track.x)) == pytest.approx(1.5, abs=1e-3)
    assert np.max(np.abs(track.y)) == pytest.approx(1.05, abs=1e-3)


def test_curvature_is_positive_counter_clockwise(track: Track) -> None:
    ds = np.diff(np.append(track.arc_length, track.length))
    total_turn = float(np.sum(track.curvature * ds))
    # Driven counter-clockwise: one full positive turn per lap.
    assert total_turn == pytest.approx(2.0 * np.pi, abs=0.1)
    assert np.mean(track.curvature) > 0.0
    assert np.max(np.abs(track.curvature)) == pytest.approx(1.0 / 0.3, rel=1e-3)
    heading = np.unwrap(np.append(track.heading, track.heading[0]))
    assert heading[-1] - heading[0] == pytest.approx(2.0 * np.pi, abs=1e-9)


def test_projection_of_centerline_points_returns_their_arc_length(track: Track) -> None:
    step = max(track.num_points // 200, 1)
    for i in range(0, track.num_points, step):
        p = track.project(track.x[i], track.y[i])
        assert p.s == pytest.approx(track.arc_length[i], abs=1e-9)
        assert p.lateral_error == pytest.approx(0.0, abs=1e-12)
        assert math.cos(p.heading - track.heading[i]) == pytest.approx(1.0, abs=1e-9)
        hinted = track.project(track.x[i], track.y[i], s_hint=track.arc_length[i] + 0.05)
        assert hinted.s == pytest.approx(p.s, abs=1e-9)


def test_projection_between_samples_is_refined(demo: Track) -> None:
    s = 0.5 * (demo.arc_length[3] + demo.arc_length[4])  # on the first straight
    x, y, _, _ = demo.interpolate(s)
    assert demo.project(float(x), float(y)).s == pytest.approx(s, abs=1e-9)


@pytest.mark.parametrize("offset", [0.1, -0.1])
def test_lateral_error_is_positive_to_the_left(track: Track, offset: float) -> None:
    step = max(track.num_points // 100, 1)
    for i in range(0, track.num_points, step):
        normal = (-math.sin(track.heading[i]), math.cos(track.heading[i]))
        px = track.x[i] + offset * normal[0]
        py = track.y[i] + offset * normal[1]
        for hint in (None, track.arc_length[i]):
            p = track.project(px, py, s_hint=hint)
            assert p.lateral_error == pytest.approx(offset, abs=1e-3)
            gap = abs(
                (p.s - track.arc_length[i] + 0.5 * track.length) % track.length - 0.5 * track.length
            )
            assert gap < 0.05


def test_hint_far_from_the_car_falls_back_to_global_search(demo: Track) -> None:
    i = demo.num_points // 2
    p = demo.project(demo.x[i], demo.y[i], s_hint=demo.arc_length[i] + 3.0)
    assert p.s == pytest.approx(demo.arc_length[i], abs=1e-9)


def test_interpolation_wraps_and_heading_is_continuous(track: Track) -> None:
    s = np.linspace(0.0, track.length, 1001)
    x0, y0, h0, k0 = track.interpolate(s)
    for shift in (-2.0 * track.length, track.length, 3.0 * track.length):
        x1, y1, h1, k1 = track.interpolate(s + shift)
        np.testing.assert_allclose(x1, x0, atol=1e-9)
        np.testing.assert_allclose(y1, y0, atol=1e-9)
        np.testing.assert_allclose(np.cos(h1 - h0), 1.0, atol=1e-9)
        np.testing.assert_allclose(k1, k0, atol=1e-9)
    # Arc length ``length`` is the start point again.
    assert (x0[-1], y0[-1]) == pytest.approx((track.x[0], track.y[0]))
    # The heading changes by at most curvature * ds between close samples (no 2 pi jumps).
    dh = np.abs(wrap_angle(np.diff(h0)))
    assert np.max(dh) < 0.2
    assert np.all((h0 >= -np.pi) & (h0 < np.pi))
    # Scalars give 0-d arrays.
    xs, _, _, _ = track.interpolate(0.0)
    assert np.ndim(xs) == 0


def test_interpolation_rejects_non_finite(demo: Track) -> None:
    with pytest.raises(ValueError, match="s:"):
        demo.interpolate([0.0, np.nan])


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


def test_progress_unwrapped(demo: Track) -> None:
    progress = 3.0 + np.linspace(0.0, 30.0, 3001)
    unwrapped = demo.progress_unwrapped(progress % demo.length)
    np.testing.assert_allclose(unwrapped, progress, atol=1e-9)
