"""Controller node: races a track (the DEMO_TRACK by default) with the ``crs_core`` MPCC, or
follows its centreline with the path follower.

Subscribes to ``estimate/state`` (and ``estimate/parameters``: an estimator's online parameters,
which the MPCC's model follows at its ``parameter_rate``, :mod:`crs_core.model.online`; one at its
bound slows the car as a degraded estimate does) and publishes ``input`` at ``rate_hz`` (default 30
Hz for the MPCC, the paper's, 50 Hz for the path follower). What to send at each tick is decided by
a :class:`~crs_core.control.supervisor.Supervisor` (stale / degraded / lost estimates, the speed
cap's ramp, the prediction over the commands sent, the check of every command); the node converts
messages, reads parameters and logs what the supervisor reports. When the newest estimate is older
than ``stale_timeout``, ``lost`` (or none arrived yet), the car gets zero torque and straight wheels
and rolls to a stop (said once per episode; the MPCC keeps its plan through a gap of up to half its
horizon); while it is ``degraded`` the speed cap ramps down at ``speed_ramp`` to ``degraded_speed``,
and back up at ``speed_rise`` once the status has stayed ok as long as it was degraded (``ok_hold``
at most). With ``recover`` (default, torque commands) a car that has stood for half a second while
driven is reversed towards facing along the track (:mod:`crs_core.control.recovery`: the MPCC never
reverses, and a car stopped at the track's edge facing out has no forward way back). After an outage
of the link (``hold_safe`` ``after_outage``, default) the MPCC plans commands safe to hold through
the next one for ``caution_memory`` s (:mod:`crs_core.control.contingency`). The MPCC's iterations
in one call end within ``solve_budget`` s (default 0.08 s: the bridge repeats a command for 0.1 s,
so the car never goes without one while the controller thinks; ten cold-start iterations took 292 ms
under load, and the car cut its motors). With ``predict`` (default) the estimate, tens of ms old
when it arrives, is carried forward to the time the command acts with the model and the commands
sent since its stamp: the tick plus the command delay, measured by matching the car's reports of the
drive power it applies (``input/applied``) to the commands' torques
(:mod:`crs_core.control.command_delay`; ``command_delay`` s until measured, and in velocity mode or
in the simulator, which report none). A controller that raises, or a command that is not finite or
out of its limits, is answered by a stop command and a throttled error; the node keeps running.

With ``output`` velocity (MPCC only) it publishes ``MODE_VELOCITY`` commands ``[delta, v_x]`` for
a car that tracks its speed on board (the MPCC's planned speed a short lead ahead; the simulator
needs ``onboard:=true``); the prediction then uses the torque of the MPCC's plan, and a stop is a
zero velocity reference.

For a viewer (:mod:`ros4crs.visualizer_node`) it publishes, only while someone subscribes,
``controller/plan`` (``nav_msgs/Path`` in ``world``: the MPCC's planned positions over its
horizon, at each tick with a plan), ``controller/reference`` (the same for the centreline
points at the plan's progress, where the contouring cost pulls each stage) and
``controller/solve_time`` (``std_msgs/Float64``: each controller call's wall time, s).

Parameters: ``controller`` (``mpcc`` | ``path``), ``output`` (``torque`` | ``velocity``; the
latter with ``mpcc`` only), ``rate_hz``, ``v_ref`` (m/s, path follower), ``stale_timeout`` (s),
``degraded_speed`` (m/s), ``speed_ramp``, ``speed_rise`` (m/s^2), ``ok_hold`` (s), ``hold_safe``
(``after_outage`` | ``always`` | ``never``), ``caution_memory`` (s), ``recover``,
``solve_budget`` (s), ``predict``, ``command_delay`` (s), ``drive_file`` (with ``path``: a
``drive.yaml`` of ``crs plan-drive``, the follower plus its command offsets,
:class:`~crs_core.discrepancy.drive_file.DriveController`), ``drive_after`` (s: the follower
alone before the drive), ``track_file``
(CRS track YAML; default DEMO_TRACK), ``params_file`` (model parameter YAML: the prediction
model's and the MPCC's), ``model`` (their model: ``dynamic``, ``kinematic`` or
``FILE.py:CLASS``; empty: the one ``params_file`` names, else dynamic).
"""

from __future__ import annotations

import time
from collections import deque
from collections.abc import Sequence
from typing import Any

import numpy as np
from rclpy.node import Node

from crs_core.analysis.statistics import summary
from crs_core.control.command_delay import CommandDelay, CommandDelaySettings
from crs_core.control.mpcc import OUTPUTS, Mpcc
from crs_core.control.mpcc_problem import MpccSettings
from crs_core.control.overload import OverloadSettings
from crs_core.control.path_following import PathFollower, PathFollowerSettings
from crs_core.control.recovery import StuckRecovery
from crs_core.control.supervisor import Supervisor, SupervisorSettings
from crs_core.discrepancy.drive_file import DriveController, load_drive
from crs_core.estimation.base import OnlineValue
from crs_core.model import CarModel
from ros4crs import conversions
from ros4crs.node_support import (
    STREAM_OUT_QOS,
    CheckedSubscription,
    ParameterError,
    declare,
    declare_model,
    declare_track,
    file_or_empty,
    non_negative,
    one_of,
    positive,
    run,
    throttled_warning,
)
from ros4crs.settings_parameters import SettingsParameters, declare_fields, declare_settings

#: Controllers the node runs.
CONTROLLERS = ("mpcc", "path")


def _controller_kind(value: str) -> str | None:
    return None if value in CONTROLLERS else f"must be one of {', '.join(CONTROLLERS)}"


#: The supervisor's settings that are parameters (default, description and bounds: the
#: dataclass's); the others come from the controller.
SUPERVISOR_PARAMETERS = SettingsParameters(
    SupervisorSettings,
    (
        "stale_timeout",
        "degraded_speed",
        "ramp_rate",
        "rise_rate",
        "ok_hold",
        "hold_safe",
        "caution_memory",
    ),
    rename={"ramp_rate": "speed_ramp", "rise_rate": "speed_rise"},
)
#: The command delay until measured (``command_delay``).
COMMAND_DELAY_PARAMETERS = SettingsParameters(
    CommandDelaySettings, ("initial",), rename={"initial": "command_delay"}
)


def wheelbase(model: CarModel) -> float:
    """The path follower's wheelbase, m: the model's ``lf + lr`` (a model without them is
    refused naming the ``model`` parameter)."""
    names = model.parameters.names
    missing = [name for name in ("lf", "lr") if name not in names]
    if missing:
        raise ParameterError(
            "model",
            f"the path follower needs the wheelbase lf + lr; model {model.plant.name} has no "
            f"parameter {', '.join(missing)}",
        )
    return model.parameters.value("lf") + model.parameters.value("lr")


class ControllerNode(Node):
    """MPCC (or path following) on the latest estimate, through a :class:`Supervisor`."""

    def __init__(self, **node_options: Any) -> None:
        super().__init__("controller", **node_options)
        kind = declare(self, "controller", "mpcc", "mpcc or path", _controller_kind)
        self.output = declare(
            self, "output", "torque", "command torque or velocity (MPCC)", one_of(*OUTPUTS)
        )
        if self.output == "velocity" and kind != "mpcc":
            raise ParameterError(
                "output",
                f"velocity needs controller:=mpcc (the {kind} controller commands torque), "
                "got 'velocity'",
            )
        default_rate = MpccSettings.rate_hz if kind == "mpcc" else 50.0
        rate_hz = declare(self, "rate_hz", default_rate, "control rate, Hz", positive)
        v_ref = declare(
            self,
            "v_ref",
            PathFollowerSettings.v_ref,
            "path follower: reference speed, m/s",
            positive,
        )
        drive_file = declare(
            self,
            "drive_file",
            "",
            "path follower: a drive.yaml of crs plan-drive (its speed and command offsets); "
            "empty: none",
            file_or_empty,
        )
        drive_after = declare(
            self,
            "drive_after",
            0.0,
            "with drive_file: the follower alone drives this long before the drive, s",
            non_negative,
        )
        if drive_file and kind != "path":
            raise ParameterError(
                "drive_file", f"needs controller:=path (got controller:={kind}), got {drive_file!r}"
            )
        # checked when the settings are built below; degraded_speed before it is clamped there
        supervision = declare_fields(
            self, SUPERVISOR_PARAMETERS, checks={"degraded_speed": positive}
        )
        recover = declare(self, "recover", True, "back a stuck car out (torque commands only)")
        solve_budget = declare(
            self,
            "solve_budget",
            0.08,
            "MPCC: wall time within which a call's SQP iterations end, s (0: no limit)",
            non_negative,
        )
        model = declare_model(self)
        predict = declare(
            self, "predict", True, "predict the estimate forward to now with the commands sent"
        )
        delay = CommandDelay(declare_settings(self, COMMAND_DELAY_PARAMETERS))
        track = declare_track(self)
        limits: MpccSettings | PathFollowerSettings
        drive = None
        if kind == "mpcc":
            limits = MpccSettings(rate_hz=rate_hz, solve_time_budget=solve_budget)
            # a simple model races only as fast as it holds (the MPCC caps its plan the same)
            racing_speed = model.plant.racing_speed
            max_speed = limits.progress_speed_max
            if racing_speed is not None:
                max_speed = min(max_speed, racing_speed)
        elif drive_file:
            try:
                drive = load_drive(drive_file)
            except ValueError as error:
                raise ParameterError("drive_file", str(error)) from None
            limits = drive.follower_settings()
            max_speed = drive.v_ref
        else:
            limits = PathFollowerSettings(v_ref=v_ref)
            max_speed = v_ref
        # checked before the controller is built (the MPCC may compile its functions first)
        settings = SUPERVISOR_PARAMETERS.build(
            {
                **supervision,
                # as the controllers clamp it
                "degraded_speed": min(supervision["degraded_speed"], max_speed),
            },
            max_speed=max_speed,
            overload=OverloadSettings(period=1.0 / rate_hz),
            steer_max=limits.steer_max,
            torque_min=limits.torque_min,
            torque_max=limits.torque_max,
            velocity_max=conversions.VELOCITY_LIMIT,
        )
        if isinstance(limits, MpccSettings):
            controller: Mpcc | PathFollower | DriveController = Mpcc(
                track, model, limits, output=self.output
            )
            controller.warm_up()
        elif drive is not None:
            controller = DriveController(
                drive, track, wheelbase(model), t_start=None, lead_in_s=drive_after
            )
        else:
            controller = PathFollower(track, wheelbase(model), limits)
        recovery = None
        if recover and self.output == "torque":
            recovery = StuckRecovery(track, limits.steer_max)
        self.supervisor = Supervisor(
            controller, settings, model if predict else None, self.output, recovery, delay
        )
        self._log = {
            "stale": throttled_warning(self),
            "degraded": throttled_warning(self),
            "controller": throttled_warning(self),
            "fresh": self.get_logger().info,
            "recovered": self.get_logger().info,
            # its own call site: rclpy refuses a second severity from one (the info above)
            "stuck": lambda message: self.get_logger().warning(message),
            "unstuck": self.get_logger().info,
            "cautious": lambda message: self.get_logger().warning(message),
            "relaxed": lambda message: self.get_logger().info(message),
            "starved": lambda message: self.get_logger().warning(message),
            "standing": lambda message: self.get_logger().warning(message),
            "fed": lambda message: self.get_logger().info(message),
            "failed": lambda message: self.get_logger().error(message, throttle_duration_sec=1.0),
            "rejected": lambda message: self.get_logger().error(message, throttle_duration_sec=1.0),
        }
        from nav_msgs.msg import Path
        from std_msgs.msg import Float64

        from chronos_msgs.msg import CarInput, CarState, OnlineParameters

        self._plan_publisher = self.create_publisher(Path, conversions.TOPICS["plan"], 1)
        self._reference_publisher = self.create_publisher(Path, conversions.TOPICS["reference"], 1)
        self._solve_publisher = self.create_publisher(Float64, conversions.TOPICS["solve_time"], 1)
        self._input_publisher = self.create_publisher(
            CarInput, conversions.TOPICS["input"], STREAM_OUT_QOS
        )
        self._applied = CheckedSubscription(
            self,
            CarInput,
            conversions.TOPICS["applied_input"],
            conversions.input_from_msg,
            self._on_applied,
            "applied input",
        )
        self._estimates = CheckedSubscription(
            self,
            CarState,
            conversions.TOPICS["state"],
            conversions.status_from_msg,
            self._on_state,
            "state estimate",
        )
        self._online_parameters = CheckedSubscription(
            self,
            OnlineParameters,
            conversions.TOPICS["parameters"],
            conversions.online_parameters_from_msg,
            self._on_parameters,
            "online parameters",
        )
        #: the controller's call times of the last 30 s at 30 Hz, s (bounded: a node runs for hours)
        self.solve_times: deque[float] = deque(maxlen=900)
        self._calls = 0
        #: CPU time of the ticks' decisions (the supervisor and the controller it calls), s
        self.solver_cpu_seconds = 0.0
        self._ticks = 0
        self.create_timer(1.0 / rate_hz, self._control)

    def _on_state(self, value: tuple[float, np.ndarray, str]) -> None:
        self.supervisor.observe(*value)

    def _on_parameters(self, value: tuple[float, dict[str, OnlineValue]]) -> None:
        self.supervisor.observe_parameters({n: p.value for n, p in value[1].items()})

    def _on_applied(self, applied: conversions.CarCommand) -> None:
        if applied.mode == "torque":
            self.supervisor.applied(applied.stamp, float(applied.u[1]))

    def _control(self) -> None:
        self._applied.take_pending()
        self._estimates.take_pending()  # act on the newest estimate that has arrived
        self._online_parameters.take_pending()
        now = self.get_clock().now().nanoseconds * 1e-9
        cpu_started = time.thread_time()
        step = self.supervisor(now)
        self.solver_cpu_seconds += time.thread_time() - cpu_started
        self._ticks += 1
        self._input_publisher.publish(conversions.car_input_msg(step.command, now, self.output))
        for event in step.events:
            self._log[event.kind](event.message)
        if step.solve_time is not None:
            self._record_solve_time(step.solve_time)
        self._publish_for_viewers(now, step.solve_time)

    def timing_stats(self) -> dict[str, float]:
        """What the controller's own computing cost so far (written out at the end of a run by
        :func:`ros4crs.node_support.run_nodes`): ticks and the CPU time of their decisions, s."""
        return {"ticks": self._ticks, "solver_cpu_s": round(self.solver_cpu_seconds, 4)}

    def _publish_for_viewers(self, now: float, solve_time: float | None) -> None:
        """The MPCC's plan, its progress reference and the call time, when someone listens (a
        viewer)."""
        from std_msgs.msg import Float64

        if solve_time is not None and self._solve_publisher.get_subscription_count():
            self._solve_publisher.publish(Float64(data=solve_time))
        controller = self.supervisor.controller
        if not isinstance(controller, Mpcc):
            return
        if self._plan_publisher.get_subscription_count():
            plan = controller.plan
            if plan is not None:
                self._plan_publisher.publish(conversions.plan_msg(plan[0][:, :2], now))
        if self._reference_publisher.get_subscription_count():
            reference = controller.progress_reference
            if reference is not None:
                self._reference_publisher.publish(conversions.plan_msg(reference, now))

    def _record_solve_time(self, seconds: float) -> None:
        self.solve_times.append(seconds)
        self._calls += 1
        if self._calls % self.solve_times.maxlen == 0:  # every 30 s at 30 Hz
            delay = self.supervisor.command_delay
            ms = summary(1e3 * np.array(self.solve_times), ("median", "p99", "max"))
            self.get_logger().info(
                f"controller call: median {ms['median']:.2f} ms, "
                f"p99 {ms['p99']:.2f} ms, max {ms['max']:.2f} ms; command delay "
                f"{1e3 * delay.delay:.1f} ms ({delay.matched} commands matched to the car's "
                "reports)"
            )


def main(argv: Sequence[str] | None = None) -> int:
    return run(ControllerNode, argv)


if __name__ == "__main__":
    raise SystemExit(main())
