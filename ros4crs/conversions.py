"""Conversions between ROS 2 messages and crs_core types, validated at the boundary.

Every ``*_from_msg`` function raises :class:`~crs_core.errors.FieldError` (a ``ValueError``)
naming the field (``.field``, and the message ``"<field>: <reason>"``) when the message is
malformed (NaN, infinite, wrong-size arrays, bad enums); nodes catch it, log a warning and drop
the message. The functions only read attributes, so they accept both rclpy
messages and the rosbags dataclasses of the same types (bag replay uses the same code).

Topic conventions (relative to a car's namespace, e.g. ``/car1``):

====================  ===============================  =====================================
topic                 type                             content
====================  ===============================  =====================================
sensors/imu           sensor_msgs/Imu                  a_x, a_y (body, m/s^2), yaw rate
sensors/gyro          sensor_msgs/Imu                  yaw rate only (accel covariance -1)
sensors/wheel_speeds  chronos_msgs/WheelSpeeds         rad/s
sensors/lighthouse    chronos_msgs/LighthouseSweep     one plane of one base station
sensors/pose          geometry_msgs/PoseStamped        motion capture
sensors/batch         chronos_msgs/SensorBatch         many readings of any of the above
input                 chronos_msgs/CarInput            steer (rad), torque (-) or v_x (m/s)
ground_truth          chronos_msgs/CarState            simulator truth
estimate/state        chronos_msgs/CarState            estimate with covariance
estimate/odometry     nav_msgs/Odometry                the same for any ROS tool
estimate/diagnostics  chronos_msgs/EstimatorDiagnostics
estimate/query        chronos_msgs/EstimatorQuery      each query and the newest data it had
controller/plan       nav_msgs/Path                    the MPCC's planned positions (world)
controller/solve_time std_msgs/Float64                 the controller's call time, s
lighthouse_fix        geometry_msgs/                   a Lighthouse pose fix (world; while
                      PoseWithCovarianceStamped        someone subscribes)
/tf (absolute)        tf2_msgs/TFMessage               ``world`` -> ``<car>/base_link``
====================  ===============================  =====================================

Frames (REP 103/105): ``world`` is the track frame; a car's body frame is ``<ns>/base_link``
(``car1/base_link`` for the node namespace ``/car1``, see :func:`body_frame`), so the cars of
one ROS graph share one TF tree.
"""

from __future__ import annotations

import math
from array import array
from collections.abc import Mapping, Sequence
from typing import Any, NamedTuple

import numpy as np

from crs_core.errors import FieldError
from crs_core.estimation.base import Estimate, OnlineValue
from crs_core.estimation.lighthouse_pose import PoseFix
from crs_core.measurements import (
    InputSample,
    Measurement,
    lighthouse_sensor,
    parse_lighthouse,
    sensor_size,
)

TOPICS = {
    "imu": "sensors/imu",
    "gyro": "sensors/gyro",
    "wheel_encoders": "sensors/wheel_speeds",
    "lighthouse": "sensors/lighthouse",
    "pose": "sensors/pose",
    "batch": "sensors/batch",
    "input": "input",
    "applied_input": "input/applied",
    "ground_truth": "ground_truth",
    "truth_parameters": "ground_truth/parameters",
    "state": "estimate/state",
    "odometry": "estimate/odometry",
    "diagnostics": "estimate/diagnostics",
    "query": "estimate/query",
    "parameters": "estimate/parameters",
    "plan": "controller/plan",
    "reference": "controller/reference",
    "solve_time": "controller/solve_time",
    "lighthouse_fix": "lighthouse_fix",
}


def body_frame(namespace: str) -> str:
    """The body frame id of the car in ``namespace``: ``/car1`` -> ``car1/base_link``."""
    prefix = namespace.strip("/")
    return f"{prefix}/base_link" if prefix else "base_link"


# --- time ------------------------------------------------------------------------------------
def seconds_from_stamp(stamp: Any) -> float:
    """``builtin_interfaces/Time`` -> float seconds (``nanosec`` must be below 1e9)."""
    if not 0 <= stamp.nanosec < 1_000_000_000:
        raise FieldError("header.stamp.nanosec", f"must be in [0, 1e9), got {stamp.nanosec}")
    return float(stamp.sec) + 1e-9 * float(stamp.nanosec)


def fill_stamp(stamp: Any, seconds: float) -> None:
    """Write float seconds (>= 0) into a ``builtin_interfaces/Time``."""
    stamp.sec, stamp.nanosec = divmod(stamp_ns(seconds), 1_000_000_000)


def stamp_ns(seconds: float) -> int:
    """Float seconds (>= 0) -> integer nanoseconds, as :func:`fill_stamp` writes them."""
    if not math.isfinite(seconds) or seconds < 0:
        raise FieldError("header.stamp", f"must be finite and >= 0, got {seconds}")
    sec = math.floor(seconds)
    return int(sec) * 1_000_000_000 + round((seconds - sec) * 1e9)


def _finite(name: str, values: Any, size: int | None = None) -> np.ndarray:
    array = np.asarray(values, dtype=float).ravel()
    if size is not None and array.size != size:
        raise FieldError(name, f"expected {size} values, got {array.size}")
    if not np.all(np.isfinite(array)):
        raise FieldError(name, f"contains NaN or inf ({array})")
    return array


# --- sensors ---------------------------------------------------------------------------------
def measurement_to_msg(measurement: Measurement, frame_id: str = "base_link") -> Any:
    """The ROS message of a measurement (type by sensor, see the module table)."""
    from geometry_msgs.msg import PoseStamped
    from sensor_msgs.msg import Imu

    from chronos_msgs.msg import LighthouseSweep, WheelSpeeds

    sensor, v = measurement.sensor, measurement.values
    if sensor in ("imu", "gyro"):
        msg = Imu()
        if sensor == "imu":
            msg.linear_acceleration.x, msg.linear_acceleration.y = float(v[0]), float(v[1])
            msg.angular_velocity.z = float(v[2])
        else:
            msg.linear_acceleration_covariance[0] = -1.0  # REP 145: not measured
            msg.angular_velocity.z = float(v[0])
        msg.orientation_covariance[0] = -1.0
    elif sensor == "wheel_encoders":
        msg = WheelSpeeds()
        msg.front_left, msg.front_right, msg.rear_left, msg.rear_right = map(float, v)
    elif sensor == "pose":
        msg = PoseStamped()
        _fill_planar_pose(msg.pose, v)
        frame_id = "world"
    else:
        station, plane = parse_lighthouse(sensor)
        msg = LighthouseSweep()
        msg.base_station, msg.plane = station, plane
        msg.angles = [float(a) for a in v]
    msg.header.frame_id = frame_id
    fill_stamp(msg.header.stamp, measurement.stamp)
    return msg


def imu_from_msg(msg: Any) -> Measurement:
    """``sensor_msgs/Imu`` -> ``imu`` (or ``gyro`` when the acceleration is marked unused)."""
    stamp = seconds_from_stamp(msg.header.stamp)
    omega = _finite("angular_velocity.z", [msg.angular_velocity.z], 1)
    if msg.linear_acceleration_covariance[0] == -1.0:
        return Measurement(stamp, "gyro", omega)
    acc = _finite("linear_acceleration", [msg.linear_acceleration.x, msg.linear_acceleration.y])
    return Measurement(stamp, "imu", np.concatenate([acc, omega]))


def wheel_speeds_from_msg(msg: Any) -> Measurement:
    """``chronos_msgs/WheelSpeeds`` -> ``wheel_encoders``."""
    values = [msg.front_left, msg.front_right, msg.rear_left, msg.rear_right]
    return Measurement(
        seconds_from_stamp(msg.header.stamp), "wheel_encoders", _finite("wheel speeds", values, 4)
    )


def lighthouse_from_msg(msg: Any) -> Measurement:
    """``chronos_msgs/LighthouseSweep`` -> ``lighthouse/<station>/<plane>``."""
    if msg.plane not in (1, 2):
        raise FieldError("plane", f"must be 1 or 2, got {msg.plane}")
    angles = _finite("angles", msg.angles, 4)
    sensor = lighthouse_sensor(int(msg.base_station), int(msg.plane))
    return Measurement(seconds_from_stamp(msg.header.stamp), sensor, angles)


def pose_from_msg(msg: Any) -> Measurement:
    """``geometry_msgs/PoseStamped`` -> ``pose`` (x, y, yaw from the quaternion)."""
    return Measurement(seconds_from_stamp(msg.header.stamp), "pose", _planar_pose("pose", msg.pose))


def _fill_yaw(quaternion: Any, yaw: float) -> None:
    """Write the rotation by ``yaw`` (rad) about z into a ``geometry_msgs/Quaternion``."""
    quaternion.z, quaternion.w = math.sin(yaw / 2), math.cos(yaw / 2)


def _fill_planar_pose(pose: Any, planar: Sequence[float]) -> None:
    """Write ``[x, y, yaw]`` (m, m, rad) into a ``geometry_msgs/Pose`` (z and the other
    rotations left 0): the inverse of :func:`_planar_pose`."""
    pose.position.x, pose.position.y = float(planar[0]), float(planar[1])
    _fill_yaw(pose.orientation, float(planar[2]))


def _planar_pose(field: str, pose: Any) -> np.ndarray:
    """``geometry_msgs/Pose`` -> ``[x, y, yaw]`` (m, m, rad; yaw from the quaternion, checked
    to be near unit length); ``field`` names it in errors."""
    o = pose.orientation
    q = _finite(f"{field}.orientation", [o.x, o.y, o.z, o.w], 4)
    norm = float(np.linalg.norm(q))
    if not 0.5 < norm < 1.5:
        raise FieldError(f"{field}.orientation", f"not a unit quaternion (norm {norm:.3g})")
    x, y, z, w = q / norm
    yaw = math.atan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))
    position = _finite(f"{field}.position", [pose.position.x, pose.position.y], 2)
    return np.append(position, yaw)


class BatchReadings(NamedTuple):
    """A ``chronos_msgs/SensorBatch`` converted: its valid readings (in message order) and, for
    each reading dropped, why (``"readings[3] (imu): ..."``)."""

    measurements: list[Measurement]
    rejected: list[str]


def batch_msg(measurements: Sequence[Measurement], frame_id: str = "base_link") -> Any:
    """``chronos_msgs/SensorBatch`` holding ``measurements`` (at least one), stamped with the
    newest of them."""
    from chronos_msgs.msg import SensorBatch

    if not measurements:
        raise FieldError("measurements", "a batch needs at least one reading")
    msg = SensorBatch()
    msg.header.frame_id = frame_id
    stamps = [stamp_ns(m.stamp) for m in measurements]
    msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(max(stamps), 1_000_000_000)
    msg.sensors = [m.sensor for m in measurements]
    msg.stamps_ns = array("q", stamps)
    msg.values = array("d", np.concatenate([m.values for m in measurements]).tobytes())
    return msg


def batch_from_msg(msg: Any) -> BatchReadings:
    """``chronos_msgs/SensorBatch`` -> :class:`BatchReadings`.

    A batch whose arrays do not fit together (as many stamps as sensors, known sensors, the
    values the sensors need) raises :class:`~crs_core.errors.FieldError` naming the field; a
    reading with a negative stamp or a NaN is dropped alone, the others are kept.
    """
    sensors, stamps = list(msg.sensors), np.asarray(msg.stamps_ns, dtype=np.int64)
    values = np.asarray(msg.values, dtype=float)
    if stamps.size != len(sensors):
        raise FieldError("stamps_ns", f"{stamps.size} stamps for {len(sensors)} sensors")
    sizes = []
    for i, sensor in enumerate(sensors):
        try:
            sizes.append(sensor_size(sensor))
        except FieldError as error:
            raise error.renamed(f"sensors[{i}]") from None
    if sum(sizes) != values.size:
        raise FieldError(
            "values", f"the {len(sensors)} readings need {sum(sizes)} values, got {values.size}"
        )
    whole = stamps // 1_000_000_000
    seconds = whole.astype(float) + 1e-9 * (stamps - whole * 1_000_000_000).astype(float)
    measurements, rejected, start = [], [], 0
    for i, (sensor, size) in enumerate(zip(sensors, sizes, strict=True)):
        reading = values[start : start + size]
        start += size
        try:
            if stamps[i] < 0:
                raise FieldError("stamps_ns", f"must be >= 0, got {stamps[i]}")
            measurements.append(Measurement(float(seconds[i]), sensor, reading))
        except ValueError as error:
            rejected.append(f"readings[{i}] ({sensor}): {error}")
    return BatchReadings(measurements, rejected)


# --- inputs and states -----------------------------------------------------------------------
#: ``CarInput.mode`` of each command mode: ``torque`` (``[steer, torque]`` drives the motor
#: directly) and ``velocity`` (``[steer, v_x]``, a reference for the car's onboard velocity PID).
INPUT_MODES = {"torque": 0, "velocity": 1}
#: Largest velocity reference (either direction) the boundary accepts, m/s (a 1:28 car races at
#: up to ~3 m/s).
VELOCITY_LIMIT = 5.0


class CarCommand(NamedTuple):
    """A validated ``chronos_msgs/CarInput``: its stamp (s), ``u`` and the mode.

    ``u`` is ``[steer (rad), torque (-)]`` in ``torque`` mode and ``[steer (rad), v_x (m/s)]``
    in ``velocity`` mode; only a torque-mode command is an input of the car model
    (:meth:`input_sample`).
    """

    stamp: float
    u: np.ndarray
    mode: str = "torque"

    def input_sample(self) -> InputSample:
        """The model input ``[steer, torque]`` (torque mode only; else ``FieldError``: ``mode``)."""
        if self.mode != "torque":
            raise FieldError("mode", f"a {self.mode!r} command carries no torque")
        return InputSample(self.stamp, self.u)


def car_input_msg(u: np.ndarray, seconds: float, mode: str = "torque") -> Any:
    """``chronos_msgs/CarInput`` from ``u``: ``[steer, torque]`` (``mode="torque"``) or
    ``[steer, v_x]`` (``mode="velocity"``: ``velocity`` = ``u[1]``, ``torque`` 0). The values
    are written as given (the receiver validates them)."""
    from chronos_msgs.msg import CarInput

    if mode not in INPUT_MODES:
        raise FieldError("mode", f"must be one of {', '.join(INPUT_MODES)}, got {mode!r}")
    msg = CarInput()
    msg.mode = INPUT_MODES[mode]
    msg.steer = float(u[0])
    if mode == "torque":
        msg.torque = float(u[1])
    else:
        msg.torque, msg.velocity = 0.0, float(u[1])
    fill_stamp(msg.header.stamp, seconds)
    return msg


def input_from_msg(msg: Any) -> CarCommand:
    """``chronos_msgs/CarInput`` -> :class:`CarCommand` (stamp, ``u``, mode).

    Torque mode: ``u = [steer, torque]``, the torque finite and within [-1, 1] (the velocity
    field is ignored). Velocity mode: ``u = [steer, velocity]``, the velocity finite and within
    ±:data:`VELOCITY_LIMIT` m/s (the torque field is ignored).
    """
    modes = {code: name for name, code in INPUT_MODES.items()}
    if msg.mode not in modes:
        raise FieldError(
            "mode",
            f"must be {INPUT_MODES['torque']} (MODE_TORQUE) or "
            f"{INPUT_MODES['velocity']} (MODE_VELOCITY), got {msg.mode}",
        )
    mode = modes[msg.mode]
    steer = _finite("steer", [msg.steer], 1)[0]
    if mode == "torque":
        torque = _finite("torque", [msg.torque], 1)[0]
        if abs(torque) > 1.0:
            raise FieldError("torque", f"must be within [-1, 1], got {torque}")
        second = torque
    else:
        velocity = _finite("velocity", [msg.velocity], 1)[0]
        if abs(velocity) > VELOCITY_LIMIT:
            raise FieldError(
                "velocity",
                f"must be within [-{VELOCITY_LIMIT:g}, {VELOCITY_LIMIT:g}] m/s, got {velocity}",
            )
        second = velocity
    return CarCommand(seconds_from_stamp(msg.header.stamp), np.array([steer, second]), mode)


#: ``CarState.status`` of each estimate status.
STATUS_CODES = {"ok": 0, "degraded": 1, "lost": 2}


def car_state_msg(
    x: np.ndarray, seconds: float, covariance: np.ndarray | None = None, status: str = "ok"
) -> Any:
    """``chronos_msgs/CarState`` from a base state (its 6 x 6 covariance, its status)."""
    from chronos_msgs.msg import CarState

    msg = CarState(status=STATUS_CODES[status])
    msg.header.frame_id = "world"
    fill_stamp(msg.header.stamp, seconds)
    msg.x, msg.y, msg.yaw, msg.vx, msg.vy, msg.omega = map(float, x[:6])
    if covariance is not None:
        # a float64 array is taken as it is (a list is checked element by element: 4x slower)
        msg.covariance = np.array(covariance, dtype=np.float64).ravel()
    return msg


def state_from_msg(msg: Any) -> tuple[float, np.ndarray]:
    """``chronos_msgs/CarState`` -> (stamp, state (6,))."""
    x = _finite("state", [msg.x, msg.y, msg.yaw, msg.vx, msg.vy, msg.omega], 6)
    return seconds_from_stamp(msg.header.stamp), x


def state_sigma_from_msg(msg: Any) -> np.ndarray:
    """``chronos_msgs/CarState`` -> the states' standard deviations (6,), from the diagonal of
    its covariance; NaN where the covariance is all zeros (unknown) or not finite."""
    covariance = np.asarray(msg.covariance, dtype=float).reshape(6, 6)
    variance = np.diag(covariance).copy()
    if not np.any(covariance) or not np.all(np.isfinite(variance)):
        variance[:] = np.nan
    return np.sqrt(np.clip(variance, 0.0, None))


def status_from_msg(msg: Any) -> tuple[float, np.ndarray, str]:
    """``chronos_msgs/CarState`` -> (stamp, state (6,), status ``ok`` | ``degraded`` | ``lost``)."""
    names = {code: name for name, code in STATUS_CODES.items()}
    if msg.status not in names:
        raise FieldError("status", f"must be 0 (ok), 1 (degraded) or 2 (lost), got {msg.status}")
    stamp, x = state_from_msg(msg)
    return stamp, x, names[msg.status]


def odometry_msg(estimate: Estimate, child_frame_id: str = "base_link") -> Any:
    """``nav_msgs/Odometry``: pose in ``world``, twist in the body frame, covariances mapped."""
    from nav_msgs.msg import Odometry

    msg = Odometry()
    msg.header.frame_id, msg.child_frame_id = "world", child_frame_id
    fill_stamp(msg.header.stamp, estimate.stamp)
    x = estimate.x
    _fill_planar_pose(msg.pose.pose, x)
    msg.twist.twist.linear.x, msg.twist.twist.linear.y = float(x[3]), float(x[4])
    msg.twist.twist.angular.z = float(x[5])
    P = estimate.covariance
    msg.pose.covariance = _planar_to_6d(P[:3, :3]).ravel()
    msg.twist.covariance = _planar_to_6d(P[3:, 3:]).ravel()
    return msg


#: Where a planar ``(x, y, yaw)`` (or ``(v_x, v_y, omega)``) covariance sits in ROS's 6 x 6
#: ``(x, y, z, roll, pitch, yaw)`` layout.
_PLANAR_INDEX = [0, 1, 5]


def _planar_to_6d(covariance: np.ndarray) -> np.ndarray:
    """A 3 x 3 planar covariance in ROS's 6 x 6 layout (zeros elsewhere)."""
    full = np.zeros((6, 6))
    full[np.ix_(_PLANAR_INDEX, _PLANAR_INDEX)] = covariance
    return full


def transform_msg(estimate: Estimate, child_frame_id: str = "base_link") -> Any:
    """``tf2_msgs/TFMessage`` with the one transform ``world`` -> ``child_frame_id`` (the
    estimated planar pose, z = 0)."""
    from geometry_msgs.msg import TransformStamped

    from tf2_msgs.msg import TFMessage

    transform = TransformStamped()
    transform.header.frame_id, transform.child_frame_id = "world", child_frame_id
    fill_stamp(transform.header.stamp, estimate.stamp)
    x = estimate.x
    transform.transform.translation.x = float(x[0])
    transform.transform.translation.y = float(x[1])
    _fill_yaw(transform.transform.rotation, x[2])
    return TFMessage(transforms=[transform])


def online_parameters_msg(estimate: Estimate) -> Any:
    """``chronos_msgs/OnlineParameters`` of an estimate's online parameters."""
    return parameters_msg(estimate.parameters, estimate.stamp)


def truth_parameters_msg(values: Mapping[str, float], stamp: float) -> Any:
    """``chronos_msgs/OnlineParameters`` of a simulated car's drifted parameters as they are at
    ``stamp`` (s): each exact (std 0, informed)."""
    return parameters_msg({k: OnlineValue(float(v), 0.0, True) for k, v in values.items()}, stamp)


def parameters_msg(parameters: Mapping[str, OnlineValue], stamp: float) -> Any:
    """``chronos_msgs/OnlineParameters`` of ``parameters`` by name at ``stamp`` (s)."""
    from chronos_msgs.msg import OnlineParameters

    msg = OnlineParameters(
        names=list(parameters),
        values=[p.value for p in parameters.values()],
        stds=[p.std for p in parameters.values()],
        informed=[p.informed for p in parameters.values()],
    )
    fill_stamp(msg.header.stamp, stamp)
    return msg


def online_parameters_from_msg(msg: Any) -> tuple[float, dict[str, OnlineValue]]:
    """``chronos_msgs/OnlineParameters`` -> (stamp, value, std and informed by name); a
    message whose lists differ in length, or with a value or std that is not finite (a std
    below 0), is refused naming the field."""
    names = list(msg.names)
    if len(set(names)) != len(names) or not all(names):
        raise FieldError("names", f"must be distinct, non-empty names, got {names}")
    for field in ("values", "stds", "informed"):
        if len(getattr(msg, field)) != len(names):
            raise FieldError(
                field, f"has {len(getattr(msg, field))} entries for {len(names)} names"
            )
    values = _finite("values", list(msg.values), len(names))
    stds = _finite("stds", list(msg.stds), len(names))
    if np.any(stds < 0):
        raise FieldError("stds", "must be >= 0")
    online = {
        name: OnlineValue(float(v), float(s), bool(i))
        for name, v, s, i in zip(names, values, stds, msg.informed, strict=True)
    }
    return seconds_from_stamp(msg.header.stamp), online


def query_msg(stamp: float, start: bool, newest: dict[str, float], oldest: dict[str, float]) -> Any:
    """``chronos_msgs/EstimatorQuery``: the time queried and, per stream, the newest stamp and
    the first since the (re)start (``oldest`` has the streams of ``newest``)."""
    from builtin_interfaces.msg import Time

    from chronos_msgs.msg import EstimatorQuery

    msg = EstimatorQuery(start=start, streams=list(newest))
    fill_stamp(msg.header.stamp, stamp)
    for stream, value in newest.items():
        for stamps, seconds in ((msg.newest, value), (msg.oldest, oldest[stream])):
            time_msg = Time()
            fill_stamp(time_msg, seconds)
            stamps.append(time_msg)
    return msg


def query_from_msg(msg: Any) -> tuple[float, bool, dict[str, float], dict[str, float]]:
    """``chronos_msgs/EstimatorQuery`` -> (stamp, start, newest stamp per stream, first stamp
    per stream)."""
    for field in ("newest", "oldest"):
        if len(getattr(msg, field)) != len(msg.streams):
            raise FieldError(
                field,
                f"{len(getattr(msg, field))} stamps for {len(msg.streams)} streams, expected equal",
            )
    newest = {s: seconds_from_stamp(t) for s, t in zip(msg.streams, msg.newest, strict=True)}
    oldest = {s: seconds_from_stamp(t) for s, t in zip(msg.streams, msg.oldest, strict=True)}
    return seconds_from_stamp(msg.header.stamp), bool(msg.start), newest, oldest


def estimator_health_from_msg(msg: Any) -> tuple[str, int]:
    """``chronos_msgs/EstimatorDiagnostics`` -> (status text, deadline misses).

    The status is ``ok``, ``degraded: <why>`` or ``lost: <why>``."""
    status = str(msg.status)
    if status.partition(":")[0] not in STATUS_CODES:
        raise FieldError("status", f"must start with ok, degraded or lost, got {status!r}")
    return status, int(msg.deadline_misses)


# --- the controller's plan -------------------------------------------------------------------
def plan_msg(points: np.ndarray, seconds: float) -> Any:
    """``nav_msgs/Path`` in ``world`` through the planned positions ``(n, 2)`` (m), each pose
    and the path stamped ``seconds`` (the control tick that planned them)."""
    from geometry_msgs.msg import PoseStamped
    from nav_msgs.msg import Path

    msg = Path()
    msg.header.frame_id = "world"
    fill_stamp(msg.header.stamp, seconds)
    for x, y in np.asarray(points, dtype=float).reshape(-1, 2):
        pose = PoseStamped()
        pose.header = msg.header
        pose.pose.position.x, pose.pose.position.y = float(x), float(y)
        pose.pose.orientation.w = 1.0
        msg.poses.append(pose)
    return msg


def plan_from_msg(msg: Any) -> np.ndarray:
    """``nav_msgs/Path`` -> its positions ``(n, 2)``, m."""
    xy = [(p.pose.position.x, p.pose.position.y) for p in msg.poses]
    return _finite("poses", xy).reshape(-1, 2)


# --- Lighthouse pose fixes ------------------------------------------------------------------
def pose_fix_msg(fix: PoseFix) -> Any:
    """``geometry_msgs/PoseWithCovarianceStamped`` in ``world``: the fix's pose, its planar
    covariance in ROS's 6 x 6 layout, stamped with the fix's stamp."""
    from geometry_msgs.msg import PoseWithCovarianceStamped

    msg = PoseWithCovarianceStamped()
    msg.header.frame_id = "world"
    fill_stamp(msg.header.stamp, fix.stamp)
    _fill_planar_pose(msg.pose.pose, fix.pose)
    msg.pose.covariance = _planar_to_6d(fix.covariance).ravel().tolist()
    return msg


def pose_fix_from_msg(msg: Any) -> tuple[float, np.ndarray]:
    """``geometry_msgs/PoseWithCovarianceStamped`` -> (stamp s, ``[x, y, yaw]`` m, m, rad)."""
    return seconds_from_stamp(msg.header.stamp), _planar_pose("pose.pose", msg.pose.pose)


def solve_time_from_msg(msg: Any) -> float:
    """``std_msgs/Float64`` (a call time, s) -> the time, finite and >= 0."""
    seconds = _finite("data", [msg.data], 1)[0]
    if seconds < 0:
        raise FieldError("data", f"must be >= 0, got {seconds}")
    return float(seconds)


def sensor_message_types() -> dict[str, type]:
    """Message type of each sensor topic family (imported on first use: ROS-free callers of
    this module never load the message packages)."""
    from geometry_msgs.msg import PoseStamped
    from sensor_msgs.msg import Imu

    from chronos_msgs.msg import LighthouseSweep, WheelSpeeds

    return {
        "imu": Imu,
        "gyro": Imu,
        "wheel_encoders": WheelSpeeds,
        "lighthouse": LighthouseSweep,
        "pose": PoseStamped,
    }


SENSOR_PARSERS = {
    "imu": imu_from_msg,
    "gyro": imu_from_msg,
    "wheel_encoders": wheel_speeds_from_msg,
    "lighthouse": lighthouse_from_msg,
    "pose": pose_from_msg,
}


def topic_family(sensor: str) -> str:
    """Topic key of a stream sensor: ``lighthouse/0/2`` -> ``lighthouse``."""
    return "lighthouse" if parse_lighthouse(sensor) else sensor
