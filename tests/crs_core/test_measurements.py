"""Tests of crs_core.measurements: the validated (stamp, sensor, values) stream types."""

from __future__ import annotations

import math

import numpy as np
import pytest

from crs_core.errors import FieldError
from crs_core.measurements import (
    InputSample,
    Measurement,
    lighthouse_sensor,
    parse_lighthouse,
    sensor_size,
)


@pytest.mark.parametrize(
    ("sensor", "size"),
    [
        ("imu", 3),
        ("gyro", 1),
        ("wheel_encoders", 4),
        ("pose", 3),
        ("lighthouse/0/1", 4),
        ("lighthouse/3/2", 4),
        ("lighthouse/12/1", 4),
    ],
)
def test_known_sensors_accept_values_of_their_size(sensor: str, size: int):
    """Every documented sensor name takes exactly its number of values, stored as float64."""
    assert sensor_size(sensor) == size
    m = Measurement(1.5, sensor, list(range(size)))
    assert m.values.dtype == np.float64
    np.testing.assert_array_equal(m.values, np.arange(size, dtype=float))
    assert m.stamp == 1.5
    assert m.sensor == sensor


def test_lighthouse_names_round_trip():
    """lighthouse_sensor and parse_lighthouse are inverse; other names parse to None."""
    assert lighthouse_sensor(3, 2) == "lighthouse/3/2"
    assert parse_lighthouse("lighthouse/3/2") == (3, 2)
    assert parse_lighthouse("imu") is None
    assert parse_lighthouse("lighthouse/3/3") is None


def test_integer_stamp_is_stored_as_float():
    """An int stamp is accepted and stored as a Python float."""
    m = Measurement(2, "gyro", [0.1])
    assert isinstance(m.stamp, float)
    assert m.stamp == 2.0


@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
def test_non_finite_values_are_rejected_naming_values(bad: float):
    """NaN or inf in any channel raises FieldError on ``values`` (the message starts with it)."""
    with pytest.raises(FieldError, match=r"^values: imu") as error:
        Measurement(0.0, "imu", [0.0, bad, 0.0])
    assert error.value.field == "values"


@pytest.mark.parametrize(
    ("sensor", "values"),
    [
        ("imu", [0.0, 0.0]),
        ("imu", [0.0] * 4),
        ("gyro", [[0.1]]),
        ("wheel_encoders", 1.0),
        ("lighthouse/0/1", [0.0] * 8),
        ("pose", np.zeros((3, 1))),
    ],
)
def test_wrong_number_or_shape_of_values_is_rejected(sensor: str, values):
    """Values of the wrong size or dimension raise FieldError naming `values` and the shape."""
    size = sensor_size(sensor)
    with pytest.raises(FieldError, match=rf"^values: .*needs shape \({size},\)") as error:
        Measurement(0.0, sensor, values)
    assert error.value.field == "values"


@pytest.mark.parametrize(
    "sensor",
    [
        "IMU",
        "camera",
        "lighthouse",
        "lighthouse/0",
        "lighthouse/0/3",
        "lighthouse/0/0",
        "lighthouse/a/1",
        "lighthouse/-1/1",
        "lighthouse/0/1/x",
        " imu",
        "",
    ],
)
def test_unknown_sensor_names_are_rejected_naming_sensor(sensor: str):
    """Names outside the documented set raise FieldError on `sensor`."""
    with pytest.raises(FieldError, match=r"^sensor: unknown name") as error:
        Measurement(0.0, sensor, [0.0] * 4)
    assert error.value.field == "sensor"


@pytest.mark.parametrize("stamp", [math.nan, math.inf, -math.inf, "1.0", None])
def test_non_finite_or_non_numeric_stamps_are_rejected_naming_stamp(stamp):
    """NaN, inf, a string or None as stamp raise FieldError on `stamp`."""
    with pytest.raises(FieldError, match=r"^stamp: must be (a )?finite") as error:
        Measurement(stamp, "gyro", [0.0])
    assert error.value.field == "stamp"


def test_measurement_is_immutable():
    """Fields of a measurement cannot be reassigned after validation."""
    m = Measurement(0.0, "gyro", [0.0])
    with pytest.raises(AttributeError):
        m.stamp = math.nan  # type: ignore[misc]


def test_sensor_name_with_trailing_newline_is_rejected():
    """'lighthouse/0/1\\n' is not a sensor name (it would open a separate stream)."""
    with pytest.raises(ValueError, match=r"^sensor:"):
        Measurement(0.0, "lighthouse/0/1\n", [0.0] * 4)


@pytest.mark.parametrize("sensor", [None, 5, ["imu"]])
def test_non_string_sensor_is_rejected_with_value_error(sensor):
    """A sensor that is not a string raises ValueError naming `sensor`."""
    with pytest.raises(ValueError, match=r"^sensor:"):
        Measurement(0.0, sensor, [0.0] * 3)


@pytest.mark.parametrize("stamp", [np.float32(0.5), np.int64(2)])
def test_numpy_scalar_stamps_are_accepted(stamp):
    """Finite numpy scalars (e.g. from a float32 or int array) are valid stamps."""
    assert Measurement(stamp, "gyro", [0.0]).stamp == float(stamp)


# --- InputSample -------------------------------------------------------------------------------
def test_input_sample_converts_u_to_float_array():
    """A valid input keeps its stamp and stores u as a float64 array [steer, torque]."""
    s = InputSample(0.25, [0.1, 1])
    assert s.stamp == 0.25
    assert s.u.dtype == np.float64
    np.testing.assert_array_equal(s.u, [0.1, 1.0])


@pytest.mark.parametrize(
    ("stamp", "u"),
    [
        (0.0, [0.1]),
        (0.0, [0.1, 0.2, 0.3]),
        (0.0, [[0.1, 0.2]]),
        (0.0, [np.nan, 0.2]),
        (0.0, [0.1, np.inf]),
        (math.nan, [0.1, 0.2]),
        (math.inf, [0.1, 0.2]),
    ],
)
def test_input_sample_rejects_bad_shape_and_non_finite(stamp: float, u):
    """Wrong shape, NaN/inf in u, or a non-finite stamp raise FieldError naming the field."""
    field = "stamp" if not math.isfinite(stamp) else "u"
    with pytest.raises(FieldError, match=rf"^{field}: ") as error:
        InputSample(stamp, u)
    assert error.value.field == field


@pytest.mark.parametrize("stamp", [None, "0.5"])
def test_input_sample_rejects_non_numeric_stamp_with_value_error(stamp):
    """A stamp that is not a number raises ValueError, like every other bad input."""
    with pytest.raises(ValueError, match=r"^stamp: "):
        InputSample(stamp, [0.1, 0.2])
