"""The measurement stream: stamped values from named sensors, validated at the boundary.

A measurement is ``(stamp, sensor, values)``. Sensor names:

==========================  ======  ====================================================
name                        size    values
==========================  ======  ====================================================
``imu``                     3       a_x, a_y (m/s^2, body), yaw rate (rad/s)
``gyro``                    1       yaw rate only (rad/s), as in the real recordings
``wheel_encoders``          4       wheel speeds fl, fr, rl, rr (rad/s)
``lighthouse/<bs>/<plane>`` 4       sweep angles of photodiodes 0..3 (rad), plane 1 or 2
``pose``                    3       x, y (m), yaw (rad): motion capture
==========================  ======  ====================================================

The same stream comes out of the simulator, a dataset on disk, a bag or the bridge, and goes
into every estimator.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass

import numpy as np

_FIXED_SIZES = {"imu": 3, "gyro": 1, "wheel_encoders": 4, "pose": 3}
_LIGHTHOUSE = re.compile(r"^lighthouse/(\d+)/([12])$")


def sensor_size(sensor: str) -> int:
    """Number of values of ``sensor``; ``ValueError`` for an unknown name."""
    if sensor in _FIXED_SIZES:
        return _FIXED_SIZES[sensor]
    if _LIGHTHOUSE.match(sensor):
        return 4
    raise ValueError(
        f"sensor: unknown name {sensor!r} (imu, gyro, wheel_encoders, pose, lighthouse/<bs>/<1|2>)"
    )


def lighthouse_sensor(station: int, plane: int) -> str:
    return f"lighthouse/{station}/{plane}"


def parse_lighthouse(sensor: str) -> tuple[int, int] | None:
    """``(station, plane)`` of a Lighthouse sensor name, else ``None``."""
    match = _LIGHTHOUSE.match(sensor)
    return (int(match.group(1)), int(match.group(2))) if match else None


@dataclass(frozen=True, slots=True)
class Measurement:
    """One stamped sensor reading.

    Attributes
    ----------
    stamp : float
        Time the values refer to, s (the stream's clock).
    sensor : str
        Sensor name (see module docstring).
    values : np.ndarray
        Readings, shape ``(sensor_size(sensor),)``, SI units.
    """

    stamp: float
    sensor: str
    values: np.ndarray

    def __post_init__(self) -> None:
        if not isinstance(self.stamp, int | float) or not math.isfinite(self.stamp):
            raise ValueError(f"stamp: must be a finite number, got {self.stamp!r}")
        size = sensor_size(self.sensor)
        values = np.asarray(self.values, dtype=float)
        if values.shape != (size,):
            raise ValueError(f"values: {self.sensor} needs shape ({size},), got {values.shape}")
        if not np.all(np.isfinite(values)):
            raise ValueError(f"values: {self.sensor} at t={self.stamp} has NaN or inf: {values}")
        object.__setattr__(self, "stamp", float(self.stamp))
        object.__setattr__(self, "values", values)


@dataclass(frozen=True, slots=True)
class InputSample:
    """A commanded input ``[steer (rad), torque (-)]`` applied from ``stamp`` on (s)."""

    stamp: float
    u: np.ndarray

    def __post_init__(self) -> None:
        u = np.asarray(self.u, dtype=float)
        if u.shape != (2,) or not np.all(np.isfinite(u)) or not math.isfinite(self.stamp):
            raise ValueError(f"input: needs finite stamp and u of shape (2,), got {self.u!r}")
        object.__setattr__(self, "u", u)
