"""Simulator node: the ``sim`` engine in real time (or faster, publishing ``/clock``).

Publishes every sensor at its own rate with its own stamp (in batches on ``sensors/batch``, or
one message each on ``sensors/*``: :mod:`ros4crs.sensor_output`), the ground truth
(``ground_truth``), and applies each ``input`` command when it arrives. With ``onboard`` the car's
250 Hz onboard loop runs in the simulation (:mod:`sim.onboard`, as on the real car): a command is
then a reference for its steering PID and either a torque (``MODE_TORQUE``) or a velocity reference
for its velocity PID (``MODE_VELOCITY``). Without it the commands act on the model directly, and a
``MODE_VELOCITY`` command is dropped with a (throttled) warning naming ``mode``. Stamps are
``epoch + simulation time`` with ``epoch`` the wall time at start, so at ``rate_factor`` 1 they are
wall-clock times; at any other factor the node publishes ``/clock`` and the other nodes run with
``use_sim_time``.

Parameters: ``seed``, ``noise_free``, ``effects`` ("name=value,..."), ``blackouts``
("sensor:start:duration;..."), ``stations``, ``rate_factor``, ``tick_hz``, ``truth_rate_hz``,
``initial_state`` (6 floats; default the track's start), ``track_file`` (CRS track YAML; default
DEMO_TRACK), ``params_file`` (parameter YAML of the simulated car), ``model`` (its model:
``dynamic``, ``kinematic`` or ``FILE.py:CLASS``; empty: the one ``params_file`` names, else
dynamic; the ground truth is its car state), ``duration`` (s, 0 = forever),
``wait_for_subscribers`` (simulated time starts once every sensor topic has this many
subscribers, so a launched stack misses nothing at the start; 0 = start at once),
``wait_for_commands`` (bool, default false: simulated time also waits for a publisher on
``input``, the controller, which exists once the controller is built: on a cold compile cache
the controller came 7 s after the simulator had started, and the estimator ran those 7 s beside
its compiler), ``onboard``
(bool, default false: run the onboard loop; with ``noise_free`` its potentiometer is ideal),
``sensor_messages`` and ``batch_period`` (:mod:`ros4crs.sensor_output`; the period in simulated
time), ``command_timeout`` (s of simulated time without a command that cut the drive motor, as
the car's firmware does after 200 ms (:mod:`sim.cutoff`): torque 0, the steering held, until the
next command; 0 = hold the last command for ever), ``drift_file`` (a schedule of changes to the
simulated car while it races, :mod:`sim.drift`; empty: none; the parameters it changes are
published as they are with the ground truth, on ``ground_truth/parameters``).
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from typing import Any

import numpy as np
import rclpy
from rclpy.node import Node

from crs_core.errors import FieldError
from crs_core.model.effects import effect_spec, parse_effect
from ros4crs import conversions
from ros4crs.node_support import (
    ParameterError,
    declare,
    declare_initial_state,
    declare_model,
    in_range,
    input_subscription,
    non_negative,
    parsed_with,
    positive,
    run,
    throttled_warning,
)
from ros4crs.sensor_output import declare_sensor_output
from sim.cutoff import DISCONNECT_THRESHOLD_S, MotorCutoff
from sim.drift import load_drift
from sim.onboard import OnboardSettings
from sim.sensors import Blackout, SensorSuite, parse_blackout
from sim.simulator import Simulator

#: Ground truth published per second unless ``truth_rate_hz`` says otherwise.
DEFAULT_TRUTH_RATE_HZ = 50.0


def parse_effects(text: str) -> dict[str, dict[str, float] | None]:
    """``"steering_lag=0.05,gyro_bias"`` -> the ``effects`` mapping of ``CarModel``.

    Each item is ``NAME``, ``NAME=VALUE`` or ``NAME.PARAM=VALUE``
    (:func:`~crs_core.model.effects.parse_effect`).
    """
    return effect_spec(parse_effect(item) for item in text.split(",") if item.strip())


def parse_blackouts(text: str) -> tuple[Blackout, ...]:
    """``"lighthouse:10:1.127;imu:3:0.5"`` -> blackouts (see :func:`sim.sensors.parse_blackout`)."""
    return tuple(parse_blackout(item) for item in text.split(";") if item.strip())


class SimulatorNode(Node):
    """Runs a :class:`sim.simulator.SimulationSession` against the wall clock."""

    def __init__(self, **node_options: Any) -> None:
        super().__init__("simulator", **node_options)
        seed = declare(self, "seed", 0, "seed of all noise")
        noise_free = declare(self, "noise_free", False, "ideal sensors")
        effects = parse_effects(
            declare(
                self,
                "effects",
                "",
                "hidden truth effects name=value,...",
                parsed_with(parse_effects),
            )
        )
        blackouts = parse_blackouts(
            declare(
                self, "blackouts", "", "sensor:start:duration;...", parsed_with(parse_blackouts)
            )
        )
        stations = declare(self, "stations", 1, "Lighthouse base stations", in_range(1, 8))
        self.rate_factor = declare(self, "rate_factor", 1.0, "simulated s per wall s", positive)
        tick_hz = declare(self, "tick_hz", 250.0, "how often the engine advances, Hz", positive)
        truth_hz = declare(
            self, "truth_rate_hz", DEFAULT_TRUTH_RATE_HZ, "ground-truth rate, Hz", positive
        )
        initial = declare_initial_state(self, "x, y, yaw, vx, vy, omega")
        self.duration = declare(self, "duration", 0.0, "stop after (s); 0 = never", non_negative)
        self.wait_for_subscribers = declare(
            self,
            "wait_for_subscribers",
            0,
            "hold t = 0 until every sensor topic has this many subscribers",
            in_range(0, 100),
        )
        self.wait_for_commands = declare(
            self, "wait_for_commands", False, "hold t = 0 until a controller publishes input"
        )
        self._waiting = self.wait_for_subscribers > 0 or self.wait_for_commands
        self.onboard = declare(
            self, "onboard", False, "run the car's 250 Hz onboard loop (steering and velocity PIDs)"
        )
        timeout = declare(
            self,
            "command_timeout",
            DISCONNECT_THRESHOLD_S,
            "s without a command that cut the drive motor, as the firmware; 0 = never",
            non_negative,
        )
        self._cutoff = MotorCutoff(timeout) if timeout > 0 else None
        self._now = 0.0
        self._steer = 0.0
        self._cut_log = throttled_warning(self)
        drift_file = declare(
            self,
            "drift_file",
            "",
            "YAML schedule of changes to the car's truth (empty: none)",
            parsed_with(lambda path: load_drift(path) if path else None),
        )
        drift = load_drift(drift_file) if drift_file else None
        sensors = SensorSuite(blackouts=blackouts)
        model = declare_model(self, effects, n_base_stations=stations)
        onboard = OnboardSettings() if self.onboard else None
        if onboard is not None and noise_free:
            onboard = onboard.ideal()
        try:
            simulator = Simulator(
                model, sensors.ideal() if noise_free else sensors, seed, onboard, drift
            )
        except FieldError as error:  # the schedule names a parameter the car lacks
            if not error.field.startswith("drift"):
                raise
            raise ParameterError("drift_file", f"{error.field}: {error.reason}") from None
        self.session = simulator.session(np.asarray(initial, dtype=float), keep_history=False)
        self._warn_mode = throttled_warning(self)
        #: Commands refused for their mode (velocity references without the onboard loop).
        self.refused_commands = 0
        self.epoch = time.time()
        self._wall_start = time.monotonic()
        self.body_frame = conversions.body_frame(self.get_namespace())
        self._sensors = declare_sensor_output(self, self.body_frame)
        from chronos_msgs.msg import CarState

        self._truth = self.create_publisher(CarState, conversions.TOPICS["ground_truth"], 10)
        self._truth_parameters = None
        if drift is not None:
            from chronos_msgs.msg import OnlineParameters

            topic = conversions.TOPICS["truth_parameters"]
            self._truth_parameters = self.create_publisher(OnlineParameters, topic, 10)
        self._inputs = input_subscription(self, self._on_input)
        self._clock_publisher = None
        if self.rate_factor != 1.0:
            from rosgraph_msgs.msg import Clock

            self._clock_publisher = self.create_publisher(Clock, "/clock", 10)
        self._next_truth = 0.0
        self._truth_period = 1.0 / truth_hz
        self.create_timer(1.0 / tick_hz, self._tick)
        self.get_logger().info(
            f"simulating {model!r}, seed {seed}, rate x{self.rate_factor:g}, "
            f"{'ideal' if noise_free else 'noisy'} sensors"
            + (", onboard loop (torque and velocity commands)" if self.onboard else "")
        )

    def _tick(self) -> None:
        if self._waiting:  # every sensor topic heard by the estimator and the recorder
            listeners = self._sensors.subscription_count()
            if listeners < self.wait_for_subscribers:
                return
            controllers = self.count_publishers(self._inputs.subscription.topic_name)
            if self.wait_for_commands and controllers < 1:
                return
            self._waiting = False  # the clock starts when the stack is listening
            self.epoch, self._wall_start = time.time(), time.monotonic()
            self.get_logger().info(
                f"{listeners} subscribers to the sensors, {controllers} publisher(s) of "
                "commands: starting"
            )
        t = self._now = (time.monotonic() - self._wall_start) * self.rate_factor
        self._inputs.take_pending()  # commands that arrived apply before time advances
        # a late tick (a starved process) integrates up to the cut-off's own instant first: the
        # firmware cuts the motor 0.2 s into a silence, however long the silence lasts
        cut_at = t
        if self._cutoff is not None and self._cutoff.last_command is not None:
            if not self._cutoff.cut:
                cut_at = min(t, self._cutoff.last_command + self._cutoff.threshold)
        measurements = self.session.advance(cut_at) if cut_at < t else []
        if self._cutoff is not None and self._cutoff.expired(cut_at):
            self.session.command(np.array([self._steer, 0.0]), "torque")
            self._cut_log(
                f"no command for {self._cutoff.threshold * 1e3:.0f} ms: motors cut "
                f"({self._cutoff.cuts} so far)"
            )
        if self.duration and t >= self.duration:
            self.get_logger().info(f"simulated {self.duration:g} s; stopping")
            rclpy.try_shutdown()
            return
        measurements += self.session.advance(t)
        self._sensors.add(
            (type(m)(self.epoch + m.stamp, m.sensor, m.values) for m in measurements), t
        )
        if self._clock_publisher is not None:
            from rosgraph_msgs.msg import Clock

            clock = Clock()
            conversions.fill_stamp(clock.clock, self.epoch + t)
            self._clock_publisher.publish(clock)
        if t >= self._next_truth:
            self._next_truth = t + self._truth_period
            self._truth.publish(conversions.car_state_msg(self.session.base_state, self.epoch + t))
            if self._truth_parameters is not None:
                self._truth_parameters.publish(
                    conversions.truth_parameters_msg(self.session.drifted, self.epoch + t)
                )

    def _on_input(self, command: conversions.CarCommand) -> None:
        if command.mode != "torque" and self.session.onboard is None:
            self.refused_commands += 1
            self._warn_mode(
                f"dropped input on {conversions.TOPICS['input']}: mode: {command.mode!r} commands "
                f"need the onboard loop (parameter onboard:=true) ({self.refused_commands} so far)"
            )
            return
        try:
            self.session.command(command.u, command.mode)
        except ValueError as error:  # validated at the boundary already; never crash on it
            self.refused_commands += 1
            self._warn_mode(f"dropped input on {conversions.TOPICS['input']}: {error}")
            return
        self._steer = float(command.u[0])
        if self._cutoff is not None and self._cutoff.commanded(self._now) and self._cutoff.cuts:
            self.get_logger().info("commands again: drives")


def main(argv: Sequence[str] | None = None) -> int:
    return run(SimulatorNode, argv)


if __name__ == "__main__":
    raise SystemExit(main())
