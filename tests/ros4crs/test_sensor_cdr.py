"""The sensors' fast path from CDR bytes gives what the full path gives, or leaves it to it.

``conversions.*_from_cdr`` read a serialized sensor message directly; whenever they return a
measurement it must be exactly the one ``deserialize_message`` + ``*_from_msg`` returns, and
every message the full path refuses (with its error text) must go to the full path (``None``).
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from rclpy.serialization import deserialize_message, serialize_message

from crs_core.measurements import Measurement
from ros4crs import conversions

FRAMES = ["", "b", "base_link", "car1/base_link", "c" * 7, "c" * 8, "c" * 9, "x" * 40]


def _full(data: bytes, family: str) -> Measurement | Exception:
    msg_type = conversions.sensor_message_types()[family]
    try:
        return conversions.SENSOR_PARSERS[family](deserialize_message(data, msg_type))
    except Exception as error:  # what the node logs
        return error


def _same(a: Measurement, b: Measurement) -> bool:
    return (
        a.sensor == b.sensor
        and math.copysign(1, a.stamp) == math.copysign(1, b.stamp)
        and a.stamp == b.stamp
        and np.array_equal(a.values, b.values)
        and a.values.dtype == b.values.dtype
    )


def _measurements() -> list[Measurement]:
    rng = np.random.default_rng(3)
    out = []
    for stamp in (0.0, 1.5, 12345.000000001, 1.7e9 + 0.123456789):
        out.append(Measurement(stamp, "imu", rng.normal(size=3)))
        out.append(Measurement(stamp, "gyro", rng.normal(size=1)))
        out.append(Measurement(stamp, "wheel_encoders", rng.normal(size=4) * 50))
        for station, plane in ((0, 1), (0, 2), (3, 1), (255, 2)):
            out.append(Measurement(stamp, f"lighthouse/{station}/{plane}", rng.normal(size=4)))
    return out


def _messages():
    """(family, message) for valid messages with many frame ids, and invalid variants."""
    for m in _measurements():
        family = conversions.topic_family(m.sensor)
        for frame in FRAMES:
            yield family, conversions.measurement_to_msg(m, frame)
    bad = conversions.measurement_to_msg(Measurement(2.0, "imu", [1.0, 2.0, 3.0]))
    for field, value in (("x", math.nan), ("y", math.inf), ("z", math.nan)):
        msg = conversions.measurement_to_msg(Measurement(2.0, "imu", [1.0, 2.0, 3.0]))
        target = msg.angular_velocity if field == "z" else msg.linear_acceleration
        setattr(target, field, value)
        yield "imu", msg
    gyro = conversions.measurement_to_msg(Measurement(2.0, "gyro", [1.0]))
    gyro.linear_acceleration.x = math.nan  # not measured: not checked
    yield "imu", gyro
    gyro = conversions.measurement_to_msg(Measurement(2.0, "gyro", [1.0]))
    gyro.angular_velocity.z = -math.inf
    yield "imu", gyro
    bad.header.stamp.nanosec = 1_000_000_000
    yield "imu", bad
    negative = conversions.measurement_to_msg(Measurement(2.0, "imu", [1.0, 2.0, 3.0]))
    negative.header.stamp.sec = -5
    yield "imu", negative
    for value in (math.nan, math.inf):
        msg = conversions.measurement_to_msg(Measurement(2.0, "wheel_encoders", [1.0] * 4))
        msg.rear_right = value
        yield "wheel_encoders", msg
    for plane in (0, 3, 255):
        msg = conversions.measurement_to_msg(Measurement(2.0, "lighthouse/0/1", [0.1] * 4))
        msg.plane = plane
        yield "lighthouse", msg
    msg = conversions.measurement_to_msg(Measurement(2.0, "lighthouse/1/2", [0.1] * 4))
    msg.angles[2] = math.nan
    msg.sensor_timestamp, msg.sync_timestamp = 123456, 654321
    yield "lighthouse", msg
    msg = conversions.measurement_to_msg(Measurement(2.0, "wheel_encoders", [1.0] * 4), "ü/base")
    yield "wheel_encoders", msg


def test_the_fast_path_takes_every_valid_sensor_message_and_gives_the_same_measurement():
    valid = 0
    for family, msg in _messages():
        data = serialize_message(msg)
        fast = conversions.SENSOR_CDR_PARSERS[family](data)
        full = _full(data, family)
        if isinstance(full, Exception):
            assert fast is None, (family, msg, full)
            continue
        if msg.header.frame_id.isascii():
            assert fast is not None, (family, msg)
            assert _same(fast, full), (fast, full)
            valid += 1
        else:
            assert fast is None or _same(fast, full)
    assert valid >= len(_measurements()) * len(FRAMES)


@pytest.mark.parametrize("family", ["imu", "wheel_encoders", "lighthouse"])
def test_a_corrupted_message_is_never_taken_differently_from_the_full_path(family):
    """Bytes flipped, cut or added: the fast path either agrees with the full path or leaves
    the message to it (which drops it with its own error text when it is malformed)."""
    rng = np.random.default_rng(7)
    sensor = {"imu": "imu", "wheel_encoders": "wheel_encoders", "lighthouse": "lighthouse/0/2"}
    values = {"imu": [0.5, -0.25, 1.0], "wheel_encoders": [10.0] * 4, "lighthouse": [0.1] * 4}
    fast_path = conversions.SENSOR_CDR_PARSERS[family]
    taken = 0
    for _ in range(3000):
        frame = FRAMES[rng.integers(len(FRAMES))]
        msg = conversions.measurement_to_msg(
            Measurement(float(rng.uniform(0, 100)), sensor[family], values[family]), frame
        )
        data = bytearray(serialize_message(msg))
        change = rng.integers(4)
        if change == 0:  # flip a few bytes
            for i in rng.integers(len(data), size=rng.integers(1, 4)):
                data[i] = int(rng.integers(256))
        elif change == 1:  # cut
            data = data[: rng.integers(len(data))]
        elif change == 2:  # trailing bytes
            data += bytes(rng.integers(256, size=rng.integers(1, 12)).astype(np.uint8))
        else:  # one byte at every place, once
            data[rng.integers(len(data))] ^= 1 << int(rng.integers(8))
        data = bytes(data)
        fast = fast_path(data)
        if fast is None:
            continue
        full = _full(data, family)
        assert not isinstance(full, Exception), (data.hex(), full)
        assert _same(fast, full), (data.hex(), fast, full)
        taken += 1
    assert taken > 100  # the fast path did take corrupted-but-valid messages (e.g. new values)
