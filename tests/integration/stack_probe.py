"""Helpers of the integration tests: a ROS probe node in the test process, waiting, logs.

The tests start real node processes with :class:`launch_scripts.launcher.Launcher` (each test in
its own ``ROS_DOMAIN_ID``, discovery on loopback only) and watch them from the test process
through a :class:`Probe`: an rclpy node in its own context, spun in a background thread.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest
import rclpy
from rclpy.context import Context
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor

from ros4crs.discovery import FASTDDS_PROFILE
from ros4crs.node_support import STREAM_QOS


def wait_for(
    condition: Callable[[], Any],
    timeout: float,
    what: str | Callable[[], str],
    period: float = 0.05,
) -> Any:
    """Poll ``condition`` until it returns something truthy (returned); fail after ``timeout``
    naming ``what`` (a callable is called then, to describe what was seen instead)."""
    deadline = time.monotonic() + timeout
    while True:
        value = condition()
        if value:
            return value
        if time.monotonic() > deadline:
            described = what() if callable(what) else what
            pytest.fail(f"timed out after {timeout:g} s waiting for {described}")
        time.sleep(period)


def log_text(log_dir: Path, full_name: str) -> str:
    """What a node launched by the Launcher has logged so far (``/car1/estimator`` ->
    ``log_dir/car1_estimator.log``)."""
    path = Path(log_dir) / (full_name.strip("/").replace("/", "_") + ".log")
    return path.read_text(errors="replace") if path.exists() else ""


class Probe:
    """An rclpy node of the test process in ``domain_id`` (loopback discovery), spinning in a
    background thread; subscriptions collect ``(wall receive time, message)`` into lists."""

    def __init__(self, domain_id: int, name: str = "integration_probe") -> None:
        self.context = Context()
        # discovery settings are read when the context and the node are created
        with pytest.MonkeyPatch.context() as patch:
            patch.setenv("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
            patch.setenv("ROS_DOMAIN_ID", str(domain_id))
            patch.setenv("FASTRTPS_DEFAULT_PROFILES_FILE", str(FASTDDS_PROFILE))
            rclpy.init(context=self.context, domain_id=domain_id)
            self.node = rclpy.create_node(name, context=self.context)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self._thread = threading.Thread(target=self._spin, daemon=True)
        self._thread.start()

    def _spin(self) -> None:
        try:
            self.executor.spin()
        except (ExternalShutdownException, rclpy.executors.ShutdownException):
            pass

    def collect(self, msg_type: type, topic: str) -> list[tuple[float, Any]]:
        """A list that fills with ``(time.time(), msg)`` of every message on ``topic``."""
        received: list[tuple[float, Any]] = []
        self.node.create_subscription(
            msg_type, topic, lambda msg: received.append((time.time(), msg)), STREAM_QOS
        )
        return received

    def publisher(self, msg_type: type, topic: str, subscribers: int = 1, timeout: float = 30.0):
        """A publisher on ``topic``, returned once it is matched with ``subscribers`` readers."""
        publisher = self.node.create_publisher(msg_type, topic, STREAM_QOS)
        wait_for(
            lambda: publisher.get_subscription_count() >= subscribers,
            timeout,
            f"{subscribers} subscriber(s) on {topic}",
        )
        return publisher

    def publishers_of(self, topic: str) -> list[str]:
        """Full names of the nodes publishing ``topic`` (as the graph shows them now)."""
        infos = self.node.get_publishers_info_by_topic(topic)
        return sorted(f"{i.node_namespace.rstrip('/')}/{i.node_name}" for i in infos)

    def subscribers_of(self, topic: str) -> list[str]:
        """Full names of the nodes subscribed to ``topic``, this probe excluded."""
        infos = self.node.get_subscriptions_info_by_topic(topic)
        names = (f"{i.node_namespace.rstrip('/')}/{i.node_name}" for i in infos)
        return sorted(n for n in names if n != f"/{self.node.get_name()}")

    def close(self) -> None:
        self.executor.shutdown(timeout_sec=2.0)
        self.node.destroy_node()
        self.context.try_shutdown()
        self._thread.join(timeout=5.0)
