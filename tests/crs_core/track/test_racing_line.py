"""Tests of crs_core.track.racing_line: the minimum-curvature line within a track's borders."""

from __future__ import annotations

import math

import numpy as np
import pytest

from crs_core.errors import FieldError
from crs_core.track import Track, load_demo_track, minimum_curvature_line


def _circle(radius: float, points: int = 400) -> Track:
    """A counter-clockwise circle 0.4 m wide."""
    angle = np.linspace(0.0, 2 * math.pi, points, endpoint=False)
    return Track(
        x=radius * np.cos(angle),
        y=radius * np.sin(angle),
        heading=angle + math.pi / 2,
        arc_length=radius * angle,
        curvature=np.full(points, 1 / radius),
        length=2 * math.pi * radius,
        width=0.4,
        start_x=radius,
        start_y=0.0,
        start_yaw=math.pi / 2,
    )


def test_on_a_circle_the_line_is_the_shorter_inner_circle() -> None:
    """A circle of radius 1 m, 0.15 m either side: at the centreline's spacing a shorter line
    has smaller second differences, so the line is the inner circle all along (the module's
    documented lean; corner speeds drawn from it err on the slow side)."""
    line = minimum_curvature_line(_circle(1.0), 0.15)
    assert np.allclose(line.offset, 0.15, atol=2e-3)
    assert np.allclose(line.curvature, 1 / 0.85, rtol=2e-2)


def test_the_demo_hairpins_open_up_within_the_borders() -> None:
    """The demo track (hairpins of centreline radius 0.3 m): the line stays within its bound,
    swings out on the straights before the hairpins, and its squared curvature sums to
    less than 0.7 of the centreline's (0.6 on this track)."""
    track = load_demo_track()
    line = minimum_curvature_line(track, 0.17)
    _, _, _, centre = track.interpolate(line.s)
    assert np.max(np.abs(line.offset)) <= 0.17 + 1e-9
    assert np.min(line.offset) < -0.15  # out to the border on the long straight
    assert np.sum(line.curvature**2) < 0.7 * np.sum(np.asarray(centre) ** 2)


@pytest.mark.parametrize(
    ("field", "kwargs"),
    [("max_offset", {"max_offset": 0.3}), ("step", {"max_offset": 0.1, "step": 0.0})],
)
def test_bad_arguments_name_the_field(field: str, kwargs: dict) -> None:
    with pytest.raises(FieldError) as caught:
        minimum_curvature_line(_circle(1.0), **kwargs)
    assert caught.value.field == field
