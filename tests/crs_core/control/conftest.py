"""Fixtures of the control tests."""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np
import pytest

from crs_core.track import Track, load_demo_track


@pytest.fixture(scope="module")
def track() -> Track:
    """The demo track (the real one of the recordings)."""
    return load_demo_track()


@pytest.fixture(scope="module")
def pose_at() -> Callable[[Track, float, float, float], np.ndarray]:
    """``pose_at(track, s, lateral, heading_offset)``: a standing car's state at arc length ``s``
    (m), ``lateral`` m left of the centreline, turned ``heading_offset`` rad left of the track's
    direction."""

    def pose(track: Track, s: float, lateral: float, heading_offset: float) -> np.ndarray:
        x, y, heading, _ = (float(v[0]) for v in track.interpolate(np.array([s])))
        return np.array(
            [
                x - lateral * math.sin(heading),
                y + lateral * math.cos(heading),
                heading + heading_offset,
                0.0,
                0.0,
                0.0,
            ]
        )

    return pose
