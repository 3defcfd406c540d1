"""Blackouts named on a command line or in a node parameter: ``SENSOR:START:DURATION``."""

from __future__ import annotations

import re

import pytest

from crs_core.errors import FieldError
from sim.sensors import Blackout, parse_blackout


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
