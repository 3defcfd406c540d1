"""Datagram bytes <-> validated :class:`~chronos_bridge.packets.Packet`, both directions.

Host side (the bridge):

- :func:`decode_from_car` -- a datagram from a car -> ``Packet`` whose contents is a
  :class:`~chronos_bridge.packets.CarState` or a :class:`~chronos_bridge.packets.Ping`; anything
  else raises :class:`DecodeError` naming the field.
- :func:`encode_torque_command`, :func:`encode_velocity_command` -- the controller's input as a
  ``CarReference`` (steering as ``angle``); :func:`encode_ping_reply` -- ``should_bounce=False``.
  Host packets carry the host's time (µs since the Unix epoch, :func:`now_us` by default).

Car side (the emulator):

- :func:`encode_car_state` / :func:`encode_car_state_fitting` -- a ``CarState`` packet within the
  firmware's 255-byte buffer; :func:`encode_discovery_ping` -- ``should_bounce=True``.
- :func:`decode_from_host` -- a host datagram -> ``Packet`` with a
  :class:`~chronos_bridge.packets.Reference`, a :class:`~chronos_bridge.packets.ControlInput`
  (the older form) or a ``Ping``.

Decoding is strict: a datagram over the size limit, one protobuf cannot parse, one with a missing
required field, an unknown field anywhere (also a known field number with the wrong wire type,
which protobuf keeps as unknown), no known ``contents`` (an unknown oneof tag), a content the
sender does not send, a NaN/inf or an out-of-range value (:mod:`chronos_bridge.packets`) or a
``timestamp`` outside years 2000..2100 raises :class:`DecodeError`; its ``field`` is the dotted
wire path, e.g. ``car_state.imu_data.angular_velocity.z``.
"""

from __future__ import annotations

import logging
import time
from dataclasses import replace
from typing import Any

from google.protobuf import message as pb_message
from google.protobuf.unknown_fields import UnknownFieldSet

from chronos_bridge.packets import (
    CURRENT_TORQUE_REF_LIMIT,
    MAX_FRAMES,
    MAX_SWEEPS,
    Battery,
    CarState,
    ControlInput,
    FieldError,
    Imu,
    LighthouseFrame,
    LighthouseSweep,
    Packet,
    Ping,
    Reference,
    Steering,
    WheelSpeeds,
    check_float,
)
from chronos_bridge.proto import chronos_pb2 as pb

#: Largest datagram a car sends (the firmware encodes into a 255-byte buffer), bytes.
CAR_DATAGRAM_MAX = 255
#: The host warns when it sends a datagram larger than this, bytes; the car side refuses more.
HOST_DATAGRAM_WARN = 256

_log = logging.getLogger(__name__)


class DecodeError(FieldError):
    """A datagram that is not a valid packet; ``field`` names the offending field (dotted wire
    path), or ``datagram`` / ``contents`` for the datagram as a whole."""

    @classmethod
    def of(cls, error: FieldError, prefix: str = "") -> DecodeError:
        return cls(f"{prefix}.{error.field}" if prefix else error.field, error.reason)


class EncodeError(ValueError):
    """A packet that cannot be sent as asked (e.g. larger than the car's 255-byte buffer)."""


def now_us() -> int:
    """The host's clock in µs since the Unix epoch (the stamp of every packet it sends)."""
    return time.time_ns() // 1000


# --------------------------------------------------------------------------- decoding


def decode_from_car(data: bytes) -> Packet:
    """Decode and validate a datagram received from a car (host side).

    Returns a ``Packet`` with ``CarState`` or ``Ping`` contents; raises :class:`DecodeError`
    otherwise (over :data:`CAR_DATAGRAM_MAX` bytes, undecodable, ...; see the module docstring).
    """
    return _decode(data, CAR_DATAGRAM_MAX, ("car_state", "ping"))


def decode_from_host(data: bytes) -> Packet:
    """Decode and validate a datagram received from the host (car side, the emulator).

    Returns a ``Packet`` with ``Reference``, ``ControlInput`` or ``Ping`` contents; raises
    :class:`DecodeError` otherwise (over :data:`HOST_DATAGRAM_WARN` bytes, undecodable, ...).
    """
    return _decode(data, HOST_DATAGRAM_WARN, ("reference", "control_input", "ping"))


def _decode(data: bytes, max_size: int, allowed: tuple[str, ...]) -> Packet:
    if not isinstance(data, bytes | bytearray | memoryview):
        raise DecodeError("datagram", f"expected bytes, got {type(data).__name__}")
    data = bytes(data)
    if len(data) > max_size:
        raise DecodeError("datagram", f"{len(data)} bytes > {max_size}")
    msg = pb.Packet()
    try:
        msg.ParseFromString(data)
    except pb_message.DecodeError as error:
        raise DecodeError("datagram", f"undecodable protobuf ({error})") from None
    if msg.HasField("car_state"):  # counted first: an entry may be empty
        try:
            _check_counts(msg.car_state)
        except FieldError as error:
            raise DecodeError.of(error, "car_state") from None
    _reject_unknown(msg, "")
    missing = msg.FindInitializationErrors()
    if missing:
        raise DecodeError(missing[0], "required field missing")
    which = msg.WhichOneof("contents")
    if which is None:
        raise DecodeError("contents", "no known message (empty or an unknown oneof tag)")
    if which not in allowed:
        raise DecodeError("contents", f"{which} is not sent in this direction")
    try:
        contents = _CONVERTERS[which](getattr(msg, which))
    except FieldError as error:
        raise DecodeError.of(error, which) from None
    stamp = msg.timestamp if msg.HasField("timestamp") else None
    try:
        return Packet(contents, stamp)
    except FieldError as error:
        raise DecodeError.of(error) from None


def _check_counts(msg: Any) -> None:
    if len(msg.lighthouse_data) > MAX_FRAMES:
        raise FieldError("lighthouse_data", f"{len(msg.lighthouse_data)} frames > {MAX_FRAMES}")
    if len(msg.lighthouse_sweeps) > MAX_SWEEPS:
        count = len(msg.lighthouse_sweeps)
        raise FieldError("lighthouse_sweeps", f"{count} sweeps > {MAX_SWEEPS}")


def _reject_unknown(msg: Any, path: str) -> None:
    unknown = UnknownFieldSet(msg)
    if len(unknown):
        number = unknown[0].field_number
        where = f"{path}.<field {number}>" if path else f"<field {number}>"
        raise DecodeError(where, "unknown field or wrong wire type")
    for descriptor, value in msg.ListFields():
        if descriptor.message_type is None:
            continue
        sub = f"{path}.{descriptor.name}" if path else descriptor.name
        if descriptor.is_repeated:
            for k, item in enumerate(value):
                _reject_unknown(item, f"{sub}[{k}]")
        else:
            _reject_unknown(value, sub)


def _within(prefix: str, build: Any, *args: Any, **kwargs: Any) -> Any:
    try:
        return build(*args, **kwargs)
    except FieldError as error:
        raise error.within(prefix) from None


def _ping(msg: Any) -> Ping:
    return Ping(msg.should_bounce)


def _control_input(msg: Any, torque_limit: float = 1.0) -> ControlInput:
    which = msg.steer_input.WhichOneof("input") if msg.HasField("steer_input") else None
    return ControlInput(
        msg.torque_ref,
        msg.steer_ref,
        steer_angle=msg.steer_input.steer_angle if which == "steer_angle" else None,
        steer_voltage=msg.steer_input.steer_voltage if which == "steer_voltage" else None,
        torque_limit=torque_limit,
    )


def _reference(msg: Any) -> Reference:
    throttle = msg.WhichOneof("throttle_reference")
    steering = msg.WhichOneof("steering_reference")
    return Reference(
        throttle=msg.throttle if throttle == "throttle" else None,
        longitudinal_velocity=(
            msg.longitudinal_velocity if throttle == "longitudinal_velocity" else None
        ),
        angle=msg.angle if steering == "angle" else None,
        voltage=msg.voltage if steering == "voltage" else None,
    )


def _vector(msg: Any) -> tuple[float, float, float]:
    return (msg.x, msg.y, msg.z)


def _car_state(msg: Any) -> CarState:
    imu = msg.imu_data
    steer = msg.steer_data
    try:
        return CarState(
            current_reference=_within(
                "current_reference", _control_input, msg.current_reference, CURRENT_TORQUE_REF_LIMIT
            ),
            drive_power=_within("drive_motor_input", _power, msg.drive_motor_input),
            steer_power=_within("steer_motor_input", _power, msg.steer_motor_input),
            imu=_within(
                "imu_data", Imu, _vector(imu.linear_acceleration), _vector(imu.angular_velocity)
            ),
            steering=_within(
                "steer_data",
                Steering,
                steer.steer_rad,
                steer.adc_meas,
                steer.adc_limits if steer.HasField("adc_limits") else None,
                steer.amplitude if steer.HasField("amplitude") else None,
            ),
            wheel_speeds=(
                _within(
                    "wheel_speed_data",
                    WheelSpeeds,
                    msg.wheel_speed_data.front_right,
                    msg.wheel_speed_data.front_left,
                    msg.wheel_speed_data.rear_right,
                    msg.wheel_speed_data.rear_left,
                )
                if msg.HasField("wheel_speed_data")
                else None
            ),
            battery=(
                _within(
                    "battery_state",
                    Battery,
                    msg.battery_state.voltage,
                    msg.battery_state.current if msg.battery_state.HasField("current") else None,
                )
                if msg.HasField("battery_state")
                else None
            ),
            frames=tuple(
                _within(
                    f"lighthouse_data[{k}]",
                    LighthouseFrame,
                    f.sensor_id,
                    f.polynomial,
                    f.pulse_width,
                    f.sync_offset,
                    f.beam_word,
                    f.timestamp,
                )
                for k, f in enumerate(msg.lighthouse_data)
            ),
            sweeps=tuple(
                _within(
                    f"lighthouse_sweeps[{k}]",
                    LighthouseSweep,
                    (s.angle_0, s.angle_1, s.angle_2, s.angle_3),
                    s.polynomial,
                    s.first_timestamp,
                    s.sync_timestamp,
                )
                for k, s in enumerate(msg.lighthouse_sweeps)
            ),
            longitudinal_velocity=(
                msg.longitudinal_velocity if msg.HasField("longitudinal_velocity") else None
            ),
        )
    except FieldError as error:
        if error.field in _CAR_STATE_WIRE_NAMES:
            raise FieldError(_CAR_STATE_WIRE_NAMES[error.field], error.reason) from None
        raise


def _power(msg: Any) -> float:
    return check_float("power", msg.power, -1.0, 1.0)


_CAR_STATE_WIRE_NAMES = {
    "drive_power": "drive_motor_input.power",
    "steer_power": "steer_motor_input.power",
}

_CONVERTERS = {
    "ping": _ping,
    "control_input": _control_input,
    "reference": _reference,
    "car_state": _car_state,
}


# --------------------------------------------------------------------------- encoding


def encode_packet(packet: Packet) -> bytes:
    """Serialise a validated ``Packet`` (no size check; see the direction-specific encoders)."""
    msg = pb.Packet()
    contents = packet.contents
    if isinstance(contents, Ping):
        msg.ping.should_bounce = contents.should_bounce
    elif isinstance(contents, Reference):
        _fill_reference(msg.reference, contents)
    elif isinstance(contents, ControlInput):
        _fill_control_input(msg.control_input, contents)
    else:
        _fill_car_state(msg.car_state, contents)
    if packet.timestamp_us is not None:
        msg.timestamp = packet.timestamp_us
    return msg.SerializeToString()


def host_datagram_too_large(data: bytes) -> bool:
    """True when a host datagram exceeds :data:`HOST_DATAGRAM_WARN` bytes (the host warns)."""
    return len(data) > HOST_DATAGRAM_WARN


def encode_torque_command(steer: float, torque: float, timestamp_us: int | None = None) -> bytes:
    """``CarReference{throttle=torque, angle=steer}`` from a torque command ``u = [δ, T]``.

    ``steer`` δ in rad (±1), ``torque`` T normalised in [-1, 1]; ``timestamp_us`` defaults to
    :func:`now_us`. Raises ``FieldError`` (a ``ValueError``) naming a NaN/inf/out-of-range value.
    """
    return _host(Reference(throttle=torque, angle=steer), timestamp_us)


def encode_velocity_command(
    steer: float, velocity: float, timestamp_us: int | None = None
) -> bytes:
    """``CarReference{longitudinal_velocity=velocity, angle=steer}`` from ``[δ, v_x]``.

    ``steer`` in rad (±1), ``velocity`` in m/s (±5), tracked by the car's own PID.
    """
    return _host(Reference(longitudinal_velocity=velocity, angle=steer), timestamp_us)


def encode_control_input(command: ControlInput, timestamp_us: int | None = None) -> bytes:
    """The older command form ``Packet{control_input}`` (for old firmware and tests)."""
    return _host(command, timestamp_us)


def encode_ping_reply(timestamp_us: int | None = None) -> bytes:
    """The host's answer to a discovery ping: ``Packet{ping{should_bounce=false}}``."""
    return _host(Ping(False), timestamp_us)


def _host(contents: Ping | Reference | ControlInput, timestamp_us: int | None) -> bytes:
    stamp = now_us() if timestamp_us is None else timestamp_us
    data = encode_packet(Packet(contents, stamp))
    if host_datagram_too_large(data):
        _log.warning("host datagram of %d bytes > %d", len(data), HOST_DATAGRAM_WARN)
    return data


def encode_discovery_ping(timestamp_us: int | None = None) -> bytes:
    """The car's discovery ping ``Packet{ping{should_bounce=true}}`` (every 5 s); the stamp is
    omitted unless given (the car's clock may not be synchronised yet)."""
    return encode_packet(Packet(Ping(True), timestamp_us))


def encode_car_state(state: CarState, timestamp_us: int | None = None) -> bytes:
    """``Packet{car_state}`` as the car sends it; ``EncodeError`` over 255 bytes."""
    data = encode_packet(Packet(state, timestamp_us))
    if len(data) > CAR_DATAGRAM_MAX:
        raise EncodeError(f"car state of {len(data)} bytes > {CAR_DATAGRAM_MAX}")
    return data


def encode_car_state_fitting(
    state: CarState, timestamp_us: int | None = None
) -> tuple[bytes, tuple[LighthouseSweep, ...]]:
    """Encode ``state`` with as many of its sweeps (in order) as fit in 255 bytes.

    Returns the datagram and the sweeps left over, to send with the next state (a car state
    with all ``MAX_SWEEPS`` sweeps does not fit in the firmware's buffer; about 3 do).
    ``EncodeError`` when even no sweep fits.
    """
    sweeps = state.sweeps
    for count in range(len(sweeps), -1, -1):
        data = encode_packet(Packet(_with_sweeps(state, sweeps[:count]), timestamp_us))
        if len(data) <= CAR_DATAGRAM_MAX:
            return data, sweeps[count:]
    raise EncodeError(f"car state without sweeps is {len(data)} bytes > {CAR_DATAGRAM_MAX}")


def _with_sweeps(state: CarState, sweeps: tuple[LighthouseSweep, ...]) -> CarState:
    return replace(state, sweeps=sweeps)


def _fill_reference(msg: Any, ref: Reference) -> None:
    if ref.throttle is not None:
        msg.throttle = ref.throttle
    else:
        msg.longitudinal_velocity = ref.longitudinal_velocity
    if ref.angle is not None:
        msg.angle = ref.angle
    elif ref.voltage is not None:
        msg.voltage = ref.voltage


def _fill_control_input(msg: Any, command: ControlInput) -> None:
    msg.torque_ref = command.torque_ref
    msg.steer_ref = command.steer_ref
    if command.steer_angle is not None:
        msg.steer_input.steer_angle = command.steer_angle
    elif command.steer_voltage is not None:
        msg.steer_input.steer_voltage = command.steer_voltage


def _fill_car_state(msg: Any, state: CarState) -> None:
    _fill_control_input(msg.current_reference, state.current_reference)
    msg.drive_motor_input.power = state.drive_power
    msg.steer_motor_input.power = state.steer_power
    imu = msg.imu_data
    for vector, values in (
        (imu.linear_acceleration, state.imu.linear_acceleration),
        (imu.angular_velocity, state.imu.angular_velocity),
    ):
        vector.x, vector.y, vector.z = values
    imu.linear_acceleration.SetInParent()  # present even when all zero (proto3 Vector3)
    imu.angular_velocity.SetInParent()
    steer = state.steering
    msg.steer_data.steer_rad = steer.steer_rad
    msg.steer_data.adc_meas = steer.adc_meas
    if steer.adc_limits is not None:
        msg.steer_data.adc_limits = steer.adc_limits
    if steer.amplitude is not None:
        msg.steer_data.amplitude = steer.amplitude
    if state.wheel_speeds is not None:
        w = state.wheel_speeds
        ws = msg.wheel_speed_data
        ws.front_right, ws.front_left = w.front_right, w.front_left
        ws.rear_right, ws.rear_left = w.rear_right, w.rear_left
    if state.battery is not None:
        msg.battery_state.voltage = state.battery.voltage
        if state.battery.current is not None:
            msg.battery_state.current = state.battery.current
    for frame in state.frames:
        msg.lighthouse_data.add(
            sensor_id=frame.sensor_id,
            polynomial=frame.polynomial,
            pulse_width=frame.pulse_width,
            sync_offset=frame.sync_offset,
            beam_word=frame.beam_word,
            timestamp=frame.timestamp,
        )
    for sweep in state.sweeps:
        a0, a1, a2, a3 = sweep.angles
        msg.lighthouse_sweeps.add(
            angle_0=a0,
            angle_1=a1,
            angle_2=a2,
            angle_3=a3,
            polynomial=sweep.polynomial,
            first_timestamp=sweep.first_timestamp,
            sync_timestamp=sweep.sync_timestamp,
        )
    if state.longitudinal_velocity is not None:
        msg.longitudinal_velocity = state.longitudinal_velocity
