"""Controller node: tracks a track (the DEMO_TRACK by default) with the ``crs_core`` path follower.

Subscribes to ``estimate/state`` and publishes ``input`` at ``rate_hz``. When the newest estimate
is older than ``stale_timeout``, ``lost`` (or none arrived yet), it commands zero torque and
straight wheels, so the car rolls to a stop, and says so once per episode; while it is
``degraded`` the car drives at ``degraded_speed`` at most. With ``predict`` (default) the
estimate, tens of ms old when it arrives, is carried forward to the time the command acts with
the model and the last command. The MPCC replaces the path
follower through this same node later.

Parameters: ``rate_hz``, ``v_ref`` (m/s), ``stale_timeout`` (s), ``degraded_speed`` (m/s),
``predict``, ``track_file`` (CRS track YAML; default DEMO_TRACK), ``params_file`` (model
parameter YAML: the wheelbase and the prediction).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from rclpy.node import Node

from crs_core.control.path_following import PathFollower, PathFollowerSettings
from ros4crs import conversions
from ros4crs.node_support import (
    STREAM_QOS,
    CheckedSubscription,
    declare,
    declare_model,
    declare_track,
    positive,
    run,
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
        model = declare_model(self)
        parameters = model.parameters
        wheelbase = parameters.value("lf") + parameters.value("lr")
        self.predict = declare(
            self, "predict", True, "predict the estimate forward to now with the last command"
        )
        self._numeric = model.numeric if self.predict else None
        self._p = parameters.vector()
        self._u = STOP
        self.follower = PathFollower(
            declare_track(self), wheelbase, PathFollowerSettings(v_ref=v_ref)
        )
        from chronos_msgs.msg import CarInput, CarState

        self._input_publisher = self.create_publisher(
            CarInput, conversions.TOPICS["input"], STREAM_QOS
        )
        self._estimates = CheckedSubscription(
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
            u = self.follower(now, self._predicted(now), self.degraded_speed if degraded else None)
        self._u = u
        self._input_publisher.publish(conversions.car_input_msg(u, now))

    def _predicted(self, now: float) -> np.ndarray:
        """The newest estimate carried forward to ``now``, when the command will act, with the
        model and the last command (the estimate is tens of ms old: the estimator's lag and
        the transport); as it is without ``predict``."""
        stamp, x, _ = self._latest
        if self._numeric is None or now <= stamp:
            return x
        return self._numeric.step(x, self._u, self._p, min(now - stamp, self.stale_timeout))


def main(argv: Sequence[str] | None = None) -> int:
    return run(ControllerNode, argv)


if __name__ == "__main__":
    raise SystemExit(main())
