"""Fixtures of the track tests: the packaged demo track and the original two-lap file."""

from __future__ import annotations

from pathlib import Path

import pytest

from crs_core.track import Track, load_demo_track, read_track

ORIGINAL_PATH = (
    Path(__file__).resolve().parents[3] / ".." / "shared" / "data" / "tracks" / "DEMO_TRACK.yaml"
)


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
