"""Decoder fuzzing: random and mutated datagrams through decode + CarStateConverter in-process.

Every datagram is counted as accepted or rejected; nothing raises except ``DecodeError``; every
measurement published is finite and within range.
"""

from __future__ import annotations

import math
import random
import struct
import time

import numpy as np
from bridge_builders import STAMP_US, make_state

from chronos_bridge.car_state import IN_VIEW_RAD, CarStateConverter
from chronos_bridge.codec import (
    DecodeError,
    decode_from_car,
    encode_car_state,
    encode_discovery_ping,
    encode_torque_command,
)
from chronos_bridge.packets import (
    ACCEL_LIMIT,
    GYRO_LIMIT,
    SWEEP_ANGLE_LIMIT,
    WHEEL_SPEED_LIMIT,
    LighthouseSweep,
)

N_DATAGRAMS = 100_000
TIME_BOUND_S = 60.0
_BAD_FLOATS = [struct.pack("<f", v) for v in (math.nan, math.inf, -math.inf, 1e30, -3.4e38)]


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
        base[i : i + 4] = rng.choice(_BAD_FLOATS)
        return bytes(base)
    if kind == 5:  # huge repeated field: many sweep or frame records appended in car_state
        record = bytes([0x4A if rng.random() < 0.5 else 0x42]) + bytes([rng.randrange(0, 40)])
        record += rng.randbytes(record[1])
        return bytes(base) + record * rng.randrange(1, 60)
    if kind == 6:  # an unknown oneof tag / unknown field, before or after
        number = rng.choice([4, 5, 9, 11, 50, 98, 100, 2**20])
        field = bytes(_varint(number << 3 | 2)) + bytes([2, 8, 1])
        return field + bytes(base) if rng.random() < 0.5 else bytes(base) + field
    if kind == 7:  # inserted random bytes
        i = rng.randrange(len(base) + 1)
        return bytes(base[:i]) + rng.randbytes(rng.randrange(1, 8)) + bytes(base[i:])
    return bytes(base)  # valid as sent


def _varint(n: int) -> bytearray:
    out = bytearray()
    while n > 0x7F:
        out.append(n & 0x7F | 0x80)
        n >>= 7
    out.append(n)
    return out


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
    assert elapsed < TIME_BOUND_S
