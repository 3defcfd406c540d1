"""Replayer node: publish a bag with its original timing.

The bag is streamed: messages are read as they fall due, so a long bag needs no more memory
than a short one.

Messages go out as the raw CDR bytes stored in the bag, on their original topics, spaced as
recorded divided by ``rate``. ``loop`` starts over at the end; ``topics`` (comma-separated
prefixes) filters. Without ``loop`` the node shuts down after the last message.

With ``clock`` the node also publishes ``/clock`` (like ``ros2 bag play --clock``): the playback
time on the bag's recorded time axis (the recorder's receive times), frozen at the first
recorded time until the replay starts, then advancing with the replay, each tick after the
messages due by then (a loop makes it jump back). Nodes run with ``use_sim_time`` then live on
the recording's timeline, so a node that works at "now" (e.g. the estimator, which queries at
``now - lag``) treats the replayed data, which keep their original stamps, as it treated them
live. With ``min_subscribers`` > 0 the replay (and the ``start_delay``) starts only once every
replay publisher (``/clock`` included) has that many matched subscriptions, so a node still
starting up misses nothing.

A bag whose MCAP file was cut off (recorder killed, disk full) is replayed up to its last
complete message (:func:`ros4crs.bag_repair.open_bag`), with a logged warning saying what was lost;
a bag that cannot be read at all is a one-line ``ValueError`` on ``bag``.

Parameters: ``bag``, ``rate``, ``loop``, ``topics``, ``start_delay`` (s, lets subscribers connect),
``clock``, ``min_subscribers``.
"""

from __future__ import annotations

import contextlib
import time
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import Any

import rclpy
from rclpy.node import Node
from rosbags.rosbag2 import Reader, ReaderError

from ros4crs.bag_repair import BagCheck, open_bag
from ros4crs.node_support import (
    STREAM_QOS,
    ParameterError,
    declare,
    in_range,
    message_class,
    non_negative,
    positive,
    run,
)


class ReplayerNode(Node):
    """Publishes the messages of a bag in recorded order and timing."""

    def __init__(self, **node_options: Any) -> None:
        super().__init__("replayer", **node_options)
        self.bag = declare(self, "bag", "", "bag directory")
        self.rate = declare(self, "rate", 1.0, "replay speed factor", positive)
        self.loop = declare(self, "loop", False, "start over at the end")
        prefixes = [p.strip() for p in declare(self, "topics", "", "prefixes").split(",")]
        self.prefixes = [p for p in prefixes if p]
        self.start_delay = declare(
            self, "start_delay", 0.5, "s before the first message", non_negative
        )
        clock = declare(self, "clock", False, "publish /clock from the recorded times")
        self.min_subscribers = declare(
            self,
            "min_subscribers",
            0,
            "start once every publisher has this many",
            in_range(0, 100),
        )
        self.published = 0
        self._topic_publishers: dict[str, object] = {}
        self._bag_context = contextlib.ExitStack()
        self._reader, chosen = self._open_bag()
        self._connections = chosen
        for connection in chosen:
            if connection.topic not in self._topic_publishers:
                self._topic_publishers[connection.topic] = self.create_publisher(
                    message_class(connection.msgtype), connection.topic, STREAM_QOS
                )
        count = sum(c.msgcount for c in chosen)
        self._messages = self._stream()
        self._next = next(self._messages, None)
        if self._next is None:
            self._bag_context.close()
            raise ParameterError(
                "bag", f"no messages on {self.prefixes or 'any topic'} in {self.bag}"
            )
        self._clock_publisher = None
        if clock:
            from rosgraph_msgs.msg import Clock

            self._clock_publisher = self.create_publisher(Clock, "/clock", 10)
        self.get_logger().info(f"replaying {count} messages x{self.rate:g}")
        self._t0_bag = self._next[1]
        self._t0_wall: float | None = None  # set once the subscribers are there
        self.create_timer(0.001, self._tick)

    def _open_bag(self) -> tuple[Reader, list]:
        """The open reader (kept open while replaying: messages are read as they are due, not
        loaded at once) and the wanted connections that hold messages."""
        if not self.bag:
            raise ParameterError("bag", "no bag directory given")
        try:
            reader = self._bag_context.enter_context(open_bag(self.bag, on_damage=self._log_damage))
        except (ValueError, OSError, ReaderError) as error:
            self._bag_context.close()
            reason = " ".join(str(error).split()) or type(error).__name__
            where = "" if str(Path(self.bag)) in reason else f"cannot read {self.bag}: "
            raise ParameterError("bag", f"{where}{reason}") from None
        # a topic that was only subscribed to while recording has no message: no publisher for
        # it (its subscribers would be waited for, and a replay into a node that does not
        # subscribe to it would never start)
        return reader, [c for c in reader.connections if c.msgcount > 0 and self._wanted(c.topic)]

    def _stream(self) -> Iterator[tuple[str, int, bytes]]:
        """``(topic, log time ns, CDR bytes)`` of the wanted messages, in log-time order."""
        if not self._connections:  # rosbags reads every connection when given none
            return
        for connection, stamp, data in self._reader.messages(self._connections):
            yield connection.topic, stamp, bytes(data)

    def _log_damage(self, report: BagCheck) -> None:
        self.get_logger().warning(f"damaged bag {self.bag}: {report.warning}")

    def _subscribers_ready(self) -> bool:
        publishers = list(self._topic_publishers.values())
        if self._clock_publisher is not None:
            publishers.append(self._clock_publisher)
        return all(p.get_subscription_count() >= self.min_subscribers for p in publishers)

    def _publish_clock(self, nanoseconds: int) -> None:
        from rosgraph_msgs.msg import Clock

        msg = Clock()
        msg.clock.sec, msg.clock.nanosec = divmod(nanoseconds, 1_000_000_000)
        self._clock_publisher.publish(msg)

    def _wanted(self, topic: str) -> bool:
        return not self.prefixes or any(topic.startswith(p) for p in self.prefixes)

    def _tick(self) -> None:
        if self._t0_wall is None and self._subscribers_ready():
            self._t0_wall = time.monotonic() + self.start_delay
        if self._t0_wall is None or time.monotonic() < self._t0_wall:
            if self._clock_publisher is not None:
                self._publish_clock(self._t0_bag)
            return
        elapsed = (time.monotonic() - self._t0_wall) * self.rate * 1e9
        while self._next is not None and self._next[1] - self._t0_bag <= elapsed:
            topic, _, data = self._next
            self._topic_publishers[topic].publish(data)
            self.published += 1
            self._next = next(self._messages, None)
        if self._clock_publisher is not None:
            self._publish_clock(self._t0_bag + int(elapsed))
        if self._next is not None:
            return
        if self.loop:
            self._messages = self._stream()
            self._next = next(self._messages, None)
            self._t0_wall = time.monotonic()
        else:
            self.get_logger().info(f"replayed {self.published} messages")
            rclpy.try_shutdown()

    def destroy_node(self) -> None:
        self._bag_context.close()
        super().destroy_node()


def main(argv: Sequence[str] | None = None) -> int:
    return run(ReplayerNode, argv)


if __name__ == "__main__":
    raise SystemExit(main())
