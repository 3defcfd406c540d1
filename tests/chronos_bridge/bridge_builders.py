"""Shared builders for the chronos_bridge tests."""

from __future__ import annotations

import math
import struct

from chronos_bridge.packets import (
    CURRENT_TORQUE_REF_LIMIT,
    Battery,
    CarState,
    ControlInput,
    Imu,
    LighthouseFrame,
    LighthouseSweep,
    Steering,
    WheelSpeeds,
)

STAMP_US = 1_700_000_000_000_000
#: The host's stamp on its commands to an emulated car (ignored by the car).
HOST_STAMP_US = 1_760_000_000_000_000
#: Float32 values a decoder must refuse (NaN, infinities, beyond every range), as wire bytes.
BAD_FLOATS = [struct.pack("<f", v) for v in (math.nan, math.inf, -math.inf, 1e30, -3.4e38)]


def make_state(**changes: object) -> CarState:
    fields: dict[str, object] = dict(
        current_reference=ControlInput(0.25, -0.125, torque_limit=CURRENT_TORQUE_REF_LIMIT),
        drive_power=0.5,
        steer_power=-0.25,
        imu=Imu((-1.5, 0.5, 9.75), (0.125, -0.25, 1.5)),
        steering=Steering(0.125, 2100, 300 | 3800 << 16, 2.0),
        wheel_speeds=WheelSpeeds(10.0, 11.0, 12.0, 13.0),
        battery=Battery(7.5, -1.25),
        frames=(LighthouseFrame(1, 3, 4, 5, 6, 7),),
        sweeps=(LighthouseSweep((2.0, 2.01, 2.02, 2.03), 2, 300, 400),),
        longitudinal_velocity=1.75,
    )
    fields.update(changes)
    return CarState(**fields)  # type: ignore[arg-type]


# ---- hand encoders (independent of protobuf): tag = number << 3 | wire type
def varint(n: int) -> bytes:
    """``n`` as a protobuf varint (7 bits a byte, low first)."""
    if n < 0:
        n += 1 << 64  # int32/int64 negatives: two's complement over 64 bits -> 10 bytes
    out = bytearray()
    while True:
        byte = n & 0x7F
        n >>= 7
        if n:
            out.append(byte | 0x80)
        else:
            out.append(byte)
            return bytes(out)


def tag(number: int, wire_type: int) -> bytes:
    """The key of field ``number`` with ``wire_type`` (0 varint, 2 length-delimited, 5 32-bit)."""
    return varint(number << 3 | wire_type)
