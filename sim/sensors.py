"""Sensor settings of the simulator: rates, noise, bias, latency, drop-outs, blackouts.

Defaults resemble the real recordings in ``data/chronos_real``: Lighthouse angles there scatter
by 0.3-0.8 mrad *after* a 7-sample median filter and about 5 % of the station-0 sweep intervals
are missing (steps of 40-100 ms instead of 20 ms), so raw angle noise is set to 1 mrad and the
drop-out probability to 5 %. Wheel speeds and yaw rate in the recordings are low-pass filtered
(5 Hz); raw noise is set higher than what remains there: 2 rad/s per wheel (8 magnets per turn,
about 3.5 cm/s) and 0.05 rad/s on the gyroscope; 0.5 m/s^2 on the accelerometer (not recorded).
Latency defaults to zero: the car stamps its packets with an SNTP-synchronised clock.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

from crs_core.errors import FieldError, parse_finite
from crs_core.settings import Settings, non_negative, positive, within


@dataclass(frozen=True)
class SensorSpec(Settings):
    """Rate and imperfections of one sensor.

    Attributes
    ----------
    rate_hz : float
        Sampling rate, Hz (for Lighthouse: sweeps of each plane per base station).
    noise_std : tuple of float
        Standard deviation of white Gaussian noise per channel, SI units.
    bias : tuple of float
        Constant additive bias per channel (empty: none), SI units.
    latency_s : float
        The value refers to the state ``latency_s`` before its stamp (stamps on arrival), s.
    dropout_probability : float
        Probability that a sample is lost, independently per sample.
    jitter_std_s : float
        Standard deviation of the sampling-time jitter, s.
    """

    rate_hz: float = positive()
    noise_std: tuple[float, ...]
    bias: tuple[float, ...] = ()
    latency_s: float = non_negative(0.0)
    dropout_probability: float = within(0.0, low=0, high=1, high_open=True)
    jitter_std_s: float = non_negative(0.0)

    def _check_relations(self) -> None:
        if any(s < 0 for s in self.noise_std):
            raise FieldError("noise_std", "must be >= 0")
        if self.bias and len(self.bias) != len(self.noise_std):
            raise FieldError("bias", "needs one value per channel")

    def ideal(self) -> SensorSpec:
        """Same rate, no noise, bias, latency, drop-outs or jitter."""
        return replace(
            self,
            noise_std=(0.0,) * len(self.noise_std),
            bias=(),
            latency_s=0.0,
            dropout_probability=0.0,
            jitter_std_s=0.0,
        )


@dataclass(frozen=True)
class Blackout:
    """Scheduled outage of every sensor whose name starts with ``sensor``.

    No sample is acquired in ``[start, start + duration)``.

    ``sensor`` is a prefix: ``"lighthouse"`` blanks every station and plane, ``"lighthouse/1"``
    one station, ``"imu"`` the IMU. Times in s since the start of the simulation.
    """

    sensor: str
    start: float
    duration: float

    def __post_init__(self) -> None:
        if self.duration <= 0 or self.start < 0:
            raise FieldError("blackout", "needs start >= 0 and duration > 0")

    def covers(self, sensor: str, t: float) -> bool:
        return sensor.startswith(self.sensor) and self.start <= t < self.start + self.duration


#: Sensor prefixes a blackout may name (a station: ``lighthouse/<n>``).
BLACKOUT_SENSORS = ("lighthouse", "imu", "wheel_encoders", "gyro", "pose")


def parse_blackout(text: str) -> Blackout:
    """``SENSOR:START:DURATION`` (s), e.g. ``lighthouse:10:1.127``; ``ValueError`` naming the
    text and the part that is wrong (the text is not a field: the caller names the option)."""
    parts = text.strip().split(":")
    if len(parts) != 3:
        raise ValueError(f"{text!r}: expected SENSOR:START:DURATION (e.g. lighthouse:10:1.127)")
    sensor, start, duration = parts
    family, _, station = sensor.partition("/")
    if family not in BLACKOUT_SENSORS or (
        station and (family != "lighthouse" or not station.isdigit())
    ):
        raise ValueError(
            f"{text!r}: sensor {sensor!r} is not one of {', '.join(BLACKOUT_SENSORS)} or "
            "lighthouse/<station>"
        )
    values = []
    for name, value in (("START", start), ("DURATION", duration)):
        number = parse_finite(value)
        if number is None:
            raise ValueError(f"{text!r}: {name} {value!r} is not a finite number")
        values.append(number)
    try:
        return Blackout(sensor, *values)
    except FieldError as error:
        raise ValueError(f"{text!r}: {error.reason}") from None


@dataclass(frozen=True)
class SensorSuite:
    """All simulated sensors. ``pose`` (motion capture) is off unless given."""

    imu: SensorSpec = SensorSpec(250.0, (0.5, 0.5, 0.05))
    wheel_encoders: SensorSpec = SensorSpec(250.0, (2.0, 2.0, 2.0, 2.0))
    lighthouse: SensorSpec = SensorSpec(
        50.0, (1e-3,) * 4, dropout_probability=0.05, jitter_std_s=2e-4
    )
    pose: SensorSpec | None = None
    blackouts: tuple[Blackout, ...] = field(default=())

    def ideal(self) -> SensorSuite:
        """Noise-free sensors at the same rates; scheduled blackouts are kept."""
        return replace(
            self,
            imu=self.imu.ideal(),
            wheel_encoders=self.wheel_encoders.ideal(),
            lighthouse=self.lighthouse.ideal(),
            pose=self.pose.ideal() if self.pose else None,
        )

    def spec(self, sensor: str) -> SensorSpec:
        """Settings of a stream sensor (``lighthouse/<bs>/<plane>`` maps to ``lighthouse``)."""
        family = sensor.split("/")[0]
        spec = getattr(self, family, None)
        if not isinstance(spec, SensorSpec):
            raise KeyError(f"sensor {sensor!r} is not simulated")
        return spec

    def blacked_out(self, sensor: str, t: float) -> bool:
        return any(b.covers(sensor, t) for b in self.blackouts)

    def to_dict(self) -> dict:
        """Plain description for dataset metadata."""
        out = {}
        for name in ("imu", "wheel_encoders", "lighthouse", "pose"):
            spec = getattr(self, name)
            if spec is not None:
                out[name] = {
                    "rate_hz": spec.rate_hz,
                    "noise_std": list(spec.noise_std),
                    "bias": list(spec.bias),
                    "latency_s": spec.latency_s,
                    "dropout_probability": spec.dropout_probability,
                    "jitter_std_s": spec.jitter_std_s,
                }
        out["blackouts"] = [
            {"sensor": b.sensor, "start": b.start, "duration": b.duration} for b in self.blackouts
        ]
        return out
