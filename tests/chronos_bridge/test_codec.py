"""Codec: round trips both directions, every validation rule naming its field, and fuzzed
datagrams (nothing raises but ``DecodeError``, nothing out of range is published)."""

from __future__ import annotations

import math
import random
import struct
import time
from dataclasses import replace

import numpy as np
import pytest

from chronos_bridge.car_state import IN_VIEW_RAD, CarStateConverter
from chronos_bridge.codec import (
    CAR_DATAGRAM_MAX,
    DecodeError,
    EncodeError,
    decode_from_car,
    decode_from_host,
    encode_car_state,
    encode_car_state_fitting,
    encode_control_input,
    encode_discovery_ping,
    encode_ping_reply,
    encode_torque_command,
    encode_velocity_command,
    host_datagram_too_large,
    now_us,
)
from chronos_bridge.packets import (
    ACCEL_LIMIT,
    GYRO_LIMIT,
    SWEEP_ANGLE_LIMIT,
    WHEEL_SPEED_LIMIT,
    ControlInput,
    FieldError,
    LighthouseSweep,
    Packet,
    Ping,
    Reference,
)
from chronos_bridge.proto import chronos_pb2 as pb
from tests.chronos_bridge.bridge_builders import BAD_FLOATS, STAMP_US, make_state, tag


def f32(x: float) -> float:
    return struct.unpack("<f", struct.pack("<f", x))[0]


def test_car_state_round_trip_to_float32() -> None:
    state = make_state()
    packet = decode_from_car(encode_car_state(state, STAMP_US))
    assert packet.timestamp_us == STAMP_US
    assert packet.stamp_s == pytest.approx(1_700_000_000.0)
    got = packet.contents
    assert got.imu.linear_acceleration == state.imu.linear_acceleration  # exact in float32
    assert got.sweeps[0].angles == tuple(f32(a) for a in state.sweeps[0].angles)
    assert got.steering.adc_range == (300, 3800)
    assert got == replace(state, sweeps=got.sweeps)
    assert decode_from_car(encode_car_state(state)).timestamp_us is None


def test_host_commands_round_trip_on_the_car_side() -> None:
    packet = decode_from_host(encode_torque_command(0.25, -0.5, STAMP_US))
    assert packet == Packet(Reference(throttle=-0.5, angle=0.25), STAMP_US)
    packet = decode_from_host(encode_velocity_command(-0.125, 2.5, STAMP_US))
    assert packet.contents == Reference(longitudinal_velocity=2.5, angle=-0.125)
    packet = decode_from_host(encode_ping_reply(STAMP_US))
    assert packet.contents == Ping(False)
    old = ControlInput(0.5, 0.25, steer_voltage=1500)
    assert decode_from_host(encode_control_input(old, STAMP_US)).contents == old
    before = now_us()
    stamped = decode_from_host(encode_torque_command(0.0, 0.0)).timestamp_us
    assert before <= stamped <= now_us()  # the host stamps every packet it sends


def test_discovery_ping_from_the_car() -> None:
    assert decode_from_car(encode_discovery_ping()) == Packet(Ping(True))
    assert encode_discovery_ping() == b"\x0a\x02\x08\x01"


@pytest.mark.parametrize(
    ("build", "field"),
    [
        (lambda: encode_torque_command(0.1, 1.5), "throttle"),
        (lambda: encode_torque_command(math.nan, 0.5), "angle"),
        (lambda: encode_velocity_command(0.1, math.inf), "longitudinal_velocity"),
        (lambda: encode_velocity_command(0.1, 6.0), "longitudinal_velocity"),
    ],
)
def test_host_encoders_refuse_bad_commands(build, field: str) -> None:
    with pytest.raises(FieldError) as error:
        build()
    assert error.value.field == field


def test_host_size_warning_threshold() -> None:
    assert not host_datagram_too_large(bytes(256))
    assert host_datagram_too_large(bytes(257))
    assert len(encode_torque_command(0.1, 0.1)) < 32


def test_car_state_beyond_255_bytes_is_refused_or_split() -> None:
    sweeps = tuple(LighthouseSweep((2.0,) * 4, 2, 300 + k, 0xFFFFFF) for k in range(5))
    state = make_state(sweeps=sweeps)
    with pytest.raises(EncodeError, match="255"):
        encode_car_state(state, STAMP_US)
    data, left = encode_car_state_fitting(state, STAMP_US)
    assert len(data) <= CAR_DATAGRAM_MAX
    sent = decode_from_car(data).contents.sweeps
    assert 1 <= len(sent) < 5
    assert sent + left == tuple(replace(s) for s in sweeps)


def _raw_state_bytes(mutate) -> bytes:
    msg = pb.Packet()
    msg.car_state.ParseFromString(
        pb.Packet.FromString(encode_car_state(make_state(), STAMP_US)).car_state.SerializeToString()
    )
    msg.timestamp = STAMP_US
    mutate(msg)
    return msg.SerializePartialToString()


def _set(path: str, value) -> object:
    def mutate(msg) -> None:
        *parents, leaf = path.split(".")
        target = msg
        for name in parents:
            target = getattr(target, name)
        setattr(target, leaf, value)

    return mutate


@pytest.mark.parametrize(
    ("mutate", "field"),
    [
        (_set("car_state.imu_data.angular_velocity.z", math.nan), "imu_data.angular_velocity.z"),
        (_set("car_state.imu_data.angular_velocity.x", 5.5), "imu_data.angular_velocity.x"),
        (_set("car_state.imu_data.linear_acceleration.y", -40.0), "linear_acceleration.y"),
        (_set("car_state.imu_data.linear_acceleration.z", math.inf), "linear_acceleration.z"),
        (_set("car_state.wheel_speed_data.rear_left", 1e4), "wheel_speed_data.rear_left"),
        (_set("car_state.battery_state.voltage", -1.0), "battery_state.voltage"),
        (_set("car_state.battery_state.current", math.nan), "battery_state.current"),
        (_set("car_state.steer_data.steer_rad", 2.0), "steer_data.steer_rad"),
        (_set("car_state.steer_data.adc_meas", -5), "steer_data.adc_meas"),
        (_set("car_state.steer_data.amplitude", math.inf), "steer_data.amplitude"),
        (_set("car_state.drive_motor_input.power", 1.5), "drive_motor_input.power"),
        (_set("car_state.steer_motor_input.power", math.nan), "steer_motor_input.power"),
        (_set("car_state.longitudinal_velocity", 50.0), "car_state.longitudinal_velocity"),
        (_set("car_state.current_reference.steer_ref", math.nan), "current_reference.steer_ref"),
        (_set("timestamp", 0), "timestamp"),
        (_set("timestamp", -1), "timestamp"),
        (_set("timestamp", 2**62), "timestamp"),
    ],
)
def test_each_bad_value_is_rejected_naming_its_field(mutate, field: str) -> None:
    with pytest.raises(DecodeError) as error:
        decode_from_car(_raw_state_bytes(mutate))
    assert field in error.value.field
    assert field.rsplit(".", 1)[-1] in str(error.value)


def _sweep_change(**kwargs):
    def mutate(msg) -> None:
        for name, value in kwargs.items():
            setattr(msg.car_state.lighthouse_sweeps[0], name, value)

    return mutate


@pytest.mark.parametrize(
    ("mutate", "field"),
    [
        (_sweep_change(angle_2=math.nan), "lighthouse_sweeps[0].angle_2"),
        (_sweep_change(angle_0=7.0), "lighthouse_sweeps[0].angle_0"),
        (_sweep_change(polynomial=40), "lighthouse_sweeps[0].polynomial"),
        (_sweep_change(sync_timestamp=1 << 24), "lighthouse_sweeps[0].sync_timestamp"),
        (_sweep_change(first_timestamp=1 << 30), "lighthouse_sweeps[0].first_timestamp"),
    ],
)
def test_bad_sweeps_are_rejected_naming_the_entry(mutate, field: str) -> None:
    with pytest.raises(DecodeError) as error:
        decode_from_car(_raw_state_bytes(mutate))
    assert error.value.field == f"car_state.{field}"


def test_too_many_repeated_entries() -> None:
    def frames(msg) -> None:
        for name in ("lighthouse_sweeps", "battery_state", "wheel_speed_data", "lighthouse_data"):
            msg.car_state.ClearField(name)
        for _ in range(9):
            msg.car_state.lighthouse_data.add(
                sensor_id=0, polynomial=0, pulse_width=0, sync_offset=0, beam_word=0, timestamp=0
            )
        assert len(msg.SerializePartialToString()) <= CAR_DATAGRAM_MAX

    with pytest.raises(DecodeError) as error:
        decode_from_car(_raw_state_bytes(frames))
    assert error.value.field == "car_state.lighthouse_data"

    def sweeps(msg) -> None:
        for _ in range(5):
            msg.car_state.lighthouse_sweeps.add()  # empty entries: small, and counted first

    with pytest.raises(DecodeError) as error:
        decode_from_car(_raw_state_bytes(sweeps))
    assert error.value.field == "car_state.lighthouse_sweeps"


def test_missing_required_fields_are_named() -> None:
    data = _raw_state_bytes(lambda msg: msg.car_state.imu_data.ClearField("angular_velocity"))
    with pytest.raises(DecodeError) as error:
        decode_from_car(data)
    assert error.value.field == "car_state.imu_data.angular_velocity"
    data = _raw_state_bytes(lambda msg: msg.car_state.lighthouse_sweeps[0].ClearField("angle_3"))
    with pytest.raises(DecodeError, match="angle_3"):
        decode_from_car(data)


def test_datagram_level_errors() -> None:
    good = encode_car_state(make_state(), STAMP_US)
    cases = {
        "oversize": good + bytes(CAR_DATAGRAM_MAX + 1 - len(good)),
        "truncated": good[:-3],
        "empty": b"",
        "unknown oneof tag": b"\x22\x00",  # field 4, length-delimited: not a known content
        "wrong wire type": b"\x0d\x00\x00\x00\x00",  # field 1 (ping) as fixed32
        "unknown field inside": good + b"\x98\x06\x01"[:0] + b"\xa0\x06\x01",  # field 100
        "host content from a car": encode_torque_command(0.1, 0.1),
        "not bytes": "hello",
    }
    fields = {}
    for name, data in cases.items():
        with pytest.raises(DecodeError) as error:
            decode_from_car(data)  # type: ignore[arg-type]
        fields[name] = error.value.field
    assert fields["oversize"] == "datagram"
    assert fields["truncated"] in ("datagram", "car_state.longitudinal_velocity", "timestamp")
    assert fields["empty"] == "contents"
    assert fields["unknown oneof tag"] == "<field 4>"
    assert fields["wrong wire type"] == "<field 1>"
    assert fields["unknown field inside"] == "<field 100>"
    assert fields["host content from a car"] == "contents"
    assert fields["not bytes"] == "datagram"
    with pytest.raises(DecodeError, match="contents"):
        decode_from_host(good)  # a car state sent to a car


# --------------------------------------------------------------------------- decoder fuzzing
# Random and mutated datagrams through decode + CarStateConverter in-process. Every datagram is
# counted as accepted or rejected; nothing raises except ``DecodeError``; every measurement
# published is finite and within range.

N_DATAGRAMS = 100_000


def _seeds() -> list[bytes]:
    seeds = [
        encode_discovery_ping(),
        encode_discovery_ping(STAMP_US),
        encode_torque_command(0.1, 0.2),
    ]
    for k in range(4):
        sweeps = tuple(
            LighthouseSweep((2.0 + 0.01 * j, 2.0, 2.1, 2.2), (j % 2) << 1, 1000 * j, 1000 * j + k)
            for j in range(k)
        )
        seeds.append(encode_car_state(make_state(sweeps=sweeps), STAMP_US + k))
    seeds.append(encode_car_state(make_state(wheel_speeds=None, battery=None, frames=())))
    return seeds


def _mutate(rng: random.Random, seeds: list[bytes]) -> bytes:
    base = bytearray(rng.choice(seeds))
    kind = rng.randrange(9)
    if kind == 0:  # random bytes
        return rng.randbytes(rng.randrange(0, 300))
    if kind == 1:  # truncated
        return bytes(base[: rng.randrange(len(base))])
    if kind == 2:  # bit flips
        for _ in range(rng.randrange(1, 9)):
            i = rng.randrange(len(base))
            base[i] ^= 1 << rng.randrange(8)
        return bytes(base)
    if kind == 3:  # wrong wire type on some byte (a tag, often)
        i = rng.randrange(len(base))
        base[i] = (base[i] & ~7) | rng.choice([0, 1, 2, 3, 4, 5, 6, 7])
        return bytes(base)
    if kind == 4:  # NaN / inf / huge float written over 4 bytes
        i = rng.randrange(max(1, len(base) - 4))
        base[i : i + 4] = rng.choice(BAD_FLOATS)
        return bytes(base)
    if kind == 5:  # huge repeated field: many sweep or frame records appended in car_state
        record = bytes([0x4A if rng.random() < 0.5 else 0x42]) + bytes([rng.randrange(0, 40)])
        record += rng.randbytes(record[1])
        return bytes(base) + record * rng.randrange(1, 60)
    if kind == 6:  # an unknown oneof tag / unknown field, before or after
        number = rng.choice([4, 5, 9, 11, 50, 98, 100, 2**20])
        field = tag(number, 2) + bytes([2, 8, 1])
        return field + bytes(base) if rng.random() < 0.5 else bytes(base) + field
    if kind == 7:  # inserted random bytes
        i = rng.randrange(len(base) + 1)
        return bytes(base[:i]) + rng.randbytes(rng.randrange(1, 8)) + bytes(base[i:])
    return bytes(base)  # valid as sent


def _check(measurement) -> None:
    values = measurement.values
    assert np.all(np.isfinite(values)) and math.isfinite(measurement.stamp)
    if measurement.sensor == "imu":
        assert np.all(np.abs(values[:2]) <= ACCEL_LIMIT) and abs(values[2]) <= GYRO_LIMIT
    elif measurement.sensor == "wheel_encoders":
        assert np.all(np.abs(values) <= WHEEL_SPEED_LIMIT)
    else:
        assert measurement.sensor.startswith("lighthouse/")
        assert abs(values[0]) <= IN_VIEW_RAD
        assert np.all(np.abs(values) <= SWEEP_ANGLE_LIMIT + 2 * math.pi)


def test_fuzzed_datagrams_never_crash_nor_publish_garbage() -> None:
    rng = random.Random(20211)
    seeds = _seeds()
    converter = CarStateConverter()
    accepted = rejected = published = 0
    fields: dict[str, int] = {}
    start = time.perf_counter()
    for n in range(N_DATAGRAMS):
        data = _mutate(rng, seeds)
        try:
            packet = decode_from_car(data)
        except DecodeError as error:
            rejected += 1
            key = error.field.split("[")[0].split("<")[0]
            fields[key] = fields.get(key, 0) + 1
            continue
        accepted += 1
        if hasattr(packet.contents, "imu"):
            for measurement in converter.convert(packet, 1_800_000_000.0 + n).measurements:
                _check(measurement)
                published += 1
    elapsed = time.perf_counter() - start
    print(
        f"\nfuzz: {N_DATAGRAMS} datagrams in {elapsed:.1f} s: {accepted} accepted "
        f"({published} measurements), {rejected} rejected; top fields "
        f"{sorted(fields.items(), key=lambda kv: -kv[1])[:8]}"
    )
    assert accepted + rejected == N_DATAGRAMS
    assert accepted > 5_000 and rejected > 50_000  # both paths are exercised
