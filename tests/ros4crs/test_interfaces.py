"""chronos_msgs as built by ./run.sh, over rclpy (real DDS) and in the rosbags typestore."""

from __future__ import annotations

import importlib
import json
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import rclpy
from builtin_interfaces.msg import Time
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.serialization import deserialize_message, serialize_message
from rclpy.type_support import check_for_type_support
from rosbags.typesys.base import Nodetype
from std_msgs.msg import Header

from ros4crs.interfaces import PACKAGE, msg_dir, typestore

NAMES = [
    "CarInput",
    "CarState",
    "EstimatorDiagnostics",
    "LighthouseSweep",
    "SensorBatch",
    "WheelSpeeds",
]

HEADER = {"stamp": {"sec": 1_700_000_123, "nanosec": 456_789_012}, "frame_id": "world"}

# Field values per message (header excluded), at least one non-default value per field and
# the ends of the integer ranges.
SAMPLES: dict[str, dict[str, object]] = {
    "CarInput": {"mode": 1, "steer": -0.31, "torque": 0.875, "velocity": 2.5},
    "CarState": {
        "status": 1,
        "x": 1.25,
        "y": -3.5,
        "yaw": 3.0,
        "vx": 2.1,
        "vy": -0.15,
        "omega": 4.2,
        "covariance": [0.01 * i - 0.1 for i in range(36)],
    },
    "EstimatorDiagnostics": {
        "estimator": "mhe",
        "status": "degraded: Δt > deadline",
        "solve_time": 0.0021,
        "max_solve_time": 0.0094,
        "updates": 4_294_967_295,
        "deadline_misses": 3,
        "rejected_measurements": 17,
        "late_measurements": 2,
        "ignored_measurements": 250,
        "fallbacks": 1,
        "reinitializations": 2,
        "skipped_time": 1.25,
        "sensors": ["imu", "wheel_encoders", "lighthouse"],
        "received": [2500, 2498, 0],
    },
    "LighthouseSweep": {
        "base_station": 1,
        "plane": 2,
        "angles": [-0.5, 0.25, 1.0e-9, 0.75],
        "sensor_timestamp": 4_294_967_295,
        "sync_timestamp": 123_456,
    },
    "SensorBatch": {
        "sensors": ["imu", "lighthouse/1/2"],
        "stamps_ns": [9_223_372_036_854_775_807, 0],
        "values": [0.5, -0.25, 3.0, 1.0, 1.0e-9, -2.0, 0.75],
    },
    "WheelSpeeds": {"front_left": 50.5, "front_right": 51.0, "rear_left": -1.5, "rear_right": 0.0},
}


def _rclpy_class(name: str) -> type:
    return getattr(importlib.import_module(f"{PACKAGE}.msg"), name)


def _rclpy_msg(name: str, values: dict[str, object]) -> object:
    header = Header(stamp=Time(**HEADER["stamp"]), frame_id=HEADER["frame_id"])
    return _rclpy_class(name)(header=header, **values)


def _rosbags_msg(name: str, values: dict[str, object]) -> object:
    """The same message built from the rosbags types (numeric arrays as numpy arrays)."""
    ts = typestore()
    typename = f"{PACKAGE}/msg/{name}"
    header = ts.types["std_msgs/msg/Header"](
        stamp=ts.types["builtin_interfaces/msg/Time"](**HEADER["stamp"]),
        frame_id=HEADER["frame_id"],
    )
    kwargs: dict[str, object] = {"header": header}
    for field, (kind, spec) in ts.fielddefs[typename][1]:
        if field == "header":
            continue
        value = values[field]
        if kind in (Nodetype.ARRAY, Nodetype.SEQUENCE):
            (_, (base, _)), _ = spec
            value = value if base == "string" else np.asarray(value, dtype=base)
        kwargs[field] = value
    return ts.types[typename](**kwargs)


def _assert_same(ros_msg: object, bag_msg: object, where: str = "") -> None:
    """Field-by-field equality of an rclpy message and a rosbags message."""
    for field in ros_msg.get_fields_and_field_types():
        a, b = getattr(ros_msg, field), getattr(bag_msg, field)
        path = f"{where}{field}"
        if hasattr(a, "get_fields_and_field_types"):
            _assert_same(a, b, f"{path}.")
        elif isinstance(a, str) or (isinstance(a, list) and a and isinstance(a[0], str)):
            assert a == b, path  # string or string[]
        else:
            a_arr, b_arr = np.asarray(a), np.asarray(b)
            assert a_arr.shape == b_arr.shape, path
            np.testing.assert_array_equal(a_arr, b_arr, err_msg=path)


@pytest.fixture
def ros_context(monkeypatch: pytest.MonkeyPatch):
    """An rclpy context of its own on loopback, in this test file's ROS domain."""
    monkeypatch.setenv("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    monkeypatch.setenv("ROS_DOMAIN_ID", "57")
    context = Context()
    rclpy.init(context=context)
    try:
        yield context
    finally:
        context.try_shutdown()


@pytest.mark.parametrize("name", NAMES)
def test_message_imports_from_built_package(name: str) -> None:
    cls = _rclpy_class(name)
    assert Path(sys.modules[cls.__module__].__file__).is_relative_to(sys.prefix)
    msg = cls()
    assert msg.header.frame_id == ""
    check_for_type_support(cls)  # loads the generated C extension and typesupport libraries
    assert cls._TYPE_SUPPORT is not None
    assert _rclpy_class("CarInput").MODE_TORQUE == 0
    assert _rclpy_class("CarInput").MODE_VELOCITY == 1


def test_field_names_and_fixed_sizes() -> None:
    assert len(_rclpy_class("CarState")().covariance) == 36
    assert len(_rclpy_class("LighthouseSweep")().angles) == 4
    for name, values in SAMPLES.items():
        fields = set(_rclpy_class(name).get_fields_and_field_types())
        assert fields == {"header", *values}, name


def test_car_state_published_is_received_over_dds(ros_context: Context) -> None:
    car_state = _rclpy_class("CarState")
    sent = _rclpy_msg("CarState", SAMPLES["CarState"])
    node = rclpy.create_node("test_interfaces_pubsub", context=ros_context)
    executor = SingleThreadedExecutor(context=ros_context)
    try:
        received: list[object] = []
        publisher = node.create_publisher(car_state, "test_interfaces/car_state", 10)
        node.create_subscription(car_state, "test_interfaces/car_state", received.append, 10)
        executor.add_node(node)
        deadline = time.monotonic() + 10.0
        while not received and time.monotonic() < deadline:
            publisher.publish(sent)
            executor.spin_once(timeout_sec=0.05)
        assert received, "no CarState received within 10 s"
        assert received[0] == sent
        _assert_same(received[0], _rosbags_msg("CarState", SAMPLES["CarState"]))

        # The hash rclpy announces on the graph is the one rosbags computes.
        (info,) = node.get_publishers_info_by_topic("/test_interfaces/car_state")
        assert info.topic_type == f"{PACKAGE}/msg/CarState"
        assert str(info.topic_type_hash) == typestore().hash_rihs01(f"{PACKAGE}/msg/CarState")
    finally:
        executor.shutdown()
        node.destroy_node()


@pytest.mark.parametrize("name", NAMES)
def test_rclpy_to_rosbags(name: str) -> None:
    ros_msg = _rclpy_msg(name, SAMPLES[name])
    raw = serialize_message(ros_msg)
    bag_msg = typestore().deserialize_cdr(raw, f"{PACKAGE}/msg/{name}")
    _assert_same(ros_msg, bag_msg)


@pytest.mark.parametrize("name", NAMES)
def test_rosbags_to_rclpy(name: str) -> None:
    bag_msg = _rosbags_msg(name, SAMPLES[name])
    raw = typestore().serialize_cdr(bag_msg, f"{PACKAGE}/msg/{name}")
    ros_msg = deserialize_message(bytes(raw), _rclpy_class(name))
    _assert_same(ros_msg, bag_msg)
    assert ros_msg == _rclpy_msg(name, SAMPLES[name])


def test_empty_sequences_round_trip() -> None:
    values = {**SAMPLES["EstimatorDiagnostics"], "sensors": [], "received": []}
    typename = f"{PACKAGE}/msg/EstimatorDiagnostics"
    ros_msg = _rclpy_msg("EstimatorDiagnostics", values)
    _assert_same(ros_msg, typestore().deserialize_cdr(serialize_message(ros_msg), typename))
    bag_msg = _rosbags_msg("EstimatorDiagnostics", values)
    raw = bytes(typestore().serialize_cdr(bag_msg, typename))
    _assert_same(deserialize_message(raw, _rclpy_class("EstimatorDiagnostics")), bag_msg)


@pytest.mark.parametrize("name", NAMES)
def test_rosbags_type_hash_equals_generated(name: str) -> None:
    typename = f"{PACKAGE}/msg/{name}"
    json_file = Path(sys.prefix) / "share" / PACKAGE / "msg" / f"{name}.json"
    generated = json.loads(json_file.read_text())  # written by rosidl at build time
    want = {h["type_name"]: h["hash_string"] for h in generated["type_hashes"]}
    assert typestore().hash_rihs01(typename) == want[typename]


def test_typestore_is_cached_and_reads_installed_msgs() -> None:
    assert typestore() is typestore()
    assert msg_dir() == Path(sys.prefix) / "share" / PACKAGE / "msg"
    assert {f"{PACKAGE}/msg/{n}" for n in NAMES} <= set(typestore().types)
    assert typestore().types[f"{PACKAGE}/msg/CarInput"].MODE_VELOCITY == 1


def test_tf2_msgs_tfmessage_is_the_standard_type() -> None:
    """The TFMessage built by ./run.sh (the wheels lack tf2_msgs) has the standard definition:
    its generated RIHS01 hash equals that of the stock ROS 2 Jazzy type in rosbags, so RViz,
    Foxglove and any real ROS installation accept our /tf; it round-trips through rosbags."""
    from geometry_msgs.msg import TransformStamped
    from rosbags.typesys import Stores, get_typestore

    from tf2_msgs.msg import TFMessage

    typename = "tf2_msgs/msg/TFMessage"
    json_file = Path(sys.prefix) / "share" / "tf2_msgs" / "msg" / "TFMessage.json"
    generated = json.loads(json_file.read_text())
    want = {h["type_name"]: h["hash_string"] for h in generated["type_hashes"]}
    assert want[typename] == get_typestore(Stores.ROS2_JAZZY).hash_rihs01(typename)
    transform = TransformStamped(child_frame_id="car1/base_link")
    transform.header.frame_id = "world"
    transform.transform.translation.x = 1.5
    transform.transform.rotation.z, transform.transform.rotation.w = 0.6, 0.8
    raw = serialize_message(TFMessage(transforms=[transform]))
    decoded = typestore().deserialize_cdr(raw, typename)
    (got,) = decoded.transforms
    assert (got.header.frame_id, got.child_frame_id) == ("world", "car1/base_link")
    assert (got.transform.translation.x, got.transform.rotation.z) == (1.5, 0.6)


def test_estimator_query_round_trips_with_its_time_sequence() -> None:
    """EstimatorQuery (a sequence of builtin Time) between rclpy and rosbags, both ways, and its
    rosbags type hash equals the generated one."""
    from chronos_msgs.msg import EstimatorQuery

    typename = f"{PACKAGE}/msg/EstimatorQuery"
    sent = EstimatorQuery(
        header=Header(stamp=Time(**HEADER["stamp"]), frame_id=""),
        start=True,
        streams=["sensors/imu", "input"],
        newest=[Time(sec=1_700_000_122, nanosec=999_999_999), Time(sec=5, nanosec=0)],
        oldest=[Time(sec=1_700_000_100, nanosec=1), Time(sec=4, nanosec=0)],
    )
    decoded = typestore().deserialize_cdr(serialize_message(sent), typename)
    assert decoded.start is True and decoded.streams == ["sensors/imu", "input"]
    assert [(t.sec, t.nanosec) for t in decoded.newest] == [(1_700_000_122, 999_999_999), (5, 0)]
    assert [(t.sec, t.nanosec) for t in decoded.oldest] == [(1_700_000_100, 1), (4, 0)]
    back = deserialize_message(bytes(typestore().serialize_cdr(decoded, typename)), EstimatorQuery)
    assert back == sent
    json_file = Path(sys.prefix) / "share" / PACKAGE / "msg" / "EstimatorQuery.json"
    want = {
        h["type_name"]: h["hash_string"] for h in json.loads(json_file.read_text())["type_hashes"]
    }
    assert typestore().hash_rihs01(typename) == want[typename]
