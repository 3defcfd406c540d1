"""Estimator node: EKF or MHE from ``crs_core`` on whatever sensors publish.

Subscribes to ``sensors/batch`` (the readings of a car in batches, :mod:`ros4crs.sensor_output`),
the per-reading ``sensors/*`` topics and ``input`` (or, with ``input_topic`` ``input/applied``, the
inputs the car reports applying, published by the bridge: behind Wi-Fi a command reaches the car
late, out of order or not at all, and during a motor cut-off the car applies none; the car stack
uses them); every message is validated and converted at the
boundary (a malformed one is logged and dropped). The real-time policy (start, query grid,
adaptive lag, late data, clock jumps, deadlines) is a
:class:`~crs_core.estimation.realtime.RealtimeEstimator`; the node feeds it, publishes what it
returns and logs its warnings. A timer at ``rate_hz`` asks the estimator for
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

For a viewer (:mod:`ros4crs.visualizer_node`) it publishes, only while someone subscribes and
when the Lighthouse is among its sensors, ``lighthouse_fix``
(``geometry_msgs/PoseWithCovarianceStamped`` in ``world``): each base station's single-shot pose
fix from its sweep pair (:class:`~crs_core.estimation.lighthouse_pose.LighthouseFixes`), at most
:data:`FIX_RATE_HZ` per station; not recorded by the stack, and not used by the estimate (which
takes the sweeps themselves).

Velocity-mode inputs: only torque-mode commands are inputs of the model: a velocity-mode command
(``CarInput.MODE_VELOCITY``, a reference for the car's onboard velocity PID) says nothing about the
torque the car applies, so it is ignored (counted in ``velocity_references``, logged once); with
``inputs`` auto (the default) the estimator then keeps estimating the inputs from the sensors (the
input-free model), as without commands. It is not logged in ``estimate/query`` either, so a bag
replays the same way (:func:`ros4crs.bag_replay.read_car` leaves such commands out too). An
estimator that has switched to the commanded model (a torque-mode command came first) stays on it
and holds the last torque command if the car switches to velocity mode later: restart it for such a
run.

Parameters: ``estimator`` (ekf | mhe), ``input_topic`` (input | input/applied), ``sensors``
(e.g. "lh+imu+we"; default: those of lh+imu+we its model explains, the kinematic bicycle's
"lh+we", :func:`~crs_core.estimation.factory.default_sensors`), ``rate_hz``, ``lag`` (s,
default 0.02), ``max_lag`` (s; default 0.1 for the EKF, which drops late data, and 0 for the MHE,
which takes them into its window at its next update, where a longer lag would only delay the
controller: an MPCC fed estimates 110-180 ms old steered bang-bang and spun the car; not above
``lag``: the lag stays),
``horizon`` (MHE), ``catch_up_solves`` (MHE: an update that finds more grid nodes due, because it
came late, solves only the newest this many and predicts the others, so that a loaded machine's
late update does not make the next one later still; default 2), ``inputs`` (auto | commanded |
estimated), ``stations``, ``params_file`` (model parameter YAML, optional; its ``noise:``
section, ``crs tune-noise``'s, sets the estimators' noise), ``model`` (the
model: ``dynamic``, ``kinematic`` or ``FILE.py:CLASS``; empty: the one ``params_file`` names, else
dynamic; the estimate published is always the car state it maps to), ``track_file`` (CRS
track YAML; default DEMO_TRACK), ``initial_state`` (6 floats; default the track's start),
``blind_start`` (ignore ``initial_state`` and initialise from the Lighthouse), ``time_offsets``
(per sensor or group the delay of its stamps, e.g. "lh:0.004,imu:0.001"; keep ``lag`` larger),
``online_parameters`` (parameters estimated online beside the state, e.g. "Cm1,gyro_bias,grip";
:mod:`crs_core.model.online`; default none): with them, each published estimate is followed by
``estimate/parameters`` (``chronos_msgs/OnlineParameters``: value, standard deviation and whether
informed, per parameter).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
from rclpy.node import Node

from crs_core.errors import FieldError
from crs_core.estimation import (
    INPUT_MODES,
    KINDS,
    EkfSettings,
    LighthouseFixes,
    LighthousePoseSolver,
    MheSettings,
    make_estimator,
    parse_sensor_set,
)
from crs_core.estimation.base import parse_time_offsets
from crs_core.estimation.factory import default_sensors
from crs_core.estimation.noise import EstimatorNoise, noise_in_file
from crs_core.estimation.realtime import RealtimeEstimator, RealtimeSettings
from crs_core.measurements import Measurement
from crs_core.model.online import parse_online_names
from ros4crs import conversions
from ros4crs.node_support import (
    LOG_QOS,
    CheckedSubscription,
    ParameterError,
    declare,
    declare_initial_state,
    declare_model,
    in_range,
    input_subscription,
    one_of,
    parsed_with,
    run,
    throttled_warning,
)
from ros4crs.settings_parameters import SettingsParameters, declare_settings

#: Most Lighthouse pose fixes a second per base station for a viewer (the stations sweep at
#: ~50 Hz; at 10 Hz the visualizer cost 10.0 % of a core per car, against 9.1 % without fixes).
FIX_RATE_HZ = 5.0
#: The real-time policy's settings, all parameters (default, description and bounds: the
#: dataclass's; ``max_lag``'s default is the node's, by estimator).
REALTIME_PARAMETERS = SettingsParameters(RealtimeSettings, ("rate_hz", "lag", "max_lag"))


def node_noise(node: Node) -> EstimatorNoise:
    """The estimators' noise: the ``params_file``'s ``noise:`` section over the defaults
    (:func:`~crs_core.estimation.noise.noise_in_file`; a bad entry refused naming
    ``params_file``)."""
    path = node.get_parameter("params_file").value or None
    try:
        return noise_in_file(path)
    except FieldError as error:
        raise ParameterError("params_file", str(error)) from None


class EstimatorNode(Node):
    """Wraps a :class:`~crs_core.estimation.realtime.RealtimeEstimator`."""

    def __init__(self, **node_options: Any) -> None:
        super().__init__("estimator", **node_options)
        kind = declare(self, "estimator", "mhe", "ekf or mhe", one_of(*KINDS))
        stations = declare(self, "stations", 1, "Lighthouse base stations", in_range(1, 8))
        model = declare_model(self, n_base_stations=stations)
        # by default lh+imu+we, of those the model explains (the kinematic bicycle: lh+we)
        sensors = declare(
            self,
            "sensors",
            default_sensors(model),
            "sensor groups joined by +",
            parsed_with(parse_sensor_set),
        )
        # the EKF drops late data; the MHE takes them into its window at the next update, and
        # a larger lag would only make the controller's loop slower (a max_lag below lag:
        # the lag stays)
        timing = declare_settings(
            self, REALTIME_PARAMETERS, defaults={"max_lag": 0.1 if kind == "ekf" else 0.0}
        )
        self.rate_hz = timing.rate_hz
        horizon = declare(
            self, "horizon", MheSettings.horizon, "MHE horizon, stages", in_range(2, 1000)
        )
        solves = declare(
            self, "catch_up_solves", 2, "MHE: most nodes solved per update", in_range(1, 1000)
        )
        inputs = declare(
            self, "inputs", "auto", "auto, commanded or estimated", one_of(*INPUT_MODES)
        )
        self.inputs = inputs
        self.input_topic = declare(
            self,
            "input_topic",
            conversions.TOPICS["input"],
            "model inputs from: input (commands sent) or input/applied (what the car applied)",
            one_of(conversions.TOPICS["input"], conversions.TOPICS["applied_input"]),
        )
        blind_start = declare(self, "blind_start", False, "start from the Lighthouse")
        if blind_start and not parse_sensor_set(sensors) & {"lh", "pose"}:
            raise ParameterError("blind_start", "needs lh (Lighthouse) or pose among the sensors")
        online_text = declare(
            self,
            "online_parameters",
            "",
            "parameters estimated online, e.g. Cm1,gyro_bias,grip (empty: none)",
            parsed_with(lambda text: parse_online_names(text) if text.strip() else ()),
        )
        online_names = parse_online_names(online_text) if online_text.strip() else ()
        initial = np.asarray(declare_initial_state(self, "initial estimate"))
        offsets = parse_time_offsets(
            declare(
                self,
                "time_offsets",
                "",
                "stamp delays, e.g. lh:0.004,imu:0.001 (s)",
                parsed_with(parse_time_offsets),
            )
        )
        noise = node_noise(self)
        settings = (
            MheSettings(
                noise=noise,
                horizon=horizon,
                rate_hz=self.rate_hz,
                time_offsets=offsets,
                catch_up_solves=solves,
                online_parameters=online_names,
            )
            if kind == "mhe"
            else EkfSettings(noise=noise, time_offsets=offsets, online_parameters=online_names)
        )
        try:
            self.estimator = make_estimator(kind, sensors, model, settings, inputs=inputs)
        except FieldError as error:  # an online parameter the model does not have
            raise ParameterError(error.field, error.reason) from None
        self.fixes = (
            LighthouseFixes(
                LighthousePoseSolver(model, settings.noise.lighthouse_std),
                min_interval=1.0 / FIX_RATE_HZ,
            )
            if "lh" in parse_sensor_set(sensors)
            else None
        )
        self.realtime = RealtimeEstimator(
            self.estimator,
            timing,
            None if blind_start else initial,
        )
        self.kind = kind
        from geometry_msgs.msg import PoseWithCovarianceStamped
        from nav_msgs.msg import Odometry

        from chronos_msgs.msg import (
            CarState,
            EstimatorDiagnostics,
            EstimatorQuery,
            OnlineParameters,
            SensorBatch,
        )
        from tf2_msgs.msg import TFMessage

        self._checked_subscriptions: list = []
        #: Sensor messages received, by sensor name.
        self.received: dict[str, int] = {}
        #: Velocity-mode commands received (ignored: they carry no torque).
        self.velocity_references = 0
        # each its own throttle: a deadline miss on a loaded machine hid the warning of the
        # late data that followed within the second
        self._warn = {
            "late": throttled_warning(self),
            "deadline": throttled_warning(self),
            "lag": throttled_warning(self),
            "status": throttled_warning(self),
            "batch": throttled_warning(self),
            "restart": self.get_logger().warning,
        }
        #: Readings of ``sensors/batch`` messages dropped alone (a NaN, an unknown sensor).
        self.rejected_readings = 0
        for family, msg_type in conversions.sensor_message_types().items():
            self._subscribe(family, msg_type)
        self._checked_subscriptions.append(
            CheckedSubscription(
                self,
                SensorBatch,
                conversions.TOPICS["batch"],
                conversions.batch_from_msg,
                self._on_batch,
                "batch",
            )
        )
        self._checked_subscriptions.append(
            input_subscription(self, self._on_input, self.input_topic)
        )
        self._state = self.create_publisher(CarState, conversions.TOPICS["state"], LOG_QOS)
        self._odometry = self.create_publisher(Odometry, conversions.TOPICS["odometry"], 10)
        self._tf = self.create_publisher(TFMessage, "/tf", 100)
        self.body_frame = conversions.body_frame(self.get_namespace())
        self._diagnostics = self.create_publisher(
            EstimatorDiagnostics, conversions.TOPICS["diagnostics"], 10
        )
        self._queries = self.create_publisher(EstimatorQuery, conversions.TOPICS["query"], LOG_QOS)
        self._online_publisher = (
            self.create_publisher(OnlineParameters, conversions.TOPICS["parameters"], LOG_QOS)
            if online_names
            else None
        )
        self._fix_publisher = self.create_publisher(
            PoseWithCovarianceStamped, conversions.TOPICS["lighthouse_fix"], 10
        )
        self._timer = self.create_timer(1.0 / self.rate_hz, self._update)
        self.create_timer(1.0, self._publish_diagnostics)
        self.get_logger().info(
            f"{kind} on {sensors} at {self.rate_hz:g} Hz, model {model.plant.name}"
        )

    def _subscribe(self, family: str, msg_type: type) -> None:
        topic = conversions.TOPICS[family]
        self._checked_subscriptions.append(
            CheckedSubscription(
                self,
                msg_type,
                topic,
                conversions.SENSOR_PARSERS[family],
                lambda measurement: self._on_measurement(measurement, topic, self._arrival()),
                family,
            )
        )

    def _on_batch(self, readings: conversions.BatchReadings) -> None:
        """The readings of a ``sensors/batch`` message, each into the stream of its own topic
        (what the estimator's query log names and a replay feeds, whichever form it came in)."""
        now = self._arrival()  # the readings of a batch arrive together
        for measurement in readings.measurements:
            family = conversions.topic_family(measurement.sensor)
            self._on_measurement(measurement, conversions.TOPICS[family], now)
        if readings.rejected:
            self.rejected_readings += len(readings.rejected)
            self._warn["batch"](
                f"dropped {len(readings.rejected)} reading(s) of a batch on "
                f"{conversions.TOPICS['batch']}: {readings.rejected[0]} "
                f"({self.rejected_readings} so far)"
            )

    def _arrival(self) -> float | None:
        """The clock now, when the estimator tracks arrival delays (else not needed: ``None``)."""
        return self._now() if self.realtime.tracks_delays else None

    def _on_measurement(self, measurement: Measurement, source: str, now: float | None) -> None:
        received = self.received
        received[measurement.sensor] = received.get(measurement.sensor, 0) + 1
        warning = self.realtime.deliver(measurement, now, source)
        if warning is not None:
            self._warn[warning.kind](warning.message)
        if self.fixes is not None and self._fix_publisher.get_subscription_count():
            fix = self.fixes.add(measurement)
            if fix is not None:
                self._fix_publisher.publish(conversions.pose_fix_msg(fix))

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
        warning = self.realtime.deliver(command.input_sample(), self._arrival(), self.input_topic)
        if warning is not None:
            self._warn[warning.kind](warning.message)

    @property
    def malformed(self) -> int:
        """Messages and batch readings dropped at the boundary so far."""
        return sum(s.dropped for s in self._checked_subscriptions) + self.rejected_readings

    def _now(self) -> float:
        return self.get_clock().now().nanoseconds * 1e-9

    def _take_pending(self) -> None:
        """Everything that has arrived (rclpy runs a due timer before queued messages)."""
        for subscription in self._checked_subscriptions:
            subscription.take_pending()

    def _update(self) -> None:
        realtime = self.realtime
        lateness = 0.0
        if not realtime.started:  # the start is anchored at the tick's scheduled time
            until = self._timer.time_until_next_call()
            lateness = 1.0 / self.rate_hz - 1e-9 * until if until is not None else 0.0
        result = realtime.update(self._now(), lateness, self._take_pending)
        for warning in result.warnings:
            self._warn[warning.kind](warning.message)
        t = result.t
        if result.queried:
            self._queries.publish(
                conversions.query_msg(t, result.started, realtime.newest, realtime.oldest)
            )
        if result.initial is not None:
            covariance = np.diag(np.full(6, 1.0))
            self._state.publish(conversions.car_state_msg(result.initial, t, covariance))
        estimate = result.estimate
        if estimate is None or estimate.status == "lost":
            return
        self._state.publish(
            conversions.car_state_msg(estimate.x, t, estimate.covariance, estimate.status)
        )
        self._odometry.publish(conversions.odometry_msg(estimate, self.body_frame))
        self._tf.publish(conversions.transform_msg(estimate, self.body_frame))
        if self._online_publisher is not None and estimate.parameters:
            self._online_publisher.publish(conversions.online_parameters_msg(estimate))

    def timing_stats(self) -> dict[str, float]:
        """What the estimator's own computing cost so far (:func:`ros4crs.node_support.run_nodes`
        writes it out at the end of a run): updates and their CPU time, s."""
        return {
            "updates": self.realtime.updates,
            "solver_cpu_s": round(self.realtime.update_cpu_seconds, 4),
        }

    def _publish_diagnostics(self) -> None:
        from chronos_msgs.msg import EstimatorDiagnostics

        d = self.estimator.diagnostics
        realtime = self.realtime
        msg = EstimatorDiagnostics()
        conversions.fill_stamp(msg.header.stamp, max(self._now(), 0.0))
        msg.estimator, msg.status = self.kind, d.last_status
        msg.solve_time, msg.max_solve_time = d.last_solve_time_s, realtime.take_max_update_time()
        msg.updates, msg.deadline_misses = realtime.updates, realtime.deadline_misses
        msg.rejected_measurements = sum(d.rejected.values())
        msg.late_measurements = d.late
        msg.ignored_measurements = sum(d.ignored.values()) + self.malformed
        msg.fallbacks = d.fallbacks
        msg.reinitializations = d.reinitializations
        msg.skipped_time = float(d.skipped_s)
        msg.sensors = list(self.received)
        msg.received = list(self.received.values())
        self._diagnostics.publish(msg)


def main(argv: Sequence[str] | None = None) -> int:
    return run(EstimatorNode, argv)


if __name__ == "__main__":
    raise SystemExit(main())
