"""The MPCC's reference path: a smooth, periodic spline through the track's centreline."""

from __future__ import annotations

import numpy as np
import pytest

from crs_core.analysis.angles import wrap_angle
from crs_core.control.reference_path import ReferencePath
from crs_core.track import load_demo_track


@pytest.fixture(scope="module")
def path() -> ReferencePath:
    return ReferencePath(load_demo_track())


def test_the_spline_passes_through_the_samples_with_their_heading(path: ReferencePath) -> None:
    track = path.track
    theta = [path.progress(x, y) for x, y in zip(track.x, track.y, strict=True)]
    point = path.evaluate(theta)
    assert np.max(np.hypot(point.x - track.x, point.y - track.y)) < 1e-6
    assert np.max(np.abs(wrap_angle(point.heading - track.heading))) < 0.02


def test_the_parameter_is_arc_length_and_curvature_the_heading_rate(path: ReferencePath) -> None:
    theta = np.linspace(0.0, path.length, 20000, endpoint=False)
    point = path.evaluate(theta)
    step = np.hypot(np.diff(point.x), np.diff(point.y))
    assert np.max(np.abs(step / np.diff(theta) - 1.0)) < 1e-3
    assert path.length == pytest.approx(path.track.length, rel=1e-3)
    rate = np.gradient(np.unwrap(point.heading), theta)
    assert np.max(np.abs(rate - point.curvature)[5:-5]) < 0.05
    # the demo track's bends have a 0.3 m radius; where a straight meets a bend (a jump in
    # curvature) the interpolating spline overshoots by up to about 20 %
    curvature = np.abs(point.curvature)
    assert np.median(curvature[curvature > 1.0]) == pytest.approx(1 / 0.3, rel=0.01)
    assert np.max(curvature) < 1.2 / 0.3


def test_position_heading_and_curvature_are_continuous_across_the_start_line(
    path: ReferencePath,
) -> None:
    eps = 1e-7
    before, after = path.evaluate(path.length - eps), path.evaluate(path.length + eps)
    assert float(before.x) == pytest.approx(float(after.x), abs=1e-6)
    assert float(before.y) == pytest.approx(float(after.y), abs=1e-6)
    assert float(wrap_angle(before.heading - after.heading)) == pytest.approx(0.0, abs=1e-5)
    assert float(before.curvature) == pytest.approx(float(after.curvature), abs=1e-3)


def test_laps_are_unwrapped_and_positions_repeat(path: ReferencePath) -> None:
    theta = np.array([1.0, 1.0 + path.length, 1.0 - 2 * path.length])
    point = path.evaluate(theta)
    assert np.ptp(point.x) < 1e-12 and np.ptp(point.y) < 1e-12
    x, y = float(point.x[0]), float(point.y[0])
    assert path.progress(x, y) == pytest.approx(1.0, abs=1e-3)
    assert path.progress(x, y, near=1.0 + 3 * path.length) == pytest.approx(
        1.0 + 3 * path.length, abs=1e-3
    )


def test_non_finite_progress_is_refused(path: ReferencePath) -> None:
    with pytest.raises(ValueError, match="theta"):
        path.evaluate([0.0, np.nan])
    with pytest.raises(TypeError, match="track"):
        ReferencePath("DEMO_TRACK")  # type: ignore[arg-type]
