"""Controller node: races a track (the DEMO_TRACK by default) with the ``crs_core`` MPCC, or
follows its centreline with the path follower.

Subscribes to ``estimate/state`` and publishes ``input`` at ``rate_hz`` (default 30 Hz for the
MPCC, the paper's, 50 Hz for the path follower). When the newest estimate is older than
``stale_timeout``, ``lost`` (or none arrived yet), it commands zero torque and straight wheels,
so the car rolls to a stop, and says so once per episode (the MPCC keeps its plan through a gap
of up to half its horizon and goes on from it); while it is ``degraded`` the car
drives at ``degraded_speed`` at most. With ``predict`` (default) the estimate, tens of ms old
when it arrives, is carried forward to the time the command acts with the model and the
commands sent since its stamp. A controller that raises is answered by a stop command and a
throttled error; the node keeps running.

With ``output`` velocity (MPCC only) it publishes ``MODE_VELOCITY`` commands ``[delta, v_x]`` for
a car that tracks its speed on board (the MPCC's planned speed a short lead ahead; the simulator
needs ``onboard:=true``); the prediction then uses the torque of the MPCC's plan, and a stop is a
zero velocity reference.

Parameters: ``controller`` (``mpcc`` | ``path``), ``output`` (``torque`` | ``velocity``; the
latter with ``mpcc`` only), ``rate_hz``, ``v_ref`` (m/s, path follower), ``stale_timeout`` (s),
``degraded_speed`` (m/s), ``predict``, ``track_file`` (CRS track YAML; default DEMO_TRACK),
``params_file`` (model parameter YAML: the prediction model).
"""

from __future__ import annotations

import time
from collections import deque
from collections.abc import Sequence

import numpy as np
from rclpy.node import Node

from crs_core.control.mpcc import OUTPUTS, Mpcc
from crs_core.control.mpcc_problem import MpccSettings
from crs_core.control.path_following import PathFollower, PathFollowerSettings
from ros4crs import conversions
from ros4crs.node_support import (
    STREAM_QOS,
    CheckedSubscription,
    ParameterError,
    declare,
    declare_model,
    declare_track,
    one_of,
    positive,
    run,
)

STOP = np.array([0.0, 0.0])
#: Controllers the node runs.
CONTROLLERS = ("mpcc", "path")


def _controller_kind(value: str) -> str | None:
    return None if value in CONTROLLERS else f"must be one of {', '.join(CONTROLLERS)}"


class ControllerNode(Node):
    """MPCC (or path following) on the latest estimate, safe stop when it goes stale."""

    def __init__(self) -> None:
        super().__init__("controller")
        kind = declare(self, "controller", "mpcc", "mpcc or path", _controller_kind)
        self.output = declare(
            self, "output", "torque", "command torque or velocity (MPCC)", one_of(*OUTPUTS)
        )
        if self.output == "velocity" and kind != "mpcc":
            raise ParameterError(
                f"output: velocity needs controller:=mpcc (the {kind} controller commands "
                "torque), got 'velocity'"
            )
        default_rate = 30.0 if kind == "mpcc" else 50.0
        rate_hz = declare(self, "rate_hz", default_rate, "control rate, Hz", positive)
        v_ref = declare(self, "v_ref", 1.0, "path follower: reference speed, m/s", positive)
        self.stale_timeout = declare(
            self, "stale_timeout", 0.2, "stop when the estimate is this old, s", positive
        )
        self.degraded_speed = declare(
            self, "degraded_speed", 0.5, "speed while the estimate is degraded, m/s", positive
        )
        model = declare_model(self)
        parameters = model.parameters
        self.predict = declare(
            self, "predict", True, "predict the estimate forward to now with the commands sent"
        )
        track = declare_track(self)
        self._numeric = model.numeric if self.predict else None
        self._p = parameters.vector()
        #: the model inputs of the commands sent in the last ``stale_timeout`` s: (time, input)
        self._sent: deque[tuple[float, np.ndarray]] = deque()
        self.mpcc: Mpcc | None = None
        self.follower: PathFollower | None = None
        if kind == "mpcc":
            self.mpcc = Mpcc(track, model, MpccSettings(rate_hz=rate_hz), output=self.output)
        else:
            wheelbase = parameters.value("lf") + parameters.value("lr")
            self.follower = PathFollower(track, wheelbase, PathFollowerSettings(v_ref=v_ref))
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
        #: the controller's call times of the last 30 s at 30 Hz, s (bounded: a node runs for hours)
        self.solve_times: deque[float] = deque(maxlen=900)
        self._calls = 0
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
            u = self._stop(keep_plan=True)
        else:
            if self._stale:
                self.get_logger().info("state estimate is fresh: driving")
                self._reset()
            self._stale = False
            degraded = self._latest[2] == "degraded"
            if degraded != self._degraded:
                self.get_logger().warning(
                    f"state estimate degraded: slowing to {self.degraded_speed:g} m/s"
                    if degraded
                    else "state estimate ok again: full speed"
                )
                self._degraded = degraded
            u = self._command(now, self._predicted(now), self.degraded_speed if degraded else None)
        self._sent.append((now, self._model_input(u)))
        while len(self._sent) > 1 and self._sent[1][0] <= now - self.stale_timeout:
            self._sent.popleft()
        self._input_publisher.publish(conversions.car_input_msg(u, now, self.output))

    def _command(self, now: float, x: np.ndarray, speed_limit: float | None) -> np.ndarray:
        started = time.perf_counter()
        try:
            if self.mpcc is not None:
                u = self.mpcc(x, speed_limit)
                if self.mpcc.status.mode != "solved":
                    self.get_logger().warning(
                        f"MPCC {self.mpcc.status.mode}: {self.mpcc.status.reason}",
                        throttle_duration_sec=1.0,
                    )
            else:
                u = self.follower(now, x, speed_limit)
        except (ValueError, RuntimeError) as error:
            self.get_logger().error(f"controller failed: {error}", throttle_duration_sec=1.0)
            return self._stop()
        self.solve_times.append(time.perf_counter() - started)
        self._calls += 1
        if self._calls % self.solve_times.maxlen == 0:  # every 30 s at 30 Hz
            ms = 1e3 * np.array(self.solve_times)
            self.get_logger().info(
                f"controller call: median {np.median(ms):.2f} ms, "
                f"p99 {np.percentile(ms, 99):.2f} ms, max {ms.max():.2f} ms"
            )
        return u

    def _model_input(self, u: np.ndarray) -> np.ndarray:
        """The model input ``[delta, T]`` of command ``u`` (for the prediction): ``u`` itself
        in torque mode; for a velocity reference the first input of the MPCC's plan (the torque
        it expects the car's velocity PID to apply), zero torque without a plan."""
        if self.output == "torque":
            return u
        plan = self.mpcc.plan if self.mpcc is not None else None
        return plan[1][0, :2].copy() if plan is not None else np.array([u[0], 0.0])

    def _stop(self, keep_plan: bool = False) -> np.ndarray:
        """Zero torque and straight wheels: without a fresh estimate the car's speed is not
        known, so it rolls to a stop rather than being braked (which could reverse it). With
        ``output`` velocity: straight wheels and a zero velocity reference (the car's velocity
        PID brakes it to a stand, on its own wheel speeds). With ``keep_plan`` the MPCC keeps
        its plan for a short gap in the estimates (see :meth:`Mpcc.stop`)."""
        if self.mpcc is not None:
            self.mpcc.stop(None, "state estimate stale or lost", keep_plan=keep_plan)
        return STOP

    def _reset(self) -> None:
        if self.follower is not None:
            self.follower.reset()

    def _predicted(self, now: float) -> np.ndarray:
        """The newest estimate carried forward to ``now``, when the command will act, with the
        model and the commands sent since its stamp, each from its own tick (the estimate is
        tens of ms old: the estimator's lag and the transport; on an emulated lap the carried
        state is 3.9 mm from the truth (median; 54 mm not carried), and the commands' history
        matters once estimates are older than a control period); as it is without
        ``predict``."""
        stamp, x, _ = self._latest
        if self._numeric is None or now <= stamp:
            return x
        t = max(stamp, now - self.stale_timeout)
        sent = self._sent
        for k, (_issued, u) in enumerate(sent):
            until = sent[k + 1][0] if k + 1 < len(sent) else now
            if until <= t:
                continue  # replaced before the estimate's stamp
            x = self._numeric.step(x, u, self._p, until - t)
            t = until
        if t < now:  # no command sent yet (the first tick)
            x = self._numeric.step(x, STOP, self._p, now - t)
        return x


def main(argv: Sequence[str] | None = None) -> int:
    return run(ControllerNode, argv)


if __name__ == "__main__":
    raise SystemExit(main())
