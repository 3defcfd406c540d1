"""The .proto files against the spec table, and wire bytes against encodings computed by hand."""

from __future__ import annotations

import struct
import subprocess
import sys
from pathlib import Path

import pytest
from google.protobuf import descriptor, descriptor_pb2

from chronos_bridge.proto import chronos_pb2 as pb
from chronos_bridge.proto import vector3_pb2
from tests.chronos_bridge.bridge_builders import tag, varint

ROOT = Path(__file__).resolve().parents[3]
REQ, OPT, REP = "required", "optional", "repeated"


# ---- hand encoders (independent of protobuf; varint and tag are in bridge_builders)
def f32(number: int, value: float) -> bytes:
    return tag(number, 5) + struct.pack("<f", value)


def vint(number: int, value: int) -> bytes:
    return tag(number, 0) + varint(value)


def sub(number: int, payload: bytes) -> bytes:
    return tag(number, 2) + varint(len(payload)) + payload


def _label(field: descriptor.FieldDescriptor) -> str:
    if field.is_repeated:
        return REP
    return REQ if field.is_required else OPT


# (number, label, type, name, oneof) per message, from the spec's tables
SPEC = {
    "Packet": [
        (1, OPT, "Ping", "ping", "contents"),
        (2, OPT, "SingleControlInput", "control_input", "contents"),
        (3, OPT, "CarState", "car_state", "contents"),
        (10, OPT, "CarReference", "reference", "contents"),
        (99, OPT, "int64", "timestamp", None),
    ],
    "CarReference": [
        (1, OPT, "float", "throttle", "throttle_reference"),
        (2, OPT, "float", "longitudinal_velocity", "throttle_reference"),
        (11, OPT, "uint32", "voltage", "steering_reference"),
        (12, OPT, "float", "angle", "steering_reference"),
    ],
    "SingleControlInput": [
        (1, REQ, "float", "torque_ref", None),
        (2, REQ, "float", "steer_ref", None),
        (3, OPT, "SteerInput", "steer_input", None),
    ],
    "SteerInput": [
        (1, OPT, "float", "steer_angle", "input"),
        (2, OPT, "uint32", "steer_voltage", "input"),
    ],
    "Ping": [(1, REQ, "bool", "should_bounce", None)],
    "CarState": [
        (1, REQ, "SingleControlInput", "current_reference", None),
        (2, REQ, "MotorInput", "drive_motor_input", None),
        (3, REQ, "MotorInput", "steer_motor_input", None),
        (4, REQ, "IMUMeasurement", "imu_data", None),
        (5, REQ, "SteeringPositionMeasurement", "steer_data", None),
        (6, OPT, "WheelSpeedMeasurement", "wheel_speed_data", None),
        (7, OPT, "BatteryState", "battery_state", None),
        (8, REP, "LighthouseFrame", "lighthouse_data", None),
        (9, REP, "LighthouseSweep", "lighthouse_sweeps", None),
        (10, OPT, "float", "longitudinal_velocity", None),
    ],
    "MotorInput": [(1, REQ, "float", "power", None)],
    "IMUMeasurement": [
        (1, REQ, "Vector3", "linear_acceleration", None),
        (2, REQ, "Vector3", "angular_velocity", None),
    ],
    "SteeringPositionMeasurement": [
        (1, REQ, "float", "steer_rad", None),
        (2, REQ, "int32", "adc_meas", None),
        (3, OPT, "int32", "adc_limits", None),
        (4, OPT, "float", "amplitude", None),
    ],
    "WheelSpeedMeasurement": [
        (1, REQ, "float", "front_right", None),
        (2, REQ, "float", "front_left", None),
        (3, REQ, "float", "rear_right", None),
        (4, REQ, "float", "rear_left", None),
    ],
    "BatteryState": [(1, REQ, "float", "voltage", None), (2, OPT, "float", "current", None)],
    "LighthouseFrame": [
        (k + 1, REQ, "uint32", name, None)
        for k, name in enumerate(
            ["sensor_id", "polynomial", "pulse_width", "sync_offset", "beam_word", "timestamp"]
        )
    ],
    "LighthouseSweep": [
        *[(k + 1, REQ, "float", f"angle_{k}", None) for k in range(4)],
        (5, REQ, "uint32", "polynomial", None),
        (6, REQ, "uint32", "first_timestamp", None),
        (7, REQ, "uint32", "sync_timestamp", None),
    ],
}
_SCALAR = {
    descriptor.FieldDescriptor.TYPE_FLOAT: "float",
    descriptor.FieldDescriptor.TYPE_INT64: "int64",
    descriptor.FieldDescriptor.TYPE_INT32: "int32",
    descriptor.FieldDescriptor.TYPE_UINT32: "uint32",
    descriptor.FieldDescriptor.TYPE_BOOL: "bool",
}


@pytest.mark.parametrize("name", sorted(SPEC))
def test_every_message_matches_the_spec_table(name: str) -> None:
    message = pb.DESCRIPTOR.message_types_by_name[name]
    actual = []
    for field in sorted(message.fields, key=lambda f: f.number):
        kind = field.message_type.name if field.message_type else _SCALAR[field.type]
        oneof = field.containing_oneof.name if field.containing_oneof else None
        actual.append((field.number, _label(field), kind, field.name, oneof))
    assert actual == SPEC[name]


def test_syntax_reserved_ranges_and_the_proto3_vector() -> None:
    files = {}
    for module in (pb, vector3_pb2):
        files[module] = descriptor_pb2.FileDescriptorProto()
        module.DESCRIPTOR.CopyToProto(files[module])
    assert files[pb].syntax in ("", "proto2")  # empty means proto2
    assert files[vector3_pb2].syntax == "proto3"
    assert [d.name for d in pb.DESCRIPTOR.dependencies] == ["chronos_bridge/proto/vector3.proto"]
    vector = vector3_pb2.DESCRIPTOR.message_types_by_name["Vector3"]
    assert [(f.number, f.name, _SCALAR[f.type]) for f in vector.fields] == [
        (1, "x", "float"),
        (2, "y", "float"),
        (3, "z", "float"),
    ]
    reference = next(m for m in files[pb].message_type if m.name == "CarReference")
    # reserved 3 to 10 and 13 to 20 (end exclusive in the descriptor)
    assert [(r.start, r.end) for r in reference.reserved_range] == [(3, 11), (13, 21)]


def test_generated_code_imports_cleanly_with_the_pinned_runtime() -> None:
    code = (
        "import google.protobuf as p; assert p.__version__ == '7.36.2', p.__version__;"
        "import chronos_bridge.proto.chronos_pb2, chronos_bridge.proto.vector3_pb2"
    )
    done = subprocess.run(
        [sys.executable, "-W", "error", "-c", code],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert done.returncode == 0, done.stderr
    assert done.stderr == ""


def _car_state() -> pb.CarState:
    state = pb.CarState()
    state.current_reference.torque_ref = 0.25
    state.current_reference.steer_ref = -0.125
    state.current_reference.steer_input.steer_voltage = 1500
    state.drive_motor_input.power = 0.5
    state.steer_motor_input.power = -1.0
    state.imu_data.linear_acceleration.x = 1.5
    state.imu_data.linear_acceleration.z = 9.75
    state.imu_data.angular_velocity.z = -0.5
    state.steer_data.steer_rad = 0.125
    state.steer_data.adc_meas = -2
    state.steer_data.adc_limits = 300 | 3800 << 16
    state.steer_data.amplitude = 2.0
    state.wheel_speed_data.front_right = 1.0
    state.wheel_speed_data.front_left = 2.0
    state.wheel_speed_data.rear_right = 3.0
    state.wheel_speed_data.rear_left = 4.0
    state.battery_state.voltage = 7.5
    state.battery_state.current = -1.25
    state.lighthouse_data.add(
        sensor_id=1, polynomial=3, pulse_width=4, sync_offset=5, beam_word=6, timestamp=7
    )
    state.lighthouse_sweeps.add(
        angle_0=1.0,
        angle_1=2.0,
        angle_2=3.0,
        angle_3=4.0,
        polynomial=2,
        first_timestamp=300,
        sync_timestamp=0xFFFFFF,
    )
    state.longitudinal_velocity = 1.75
    return state


def test_every_message_serialises_to_the_hand_computed_bytes() -> None:
    """All messages built; bytes compared field by field with hand encodings."""
    ref = sub(1, f32(1, 0.25) + f32(2, -0.125) + sub(3, vint(2, 1500)))
    imu = sub(1, f32(1, 1.5) + f32(3, 9.75)) + sub(2, f32(3, -0.5))  # proto3: zeros omitted
    steer = f32(1, 0.125) + vint(2, -2) + vint(3, 300 | 3800 << 16) + f32(4, 2.0)
    assert len(vint(2, -2)) == 1 + 10  # negative int32: a 10-byte varint (no zigzag)
    wheels = f32(1, 1.0) + f32(2, 2.0) + f32(3, 3.0) + f32(4, 4.0)
    frame = b"".join(vint(k + 1, v) for k, v in enumerate([1, 3, 4, 5, 6, 7]))
    sweep = (
        f32(1, 1.0) + f32(2, 2.0) + f32(3, 3.0) + f32(4, 4.0) + vint(5, 2) + vint(6, 300)
    ) + vint(7, 0xFFFFFF)
    expected = (
        ref
        + sub(2, f32(1, 0.5))
        + sub(3, f32(1, -1.0))
        + sub(4, imu)
        + sub(5, steer)
        + sub(6, wheels)
        + sub(7, f32(1, 7.5) + f32(2, -1.25))
        + sub(8, frame)  # repeated messages: one length-delimited record each (never packed)
        + sub(9, sweep)
        + f32(10, 1.75)
    )
    state = _car_state()
    assert state.SerializeToString() == expected
    packet = pb.Packet(car_state=state, timestamp=1_700_000_000_123_456)
    # field 99, varint: tag 99 << 3 = 792 -> two bytes 0x98 0x06
    assert tag(99, 0) == b"\x98\x06"
    assert packet.SerializeToString() == sub(3, expected) + vint(99, 1_700_000_000_123_456)


def test_the_other_messages_hand_computed() -> None:
    ping = pb.Packet(ping=pb.Ping(should_bounce=True))
    assert ping.SerializeToString() == b"\x0a\x02\x08\x01"
    assert pb.Ping(should_bounce=False).SerializeToString() == b"\x08\x00"  # proto2: sent
    reference = pb.CarReference(longitudinal_velocity=-1.5, angle=0.25)
    assert reference.SerializeToString() == f32(2, -1.5) + f32(12, 0.25)
    reference = pb.CarReference(throttle=1.0, voltage=1234)
    assert reference.SerializeToString() == f32(1, 1.0) + vint(11, 1234)
    assert pb.Packet(reference=reference).SerializeToString() == sub(
        10, f32(1, 1.0) + vint(11, 1234)
    )
    control = pb.SingleControlInput(torque_ref=-0.5, steer_ref=0.0)
    control.steer_input.steer_angle = 0.0  # a set oneof member is sent even when zero
    assert control.SerializeToString() == f32(1, -0.5) + f32(2, 0.0) + sub(3, f32(1, 0.0))
    assert pb.Packet(control_input=control).SerializeToString() == sub(
        2, control.SerializeToString()
    )
    assert pb.MotorInput(power=0.0).SerializeToString() == f32(1, 0.0)  # proto2 presence
    vector = vector3_pb2.Vector3(x=0.0, y=-2.0, z=0.0)
    assert vector.SerializeToString() == f32(2, -2.0)  # proto3: zero scalars are not sent
    frame = pb.LighthouseFrame(
        sensor_id=0, polynomial=0, pulse_width=0, sync_offset=0, beam_word=0, timestamp=300
    )
    assert frame.SerializeToString() == b"".join(vint(k, 0) for k in range(1, 6)) + vint(6, 300)
    assert vint(6, 300) == b"\x30\xac\x02"  # 300 = 0b10_0101100 -> 0xac 0x02
