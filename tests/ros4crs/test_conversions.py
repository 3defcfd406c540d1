"""The message conversions: a malformed message is refused with a :class:`FieldError` naming the
field (``.field``; the message is ``"<field>: <reason>"``); car inputs round trip in each mode;
a ``chronos_msgs/SensorBatch`` carries what the per-reading messages carry."""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

import numpy as np
import pytest
from rclpy.serialization import deserialize_message, serialize_message

from chronos_msgs.msg import SensorBatch
from crs_core.errors import FieldError
from crs_core.estimation.base import Estimate, OnlineValue
from crs_core.measurements import InputSample, Measurement
from ros4crs import conversions
from ros4crs.interfaces import typestore


def _imu(**fields: float) -> Any:
    msg = conversions.measurement_to_msg(Measurement(2.0, "imu", [0.1, 0.2, 0.3]))
    for name, value in fields.items():
        if name == "omega":
            msg.angular_velocity.z = value
        else:
            setattr(msg.linear_acceleration, name, value)
    return msg


def _sweep(plane: int = 1, angle: float = 2.0) -> Any:
    msg = conversions.measurement_to_msg(Measurement(2.0, "lighthouse/0/1", [2.0] * 4))
    msg.plane = plane
    msg.angles = [angle, 2.0, 2.0, 2.0]
    return msg


def _pose(w: float = 1.0, x: float = 0.5) -> Any:
    msg = conversions.measurement_to_msg(Measurement(2.0, "pose", [0.5, 0.25, 0.0]))
    msg.pose.orientation.w = w
    msg.pose.position.x = x
    return msg


def _wheels(rear_left: float = 1.0, nanosec: int = 0) -> Any:
    msg = conversions.measurement_to_msg(Measurement(2.0, "wheel_encoders", [1.0] * 4))
    msg.rear_left = rear_left
    msg.header.stamp.nanosec = nanosec
    return msg


def _state(status: int = 0, vx: float = 1.0) -> Any:
    msg = conversions.car_state_msg(np.zeros(6), 4.0)
    msg.status, msg.vx = status, vx
    return msg


def _query(field: str = "newest") -> Any:
    """An EstimatorQuery whose ``field`` has one stamp for two streams."""
    msg = conversions.query_msg(3.0, False, {"sensors/imu": 2.5}, {"sensors/imu": 0.5})
    msg.streams = ["sensors/imu", "sensors/pose"]
    getattr(msg, "oldest" if field == "newest" else "newest").append(msg.newest[0])
    return msg


def _online(**changes: Any) -> Any:
    """An OnlineParameters message of Cm1 and grip, ``changes`` set on it."""
    estimate = Estimate(
        3.0,
        np.zeros(6),
        np.eye(6),
        parameters={"Cm1": OnlineValue(0.9, 0.05, True), "grip": OnlineValue(1.0, 0.1, False)},
    )
    msg = conversions.online_parameters_msg(estimate)
    for name, value in changes.items():
        setattr(msg, name, value)
    return msg


def test_online_parameters_round_trip() -> None:
    stamp, parameters = conversions.online_parameters_from_msg(_online())
    assert stamp == 3.0
    assert parameters == {
        "Cm1": OnlineValue(0.9, 0.05, True),
        "grip": OnlineValue(1.0, 0.1, False),
    }


@pytest.mark.parametrize(
    ("convert", "msg", "field", "reason"),
    [
        (conversions.imu_from_msg, _imu(omega=math.nan), "angular_velocity.z", "contains NaN"),
        (conversions.imu_from_msg, _imu(y=math.inf), "linear_acceleration", "contains NaN"),
        (conversions.wheel_speeds_from_msg, _wheels(math.nan), "wheel speeds", "contains NaN"),
        (
            conversions.wheel_speeds_from_msg,
            _wheels(nanosec=1_000_000_000),
            "header.stamp.nanosec",
            "must be in [0, 1e9)",
        ),
        (conversions.lighthouse_from_msg, _sweep(plane=3), "plane", "must be 1 or 2, got 3"),
        (conversions.lighthouse_from_msg, _sweep(angle=math.nan), "angles", "contains NaN"),
        (conversions.pose_from_msg, _pose(w=3.0), "pose.orientation", "not a unit quaternion"),
        (conversions.pose_from_msg, _pose(x=math.inf), "pose.position", "contains NaN"),
        (conversions.state_from_msg, _state(vx=math.nan), "state", "contains NaN"),
        (conversions.status_from_msg, _state(status=7), "status", "must be 0 (ok)"),
        (conversions.query_from_msg, _query(), "newest", "1 stamps for 2 streams"),
        (conversions.query_from_msg, _query("oldest"), "oldest", "1 stamps for 2 streams"),
        (conversions.online_parameters_from_msg, _online(stds=[0.1]), "stds", "has 1 entries"),
        (
            conversions.online_parameters_from_msg,
            _online(values=[0.9, math.nan]),
            "values",
            "contains NaN",
        ),
        (conversions.online_parameters_from_msg, _online(stds=[0.1, -1.0]), "stds", "must be >= 0"),
        (
            conversions.online_parameters_from_msg,
            _online(names=["Cm1", "Cm1"]),
            "names",
            "must be distinct",
        ),
    ],
)
def test_a_malformed_message_is_refused_naming_the_field(
    convert: Callable[[Any], Any], msg: Any, field: str, reason: str
) -> None:
    with pytest.raises(FieldError) as error:
        convert(msg)
    assert error.value.field == field
    assert error.value.reason.startswith(reason), error.value
    assert str(error.value) == f"{field}: {error.value.reason}"


def test_a_negative_or_non_finite_stamp_is_refused_when_writing() -> None:
    for seconds in (-1.0, math.nan):
        with pytest.raises(FieldError) as error:
            conversions.stamp_ns(seconds)
        assert error.value.field == "header.stamp"


# --- car inputs (chronos_msgs/CarInput) ----------------------------------------------------------


@pytest.mark.parametrize(
    ("mode", "u", "fields"),
    [
        ("torque", [0.12, -0.4], {"mode": 0, "steer": 0.12, "torque": -0.4, "velocity": 0.0}),
        ("velocity", [-0.2, 1.7], {"mode": 1, "steer": -0.2, "torque": 0.0, "velocity": 1.7}),
        ("velocity", [0.0, -4.5], {"mode": 1, "steer": 0.0, "torque": 0.0, "velocity": -4.5}),
    ],
)
def test_round_trip_writes_the_fields_of_the_mode(mode: str, u: list[float], fields: dict):
    msg = conversions.car_input_msg(np.array(u), 12.25, mode)
    assert {name: getattr(msg, name) for name in fields} == fields
    command = conversions.input_from_msg(msg)
    assert command.stamp == pytest.approx(12.25, abs=1e-9)
    assert command.mode == mode
    np.testing.assert_array_equal(command.u, u)
    stamp, values, read_mode = command  # a plain tuple too
    assert (stamp, values, read_mode) == (command.stamp, command.u, mode)


def test_default_mode_is_torque_and_the_message_constants_agree():
    from chronos_msgs.msg import CarInput

    msg = conversions.car_input_msg(np.array([0.1, 0.3]), 1.0)
    assert msg.mode == CarInput.MODE_TORQUE == conversions.INPUT_MODES["torque"]
    assert CarInput.MODE_VELOCITY == conversions.INPUT_MODES["velocity"]


def test_only_a_torque_command_is_a_model_input():
    torque = conversions.input_from_msg(conversions.car_input_msg(np.array([0.1, 0.3]), 2.0))
    sample = torque.input_sample()
    assert isinstance(sample, InputSample) and sample.stamp == pytest.approx(2.0)
    np.testing.assert_array_equal(sample.u, [0.1, 0.3])
    velocity = conversions.input_from_msg(
        conversions.car_input_msg(np.array([0.1, 1.0]), 2.0, "velocity")
    )
    with pytest.raises(FieldError, match="mode: a 'velocity' command carries no torque"):
        velocity.input_sample()


def test_the_ignored_field_of_each_mode_is_not_validated():
    """Torque mode ignores ``velocity``, velocity mode ``torque`` (as the message says)."""
    msg = conversions.car_input_msg(np.array([0.1, 0.3]), 1.0)
    msg.velocity = math.nan
    assert conversions.input_from_msg(msg).mode == "torque"
    msg = conversions.car_input_msg(np.array([0.1, 2.0]), 1.0, "velocity")
    msg.torque = 7.0
    command = conversions.input_from_msg(msg)
    assert command.mode == "velocity" and command.u[1] == 2.0


def _message(mode: int = 0, steer: float = 0.0, torque: float = 0.0, velocity: float = 0.0):
    from chronos_msgs.msg import CarInput

    msg = CarInput(mode=mode, steer=steer, torque=torque, velocity=velocity)
    conversions.fill_stamp(msg.header.stamp, 3.0)
    return msg


@pytest.mark.parametrize(
    ("fields", "message"),
    [
        ({"mode": 2}, "mode: must be 0 (MODE_TORQUE) or 1 (MODE_VELOCITY), got 2"),
        ({"steer": math.nan}, "steer: contains NaN or inf"),
        ({"mode": 1, "steer": math.inf, "velocity": 1.0}, "steer: contains NaN or inf"),
        ({"torque": math.nan}, "torque: contains NaN or inf"),
        ({"torque": 1.5}, "torque: must be within [-1, 1], got 1.5"),
        ({"mode": 1, "velocity": math.nan}, "velocity: contains NaN or inf"),
        ({"mode": 1, "velocity": -math.inf}, "velocity: contains NaN or inf"),
        ({"mode": 1, "velocity": 5.5}, "velocity: must be within [-5, 5] m/s, got 5.5"),
        ({"mode": 1, "velocity": -12.0}, "velocity: must be within [-5, 5] m/s, got -12.0"),
    ],
)
def test_malformed_inputs_are_refused_naming_the_field(fields: dict, message: str):
    with pytest.raises(FieldError) as error:
        conversions.input_from_msg(_message(**fields))
    assert str(error.value).startswith(message), error.value
    assert error.value.field == message.split(":")[0]


def test_an_unknown_mode_is_refused_when_writing():
    with pytest.raises(
        FieldError, match="mode: must be one of torque, velocity, got 'speed'"
    ) as error:
        conversions.car_input_msg(np.zeros(2), 1.0, "speed")
    assert error.value.field == "mode"


def test_rosbags_messages_convert_the_same(tmp_path):
    """Bag replay reads the rosbags dataclass of the message with the same function."""
    from rclpy.serialization import serialize_message

    from ros4crs.interfaces import typestore

    msg = conversions.car_input_msg(np.array([0.05, 2.5]), 4.5, "velocity")
    store = typestore()
    decoded = store.deserialize_cdr(serialize_message(msg), "chronos_msgs/msg/CarInput")
    command = conversions.input_from_msg(decoded)
    assert command.mode == "velocity"
    np.testing.assert_array_equal(command.u, [0.05, 2.5])


# --- sensor batches (chronos_msgs/SensorBatch): the same readings as the per-reading messages,
# exact stamps, and a bad reading dropped alone ---------------------------------------------------


READINGS = [
    ("imu", [0.5, -1.25, 2.0]),
    ("wheel_encoders", [20.0, 20.5, 21.0, 21.5]),
    ("lighthouse/0/1", [2.1, 2.1, 2.2, 2.2]),
    ("gyro", [-0.75]),
    ("lighthouse/1/2", [4.2, 4.2, 4.3, 4.3]),
    ("pose", [1.5, -0.5, 3.0]),
]


def measurements(t0: float = 1_764_200_000.123456789) -> list[Measurement]:
    return [
        Measurement(t0 + 0.004 * k + 1e-7 * k, sensor, values)
        for k, (sensor, values) in enumerate(READINGS)
    ]


def test_a_batch_carries_what_the_per_reading_messages_carry() -> None:
    """Through rclpy's CDR: each reading comes back with the stamp its own message would carry
    (bit for bit) and its values; the header holds the newest stamp and the frame."""
    sent = measurements()
    msg = deserialize_message(
        serialize_message(conversions.batch_msg(sent, "car1/base_link")), SensorBatch
    )
    readings = conversions.batch_from_msg(msg)
    assert readings.rejected == []
    assert msg.header.frame_id == "car1/base_link"
    assert conversions.seconds_from_stamp(msg.header.stamp) == max(
        r.stamp for r in readings.measurements
    )
    for original, got in zip(sent, readings.measurements, strict=True):
        own = conversions.measurement_to_msg(original)
        assert got.stamp == conversions.seconds_from_stamp(own.header.stamp)
        assert got.sensor == original.sensor
        np.testing.assert_array_equal(got.values, original.values)


def test_a_batch_reads_the_same_from_a_bag() -> None:
    """rosbags (bag replay) decodes the CDR to the same readings as the node."""
    raw = serialize_message(conversions.batch_msg(measurements(), "car1/base_link"))
    from_bag = typestore().deserialize_cdr(raw, "chronos_msgs/msg/SensorBatch")
    live = conversions.batch_from_msg(deserialize_message(raw, SensorBatch))
    replayed = conversions.batch_from_msg(from_bag)
    assert replayed.rejected == live.rejected == []
    for a, b in zip(replayed.measurements, live.measurements, strict=True):
        assert (a.stamp, a.sensor) == (b.stamp, b.sensor)
        np.testing.assert_array_equal(a.values, b.values)


def test_stamps_keep_nanoseconds_far_from_the_epoch() -> None:
    stamp = 1_764_200_000.000000001  # float64 resolution here is ~0.24 us
    (got,) = conversions.batch_from_msg(
        conversions.batch_msg([Measurement(stamp, "gyro", [0.1])])
    ).measurements
    assert abs(got.stamp - stamp) < 1e-6
    assert conversions.stamp_ns(got.stamp) == conversions.stamp_ns(stamp)


def test_an_empty_batch_is_refused_when_built() -> None:
    with pytest.raises(FieldError, match=r"^measurements: ") as error:
        conversions.batch_msg([])
    assert error.value.field == "measurements"


def _batch(**fields: object) -> SensorBatch:
    msg = conversions.batch_msg(measurements())
    for name, value in fields.items():
        setattr(msg, name, value)
    return msg


@pytest.mark.parametrize(
    ("fields", "field"),
    [
        ({"stamps_ns": [1, 2]}, "stamps_ns"),
        ({"values": [0.0] * 5}, "values"),
        (
            {"sensors": ["imu", "wheel_encoders", "sonar", "gyro", "lighthouse/1/2", "pose"]},
            "sensors[2]",
        ),
    ],
)
def test_a_batch_that_does_not_fit_together_is_refused_naming_the_field(
    fields: dict[str, object], field: str
) -> None:
    with pytest.raises(FieldError) as error:
        conversions.batch_from_msg(_batch(**fields))
    assert error.value.field == field
    assert str(error.value).startswith(f"{field}: ")


def test_a_bad_reading_is_dropped_alone() -> None:
    """A NaN in one reading and a negative stamp in another: those two are dropped, with the
    reading's index and sensor in the reason; the other four are kept in order."""
    msg = _batch()
    msg.values[4] = math.nan  # the second value of wheel_encoders (reading 1)
    msg.stamps_ns[3] = -5  # the gyro
    readings = conversions.batch_from_msg(msg)
    assert [m.sensor for m in readings.measurements] == [
        "imu",
        "lighthouse/0/1",
        "lighthouse/1/2",
        "pose",
    ]
    assert readings.rejected[0].startswith("readings[1] (wheel_encoders): ")
    assert "NaN" in readings.rejected[0]
    assert readings.rejected[1].startswith("readings[3] (gyro): stamps_ns: must be >= 0")


def test_the_plan_round_trips_and_a_nan_is_refused_naming_the_poses() -> None:
    points = np.array([[0.0, 1.0], [0.5, 1.25], [1.0, 1.5]])
    msg = deserialize_message(
        serialize_message(conversions.plan_msg(points, 12.5)),
        type(conversions.plan_msg(points, 0.0)),
    )
    assert msg.header.frame_id == "world"
    assert conversions.seconds_from_stamp(msg.poses[1].header.stamp) == 12.5
    np.testing.assert_array_equal(conversions.plan_from_msg(msg), points)
    assert conversions.plan_from_msg(conversions.plan_msg(np.zeros((0, 2)), 0.0)).shape == (0, 2)
    msg.poses[2].pose.position.y = math.nan
    with pytest.raises(FieldError, match="poses"):
        conversions.plan_from_msg(msg)


def test_the_solve_time_must_be_finite_and_not_negative() -> None:
    from std_msgs.msg import Float64

    assert conversions.solve_time_from_msg(Float64(data=0.004)) == 0.004
    for bad in (-0.001, math.inf):
        with pytest.raises(FieldError, match="data"):
            conversions.solve_time_from_msg(Float64(data=bad))


def test_the_estimator_health_is_its_status_text_and_deadline_misses() -> None:
    from chronos_msgs.msg import EstimatorDiagnostics

    msg = EstimatorDiagnostics(status="degraded: no Lighthouse for 0.6 s", deadline_misses=3)
    assert conversions.estimator_health_from_msg(msg) == ("degraded: no Lighthouse for 0.6 s", 3)
    with pytest.raises(FieldError, match="status: must start with ok, degraded or lost"):
        conversions.estimator_health_from_msg(EstimatorDiagnostics(status="fine"))


def test_a_lighthouse_fix_round_trips_with_its_covariance_in_the_ros_layout() -> None:
    from crs_core.estimation import PoseFix

    covariance = np.array([[4e-6, 1e-6, 2e-6], [1e-6, 9e-6, 3e-6], [2e-6, 3e-6, 1e-4]])
    fix = PoseFix(7.25, np.array([1.5, -0.5, 3.0]), covariance, 1e-3, (0,))
    msg = conversions.pose_fix_msg(fix)
    msg = deserialize_message(serialize_message(msg), type(msg))
    assert msg.header.frame_id == "world"
    stamp, pose = conversions.pose_fix_from_msg(msg)
    assert stamp == 7.25
    np.testing.assert_allclose(pose, [1.5, -0.5, 3.0], atol=1e-12)
    # x, y, yaw at rows / columns 0, 1, 5 of the 6 x 6 (x, y, z, roll, pitch, yaw)
    full = np.array(msg.pose.covariance).reshape(6, 6)
    np.testing.assert_array_equal(full[np.ix_([0, 1, 5], [0, 1, 5])], covariance)
    assert not full[2:5].any() and not full[:, 2:5].any()
    msg.pose.pose.orientation.w = math.nan
    with pytest.raises(FieldError, match=r"pose\.pose\.orientation"):
        conversions.pose_fix_from_msg(msg)
