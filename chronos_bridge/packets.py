"""Typed, validated contents of Chronos packets (``shared/specs/chronos-wifi-protocol.md``).

These are what :mod:`chronos_bridge.codec` decodes into and encodes from: plain frozen
dataclasses of Python numbers, validated on construction. A value that is NaN/inf or outside its
physical range raises :class:`FieldError` naming the field, so a malformed value can neither be
decoded nor encoded. Units are SI except where the wire format says otherwise (noted per field).
Vectors of the IMU are in the **board's** axes (x and y opposite to the body frame; see
:mod:`chronos_bridge.car_state` for the conversion). Lighthouse sweep angles are the firmware's
**raw** angles (before the host's plane offsets).

Range limits (module constants, so a bridge node can print them):

- IMU (BMI088): gyro ±250 °/s and accelerometer ±3 g, each with a 20 % margin
  (:data:`GYRO_LIMIT`, :data:`ACCEL_LIMIT`), per axis.
- Wheel speeds ±:data:`WHEEL_SPEED_LIMIT` rad/s (17.5 m/s at the 0.0175 m rim, several times the
  car's top speed).
- Battery 0..:data:`BATTERY_VOLTAGE_MAX` V, current ±:data:`BATTERY_CURRENT_LIMIT` A.
- Steering angle ±:data:`STEER_LIMIT` rad; potentiometer voltage 0..:data:`STEER_VOLTAGE_MAX` mV;
  ``adc_meas`` 0..65535 (the ADC reading; ``adc_limits`` packs two int16, any int32).
- Motor powers and the throttle reference in [-1, 1]; velocity reference ±:data:`VELOCITY_LIMIT`
  m/s; the car's own v_x ±:data:`CAR_VELOCITY_LIMIT` m/s.
- ``current_reference.torque_ref`` of a car state ±:data:`CURRENT_TORQUE_REF_LIMIT` (the firmware
  may hold a velocity reference there in velocity mode; the bound only catches garbage).
- Lighthouse: at most :data:`MAX_FRAMES` frames and :data:`MAX_SWEEPS` sweeps per state;
  polynomial 0..31 (16 stations x 2), ``sensor_id`` 0..3, deck timestamps 24-bit; raw sweep
  angles within one turn, ±2π rad.
- ``Packet.timestamp`` (µs since the Unix epoch) within years 2000..2100
  (:data:`TIMESTAMP_MIN_US`, :data:`TIMESTAMP_MAX_US`).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

from crs_core.errors import FieldError

#: Gyro range ±250 °/s plus 20 %, rad/s.
GYRO_LIMIT = 1.2 * math.radians(250.0)
#: Accelerometer range ±3 g plus 20 %, m/s^2.
ACCEL_LIMIT = 1.2 * 3.0 * 9.80665
WHEEL_SPEED_LIMIT = 1000.0
BATTERY_VOLTAGE_MAX = 20.0
BATTERY_CURRENT_LIMIT = 50.0
STEER_LIMIT = 1.0
STEER_VOLTAGE_MAX = 5000
ADC_MAX = 65535
VELOCITY_LIMIT = 5.0
CAR_VELOCITY_LIMIT = 10.0
CURRENT_TORQUE_REF_LIMIT = 10.0
SWEEP_ANGLE_LIMIT = 2.0 * math.pi
MAX_FRAMES = 8
MAX_SWEEPS = 5
MAX_POLYNOMIAL = 31
MAX_SENSOR_ID = 3
TICKS_24BIT = 1 << 24
UINT32_MAX = (1 << 32) - 1
INT32_MIN, INT32_MAX = -(1 << 31), (1 << 31) - 1
#: 2000-01-01T00:00:00Z and 2100-01-01T00:00:00Z in µs since the Unix epoch.
TIMESTAMP_MIN_US = 946_684_800_000_000
TIMESTAMP_MAX_US = 4_102_444_800_000_000


def check_float(field: str, value: object, low: float, high: float) -> float:
    """``value`` as a finite float in ``[low, high]``; else :class:`FieldError`."""
    if isinstance(value, bool) or not isinstance(value, int | float):
        try:
            value = float(value)  # numpy scalars
        except (TypeError, ValueError):
            raise FieldError(field, f"not a number: {value!r}") from None
    number = float(value)
    if not math.isfinite(number):
        raise FieldError(field, f"not finite: {number}")
    if not low <= number <= high:
        raise FieldError(field, f"{number} outside [{low:g}, {high:g}]")
    return number


def check_int(field: str, value: object, low: int, high: int) -> int:
    """``value`` as an int in ``[low, high]``; else :class:`FieldError`."""
    if isinstance(value, bool) or not isinstance(value, int):
        try:
            if int(value) != value:  # numpy integers pass, floats with a fraction do not
                raise ValueError
            value = int(value)
        except (TypeError, ValueError, OverflowError):
            raise FieldError(field, f"not an integer: {value!r}") from None
    if not low <= value <= high:
        raise FieldError(field, f"{value} outside [{low}, {high}]")
    return int(value)


def _sequence(field: str, values: object) -> tuple:
    try:
        return tuple(values)
    except TypeError:
        raise FieldError(field, f"not a sequence: {values!r}") from None


def _set(obj: object, name: str, value: object) -> None:
    object.__setattr__(obj, name, value)


def _floats(obj: object, names: tuple[str, ...], low: float, high: float) -> None:
    for name in names:
        _set(obj, name, check_float(name, getattr(obj, name), low, high))


@dataclass(frozen=True, slots=True)
class Ping:
    """Discovery ping: the car sends ``should_bounce=True`` every 5 s, the host answers False."""

    should_bounce: bool

    def __post_init__(self) -> None:
        if not isinstance(self.should_bounce, bool):
            raise FieldError("should_bounce", f"not a bool: {self.should_bounce!r}")


@dataclass(frozen=True, slots=True)
class ControlInput:
    """``SingleControlInput``, the older command form (also the car's current reference).

    ``torque_ref`` normalised (-), ``steer_ref`` rad; optional ``steer_angle`` (rad) or
    ``steer_voltage`` (mV) from the ``SteerInput`` oneof (at most one of them).
    ``torque_limit`` is the bound checked on ``torque_ref`` (1 for a command; a car state's
    current reference uses :data:`CURRENT_TORQUE_REF_LIMIT`).
    """

    torque_ref: float
    steer_ref: float
    steer_angle: float | None = None
    steer_voltage: int | None = None
    torque_limit: float = dataclasses.field(default=1.0, compare=False, repr=False)

    def __post_init__(self) -> None:
        _floats(self, ("torque_ref",), -self.torque_limit, self.torque_limit)
        _floats(self, ("steer_ref",), -STEER_LIMIT, STEER_LIMIT)
        if self.steer_angle is not None and self.steer_voltage is not None:
            raise FieldError("steer_input", "steer_angle and steer_voltage are one oneof")
        if self.steer_angle is not None:
            _floats(self, ("steer_angle",), -STEER_LIMIT, STEER_LIMIT)
        if self.steer_voltage is not None:
            v = check_int("steer_voltage", self.steer_voltage, 0, STEER_VOLTAGE_MAX)
            _set(self, "steer_voltage", v)


@dataclass(frozen=True, slots=True)
class Reference:
    """``CarReference`` (host -> car): exactly one of ``throttle`` (normalised, [-1, 1]) and
    ``longitudinal_velocity`` (m/s, tracked by the car's PID); at most one of ``angle`` (rad) and
    ``voltage`` (steering potentiometer, mV)."""

    throttle: float | None = None
    longitudinal_velocity: float | None = None
    angle: float | None = None
    voltage: int | None = None

    def __post_init__(self) -> None:
        if (self.throttle is None) == (self.longitudinal_velocity is None):
            raise FieldError(
                "throttle_reference", "needs exactly one of throttle and longitudinal_velocity"
            )
        if self.angle is not None and self.voltage is not None:
            raise FieldError("steering_reference", "angle and voltage are one oneof")
        if self.throttle is not None:
            _floats(self, ("throttle",), -1.0, 1.0)
        else:
            _floats(self, ("longitudinal_velocity",), -VELOCITY_LIMIT, VELOCITY_LIMIT)
        if self.angle is not None:
            _floats(self, ("angle",), -STEER_LIMIT, STEER_LIMIT)
        if self.voltage is not None:
            _set(self, "voltage", check_int("voltage", self.voltage, 0, STEER_VOLTAGE_MAX))


@dataclass(frozen=True, slots=True)
class Imu:
    """BMI088 reading in the **board's** axes, (x, y, z): ``linear_acceleration`` (m/s^2) and
    ``angular_velocity`` (rad/s)."""

    linear_acceleration: tuple[float, float, float]
    angular_velocity: tuple[float, float, float]

    def __post_init__(self) -> None:
        for name, limit in (
            ("linear_acceleration", ACCEL_LIMIT),
            ("angular_velocity", GYRO_LIMIT),
        ):
            vector = _sequence(name, getattr(self, name))
            if len(vector) != 3:
                raise FieldError(name, f"needs 3 values, got {len(vector)}")
            _set(
                self,
                name,
                tuple(
                    check_float(f"{name}.{a}", v, -limit, limit)
                    for a, v in zip("xyz", vector, strict=True)
                ),
            )


@dataclass(frozen=True, slots=True)
class Steering:
    """``SteeringPositionMeasurement``: ``steer_rad`` (rad), ``adc_meas`` (ADC counts),
    optional ``adc_limits`` (low int16 | high int16 << 16) and ``amplitude``."""

    steer_rad: float
    adc_meas: int
    adc_limits: int | None = None
    amplitude: float | None = None

    def __post_init__(self) -> None:
        _floats(self, ("steer_rad",), -STEER_LIMIT, STEER_LIMIT)
        _set(self, "adc_meas", check_int("adc_meas", self.adc_meas, 0, ADC_MAX))
        if self.adc_limits is not None:
            _set(self, "adc_limits", check_int("adc_limits", self.adc_limits, INT32_MIN, INT32_MAX))
        if self.amplitude is not None:
            _floats(self, ("amplitude",), -math.inf, math.inf)

    @property
    def adc_range(self) -> tuple[int, int] | None:
        """``(low, high)`` int16 halves of ``adc_limits`` (low in the low 16 bits)."""
        if self.adc_limits is None:
            return None
        bits = self.adc_limits & 0xFFFFFFFF
        low, high = bits & 0xFFFF, bits >> 16
        return (low - 0x10000 if low >= 0x8000 else low, high - 0x10000 if high >= 0x8000 else high)


@dataclass(frozen=True, slots=True)
class WheelSpeeds:
    """Wheel speeds in rad/s, in the wire order fr, fl, rr, rl."""

    front_right: float
    front_left: float
    rear_right: float
    rear_left: float

    def __post_init__(self) -> None:
        names = ("front_right", "front_left", "rear_right", "rear_left")
        _floats(self, names, -WHEEL_SPEED_LIMIT, WHEEL_SPEED_LIMIT)


@dataclass(frozen=True, slots=True)
class Battery:
    """``voltage`` (V) and optional ``current`` (A, negative when discharging)."""

    voltage: float
    current: float | None = None

    def __post_init__(self) -> None:
        _floats(self, ("voltage",), 0.0, BATTERY_VOLTAGE_MAX)
        if self.current is not None:
            _floats(self, ("current",), -BATTERY_CURRENT_LIMIT, BATTERY_CURRENT_LIMIT)


@dataclass(frozen=True, slots=True)
class LighthouseFrame:
    """One raw Lighthouse deck frame (not used by the host conversion; validated and kept)."""

    sensor_id: int
    polynomial: int
    pulse_width: int
    sync_offset: int
    beam_word: int
    timestamp: int

    def __post_init__(self) -> None:
        _set(self, "sensor_id", check_int("sensor_id", self.sensor_id, 0, MAX_SENSOR_ID))
        _set(self, "polynomial", check_int("polynomial", self.polynomial, 0, MAX_POLYNOMIAL))
        for name in ("pulse_width", "sync_offset", "beam_word"):
            _set(self, name, check_int(name, getattr(self, name), 0, UINT32_MAX))
        _set(self, "timestamp", check_int("timestamp", self.timestamp, 0, TICKS_24BIT - 1))


@dataclass(frozen=True, slots=True)
class LighthouseSweep:
    """One light-plane sweep: raw ``angles`` (rad, photodiodes 0..3, firmware convention),
    ``polynomial`` (station = polynomial >> 1) and 24-bit deck ticks ``first_timestamp`` and
    ``sync_timestamp``."""

    angles: tuple[float, float, float, float]
    polynomial: int
    first_timestamp: int
    sync_timestamp: int

    def __post_init__(self) -> None:
        angles = _sequence("angles", self.angles)
        if len(angles) != 4:
            raise FieldError("angles", f"needs 4 values, got {len(angles)}")
        _set(
            self,
            "angles",
            tuple(
                check_float(f"angle_{k}", a, -SWEEP_ANGLE_LIMIT, SWEEP_ANGLE_LIMIT)
                for k, a in enumerate(angles)
            ),
        )
        _set(self, "polynomial", check_int("polynomial", self.polynomial, 0, MAX_POLYNOMIAL))
        for name in ("first_timestamp", "sync_timestamp"):
            _set(self, name, check_int(name, getattr(self, name), 0, TICKS_24BIT - 1))

    @property
    def station(self) -> int:
        """Base-station index, ``polynomial >> 1``."""
        return self.polynomial >> 1


@dataclass(frozen=True, slots=True)
class CarState:
    """One 250 Hz car state (car -> host). Motor powers are normalised to [-1, 1]."""

    current_reference: ControlInput
    drive_power: float
    steer_power: float
    imu: Imu
    steering: Steering
    wheel_speeds: WheelSpeeds | None = None
    battery: Battery | None = None
    frames: tuple[LighthouseFrame, ...] = ()
    sweeps: tuple[LighthouseSweep, ...] = ()
    longitudinal_velocity: float | None = None

    def __post_init__(self) -> None:
        _floats(self, ("drive_power", "steer_power"), -1.0, 1.0)
        _set(self, "frames", tuple(self.frames))
        _set(self, "sweeps", tuple(self.sweeps))
        if len(self.frames) > MAX_FRAMES:
            raise FieldError("lighthouse_data", f"{len(self.frames)} frames > {MAX_FRAMES}")
        if len(self.sweeps) > MAX_SWEEPS:
            raise FieldError("lighthouse_sweeps", f"{len(self.sweeps)} sweeps > {MAX_SWEEPS}")
        if self.longitudinal_velocity is not None:
            limit = CAR_VELOCITY_LIMIT
            _floats(self, ("longitudinal_velocity",), -limit, limit)


Contents = Ping | ControlInput | Reference | CarState


@dataclass(frozen=True, slots=True)
class Packet:
    """One datagram: ``contents`` and ``timestamp_us`` (µs since the Unix epoch, or ``None`` when
    the sender's clock is not synchronised)."""

    contents: Contents
    timestamp_us: int | None = None

    def __post_init__(self) -> None:
        if not isinstance(self.contents, Ping | ControlInput | Reference | CarState):
            raise FieldError("contents", f"not a packet content: {type(self.contents).__name__}")
        if self.timestamp_us is not None:
            stamp = check_int("timestamp", self.timestamp_us, TIMESTAMP_MIN_US, TIMESTAMP_MAX_US)
            _set(self, "timestamp_us", stamp)

    @property
    def stamp_s(self) -> float | None:
        """``timestamp_us`` in s since the Unix epoch, or ``None``."""
        return None if self.timestamp_us is None else self.timestamp_us * 1e-6
