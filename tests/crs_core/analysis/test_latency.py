"""Tests of crs_core.analysis.latency on small hand-made streams whose answers are worked out
by hand in the comments (stamps and receive times in s, latencies in ms)."""

from __future__ import annotations

import numpy as np
import pytest

from crs_core.analysis.latency import (
    LATENCY_DEFINITIONS,
    command_latencies,
    input_chain_latency,
    latencies,
)

#: Sensor stamps 0.0, 0.1, 0.2, 0.3 (their receive times do not matter).
SENSORS = [(0.0, 0.01), (0.1, 0.11), (0.2, 0.21), (0.3, 0.31)]
#: (stamp, receive time) of three estimates, listed out of receive order.
ESTIMATES = [(0.22, 0.26), (0.12, 0.15), (0.32, 0.35)]


def _close(result: dict, expected: dict) -> None:
    assert set(result) == set(expected)
    for key, value in expected.items():
        assert result[key] == pytest.approx(value, abs=0.006), key


def test_sensor_to_estimate_and_sensor_to_input():
    """Estimates: newest sensors at or before 0.12, 0.22, 0.32 are 0.1, 0.2, 0.3, received
    0.15, 0.26, 0.35: 50, 60, 50 ms -> median 50, p95 50 + 0.9 * 10 = 59.
    Inputs received at 0.17 (newest estimate received: the one of 0.15, sensor 0.1: 70 ms),
    0.30 (estimate of 0.26, sensor 0.2: 100 ms) and 0.11 (no estimate yet: left out):
    median 85, p95 70 + 0.95 * 30 = 98.5."""
    times = {
        "sensor": SENSORS,
        "estimate": ESTIMATES,
        "input": [(0.16, 0.17), (0.27, 0.30), (0.10, 0.11)],
    }
    result = latencies(times)
    assert list(result) == ["sensor_to_estimate", "sensor_to_input"]
    _close(result["sensor_to_estimate"], {"median": 50.0, "p95": 59.0})
    _close(result["sensor_to_input"], {"median": 85.0, "p95": 98.5})


def test_latencies_with_missing_streams():
    assert latencies({}) == {}
    assert latencies({"sensor": SENSORS}) == {}
    assert latencies({"estimate": ESTIMATES}) == {}
    only = latencies({"sensor": SENSORS, "estimate": ESTIMATES})
    assert list(only) == ["sensor_to_estimate"]
    # inputs that all came before the first estimate match nothing
    early = latencies({"sensor": SENSORS, "estimate": ESTIMATES, "input": [(0.1, 0.11)]})
    assert early["sensor_to_input"] == {}


def test_input_chain_follows_the_input_stamp_not_its_receive_time():
    """Input stamped 0.16 (newest estimate received by then: 0.15, stamped 0.12, sensor 0.1),
    received 0.17: 70 ms. Stamped 0.20 (estimate received 0.15 again: sensor 0.1), received 0.30:
    200 ms (``sensor_to_input`` would take the estimate received 0.26 and give 100 ms).
    Stamped 0.10: no estimate yet, left out. Median 135, p95 70 + 0.95 * 130 = 193.5."""
    times = {
        "sensor": SENSORS,
        "estimate": ESTIMATES,
        "input": [(0.16, 0.17), (0.20, 0.30), (0.10, 0.11)],
    }
    _close(input_chain_latency(times), {"median": 135.0, "p95": 193.5})
    assert latencies(times)["sensor_to_input"]["median"] == pytest.approx(85.0)
    assert input_chain_latency({"sensor": SENSORS, "estimate": ESTIMATES}) == {}


def test_command_latencies_match_each_command_to_its_input_estimate_and_sensor():
    """Inputs stamped 0.16, 0.27, 0.36. Commands (bridge send stamp -> emulator read):
    0.17 -> 0.18 (input 0.16, estimate received 0.15 stamped 0.12, sensor 0.1);
    0.28 -> 0.29 and again 0.28 -> 0.33 (a repeat: counted once, at its first read; input 0.27,
    estimate received 0.26 stamped 0.22, sensor 0.2);
    0.50 -> 0.51 (newest input 0.36 is 0.14 s older: more than a controller period, left out);
    0.05 -> 0.06 (no input yet: left out); NaN send stamp: left out.
    read - sensor: 80, 90 -> median 85, p95 89.5; sent - sensor: 70, 80 -> 75, 79.5;
    read - sent: 10, 10."""
    times = {
        "sensor": SENSORS,
        "estimate": ESTIMATES,
        "input": [(0.16, 0.17), (0.27, 0.28), (0.36, 0.37)],
    }
    log = {
        "command_host_t": np.array([0.17, 0.28, 0.28, 0.50, np.nan, 0.05]),
        "command_read_t": np.array([0.18, 0.29, 0.33, 0.51, 0.60, 0.06]),
    }
    result = command_latencies(times, log)
    assert result["commands_matched"] == 2
    _close(result["sensor_to_command_read"], {"median": 85.0, "p95": 89.5})
    _close(result["sensor_to_command_sent"], {"median": 75.0, "p95": 79.5})
    _close(result["command_sent_to_read"], {"median": 10.0, "p95": 10.0})
    empty = {"command_host_t": np.array([]), "command_read_t": np.array([])}
    assert command_latencies(times, empty) == {}


def test_every_reported_latency_is_defined():
    names = {
        "sensor_to_estimate",
        "sensor_to_input",
        "sensor_to_input_chain",
        "sensor_to_command_read",
        "sensor_to_command_sent",
        "command_sent_to_read",
    }
    assert set(LATENCY_DEFINITIONS) == names
