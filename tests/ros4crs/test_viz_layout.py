"""The live view's Foxglove layout: the shipped file is the one :func:`live_layout` builds, and
every topic and message path it reads is one the visualizer serves (a field of its schema)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest

from crs_core.track import load_demo_track
from ros4crs import viz_scene
from ros4crs.viz_layout import layout_json, live_layout
from ros4crs.viz_scene import SCENE_CHANNEL, status_channel

SHIPPED = Path(__file__).resolve().parents[2] / "docs" / "foxglove" / "chronos-layout.json"
TRACK = load_demo_track()


def message_paths(content: dict[str, Any]) -> list[str]:
    """Every topic or message path a layout (its parsed JSON) reads: the 3D panels' topics,
    the series' ``value`` and the raw panels' ``topicPath``, in layout order."""
    paths: list[str] = []
    if content.get("type") == "panel":
        config = content.get("config", {})
        paths += list(config.get("topics", {}))
        paths += [series["value"] for series in config.get("paths", [])]
        paths += [config["topicPath"]] if "topicPath" in config else []
    for item in content.get("items", []):
        paths += message_paths(item["content"])
    if "content" in content:
        paths += message_paths(content["content"])
    return paths


def test_the_shipped_layout_is_the_built_one() -> None:
    built = layout_json(live_layout(("car1", "car2"), TRACK))
    assert SHIPPED.read_text() == built, (
        "docs/foxglove/chronos-layout.json is stale: crs viz --layout FILE writes it"
    )


@pytest.mark.parametrize("cars", [("car1",), ("car1", "car2", "car7")])
def test_every_path_of_the_layout_is_served_by_the_visualizer(cars: tuple[str, ...]) -> None:
    layout = json.loads(layout_json(live_layout(cars, TRACK)))
    assert layout["version"] == 1 and layout["content"]["type"] == "split"
    paths = message_paths(layout["content"])
    status_fields = set(viz_scene.STATUS_SCHEMA["properties"])
    assert paths[0] == SCENE_CHANNEL
    for path in paths[1:]:
        topic, _, field = path.partition(".")
        assert topic in {status_channel(car) for car in cars}, path
        assert not field or field in status_fields, path
    for car in cars:  # each car's status, solve time and laps
        for field in ("status", "solve_ms", "laps"):
            assert f"{status_channel(car)}.{field}" in paths


def test_the_3d_view_looks_down_on_the_whole_track() -> None:
    layout = json.loads(layout_json(live_layout(("car1",), TRACK)))
    scene = layout["content"]["items"][0]["content"]
    assert scene["panelType"] == "ThreeDee"
    camera = scene["config"]["cameraState"]
    assert camera["phi"] == 0.0 and camera["perspective"] is False
    x, y, _ = camera["target"]
    assert TRACK.x.min() < x < TRACK.x.max() and TRACK.y.min() < y < TRACK.y.max()
    assert camera["distance"] > max(TRACK.x.max() - TRACK.x.min(), TRACK.y.max() - TRACK.y.min())


def test_a_layout_needs_a_car() -> None:
    with pytest.raises(ValueError, match="cars"):
        live_layout((), TRACK)
