"""Controller node: tracks a track (the DEMO_TRACK by default) with the ``crs_core`` path follower.

Subscribes to ``estimate/state`` and publishes ``input`` at ``rate_hz``. When the newest estimate
is older than ``stale_timeout``, ``lost`` (or none arrived yet), it commands zero torque and
straight wheels, so the car rolls to a stop, and says so once per episode; while it is
``degraded`` the car drives at ``degraded_speed`` at most. The MPCC replaces the path
follower through this same node later.

Parameters: ``rate_hz``, ``v_ref`` (m/s), ``stale_timeout`` (s), ``degraded_speed`` (m/s),
``track_file`` (CRS track YAML; default DEMO_TRACK), ``params_file`` (model parameter YAML: the
wheelbase).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from rclpy.node import Node

from crs_core.control.path_following import PathFollower, PathFollowerSettings
from ros4crs import conversions
from ros4crs.node_support import (
    STREAM_QOS,
    declare,
    declare_model,
    declare_track,
    positive,
    run,
    subscribe_checked,
)

STOP = np.array([0.0, 0.0])


class ControllerNode(Node):
    """Path following on the latest estimate, safe stop when it goes stale."""

    def __init__(self) -> None:
        super().__init__("controller")
        rate_hz = declare(self, "rate_hz", 50.0, "control rate, Hz", positive)
        v_ref = declare(self, "v_ref", 1.0, "reference speed, m/s", positive)
        self.stale_timeout = declare(
            self, "stale_timeout", 0.2, "stop when the estimate is this old, s", positive
        )
        self.degraded_speed = declare(
            self, "degraded_speed", 0.5, "speed while the estimate is degraded, m/s", positive
        )
        parameters = declare_model(self).parameters
        wheelbase = parameters.value("lf") + parameters.value("lr")
        self.follower = PathFollower(
            declare_track(self), wheelbase, PathFollowerSettings(v_ref=v_ref)
        )
        from chronos_msgs.msg import CarInput, CarState

        self._input_publisher = self.create_publisher(
            CarInput, conversions.TOPICS["input"], STREAM_QOS
        )
        self._estimates = subscribe_checked(
            self,
            CarState,
            conversions.TOPICS["state"],
            conversions.status_from_msg,
            self._on_state,
            "state estimate",
        )
        self._latest: tuple[float, np.ndarray, str] | None = None
        self._stale = True
        self._degraded = False
        self.stops = 0
        self.create_timer(1.0 / rate_hz, self._control)

    def _on_state(self, value: tuple[float, np.ndarray, str]) -> None:
        self._latest = value

    def _control(self) -> None:
        self._estimates.take_pending()  # act on the newest estimate that has arrived
        now = self.get_clock().now().nanoseconds * 1e-9
        stale = (
            self._latest is None
            or now - self._latest[0] > self.stale_timeout
            or self._latest[2] == "lost"
        )
        if stale:
            if not self._stale:
                self.stops += 1
                self.get_logger().warning("state estimate is stale: stopping the car")
            self._stale = True
            u = STOP
        else:
            if self._stale:
                self.get_logger().info("state estimate is fresh: driving")
                self.follower.reset()
            self._stale = False
            degraded = self._latest[2] == "degraded"
            if degraded != self._degraded:
                self.get_logger().warning(
                    f"state estimate degraded: slowing to {self.degraded_speed:g} m/s"
                    if degraded
                    else "state estimate ok again: full speed"
                )
                self._degraded = degraded
            u = self.follower(now, self._latest[1], self.degraded_speed if degraded else None)
        self._input_publisher.publish(conversions.car_input_msg(u, now))


def main(argv: Sequence[str] | None = None) -> int:
    return run(ControllerNode, argv)


if __name__ == "__main__":
    raise SystemExit(main())
