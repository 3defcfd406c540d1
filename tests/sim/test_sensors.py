"""Sensor specs and blackouts: a bad spec names its field; blackouts are named on a command line
or in a node parameter as ``SENSOR:START:DURATION``.
"""

from __future__ import annotations

import re

import pytest

from crs_core.errors import FieldError
from sim.sensors import Blackout, SensorSpec, parse_blackout


def test_parse_blackout():
    """SENSOR:START:DURATION parses to a Blackout; malformed, unknown or non-finite forms are
    rejected with what is wrong."""
    assert parse_blackout("lighthouse:10:1.127") == Blackout("lighthouse", 10.0, 1.127)
    assert parse_blackout("lighthouse/1:0:1") == Blackout("lighthouse/1", 0.0, 1.0)
    cases = {
        "lighthouse:10": "expected SENSOR:START:DURATION",
        "bogus:1:1": "sensor 'bogus' is not one of",
        "imu/2:1:1": "sensor 'imu/2' is not one of",
        "lighthouse:nan:1": "START 'nan' is not a finite number",
        "imu:a:1": "START 'a' is not a finite number",
        "imu:1:inf": "DURATION 'inf' is not a finite number",
        "imu:-1:1": "start >= 0",
        "imu:1:0": "duration > 0",
    }
    for bad, message in cases.items():
        with pytest.raises(ValueError, match=re.escape(message)):
            parse_blackout(bad)


def test_a_bad_blackout_is_a_field_error():
    with pytest.raises(FieldError) as error:
        Blackout("imu", -1.0, 1.0)
    assert (error.value.field, error.value.reason) == (
        "blackout",
        "needs start >= 0 and duration > 0",
    )


@pytest.mark.parametrize(
    ("fields", "field"),
    [
        ({"rate_hz": 0.0}, "rate_hz"),
        ({"noise_std": (0.1, -0.1)}, "noise_std"),
        ({"bias": (0.1,)}, "bias"),
        ({"dropout_probability": 1.0}, "dropout_probability"),
        ({"latency_s": -0.01}, "latency_s"),
        ({"jitter_std_s": float("nan")}, "jitter_std_s"),
    ],
)
def test_a_bad_sensor_spec_names_the_field(fields: dict, field: str):
    with pytest.raises(FieldError, match=rf"^{field}: ") as error:
        SensorSpec(**{"rate_hz": 100.0, "noise_std": (0.1, 0.1), **fields})
    assert error.value.field == field
