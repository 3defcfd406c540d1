"""Tests of crs_core.track.geometry: closure, curvature, projection, interpolation."""

from __future__ import annotations

import math

import numpy as np
import pytest

from crs_core.analysis.angles import wrap_angle
from crs_core.track import Track


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


def test_progress_unwrapped(demo: Track) -> None:
    progress = 3.0 + np.linspace(0.0, 30.0, 3001)
    unwrapped = demo.progress_unwrapped(progress % demo.length)
    np.testing.assert_allclose(unwrapped, progress, atol=1e-9)


def test_the_start_state_stands_on_the_centreline_heading_along_it(track: Track) -> None:
    state = track.start_state(0.7)
    np.testing.assert_array_equal(
        state, [track.start_x, track.start_y, track.start_yaw, 0.7, 0.0, 0.0]
    )
    projection = track.project(state[0], state[1])
    assert abs(projection.lateral_error) < 0.02  # the demo track starts on its centreline
    assert track.start_state() is not track.start_state()  # a new array each call
    assert track.start_state()[3] == 0.0
