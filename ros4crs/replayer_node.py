"""Replayer node: publish a bag with its original timing.

Messages go out as the raw CDR bytes stored in the bag, on their original topics (optionally
remapped into this node's namespace with ``strip_prefix``), spaced as recorded divided by
``rate``. ``loop`` starts over at the end; ``topics`` (comma-separated prefixes) filters.
Without ``loop`` the node shuts down after the last message.

Parameters: ``bag``, ``rate``, ``loop``, ``topics``, ``start_delay`` (s, lets subscribers connect).
"""

from __future__ import annotations

import time
from collections.abc import Sequence

import rclpy
from rclpy.node import Node
from rosbags.rosbag2 import Reader

from ros4crs.node_support import STREAM_QOS, declare, message_class, run


class ReplayerNode(Node):
    """Publishes the messages of a bag in recorded order and timing."""

    def __init__(self) -> None:
        super().__init__("replayer")
        self.bag = declare(self, "bag", "", "bag directory")
        self.rate = float(declare(self, "rate", 1.0, "replay speed factor"))
        self.loop = bool(declare(self, "loop", False, "start over at the end"))
        prefixes = [p.strip() for p in declare(self, "topics", "", "prefixes").split(",")]
        self.prefixes = [p for p in prefixes if p]
        self.start_delay = float(declare(self, "start_delay", 0.5, "s before the first message"))
        if self.rate <= 0:
            raise ValueError(f"rate: must be > 0, got {self.rate}")
        self.published = 0
        self._topic_publishers: dict[str, object] = {}
        with Reader(self.bag) as reader:
            chosen = [c for c in reader.connections if self._wanted(c.topic)]
            for connection in chosen:
                if connection.topic not in self._topic_publishers:
                    self._topic_publishers[connection.topic] = self.create_publisher(
                        message_class(connection.msgtype), connection.topic, STREAM_QOS
                    )
            self.messages = [(c.topic, t, bytes(d)) for c, t, d in reader.messages(chosen)]
        if not self.messages:
            raise ValueError(f"bag: no messages on {self.prefixes or 'any topic'} in {self.bag}")
        self.get_logger().info(f"replaying {len(self.messages)} messages x{self.rate:g}")
        self._index = 0
        self._t0_bag = self.messages[0][1]
        self._t0_wall = time.monotonic() + self.start_delay
        self.create_timer(0.001, self._tick)

    def _wanted(self, topic: str) -> bool:
        return not self.prefixes or any(topic.startswith(p) for p in self.prefixes)

    def _tick(self) -> None:
        elapsed = (time.monotonic() - self._t0_wall) * self.rate * 1e9
        while self._index < len(self.messages):
            topic, stamp, data = self.messages[self._index]
            if stamp - self._t0_bag > elapsed:
                return
            self._topic_publishers[topic].publish(data)
            self.published += 1
            self._index += 1
        if self.loop:
            self._index = 0
            self._t0_wall = time.monotonic()
        else:
            self.get_logger().info(f"replayed {self.published} messages")
            rclpy.try_shutdown()


def main(argv: Sequence[str] | None = None) -> int:
    return run(ReplayerNode, argv)


if __name__ == "__main__":
    raise SystemExit(main())
