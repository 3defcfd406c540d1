"""The visualizer's scene, frames, status and page JSON, built from plain values (no ROS)."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from crs_core.errors import FieldError
from crs_core.estimation.base import OnlineValue
from crs_core.track import load_demo_track
from ros4crs import viz_scene
from ros4crs.viz_scene import CarView, CarWatch

TRACK = load_demo_track()


def _covariance(position: list[list[float]]) -> list[float]:
    P = np.zeros((6, 6))
    P[:2, :2] = position
    return P.ravel().tolist()


def _on_track(s: float) -> np.ndarray:
    x, y, heading, _ = TRACK.interpolate(s)
    return np.array([float(x), float(y), float(heading), 1.0, 0.0, 0.0])


def test_a_car_is_none_until_its_first_estimate_then_ok_then_lost_when_it_stops_coming():
    watch = CarWatch("car1", TRACK)
    first = watch.view(0.0)
    assert (first.status, first.reason, first.estimate) == ("none", "no estimate yet", None)
    watch.estimate(10.0, 100.0, _on_track(1.0), "ok", None)
    view = watch.view(10.1)
    assert (view.status, view.reason) == ("ok", "")
    np.testing.assert_allclose(view.estimate, _on_track(1.0)[:3])
    lost = watch.view(10.0 + viz_scene.STALE_AFTER + 0.1)
    assert lost.status == "lost" and lost.reason.startswith("no estimate for 0.6 s")
    assert lost.estimate is None and len(lost.plan) == 0
    watch.diagnostics("lost: waiting for a Lighthouse fix", 2)
    lost = watch.view(12.0)
    assert (lost.reason, lost.deadline_misses) == ("waiting for a Lighthouse fix", 2)


@pytest.mark.parametrize(
    ("age", "estimate", "estimator", "expected"),
    [
        (None, None, "lost: blind start", ("none", "blind start")),
        (
            0.1,
            "degraded",
            "degraded: no Lighthouse for 0.6 s",
            ("degraded", "no Lighthouse for 0.6 s"),
        ),
        (0.1, "degraded", None, ("degraded", "estimate degraded")),
        (0.1, "ok", "degraded: stale", ("ok", "")),
        (1.0, "ok", "ok", ("lost", "no estimate for 1.0 s")),
    ],
)
def test_the_status_and_its_reason(age, estimate, estimator, expected):
    assert viz_scene.car_status(age, estimate, estimator) == expected


def test_laps_are_counted_on_the_track_and_restart_when_the_stamps_go_back():
    watch = CarWatch("car1", TRACK)
    stamp = 0.0
    for s in np.arange(0.0, TRACK.length, 0.05):  # from the line (a crossing) once round
        watch.estimate(stamp, stamp, _on_track(s), "ok", None)
        stamp += 0.05
    watch.estimate(stamp, stamp, _on_track(0.01), "ok", None)
    view = watch.view(stamp)
    assert view.laps == 1 and view.last_lap_s == pytest.approx(TRACK.length, abs=0.1)
    watch.estimate(stamp, 1.0, _on_track(0.5), "ok", None)  # a replay that looped
    assert watch.view(stamp).laps == 0


def test_the_position_covariance_is_checked_at_the_boundary():
    assert viz_scene.position_covariance([0.0] * 36) is None
    block = viz_scene.position_covariance(_covariance([[4e-4, 1e-4], [1e-4, 1e-4]]))
    np.testing.assert_allclose(block, [[4e-4, 1e-4], [1e-4, 1e-4]])
    for bad, reason in (
        ([0.0] * 35, "36 finite values"),
        ([math.nan] + [0.0] * 35, "36 finite values"),
        (_covariance([[1e-4, 1e-4], [0.0, 1e-4]]), "not symmetric"),
        (_covariance([[1e-4, 0.0], [0.0, -1e-4]]), "not positive"),
    ):
        with pytest.raises(FieldError, match=f"covariance: .*{reason}"):
            viz_scene.position_covariance(bad)


def _view(**fields) -> CarView:
    base = dict(
        name="car1",
        status="ok",
        reason="",
        estimate=np.array([1.0, 2.0, 0.5]),
        covariance=np.diag([1e-4, 1e-4]),
        truth=np.array([1.01, 2.0, 0.5]),
        plan=np.array([[1.0, 2.0], [1.2, 2.1], [1.4, 2.3]]),
        reference=np.array([[1.0, 1.9], [1.2, 2.0], [1.4, 2.2], [1.6, 2.4]]),
        fixes=np.array([[1.0, 2.01, 0.5], [1.02, 2.0, 0.52]]),
        laps=3,
        last_lap_s=6.4321,
        solve_ms=4.56789,
        deadline_misses=1,
        parameters={"Cm1": OnlineValue(0.2912345678, 0.0123, True)},
    )
    return CarView(**{**base, **fields})


def _decoded(message, name: str):
    """A foxglove message encoded and decoded again with its own protobuf schema."""
    from google.protobuf import descriptor_pb2, descriptor_pool, message_factory

    schema = message.get_schema()
    pool = descriptor_pool.DescriptorPool()
    for file in descriptor_pb2.FileDescriptorSet.FromString(schema.data).file:
        pool.Add(file)
    decoded = message_factory.GetMessageClass(pool.FindMessageTypeByName(name))
    return decoded.FromString(message.encode())


def test_the_scene_draws_each_car_with_what_it_has():
    scene = _decoded(
        viz_scene.cars_scene([_view(), _view(name="car2", estimate=None, truth=None)], 5.0),
        "foxglove.SceneUpdate",
    )
    car1, car2 = scene.entities
    assert (car1.id, car1.frame_id, car1.timestamp.seconds) == ("car1", "world", 5)
    estimate, truth = car1.cubes
    assert (estimate.pose.position.x, estimate.pose.position.y) == (1.0, 2.0)
    assert estimate.pose.orientation.z == pytest.approx(math.sin(0.25))
    assert (estimate.size.x, estimate.size.y) == pytest.approx(viz_scene.CAR_SIZE)
    assert truth.color.a < estimate.color.a
    ellipse, plan, reference, ticks = car1.lines
    assert len(ellipse.points) == viz_scene.ELLIPSE_POINTS and len(plan.points) == 3
    assert len(reference.points) == 4 and reference.color != plan.color
    # each Lighthouse fix: a dot at its position, a tick from there along its heading
    dots = [(d.pose.position.x, d.pose.position.y) for d in car1.spheres]
    assert dots == [(1.0, 2.01), (1.02, 2.0)]
    tick = viz_scene.FIX_SIZE[1]
    start, end = ticks.points[2], ticks.points[3]
    assert (start.x, start.y) == (1.02, 2.0)
    assert (end.x - start.x, end.y - start.y) == pytest.approx(
        (tick * math.cos(0.52), tick * math.sin(0.52))
    )
    # the plan, its reference and the fixes only
    assert (car2.id, len(car2.cubes), len(car2.lines), len(car2.spheres)) == ("car2", 0, 3, 2)
    bare = _decoded(
        viz_scene.cars_scene([_view(fixes=np.zeros((0, 3)))], 5.0), "foxglove.SceneUpdate"
    )
    assert len(bare.entities[0].spheres) == 0 and len(bare.entities[0].lines) == 3


def test_lighthouse_fixes_are_shown_for_half_a_second_after_they_arrive():
    watch = CarWatch("car1", TRACK)
    watch.lighthouse_fix(10.0, np.array([1.0, 2.0, 0.1]))
    watch.lighthouse_fix(10.3, np.array([1.1, 2.0, 0.2]))
    np.testing.assert_allclose(watch.view(10.4).fixes, [[1.0, 2.0, 0.1], [1.1, 2.0, 0.2]])
    later = watch.view(10.0 + viz_scene.FIX_MEMORY + 0.01)
    np.testing.assert_allclose(later.fixes, [[1.1, 2.0, 0.2]])
    assert watch.view(11.0).fixes.shape == (0, 3)


def test_the_track_scene_holds_both_borders_and_the_centreline():
    (track,) = _decoded(viz_scene.track_scene(TRACK, 0.0), "foxglove.SceneUpdate").entities
    assert track.id == "track" and len(track.lines) == 3
    assert all(len(line.points) == TRACK.num_points for line in track.lines)


def test_frames_only_of_cars_with_an_estimate():
    frames = _decoded(
        viz_scene.frame_transforms([_view(), _view(name="car2", estimate=None)], 1.5),
        "foxglove.FrameTransforms",
    )
    (transform,) = frames.transforms
    assert (transform.parent_frame_id, transform.child_frame_id) == ("world", "car1/base_link")
    assert (transform.translation.x, transform.translation.y) == (1.0, 2.0)


def _valid(value, schema) -> None:
    """A small JSON-schema check (types, enums, required keys, items) of the schemas here."""
    types = {
        "object": dict,
        "array": list,
        "string": str,
        "number": (int, float),
        "null": type(None),
        "boolean": bool,
    }
    types["integer"] = int
    kinds = schema["type"] if isinstance(schema["type"], list) else [schema["type"]]
    assert any(isinstance(value, types[k]) for k in kinds), (value, schema)
    if "enum" in schema:
        assert value in schema["enum"]
    if isinstance(value, dict):
        assert set(schema["required"]) <= set(value), set(schema["required"]) - set(value)
        for key, item in value.items():
            _valid(item, schema["properties"][key])
    if isinstance(value, list) and "items" in schema:
        for item in value:
            _valid(item, schema["items"])


def test_the_status_and_the_page_json_follow_their_schemas():
    views = [
        _view(),
        _view(name="car2", status="none", reason="no estimate yet", estimate=None, parameters={}),
    ]
    status = viz_scene.status_json(views[0])
    assert status == {
        "status": "ok",
        "reason": "",
        "laps": 3,
        "last_lap_s": 6.432,
        "solve_ms": 4.568,
        "deadline_misses": 1,
        "parameters": [{"name": "Cm1", "value": 0.291235, "std": 0.0123, "informed": True}],
    }
    cars = viz_scene.page_cars_json(views, 12.25)
    assert cars["stamp"] == 12.25
    car1, car2 = cars["cars"]
    assert car1["estimate"] == [1.0, 2.0, 0.5] and car1["plan"][1] == [1.2, 2.1]
    assert car1["fixes"] == [[1.0, 2.01, 0.5], [1.02, 2.0, 0.52]]
    assert car1["size"] == list(viz_scene.CAR_SIZE) and car2["estimate"] is None
    assert car1["parameters"] == status["parameters"] and car2["parameters"] == []
    track = viz_scene.page_track_json(TRACK)
    assert len(track["centre"]) == len(track["left"]) == len(track["right"]) == TRACK.num_points
    for value, schema in (
        (status, viz_scene.STATUS_SCHEMA),
        (cars, viz_scene.PAGE_CARS_SCHEMA),
        (track, viz_scene.PAGE_TRACK_SCHEMA),
    ):
        _valid(json.loads(json.dumps(value, allow_nan=False)), schema)
