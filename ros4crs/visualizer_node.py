"""Visualizer node: the race live in the Foxglove app (WebSocket protocol ``foxglove.sdk.v1``,
foxglove-sdk) and in the suite's built-in page.

Node ``visualizer`` in the global namespace. It serves a Foxglove WebSocket on ``host:port``
(a ``foxglove.Context`` of its own: nothing else of the process logs to it) and the built-in
page over HTTP on ``host:page_port`` (:mod:`ros4crs.viz_page`; the page connects to ``port``,
which the page server writes into it). Viewers may only subscribe: the
server advertises no capability (no client publishing, services or parameters), so nothing a
viewer does reaches a car. It finds the cars (``cars``, else every ``/carN`` namespace in the
graph) and the topics by polling the graph once a second, as the recorder does, and subscribes
raw and best-effort (a slow viewer never holds a publisher back, and joining or leaving does not
disturb the stack). A car's ``estimate/state``, ``ground_truth``, ``estimate/diagnostics``,
``controller/plan``, ``controller/reference``, ``controller/solve_time``,
``estimate/parameters`` and ``lighthouse_fix``
(which the estimator computes only while subscribed) are validated at the boundary
(:mod:`ros4crs.conversions`; a malformed message is dropped with a throttled warning naming the
field) and feed a :class:`~ros4crs.viz_scene.CarWatch` each (laps counted on the track).

Channels (the JSON ones with a JSON schema), each built and sent only while a viewer subscribes:

- ``/viz/scene`` (``foxglove.SceneUpdate``, world frame): the track (``track``: borders and
  centreline; at the start and every 2 s for viewers that join late) and per car (entity
  ``carN``) the estimate's footprint coloured by status, the simulator's truth (fainter), the
  2-sigma position ellipse, the MPCC's planned horizon and its progress reference (the
  centreline points the plan's stages are pulled to) and the Lighthouse pose fixes of the last
  half second (a dot with a heading tick each), at ``rate_hz``;
- ``/tf`` (``foxglove.FrameTransforms``, where the Foxglove app looks for frames):
  ``world`` -> ``carN/base_link`` from each car's estimate, at ``rate_hz`` (the ROS ``/tf`` is
  not passed through: this channel takes its name);
- ``/viz/carN/status`` (JSON): status, reason, laps, last lap, solve time, deadline misses,
  online parameters (value, std, informed);
- ``/viz/page/track`` and ``/viz/page/cars`` (JSON): the built-in page's contract
  (``docs/live-view.md``);
- every other topic of the graph as raw CDR with its ``ros2msg`` schema, at most ``rate_hz``
  messages a second per topic, except ``/rosout``, ``/parameter_events``, ``/tf`` (shown as
  the channel above), the cars' ``sensors/`` streams (250 Hz readings a viewer cannot follow, whose
  subscription would cost ~0.4 ms of CPU per message, and which the simulator counts when it
  waits for its listeners before its clock starts), ``estimate/query`` (the estimator's log
  for an exact replay, at the estimator's rate) and ``estimate/odometry`` (``estimate/state``
  again).

Parameters: ``port`` (Foxglove WebSocket, default 8765), ``page_port`` (built-in page, 8766),
``host`` (address both bind to, default 127.0.0.1; 0.0.0.0 for the lab network), ``cars``
(comma-separated car namespaces, empty: discover ``/carN``), ``rate_hz`` (30), ``track_file``
(CRS track YAML; default DEMO_TRACK).
"""

from __future__ import annotations

import ipaddress
import re
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import foxglove
import numpy as np
from foxglove.channels import FrameTransformsChannel, SceneUpdateChannel
from rclpy.node import Node
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
from rosbags.typesys import TypesysError

from ros4crs import conversions, viz_scene
from ros4crs.interfaces import typestore
from ros4crs.node_support import (
    INTERNAL_TOPICS,
    ParameterError,
    declare,
    declare_track,
    in_range,
    message_class,
    parsed_with,
    positive,
    run,
    throttled_warning,
)
from ros4crs.viz_page import start_page_server

#: Subscriptions of a viewer: best effort, so a publisher never waits for it.
VIEW_QOS = QoSProfile(
    depth=10, reliability=ReliabilityPolicy.BEST_EFFORT, history=HistoryPolicy.KEEP_LAST
)
#: Topics never passed through (``/tf``: the scene's own ``/tf`` channel shows the frames).
NOT_PASSED = (*INTERNAL_TOPICS, "/tf")
#: Parts of a topic name that keep it from being passed through: the 250 Hz sensor streams, the
#: estimator's query log (what a replay needs, nothing to look at) and its odometry (the same
#: pose as ``estimate/state``, at 60 Hz: a tenth of the node's CPU per car).
NOT_PASSED_PARTS = ("/sensors/", "/estimate/query", "/estimate/odometry")
#: A car's topics whose every message is read (events: each station's fixes), not the newest.
READ_EVERY = (conversions.TOPICS["lighthouse_fix"],)
#: How often the track is sent again, s (for viewers that join late).
TRACK_PERIOD = 2.0
#: How often the graph is polled for new cars and topics, s.
DISCOVERY_PERIOD = 1.0
_CAR_NAMESPACE = re.compile(r"car\d+")
_NAMESPACE = re.compile(r"[A-Za-z][A-Za-z0-9_]*")


def parse_cars(text: str) -> tuple[str, ...]:
    """``car1,car2`` (or ``/car1,...``) -> the names without slashes; empty: discover them.
    ``ValueError`` naming a name that is not a ROS namespace or is given twice."""
    names = tuple(part.strip().strip("/") for part in text.split(",") if part.strip())
    for name in names:
        if not _NAMESPACE.fullmatch(name):
            raise ValueError(f"{name!r} is not a car namespace (letters, digits, _)")
    if len(set(names)) != len(names):
        raise ValueError(f"{text!r} names a car twice")
    return names


def _address(text: str) -> None:
    try:
        ipaddress.ip_address(text)
    except ValueError:
        raise ValueError(
            "must be an IP address (127.0.0.1, or 0.0.0.0 for every interface)"
        ) from None


@dataclass
class _Topic:
    """A subscribed topic: its passthrough channel (None: not passed) and what reads it."""

    msg_type: type
    channel: foxglove.Channel | None
    read: Callable[[Any], None] | None
    what: str
    due: float = 0.0
    #: Whether every message is read (events, such as the Lighthouse fixes of several
    #: stations), else only the newest.
    every: bool = False
    #: The messages not read yet (CDR), read at the next scene tick: only the newest unless
    #: ``every``, so a topic faster than the scene costs one deserialisation a tick.
    pending: list[bytes] = field(default_factory=list)


class VisualizerNode(Node):
    """Serves the scene, the cars' status and the suite's topics to Foxglove viewers."""

    def __init__(self, **node_options: Any) -> None:
        super().__init__("visualizer", **node_options)
        port = declare(self, "port", 8765, "Foxglove WebSocket port", in_range(1, 65535))
        page_port = declare(
            self, "page_port", 8766, "built-in page's HTTP port", in_range(1, 65535)
        )
        host = declare(
            self,
            "host",
            "127.0.0.1",
            "address to serve on (0.0.0.0: every interface)",
            parsed_with(_address),
        )
        cars = declare(
            self,
            "cars",
            "",
            "comma-separated car namespaces; empty: discover /carN",
            parsed_with(parse_cars),
        )
        rate_hz = declare(
            self, "rate_hz", 30.0, "rate of the scene, frames and status, Hz", positive
        )
        self.track = declare_track(self)
        if page_port == port:
            raise ParameterError("page_port", f"must differ from port, got {page_port}")
        self.cars = parse_cars(cars)
        self.period = 1.0 / rate_hz
        self.view_context = foxglove.Context()
        try:
            self.server = foxglove.start_server(
                name="chronos", host=host, port=port, capabilities=[], context=self.view_context
            )
        except RuntimeError as error:
            raise ParameterError("port", f"cannot serve on {host}:{port}: {error}") from None
        try:
            self.page = start_page_server(host, page_port, self.server.port)
        except OSError as error:
            self.server.stop()
            raise ParameterError(
                "page_port", f"cannot serve on {host}:{page_port}: {error}"
            ) from None
        context = self.view_context
        self.scene = SceneUpdateChannel(viz_scene.SCENE_CHANNEL, context=context)
        self.frames = FrameTransformsChannel("/tf", context=context)
        self.page_track = foxglove.Channel(
            "/viz/page/track", schema=viz_scene.PAGE_TRACK_SCHEMA, context=context
        )
        self.page_cars = foxglove.Channel(
            "/viz/page/cars", schema=viz_scene.PAGE_CARS_SCHEMA, context=context
        )
        self.watches: dict[str, viz_scene.CarWatch] = {}
        self.status: dict[str, foxglove.Channel] = {}
        self.topics: dict[str, _Topic | None] = {}
        self._warn = throttled_warning(self)
        self._track_due = 0.0
        for name in self.cars:
            self._watch(name)
        self._discover()
        self.create_timer(DISCOVERY_PERIOD, self._discover)
        self.create_timer(self.period, self._publish)
        self.get_logger().info(
            f"Foxglove WebSocket on ws://{host}:{self.server.port}, page on "
            f"http://{host}:{page_port}/; cars: {', '.join(self.cars) or 'discovered'}"
        )

    # --- discovery --------------------------------------------------------------------------
    def _watch(self, name: str) -> None:
        self.watches[name] = viz_scene.CarWatch(name, self.track)
        self.status[name] = foxglove.Channel(
            viz_scene.status_channel(name),
            schema=viz_scene.STATUS_SCHEMA,
            context=self.view_context,
        )

    def _discover(self) -> None:
        for topic, types in self.get_topic_names_and_types():
            if topic in self.topics:
                continue
            parts = topic.split("/", 2)
            car = parts[1] if len(parts) == 3 else ""  # a namespace, not a global topic
            if not self.cars and car not in self.watches and _CAR_NAMESPACE.fullmatch(car):
                self._watch(car)
            self.topics[topic] = self._subscribe(topic, types[0], self.watches.get(car))

    def _subscribe(
        self, topic: str, msgtype: str, watch: viz_scene.CarWatch | None
    ) -> _Topic | None:
        """Subscribe to ``topic`` if it is passed through or read (None: neither)."""
        relative = topic.split("/", 2)[2] if watch is not None else ""  # the car's own name
        read, what = self._reader(relative, watch) if watch is not None else (None, "")
        passed = topic not in NOT_PASSED and not any(p in topic for p in NOT_PASSED_PARTS)
        if read is None and not passed:
            return None
        try:
            msg_type = message_class(msgtype)
            definition, _ = typestore().generate_msgdef(msgtype, ros_version=2)
        except (ImportError, AttributeError, KeyError, ValueError, TypesysError) as error:
            self.get_logger().warning(f"cannot show {topic} ({msgtype}): {error}")
            return None
        channel = None
        if passed:
            schema = foxglove.Schema(name=msgtype, encoding="ros2msg", data=definition.encode())
            channel = foxglove.Channel(
                topic, schema=schema, message_encoding="cdr", context=self.view_context
            )
        every = watch is not None and relative in READ_EVERY
        entry = _Topic(msg_type, channel, read, what or topic, every=every)
        self.create_subscription(
            msg_type, topic, lambda data: self._on_message(topic, entry, data), VIEW_QOS, raw=True
        )
        return entry

    def _reader(
        self, relative: str, watch: viz_scene.CarWatch
    ) -> tuple[Callable[[Any], None] | None, str]:
        """What reads a car's topic (``relative``: its name in the car's namespace) into its
        watch, and what the messages are."""
        topics = conversions.TOPICS
        if relative == topics["state"]:
            return lambda msg: watch.estimate(
                time.monotonic(), *_estimate_from_msg(msg)
            ), "estimate"
        if relative == topics["ground_truth"]:
            return lambda msg: watch.truth(conversions.state_from_msg(msg)[1]), "ground truth"
        if relative == topics["diagnostics"]:
            return (
                lambda msg: watch.diagnostics(*conversions.estimator_health_from_msg(msg)),
                "estimator diagnostics",
            )
        if relative == topics["plan"]:
            return lambda msg: watch.plan(conversions.plan_from_msg(msg)), "plan"
        if relative == topics["reference"]:
            return lambda msg: watch.reference(conversions.plan_from_msg(msg)), "reference"
        if relative == topics["lighthouse_fix"]:
            return (
                lambda msg: watch.lighthouse_fix(
                    time.monotonic(), conversions.pose_fix_from_msg(msg)[1]
                ),
                "Lighthouse fix",
            )
        if relative == topics["parameters"]:
            return (
                lambda msg: watch.parameters(conversions.online_parameters_from_msg(msg)[1]),
                "online parameters",
            )
        if relative == topics["solve_time"]:
            return lambda msg: watch.solve_time(conversions.solve_time_from_msg(msg)), "solve time"
        return None, ""

    # --- messages ---------------------------------------------------------------------------
    def _on_message(self, topic: str, entry: _Topic, data: bytes) -> None:
        now = time.monotonic()
        channel = entry.channel
        if channel is not None and now >= entry.due and channel.has_sinks():
            # at most rate_hz on average: a 30 Hz topic's jitter does not halve it
            entry.due = max(entry.due, now - self.period) + self.period
            channel.log(bytes(data), log_time=time.time_ns())
        if entry.read is not None:
            if entry.every:
                entry.pending.append(bytes(data))
            else:
                entry.pending = [bytes(data)]

    def _read_pending(self) -> None:
        """Read the pending messages of each read topic (validated: a malformed one is dropped
        with a throttled warning naming what it is)."""
        from rclpy.serialization import deserialize_message

        for topic, entry in list(self.topics.items()):
            if entry is None or entry.read is None:
                continue
            pending, entry.pending = entry.pending, []
            for data in pending:
                try:
                    entry.read(deserialize_message(data, entry.msg_type))
                except Exception as error:  # whatever a malformed message raises: never fatal
                    self._warn(f"dropped malformed {entry.what} on {topic}: {error}")

    def _publish(self) -> None:
        self._read_pending()
        now = time.monotonic()
        stamp = self.get_clock().now().nanoseconds * 1e-9
        if now >= self._track_due:
            self._track_due = now + TRACK_PERIOD
            if self.scene.has_sinks():
                self.scene.log(viz_scene.track_scene(self.track, stamp))
            if self.page_track.has_sinks():
                self.page_track.log(viz_scene.page_track_json(self.track))
        views = [self.watches[name].view(now) for name in sorted(self.watches)]
        if self.scene.has_sinks():
            self.scene.log(viz_scene.cars_scene(views, stamp))
        if self.frames.has_sinks():
            self.frames.log(viz_scene.frame_transforms(views, stamp))
        if self.page_cars.has_sinks():
            self.page_cars.log(viz_scene.page_cars_json(views, stamp))
        for view in views:
            channel = self.status[view.name]
            if channel.has_sinks():
                channel.log(viz_scene.status_json(view))

    def destroy_node(self) -> None:
        self.server.stop()
        self.page.close()
        super().destroy_node()


def _estimate_from_msg(msg: Any) -> tuple[float, np.ndarray, str, np.ndarray | None]:
    """``chronos_msgs/CarState`` -> stamp, state, status and the position covariance (2 x 2,
    None: unknown), each checked."""
    stamp, x, status = conversions.status_from_msg(msg)
    return stamp, x, status, viz_scene.position_covariance(msg.covariance)


def main(argv: Sequence[str] | None = None) -> int:
    return run(VisualizerNode, argv)


if __name__ == "__main__":
    raise SystemExit(main())
