"""Small command-line tools where the ``ros2`` CLI is missing: list, echo, rate of topics."""

from __future__ import annotations

import time
from collections.abc import Callable

import numpy as np
import rclpy
from rclpy.node import Node

from ros4crs.discovery import set_discovery_environment
from ros4crs.node_support import STREAM_QOS, message_class


def _with_node(work: Callable[[Node], object]) -> object:
    set_discovery_environment()
    context = rclpy.context.Context()
    rclpy.init(context=context)
    node = rclpy.create_node("crs_tools", context=context)
    executor = rclpy.executors.SingleThreadedExecutor(context=context)
    executor.add_node(node)
    try:
        return work(node, executor)
    finally:
        node.destroy_node()
        rclpy.shutdown(context=context)


def list_topics(wait: float = 1.0) -> list[tuple[str, str]]:
    """``(topic, type)`` of every topic seen within ``wait`` s of discovery, and then until the
    list has not changed for 0.3 s (at most 2 s more).

    A running node's reply to our first discovery announcement is dropped about half the time
    (Fast DDS 2.14 announces before it listens); we then see the node only at its next periodic
    announcement, so ``wait`` must exceed that period: 0.25 s for the suite's processes
    (:mod:`ros4crs.discovery`), 3 s (Fast DDS default) for others. The settling
    lets the endpoints of a node discovered near the end of ``wait`` come in.
    """

    def work(node, executor):
        start = time.monotonic()
        seen, changed = [], start
        while True:
            executor.spin_once(timeout_sec=0.05)
            now = time.monotonic()
            topics = [(name, types[0]) for name, types in sorted(node.get_topic_names_and_types())]
            if topics != seen:
                seen, changed = topics, now
            if now - start >= wait and (now - changed >= 0.3 or now - start >= wait + 2.0):
                return seen

    return _with_node(work)


def _topic_type(node, executor, topic: str, wait: float) -> str:
    end = time.monotonic() + wait
    while time.monotonic() < end:
        for name, types in node.get_topic_names_and_types():
            if name == topic:
                return types[0]
        executor.spin_once(timeout_sec=0.05)
    raise ValueError(f"topic {topic!r}: no publisher found within {wait} s")


def echo(topic: str, count: int = 1, timeout: float = 5.0) -> list[object]:
    """The next ``count`` messages on ``topic`` (printed by the CLI)."""

    def work(node, executor):
        msg_type = message_class(_topic_type(node, executor, topic, timeout))
        received: list[object] = []
        node.create_subscription(msg_type, topic, received.append, STREAM_QOS)
        end = time.monotonic() + timeout
        while len(received) < count and time.monotonic() < end:
            executor.spin_once(timeout_sec=0.05)
        return received[:count]

    return _with_node(work)


def rate(topic: str, window: float = 2.0, timeout: float = 5.0) -> dict[str, float]:
    """Receive rate (Hz) and inter-arrival statistics (ms) on ``topic`` over ``window`` s,
    measured from half a second after the first message (waited for up to ``timeout`` s)."""

    def work(node, executor):
        msg_type = message_class(_topic_type(node, executor, topic, timeout))
        arrivals: list[float] = []
        node.create_subscription(
            msg_type, topic, lambda _: arrivals.append(time.monotonic()), STREAM_QOS, raw=True
        )
        deadline = time.monotonic() + timeout  # discovery may take a while on a busy machine
        while not arrivals and time.monotonic() < deadline:
            executor.spin_once(timeout_sec=0.01)
        settle = time.monotonic() + 0.5  # the first arrivals after matching come in a burst
        while time.monotonic() < settle:
            executor.spin_once(timeout_sec=0.01)
        arrivals.clear()
        end = time.monotonic() + window
        while time.monotonic() < end:
            executor.spin_once(timeout_sec=0.01)
        gaps = np.diff(arrivals) * 1e3
        if gaps.size == 0:
            return {"rate_hz": 0.0, "messages": len(arrivals)}
        return {
            "rate_hz": round(1e3 / float(np.mean(gaps)), 2),
            "messages": len(arrivals),
            "gap_ms_median": round(float(np.median(gaps)), 3),
            "gap_ms_max": round(float(gaps.max()), 3),
        }

    return _with_node(work)
