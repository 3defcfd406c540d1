"""Wait until a simulated car passes a stretch of the demo track (a helper process of the
integration tests that run inside a network namespace, where the test's own probe cannot see).

``python -m tests.integration.arc_watch NAMESPACE FROM TO TIMEOUT`` subscribes to
``NAMESPACE/ground_truth`` in ``ROS_DOMAIN_ID`` and exits 0 once the car's centre projects onto
the centreline between arc lengths ``FROM`` and ``TO`` (m) at more than 0.5 m/s, printing
where; 1 after ``TIMEOUT`` s without.
"""

from __future__ import annotations

import os
import sys
import time

import rclpy
from rclpy.executors import SingleThreadedExecutor

from crs_core.track import load_demo_track
from ros4crs import conversions
from ros4crs.discovery import FASTDDS_PROFILE
from ros4crs.node_support import STREAM_QOS

#: Slower than this (m/s) the car is not racing yet (or stands after a stop).
RACING_SPEED = 0.5


def main(argv: list[str]) -> int:
    namespace, start, end, timeout = argv[0], float(argv[1]), float(argv[2]), float(argv[3])
    os.environ.setdefault("FASTRTPS_DEFAULT_PROFILES_FILE", str(FASTDDS_PROFILE))
    from chronos_msgs.msg import CarState

    track = load_demo_track()
    found: list[str] = []

    def on_truth(msg: CarState) -> None:
        _, x = conversions.state_from_msg(msg)
        s = track.project(float(x[0]), float(x[1])).s
        if start <= s <= end and x[3] > RACING_SPEED and not found:
            found.append(f"the car at s = {s:.2f} m, {x[3]:.2f} m/s")

    rclpy.init()
    node = rclpy.create_node("arc_watch")
    node.create_subscription(CarState, f"{namespace}/ground_truth", on_truth, STREAM_QOS)
    executor = SingleThreadedExecutor()
    executor.add_node(node)
    deadline = time.monotonic() + timeout
    while not found and time.monotonic() < deadline:
        executor.spin_once(timeout_sec=0.01)
    print(found[0] if found else f"the car did not pass s {start:g}..{end:g} m in {timeout:g} s")
    node.destroy_node()
    rclpy.try_shutdown()
    return 0 if found else 1


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
