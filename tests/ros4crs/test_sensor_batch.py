"""``chronos_msgs/SensorBatch`` conversions: the same readings as the per-reading messages,
exact stamps, and a bad reading dropped alone."""

from __future__ import annotations

import math

import numpy as np
import pytest
from rclpy.serialization import deserialize_message, serialize_message

from chronos_msgs.msg import SensorBatch
from crs_core.errors import FieldError
from crs_core.measurements import Measurement
from ros4crs import conversions
from ros4crs.interfaces import typestore

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
