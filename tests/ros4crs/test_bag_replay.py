"""Reading one car's data from a bag without ROS: sensors, inputs, estimates and truth of the
car's namespace, in stamp order, with malformed messages counted (the bag is written here, as
the recorder would, with messages out of stamp order and a second car beside the first)."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from rclpy.serialization import serialize_message
from rosbags.rosbag2 import StoragePlugin, Writer

from crs_core.measurements import InputSample, Measurement
from ros4crs import conversions
from ros4crs.bag_replay import (
    BagContents,
    Query,
    ReplayIncompleteWarning,
    read_car,
    replay_estimator,
)
from ros4crs.interfaces import typestore

T0 = 1_764_000_000.0


def _type_name(msg: Any) -> str:
    package = type(msg).__module__.split(".")[0]
    return f"{package}/msg/{type(msg).__name__}"


def _imu(t: float, yaw_rate: float = 0.5) -> Any:
    return conversions.measurement_to_msg(Measurement(T0 + t, "imu", [0.1, -0.2, yaw_rate]))


#: (topic, message, receive time after T0 in s), in the order they are written.
def _messages() -> list[tuple[str, Any, float]]:
    malformed = _imu(0.3)
    malformed.angular_velocity.z = math.nan
    wheels = Measurement(T0 + 0.15, "wheel_encoders", [10.0, 10.5, 11.0, 11.5])
    return [
        ("/car1/sensors/imu", _imu(0.2), 0.205),
        ("/car1/sensors/imu", _imu(0.1), 0.25),  # late: recorded after the later stamp
        ("/car1/sensors/wheel_speeds", conversions.measurement_to_msg(wheels), 0.16),
        ("/car1/sensors/imu", malformed, 0.31),
        ("/car1/input", conversions.car_input_msg([0.1, 0.4], T0 + 0.12), 0.125),
        ("/car1/input", conversions.car_input_msg([0.1, 1.5], T0 + 0.14, "velocity"), 0.145),
        ("/car1/input/applied", conversions.car_input_msg([0.05, 0.3], T0 + 0.13), 0.17),
        (
            "/car1/estimate/state",
            conversions.car_state_msg(np.arange(6.0), T0 + 0.2, np.diag(np.arange(1.0, 7.0))),
            0.21,
        ),
        ("/car1/ground_truth", conversions.car_state_msg(np.ones(6), T0 + 0.2), 0.2),
        ("/car2/sensors/imu", _imu(0.1, yaw_rate=-1.0), 0.11),
        ("/car1/note", conversions.car_input_msg([0.0, 0.0], T0), 0.3),  # not a known topic
    ]


@pytest.fixture(scope="module")
def bag(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("replay") / "bag"
    store = typestore()
    with Writer(path, version=9, storage_plugin=StoragePlugin.MCAP) as writer:
        connections: dict[str, Any] = {}
        for topic, msg, received in _messages():
            if topic not in connections:
                connections[topic] = writer.add_connection(topic, _type_name(msg), typestore=store)
            writer.write(connections[topic], round((T0 + received) * 1e9), serialize_message(msg))
    return path


def test_one_car_is_read_in_stamp_order_and_bad_messages_are_counted(bag: Path) -> None:
    contents = read_car(bag, "/car1")
    assert [(round(m.stamp - T0, 6), m.sensor) for m in contents.measurements] == [
        (0.1, "imu"),
        (0.15, "wheel_encoders"),
        (0.2, "imu"),
    ]
    np.testing.assert_array_equal(contents.measurements[0].values, [0.1, -0.2, 0.5])  # not car2
    assert contents.malformed == 1
    # the commanded torque only; the velocity reference is counted, not an input
    assert [(round(s.stamp - T0, 6), list(s.u)) for s in contents.inputs] == [(0.12, [0.1, 0.4])]
    assert contents.velocity_references == 1 and contents.input_topic == "input"
    ((stamp, x),) = contents.estimates
    assert stamp == pytest.approx(T0 + 0.2, abs=1e-6)
    np.testing.assert_array_equal(x, np.arange(6.0))
    (sigma,) = contents.estimate_sigmas  # the square roots of the covariance's diagonal
    np.testing.assert_allclose(sigma, np.sqrt(np.arange(1.0, 7.0)))
    ((_, truth),) = contents.truth
    np.testing.assert_array_equal(truth, np.ones(6))
    assert contents.queries == [] and contents.deadline_misses == 0


def test_the_applied_inputs_instead_of_the_commands(bag: Path) -> None:
    contents = read_car(bag, "/car1", input_topic="input/applied")
    assert [(round(s.stamp - T0, 6), list(s.u)) for s in contents.inputs] == [(0.13, [0.05, 0.3])]
    assert contents.velocity_references == 0 and contents.input_topic == "input/applied"


@pytest.mark.parametrize("input_topic", ["input", "input/applied"])
def test_receive_times_pair_each_stamp_with_its_arrival(bag: Path, input_topic: str) -> None:
    times = read_car(bag, "/car1", input_topic=input_topic).receive_times

    def offsets(kind: str) -> list[tuple[float, float]]:
        return [(round(s - T0, 6), round(r - T0, 6)) for s, r in times[kind]]

    # in the order of arrival; the NaN reading has a valid header: its times are kept
    assert offsets("sensor") == [(0.15, 0.16), (0.2, 0.205), (0.1, 0.25), (0.3, 0.31)]
    assert offsets("input") == [(0.12, 0.125), (0.14, 0.145)]  # not input/applied
    assert offsets("estimate") == [(0.2, 0.21)]


class _Recording:
    """Stands in for an estimator: what it was given, and when it was asked."""

    def __init__(self) -> None:
        self.events: list[tuple[str, float]] = []

    def reset(self, t: float, x0: Any) -> None:
        self.events.append(("reset", round(t - T0, 6)))

    def add(self, item: Measurement | InputSample) -> None:
        kind = "input" if isinstance(item, InputSample) else item.sensor
        self.events.append((kind, round(item.stamp - T0, 6)))

    def estimate(self, t: float) -> str:
        self.events.append(("estimate", round(t - T0, 6)))
        return "estimate"


def _contents(input_stamps: list[float]) -> BagContents:
    """A recording: imu from 0 s every 10 ms, commands at ``input_stamps`` (s after T0)."""
    imu = [Measurement(T0 + 0.01 * k, "imu", [0.0, 0.0, 0.0]) for k in range(10)]
    inputs = [InputSample(T0 + t, [0.0, 0.1]) for t in input_stamps]
    return BagContents(imu, inputs, [], [], 0)


def _queries(first_input: float) -> list[Query]:
    """The estimator started at 0.025 s; its first command was stamped ``first_input``."""

    def query(t: float, start: bool, newest_imu: float) -> Query:
        newest = {"sensors/imu": T0 + newest_imu, "input": T0 + 0.03}
        oldest = {"sensors/imu": T0 + 0.02, "input": T0 + first_input}
        return Query(T0 + t, start, newest, oldest)

    return [query(0.025, True, 0.03), query(0.045, False, 0.06)]


def test_a_replay_gives_only_what_the_estimator_had_since_its_first_messages() -> None:
    """The recorder subscribed first: it holds commands (-0.2, -0.1 s) and imu (0-0.01 s) from
    before the estimator's first ones (a command at 0.03 s, imu at 0.02 s). Replayed, the
    estimator starts without a command in effect, as the node did, and never sees the rest."""
    estimator = _Recording()
    out = replay_estimator(_contents([-0.2, -0.1, 0.03]), estimator, _queries(0.03), None)
    assert out == [None, "estimate"]
    assert estimator.events == [
        ("reset", 0.025),
        ("input", 0.03),
        ("imu", 0.03),
        ("imu", 0.04),
        ("imu", 0.05),
        ("imu", 0.06),
        ("estimate", 0.045),
    ]


def test_a_stream_that_begins_after_the_start_begins_at_the_estimators_first_message() -> None:
    """The estimator started (0.025 s) before its first command (0.03 s, at the second query):
    the commands the recorder had from before the estimator subscribed (-0.2, -0.1 s) are still
    left out (measured in the suite: two such commands made a replay differ by up to 8.8 cm)."""
    estimator = _Recording()
    start, later = _queries(0.03)
    start = Query(
        start.stamp,
        True,
        {"sensors/imu": start.newest["sensors/imu"]},
        {"sensors/imu": start.oldest["sensors/imu"]},
    )
    out = replay_estimator(_contents([-0.2, -0.1, 0.03]), estimator, [start, later], None)
    assert out == [None, "estimate"]
    assert [e for e in estimator.events if e[0] == "input"] == [("input", 0.03)]


def test_a_replay_warns_where_the_bag_lacks_the_estimators_first_messages() -> None:
    """The recorder subscribed last (after the estimator's command at -0.1 s, which the bag
    does not have): the replay is not exact, and says which stream."""
    estimator = _Recording()
    with pytest.warns(ReplayIncompleteWarning, match="input: the estimator's data began"):
        replay_estimator(_contents([0.03]), estimator, _queries(-0.1), None)
    assert ("input", 0.03) in estimator.events
