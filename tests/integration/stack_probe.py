"""Helpers of the integration tests: a ROS probe node in the test process, waiting, logs.

The tests start real node processes with :class:`launch_scripts.launcher.Launcher` (each test in
its own ``ROS_DOMAIN_ID``, discovery on loopback only) and watch them from the test process
through a :class:`Probe`: an rclpy node in its own context, spun in a background thread.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import pytest
import rclpy
from rclpy.context import Context
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor

from crs_core.analysis.laps import LapCounter
from crs_core.track import Track
from launch_scripts.launcher import Launcher, NodeSpec
from launch_scripts.sim_stack import PIPELINE_PROCESS
from ros4crs import conversions
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
    ``log_dir/car1_estimator.log``; a node of a car's shared pipeline process: that process's
    log, ``car1_pipeline.log``)."""
    namespace = full_name.strip("/").rpartition("/")[0]
    for stem in (full_name.strip("/").replace("/", "_"), f"{namespace}_{PIPELINE_PROCESS}"):
        path = Path(log_dir) / f"{stem}.log"
        if path.exists():
            return path.read_text(errors="replace")
    return ""


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


@contextmanager
def launched(
    nodes: list[NodeSpec], domain_id: int, log_dir: Path
) -> Iterator[tuple[Launcher, Probe]]:
    """A :class:`Launcher` of ``nodes`` (not started yet: subscribe through the probe first,
    then ``launcher.start()`` or ``launcher.run(...)``) and a :class:`Probe`, both in
    ``domain_id``; on the way out the launcher is stopped and the probe closed."""
    launcher = Launcher(nodes, domain_id, log_dir)
    probe = Probe(domain_id)
    try:
        yield launcher, probe
    finally:
        launcher.stop()
        probe.close()


def message_stamp(msg: Any) -> float:
    """A message's ``header.stamp``, s."""
    return conversions.seconds_from_stamp(msg.header.stamp)


def assert_clean_run(deaths: list, launcher: Launcher) -> None:
    """No node died during ``launcher.run`` (``deaths``), and every node exited 0 on SIGINT."""
    assert not deaths, "\n".join(f"{d.node} exited {d.returncode}:\n{d.log_tail}" for d in deaths)
    codes = {name: process.returncode for name, process in launcher.processes.items()}
    assert codes == dict.fromkeys(codes, 0), codes


#: Estimation error bounds of the stack's estimator in the loop (several times what was
#: measured: see test_stack and test_velocity_mode).
RMSE_POSITION_M = 0.02
RMSE_YAW_RAD = 0.1


def assert_tracked_lap(report: dict[str, Any]) -> None:
    """A car's part of the stack's report (``analyse``): at least one lap, the estimation RMSE
    under ``RMSE_POSITION_M`` in x and y and ``RMSE_YAW_RAD`` in yaw, no malformed messages."""
    assert report["laps_completed"] >= 1
    rmse = report["estimation_rmse"]
    assert rmse["x"] < RMSE_POSITION_M and rmse["y"] < RMSE_POSITION_M, rmse
    assert rmse["yaw"] < RMSE_YAW_RAD, rmse
    assert report["malformed_messages"] == 0


class LapWatch:
    """The laps of a car counted on its collected ground truth (``Probe.collect`` of
    ``/carN/ground_truth``) as the ``crs launch sim`` report (``analyse``) counts them: from when
    the car starts moving, on the start/finish line. Called (``Launcher.run(until=...)``): a lap
    is done and the truth has gone on for a second more, so the recorder has the crossing too."""

    def __init__(self, track: Track, truth: list[tuple[float, Any]]) -> None:
        self.track = track
        self.truth = truth
        self.counter = LapCounter(track.length, line_tolerance=0.05)
        self._seen = 0
        self._hint: float | None = None
        self._moving = False

    def __call__(self) -> bool:
        while self._seen < len(self.truth):
            msg = self.truth[self._seen][1]
            self._seen += 1
            self._moving = self._moving or msg.vx > 0.05
            if not self._moving:
                continue  # still waiting at the line
            projection = self.track.project(msg.x, msg.y, self._hint)
            self._hint = projection.s
            self.counter.update(message_stamp(msg), projection.s)
        if self.counter.laps_completed < 1:
            return False
        return message_stamp(self.truth[-1][1]) > self.counter.crossing_stamps[1] + 1.0
