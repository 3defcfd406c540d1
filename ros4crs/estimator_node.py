"""Estimator node: EKF or MHE from ``crs_core`` on whatever sensors publish.

Subscribes to ``sensors/*`` and ``input``; every message is validated and converted at the
boundary (a malformed one is logged and dropped). A timer at ``rate_hz`` asks the estimator for
the state at ``now - lag`` (the lag lets messages in flight arrive first; it must exceed the
transport latency: it is raised to cover the largest arrival delay, receipt minus stamp, of the
last 5 s, up to ``max_lag``) and publishes ``estimate/state`` (CarState), ``estimate/odometry``
(Odometry), the transform ``world`` -> ``<ns>/base_link`` on ``/tf`` and, once a second,
``estimate/diagnostics``; ``estimate/query`` logs every query with the newest data it had, so
that a recorded bag replays the estimator offline exactly. An update slower than the period
counts as a deadline miss. A missing sensor never blocks: its terms are simply absent. The
estimator starts (and publishes its initial state) at the first update after the first
measurement arrived, so no controller drives on a guess with no data behind it. While the
estimate is ``lost`` (a blind start waiting for its Lighthouse fix, or a re-initialisation)
nothing is published on ``estimate/state``, ``estimate/odometry`` and ``/tf``: a controller sees a
stale estimate and stops the car; the diagnostics say why. A clock that jumps back (a looped
bag replay with ``/clock``) restarts the estimator on the data that follow, with a warning.

Velocity-mode inputs: only torque-mode commands are inputs of the model: a velocity-mode command
(``CarInput.MODE_VELOCITY``, a reference for the car's onboard velocity PID) says nothing about the
torque the car applies, so it is ignored (counted in ``velocity_references``, logged once); with
``inputs`` auto (the default) the estimator then keeps estimating the inputs from the sensors (the
input-free model), as without commands. It is not logged in ``estimate/query`` either, so a bag
replays the same way (:func:`ros4crs.bag_replay.read_car` leaves such commands out too). An
estimator that has switched to the commanded model (a torque-mode command came first) stays on it
and holds the last torque command if the car switches to velocity mode later: restart it for such a
run.

Parameters: ``estimator`` (ekf | mhe), ``sensors`` (e.g. "lh+imu+we"), ``rate_hz``, ``lag`` (s,
default 0.02), ``max_lag`` (s; default 0.1 for the EKF, which drops late data, and 0 for the MHE,
which takes them into its window at its next update, where a longer lag would only delay the
controller: an MPCC fed estimates 110-180 ms old steered bang-bang and spun the car; not above
``lag``: the lag stays),
``horizon`` (MHE), ``catch_up_solves`` (MHE: an update that finds more grid nodes due, because it
came late, solves only the newest this many and predicts the others, so that a loaded machine's
late update does not make the next one later still; default 2), ``inputs`` (auto | commanded |
estimated), ``stations``, ``params_file`` (model parameter YAML, optional), ``track_file`` (CRS
track YAML; default DEMO_TRACK), ``initial_state`` (6 floats; default the track's start),
``blind_start`` (ignore ``initial_state`` and initialise from the Lighthouse), ``time_offsets``
(per sensor or group the delay of its stamps, e.g. "lh:0.004,imu:0.001"; keep ``lag`` larger).
"""

from __future__ import annotations

import math
import time
from collections.abc import Sequence

import numpy as np
from rclpy.node import Node

from crs_core.estimation import (
    INPUT_MODES,
    KINDS,
    EkfSettings,
    MheSettings,
    make_estimator,
    parse_sensor_set,
)
from crs_core.estimation.base import parse_time_offsets
from crs_core.measurements import InputSample, Measurement, from_start
from ros4crs import conversions
from ros4crs.node_support import (
    LOG_QOS,
    CheckedSubscription,
    ParameterError,
    declare,
    declare_model,
    declare_track,
    finite_vector,
    in_range,
    non_negative,
    one_of,
    parsed_with,
    positive,
    run,
    throttled_warning,
)

#: A clock that goes back by more than this (s) restarts the estimator (a looped replay).
CLOCK_JUMP_S = 0.5
#: A query this close (in periods) before the next grid time is asked at that time.
GRID_TOLERANCE = 0.05
#: The lag covers the largest arrival delay (receipt minus stamp) of the last this many s ...
LAG_WINDOW_S = 5.0
#: ... plus this margin, s.
LAG_MARGIN_S = 0.005


class WindowMax:
    """The largest value added in the last ``window`` s (whole seconds of buckets)."""

    def __init__(self, window: float) -> None:
        self._buckets: dict[int, float] = {}
        self._window = math.ceil(window)

    def add(self, now: float, value: float) -> None:
        second = math.floor(now)
        if value > self._buckets.get(second, -math.inf):
            self._buckets[second] = value
            if len(self._buckets) > self._window + 1:
                self._buckets = {
                    k: v for k, v in self._buckets.items() if k > second - self._window
                }

    def value(self, now: float) -> float:
        """The largest value of the window ending at ``now`` (-inf: none)."""
        oldest = math.floor(now) - self._window
        return max((v for k, v in self._buckets.items() if k > oldest), default=-math.inf)


class EstimatorNode(Node):
    """Wraps an :class:`~crs_core.estimation.base.Estimator`."""

    def __init__(self) -> None:
        super().__init__("estimator")
        kind = declare(self, "estimator", "mhe", "ekf or mhe", one_of(*KINDS))
        sensors = declare(
            self, "sensors", "lh+imu+we", "sensor groups joined by +", parsed_with(parse_sensor_set)
        )
        self.rate_hz = declare(self, "rate_hz", 60.0, "estimate rate, Hz", positive)
        self.lag = declare(self, "lag", 0.02, "estimate this many s in the past", non_negative)
        # the EKF drops late data; the MHE takes them into its window at the next update, and
        # a larger lag would only make the controller's loop slower (a max_lag below lag:
        # the lag stays)
        self.max_lag = max(
            self.lag,
            declare(
                self,
                "max_lag",
                0.1 if kind == "ekf" else 0.0,
                "raise the lag up to this for late data, s",
                non_negative,
            ),
        )
        #: the lag in use, s: ``lag`` raised while data arrive late (up to ``max_lag``)
        self.current_lag = self.lag
        self._delays = WindowMax(LAG_WINDOW_S)
        horizon = declare(self, "horizon", 40, "MHE horizon, stages", in_range(2, 1000))
        solves = declare(
            self, "catch_up_solves", 2, "MHE: most nodes solved per update", in_range(1, 1000)
        )
        inputs = declare(
            self, "inputs", "auto", "auto, commanded or estimated", one_of(*INPUT_MODES)
        )
        self.inputs = inputs
        self.blind_start = declare(self, "blind_start", False, "start from the Lighthouse")
        if self.blind_start and not parse_sensor_set(sensors) & {"lh", "pose"}:
            raise ParameterError("blind_start: needs lh (Lighthouse) or pose among the sensors")
        stations = declare(self, "stations", 1, "Lighthouse base stations", in_range(1, 8))
        model = declare_model(self, n_base_stations=stations)
        track = declare_track(self)
        start = [track.start_x, track.start_y, track.start_yaw, 0.0, 0.0, 0.0]
        self.initial = np.asarray(
            declare(self, "initial_state", start, "initial estimate", finite_vector(6))
        )
        offsets = parse_time_offsets(
            declare(
                self,
                "time_offsets",
                "",
                "stamp delays, e.g. lh:0.004,imu:0.001 (s)",
                parsed_with(parse_time_offsets),
            )
        )
        settings = (
            MheSettings(
                horizon=horizon,
                rate_hz=self.rate_hz,
                time_offsets=offsets,
                catch_up_solves=solves,
            )
            if kind == "mhe"
            else EkfSettings(time_offsets=offsets)
        )
        self.estimator = make_estimator(kind, sensors, model, settings, inputs=inputs)
        self._warn_status = throttled_warning(self)
        self.kind = kind
        from nav_msgs.msg import Odometry

        from chronos_msgs.msg import CarInput, CarState, EstimatorDiagnostics, EstimatorQuery
        from tf2_msgs.msg import TFMessage

        self._checked_subscriptions: list = []
        self._warn_late = throttled_warning(self)
        self._warn_lag = throttled_warning(self)
        for family, msg_type in conversions.sensor_message_types().items():
            self._subscribe(family, msg_type)
        self._checked_subscriptions.append(
            CheckedSubscription(
                self,
                CarInput,
                conversions.TOPICS["input"],
                conversions.input_from_msg,
                self._on_input,
                "input",
            )
        )
        self._state = self.create_publisher(CarState, conversions.TOPICS["state"], LOG_QOS)
        self._odometry = self.create_publisher(Odometry, conversions.TOPICS["odometry"], 10)
        self._tf = self.create_publisher(TFMessage, "/tf", 100)
        self.body_frame = conversions.body_frame(self.get_namespace())
        self._diagnostics = self.create_publisher(
            EstimatorDiagnostics, conversions.TOPICS["diagnostics"], 10
        )
        self._queries = self.create_publisher(EstimatorQuery, conversions.TOPICS["query"], LOG_QOS)
        self.received: dict[str, int] = {}
        #: Velocity-mode commands received (ignored: they carry no torque).
        self.velocity_references = 0
        self._newest: dict[str, float] = {}  # per input topic, the newest stamp received
        self.deadline_misses = 0
        self.updates = 0
        self._max_solve = 0.0
        self._started = False
        self.restarts = 0
        self._buffer: list[Measurement | InputSample] = []
        self._last_query = -np.inf
        self._grid_origin = 0.0
        self._timer = self.create_timer(1.0 / self.rate_hz, self._update)
        self.create_timer(1.0, self._publish_diagnostics)
        self.get_logger().info(f"{kind} on {sensors} at {self.rate_hz:g} Hz")

    def _subscribe(self, family: str, msg_type: type) -> None:
        topic = conversions.TOPICS[family]

        def handle(measurement: Measurement) -> None:
            self.received[measurement.sensor] = self.received.get(measurement.sensor, 0) + 1
            self._newest[topic] = max(self._newest.get(topic, -np.inf), measurement.stamp)
            self._deliver(measurement)

        self._checked_subscriptions.append(
            CheckedSubscription(
                self,
                msg_type,
                conversions.TOPICS[family],
                conversions.SENSOR_PARSERS[family],
                handle,
                family,
            )
        )

    def _on_input(self, command: conversions.CarCommand) -> None:
        if command.mode != "torque":  # a velocity reference: the torque is the car's secret
            self.velocity_references += 1
            if self.velocity_references == 1:
                self.get_logger().info(
                    f"input: {command.mode}-mode commands carry no torque: ignored"
                    + (
                        " (the inputs are estimated from the sensors)"
                        if self.inputs != "commanded"
                        else "; with inputs=commanded the model sees no command (use auto)"
                    )
                )
            return
        topic = conversions.TOPICS["input"]
        self._newest[topic] = max(self._newest.get(topic, -np.inf), command.stamp)
        self._deliver(command.input_sample())

    @property
    def malformed(self) -> int:
        """Messages dropped at the boundary so far."""
        return sum(s.dropped for s in self._checked_subscriptions)

    def _deliver(self, item: Measurement | InputSample) -> None:
        """Into the estimator, or a buffer until its first update (it starts at now - lag)."""
        if not self._started:
            self._buffer.append(item)
            return
        if self.max_lag > self.lag:  # the lag can rise: track the arrival delays
            now = self._now()
            self._delays.add(now, now - item.stamp)
        late_before = self.estimator.diagnostics.late
        try:
            self.estimator.add(item)
        except ValueError as error:  # a sensor the model does not have
            self._warn_late(f"dropped: {error}")
            return
        if self.estimator.diagnostics.late > late_before:
            self._warn_late(
                f"dropped out-of-order data stamped {item.stamp:.3f} s: older than what the "
                "estimator already processed"
            )

    def _now(self) -> float:
        return self.get_clock().now().nanoseconds * 1e-9

    def _query_time(self) -> float:
        """``now - lag`` on the grid of the timer's schedule: the MHE's nodes sit on a grid
        anchored at its start, and a query between two nodes costs an EKF pass over the data
        since the newer one (whose length would otherwise be set by how late the start's tick
        happened to fire: up to a whole period, a quarter of the estimator's CPU). The start is
        therefore taken at its tick's scheduled time (``now`` minus the tick's lateness), and
        every query at the newest grid time by ``now - lag``: on a node, never later than
        before by more than :data:`GRID_TOLERANCE` of a period, earlier only by the tick's
        lateness."""
        period = 1.0 / self.rate_hz
        now = self._now()
        delay = self._delays.value(now)
        lag = min(max(self.lag, delay + LAG_MARGIN_S), self.max_lag)
        if lag > self.current_lag + LAG_MARGIN_S:
            self._warn_lag(
                f"data arrive up to {1e3 * delay:.0f} ms after their stamps: estimating "
                f"{1e3 * lag:.0f} ms in the past (max_lag {1e3 * self.max_lag:.0f} ms)"
            )
        self.current_lag = lag
        raw = now - lag
        if not self._started:
            until = self._timer.time_until_next_call()
            late = period - 1e-9 * until if until is not None else 0.0
            return raw - min(max(late, 0.0), period)
        steps = np.floor((raw - self._grid_origin) / period + GRID_TOLERANCE)
        return self._grid_origin + steps * period

    def _update(self) -> None:
        t = self._query_time()
        if self._started and t < self._last_query - CLOCK_JUMP_S:
            self._restart(f"the clock jumped back by {self._last_query - t:.2f} s")
        # everything that has arrived first (rclpy runs a due timer before queued messages)
        for subscription in self._checked_subscriptions:
            subscription.take_pending()
        if not self._started and not any(isinstance(i, Measurement) for i in self._buffer):
            return  # no data yet: publishing the initial guess would let the car drive blind
        if not self._started:  # start at now - lag, with the command in effect then
            blind = self.blind_start or self.restarts > 0
            self.estimator.reset(t, None if blind else self.initial)
            self._started = True
            self._grid_origin = t
            self._last_query = t
            # data still in flight from before a clock jump lie in the future: not ours
            arrived = [i for i in self._buffer if i.stamp <= t + self.lag + CLOCK_JUMP_S]
            for item in from_start(arrived, t):
                self._deliver(item)
            self._buffer.clear()
            self._queries.publish(conversions.query_msg(t, True, self._newest))
            if not blind:
                covariance = np.diag(np.full(6, 1.0))
                self._state.publish(conversions.car_state_msg(self.initial, t, covariance))
            return
        if t <= self._last_query:
            return
        self._last_query = t
        start = time.perf_counter()
        try:
            estimate = self.estimator.estimate(t)
        except ValueError as error:  # e.g. a clock that jumped back: say so, keep running
            self._warn_status(f"no estimate at {t:.3f} s: {error}")
            return
        finally:
            self._queries.publish(conversions.query_msg(t, False, self._newest))
        elapsed = time.perf_counter() - start
        self.updates += 1
        self._max_solve = max(self._max_solve, elapsed)
        if elapsed > 1.0 / self.rate_hz:
            self.deadline_misses += 1
            self._warn_late(
                f"update took {1e3 * elapsed:.0f} ms, over the {1e3 / self.rate_hz:.0f} ms period "
                f"({self.deadline_misses} misses): the next one estimates at the newest time"
            )
        if estimate.status != "ok":
            self._warn_status(f"estimate {estimate.summary}")
        if estimate.status == "lost":
            return
        self._state.publish(
            conversions.car_state_msg(estimate.x, t, estimate.covariance, estimate.status)
        )
        self._odometry.publish(conversions.odometry_msg(estimate, self.body_frame))
        self._tf.publish(conversions.transform_msg(estimate, self.body_frame))

    def _restart(self, why: str) -> None:
        """Start over on the data that come next (the Lighthouse initialises it when the
        estimator has it; else ``initial_state``), e.g. when a looped bag replay with ``/clock``
        jumps back in time: continuing would call everything that follows late."""
        self.restarts += 1
        self._started = False
        self._buffer.clear()
        self._newest.clear()
        self.get_logger().warning(f"{why}: restarting the estimator (restart {self.restarts})")

    def _publish_diagnostics(self) -> None:
        from chronos_msgs.msg import EstimatorDiagnostics

        d = self.estimator.diagnostics
        msg = EstimatorDiagnostics()
        conversions.fill_stamp(msg.header.stamp, max(self._now(), 0.0))
        msg.estimator, msg.status = self.kind, d.last_status
        msg.solve_time, msg.max_solve_time = d.last_solve_time_s, self._max_solve
        msg.updates, msg.deadline_misses = self.updates, self.deadline_misses
        msg.rejected_measurements = sum(d.rejected.values())
        msg.late_measurements = d.late
        msg.ignored_measurements = sum(d.ignored.values()) + self.malformed
        msg.fallbacks = d.fallbacks
        msg.reinitializations = d.reinitializations
        msg.skipped_time = float(d.skipped_s)
        msg.sensors = list(self.received)
        msg.received = list(self.received.values())
        self._diagnostics.publish(msg)
        self._max_solve = 0.0


def main(argv: Sequence[str] | None = None) -> int:
    return run(EstimatorNode, argv)


if __name__ == "__main__":
    raise SystemExit(main())
