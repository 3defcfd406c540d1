"""The visualizer node in a running 1-car simulated stack, watched by a plain ``websockets``
client speaking the Foxglove protocol (subprotocol ``foxglove.sdk.v1``), as the Foxglove app
does: it reads ``serverInfo`` and the ``advertise`` messages, subscribes to every channel and
decodes what arrives (the protobuf channels with the schema the server advertises, the JSON
channels with ``json.loads``, a passthrough channel's CDR with rclpy)."""

from __future__ import annotations

import asyncio
import base64
import json
import time
from collections import defaultdict
from collections.abc import Iterator
from typing import Any

import numpy as np
import pytest

from benchmarks.foxglove_viewer import watch
from crs_core.track import load_demo_track
from launch_scripts.sim_stack import StackOptions, stack_nodes
from launch_scripts.visualizer import VizSettings
from tests.integration.browser import check_track_and_moving_car, needs_chromium, two_screenshots
from tests.integration.stack_probe import launched, wait_for

pytestmark = pytest.mark.integration

DOMAIN = 172
PORT, PAGE_PORT = 18711, 18712
#: Where ``crs viz`` serves, next to the stack's own visualizer.
ALONE_PORT, ALONE_PAGE_PORT = 18713, 18714
#: Give up after this long (the nodes start in ~5 s, the car then moves at once).
TIMEOUT_S = 60.0
#: How far the drawn car must have moved along the track, m.
MOVED_M = 0.5
TRACK = load_demo_track()
#: Topics whose passthrough the client must see.
PASSED = (
    "/car1/input",
    "/car1/ground_truth",
    "/car1/controller/plan",
    "/car1/controller/reference",
    "/car1/lighthouse_fix",
)
#: Lighthouse fixes the client waits for (4 s of them at 5 a second: the truth passed through
#: around a fix's stamp is missing near the ends of the window and in its gaps, which left 4 of
#: 10 fixes comparable in one fresh clone's run), how many of them must have the truth around
#: them, and how close to it they must be (median, m): a fix is one station's sweep pair, its
#: planes swept up to 20 ms apart while the car moves (~1 cm).
FIXES, COMPARED_FIXES, FIX_ERROR_M = 20, 5, 0.03


def _decoder(channel: dict[str, Any]) -> Any:
    """The protobuf message class of an advertised protobuf channel (from its schema)."""
    from google.protobuf import descriptor_pb2, descriptor_pool, message_factory

    files = descriptor_pb2.FileDescriptorSet.FromString(base64.b64decode(channel["schema"]))
    pool = descriptor_pool.DescriptorPool()
    for file in files.file:
        pool.Add(file)
    return message_factory.GetMessageClass(pool.FindMessageTypeByName(channel["schemaName"]))


class Viewer:
    """What one client saw: the channels by topic, each channel's decoded messages."""

    def __init__(self) -> None:
        self.info: dict[str, Any] = {}
        self.channels: dict[str, dict[str, Any]] = {}
        self.messages: dict[str, list[Any]] = defaultdict(list)

    def done(self) -> bool:
        """Whether it saw everything the test asserts (car1 moving, its plan, its status ok,
        the page's track, the passthrough of its input, truth and plan)."""
        return (
            self.moved() > MOVED_M
            and "/viz/page/track" in self.messages
            and any(len(c["plan"]) > 5 for m in self.messages["/viz/page/cars"] for c in m["cars"])
            and any(m["status"] == "ok" for m in self.messages["/viz/car1/status"])
            and all(self.messages[topic] for topic in PASSED)
            and len(self.messages["/car1/lighthouse_fix"]) >= FIXES
        )

    def moved(self) -> float:
        """How far car1's footprint on ``/viz/scene`` moved along the track, m."""
        poses = [
            (cube.pose.position.x, cube.pose.position.y)
            for scene in self.messages["/viz/scene"]
            for entity in scene.entities
            if entity.id == "car1" and entity.cubes
            for cube in entity.cubes[:1]
        ]
        if len(poses) < 2:
            return 0.0
        start, end = (TRACK.project(*poses[i]).s for i in (0, -1))
        return (end - start + TRACK.length / 2) % TRACK.length - TRACK.length / 2


async def _watch(viewer: Viewer, deadline: float, until: Any, port: int = PORT) -> None:
    """Read ``viewer``'s connection to ``port`` until ``until()`` or ``deadline``, subscribed to
    every channel advertised, decoding what arrives (protobuf with the advertised schema, JSON,
    passthrough CDR kept as bytes)."""
    decoders: dict[str, Any] = {}

    def take(channel: dict[str, Any], payload: bytes) -> None:
        topic = channel["topic"]
        if channel["encoding"] == "protobuf":
            decoder = decoders.get(topic) or decoders.setdefault(topic, _decoder(channel))
            viewer.messages[topic].append(decoder.FromString(payload))
        elif channel["encoding"] == "json":
            viewer.messages[topic].append(json.loads(payload))
        else:
            viewer.messages[topic].append(payload)

    def info(message: dict[str, Any]) -> None:
        viewer.info = message

    def advertised(channel: dict[str, Any]) -> None:
        viewer.channels[channel["topic"]] = channel

    await watch(f"ws://127.0.0.1:{port}", deadline, take, until, info, advertised)


async def _two_viewers(deadline: float) -> tuple[Viewer, Viewer]:
    """The first viewer watches until the car has moved; a second one connects once the first
    has a car on the scene, subscribes to the scene and every passthrough channel for a second,
    and closes mid-stream."""
    first, second = Viewer(), Viewer()
    watching = asyncio.create_task(_watch(first, deadline, first.done))
    while not first.messages["/viz/scene"] and time.monotonic() < deadline:
        await asyncio.sleep(0.2)
    stop = time.monotonic() + 1.0
    await _watch(second, min(stop, deadline), lambda: False)
    await watching
    return first, second


def _seen_car1(viewer: Viewer) -> bool:
    return any(
        c["name"] == "car1" and c["estimate"] is not None
        for m in viewer.messages["/viz/page/cars"]
        for c in m["cars"]
    )


@pytest.fixture(scope="module")
def race(tmp_path_factory: pytest.TempPathFactory, warm_codegen: None) -> Iterator[tuple]:
    """The 1-car stack with the visualizer, racing (``launcher``, ``probe``, the estimates the
    probe collects), for both tests of this module."""
    from chronos_msgs.msg import CarState

    out = tmp_path_factory.mktemp("visualizer")
    viz = VizSettings(port=PORT, page_port=PAGE_PORT)
    nodes = stack_nodes(1, StackOptions("ekf", viz=viz), out / "bag")
    with launched(nodes, DOMAIN, out / "logs") as (launcher, probe):
        estimates = probe.collect(CarState, "/car1/estimate/state")
        launcher.start()
        yield launcher, probe, estimates


def test_a_foxglove_client_watches_the_race_and_others_come_and_go(race) -> None:
    """``crs launch sim --viz``'s nodes: the client sees the track, car1 moving along it, car1's
    status ``ok``, the page's JSON and the suite's topics passed through (not the sensor
    streams); the server lets it do nothing but subscribe. A second client that connects and
    closes mid-stream disturbs nothing, nor does ``crs viz`` started alone (it finds car1 in the
    graph) and stopped with Ctrl-C: no node dies, and the estimates keep coming."""
    import signal
    import subprocess
    import sys

    from rclpy.serialization import deserialize_message

    from chronos_msgs.msg import CarState

    launcher, _, estimates = race
    first, second = asyncio.run(_two_viewers(time.monotonic() + TIMEOUT_S))
    command = ["viz", "--port", str(ALONE_PORT), "--page-port", str(ALONE_PAGE_PORT)]
    alone = subprocess.Popen(
        [sys.executable, "-m", "launch_scripts.cli", *command, "--domain", str(DOMAIN)],
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
    )
    third = Viewer()
    deadline = time.monotonic() + 20.0
    asyncio.run(_watch(third, deadline, lambda: _seen_car1(third), ALONE_PORT))
    # each page connects to its own node's WebSocket port (neither is 8765), no ?ws= needed
    alone_page = _page_ws_port(f"http://127.0.0.1:{ALONE_PAGE_PORT}/")
    alone.send_signal(signal.SIGINT)
    output = alone.communicate(timeout=10)[0]
    assert alone.returncode == 0, output
    assert _seen_car1(third), f"crs viz did not find car1:\n{output}"
    assert alone_page == ALONE_PORT
    assert _page_ws_port(f"http://127.0.0.1:{PAGE_PORT}/") == PORT
    before = len(estimates)
    time.sleep(1.0)
    assert len(estimates) > before + 10, "the estimates stopped after the second client"
    assert launcher.poll() == []

    assert first.info["capabilities"] == []  # no publishing, services or parameters
    assert first.moved() > MOVED_M, f"car1 did not move {MOVED_M} m on /viz/scene"
    track = [e for s in first.messages["/viz/scene"] for e in s.entities if e.id == "track"]
    assert track and len(track[0].lines) == 3
    # car1: its ellipse, the MPCC's plan and the plan's progress reference on the centreline
    # (and the ticks of its Lighthouse fixes when there are some)
    car1 = [e for s in first.messages["/viz/scene"] for e in s.entities if e.id == "car1"]
    assert any(len(e.lines) >= 3 for e in car1), [len(e.lines) for e in car1[-5:]]
    statuses = [m["status"] for m in first.messages["/viz/car1/status"]]
    assert "ok" in statuses, statuses[-5:]
    page_track = first.messages["/viz/page/track"][-1]
    assert len(page_track["centre"]) > 10 and len(page_track["left"]) == len(page_track["centre"])
    cars = [c for m in first.messages["/viz/page/cars"] for c in m["cars"]]
    assert any(c["name"] == "car1" and c["estimate"] is not None for c in cars)
    assert any(len(c["plan"]) > 5 for c in cars), "no MPCC plan on the page's JSON"
    assert first.channels["/tf"]["schemaName"] == "foxglove.FrameTransforms"
    transforms = [t for m in first.messages["/tf"] for t in m.transforms]
    assert any(t.child_frame_id == "car1/base_link" for t in transforms)
    passed = first.channels["/car1/estimate/state"]
    assert (passed["encoding"], passed["schemaEncoding"]) == ("cdr", "ros2msg")
    assert passed["schemaName"] == "chronos_msgs/msg/CarState"
    state = deserialize_message(first.messages["/car1/estimate/state"][-1], CarState)
    assert np.isfinite(state.x) and state.header.frame_id == "world"
    for topic in PASSED:
        assert first.messages[topic], f"nothing passed through on {topic}"
    _check_fixes(first)
    assert "/car1/estimate/diagnostics" in first.channels
    assert not [t for t in first.channels if "/sensors/" in t or t == "/rosout"]
    assert second.messages["/viz/scene"], "the second client got nothing"


def _serves(url: str) -> bool:
    """Whether an HTTP GET of ``url`` answers 200."""
    import urllib.error
    import urllib.request

    try:
        with urllib.request.urlopen(url, timeout=1.0) as reply:
            return reply.status == 200
    except (urllib.error.URLError, OSError):
        return False


def _page_ws_port(url: str) -> int | None:
    """The WebSocket port the page at ``url`` connects to unless told ``?ws=``: the one its
    server wrote into ``<meta name="crs-ws-port">``; ``None`` when there is none."""
    import re
    import urllib.request

    with urllib.request.urlopen(url, timeout=5.0) as reply:
        found = re.search(rb'<meta name="crs-ws-port" content="(\d+)">', reply.read())
    return int(found[1]) if found else None


def _check_fixes(viewer: Viewer) -> None:
    """car1's Lighthouse fixes: drawn on the scene, and where the simulator's truth was at the
    fix's stamp (interpolated between the passed-through truth messages)."""
    from geometry_msgs.msg import PoseWithCovarianceStamped
    from rclpy.serialization import deserialize_message

    from chronos_msgs.msg import CarState
    from ros4crs import conversions

    scenes = [e for s in viewer.messages["/viz/scene"] for e in s.entities if e.id == "car1"]
    assert any(e.spheres for e in scenes), "no Lighthouse fix drawn for car1"
    truth = sorted(
        conversions.state_from_msg(deserialize_message(data, CarState))
        for data in viewer.messages["/car1/ground_truth"]
    )
    times = np.array([t for t, _ in truth])
    xy = np.array([x[:2] for _, x in truth])
    errors = []
    for data in viewer.messages["/car1/lighthouse_fix"]:
        stamp, pose = conversions.pose_fix_from_msg(
            deserialize_message(data, PoseWithCovarianceStamped)
        )
        k = int(np.searchsorted(times, stamp))
        if 0 < k < len(times) and times[k] - times[k - 1] < 0.1:  # truth on both sides
            at = [np.interp(stamp, times[k - 1 : k + 1], xy[k - 1 : k + 1, i]) for i in (0, 1)]
            errors.append(float(np.hypot(*(pose[:2] - at))))
    assert len(errors) >= COMPARED_FIXES, f"{len(errors)} fixes with truth around them"
    assert np.median(errors) < FIX_ERROR_M, sorted(errors)


@needs_chromium
def test_the_built_in_page_shows_the_race_in_a_browser(race, tmp_path) -> None:
    """Headless Chromium on the visualizer's page (``http://127.0.0.1:PAGE_PORT/``, no ``?ws=``:
    the page connects to the WebSocket port the node was started with, PORT, not 8765):
    the screenshots show the demo track and car1, moving."""
    launcher, _, estimates = race
    # the page's server first: a page Chromium loads from a server not up yet is its error page,
    # which no retry of the suite's page reloads (the module's first test runs on a stack up)
    wait_for(lambda: _serves(f"http://127.0.0.1:{PAGE_PORT}/"), TIMEOUT_S, "the page's server")
    since = len(estimates)
    try:
        first, second = two_screenshots(f"http://127.0.0.1:{PAGE_PORT}/", tmp_path / "profile")
        (tmp_path / "first.png").write_bytes(first)
        (tmp_path / "second.png").write_bytes(second)
        check_track_and_moving_car(first, second, TRACK)
    except AssertionError as error:  # was it the page, or did the car stop?
        xy = [(m.x, m.y) for _, m in estimates[since:]]
        travelled = float(np.sum(np.hypot(*np.diff(np.array(xy), axis=0).T))) if xy else 0.0
        raise AssertionError(
            f"{error}\n(car1's estimates meanwhile: {len(xy)}, {travelled:.2f} m travelled, "
            f"nodes exited: {launcher.poll()})"
        ) from error
    assert launcher.poll() == []
