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
from collections.abc import Iterable
from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from crs_core.errors import FieldError

_FIXED_SIZES = {"imu": 3, "gyro": 1, "wheel_encoders": 4, "pose": 3}
_LIGHTHOUSE = re.compile(r"lighthouse/(0|[1-9][0-9]*)/([12])")


def sensor_size(sensor: str) -> int:
    """Number of values of ``sensor``; :class:`~crs_core.errors.FieldError` (field ``sensor``)
    for an unknown name."""
    if not isinstance(sensor, str):
        raise FieldError("sensor", f"expected a name (str), got {sensor!r}")
    if sensor in _FIXED_SIZES:
        return _FIXED_SIZES[sensor]
    if _LIGHTHOUSE.fullmatch(sensor):
        return 4
    raise FieldError(
        "sensor",
        f"unknown name {sensor!r} (imu, gyro, wheel_encoders, pose, lighthouse/<bs>/<1|2>)",
    )


def lighthouse_sensor(station: int, plane: int) -> str:
    return f"lighthouse/{station}/{plane}"


@lru_cache(maxsize=256)  # a stream names a handful of sensors, each many times a second
def parse_lighthouse(sensor: str) -> tuple[int, int] | None:
    """``(station, plane)`` of a Lighthouse sensor name, else ``None``."""
    match = _LIGHTHOUSE.fullmatch(sensor)
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
        stamp = _finite_stamp(self.stamp)
        size = sensor_size(self.sensor)
        values = _finite_vector("values", self.values, size, f"{self.sensor} at t={stamp}")
        object.__setattr__(self, "stamp", stamp)
        object.__setattr__(self, "values", values)


@dataclass(frozen=True, slots=True)
class InputSample:
    """A commanded input ``[steer (rad), torque (-)]`` applied from ``stamp`` on (s)."""

    stamp: float
    u: np.ndarray

    def __post_init__(self) -> None:
        stamp = _finite_stamp(self.stamp)
        object.__setattr__(self, "stamp", stamp)
        object.__setattr__(self, "u", _finite_vector("u", self.u, 2, f"input at t={stamp}"))


def _finite_stamp(stamp: object) -> float:
    """A finite float from a Python or numpy real number (not bool); else ``FieldError``."""
    if isinstance(stamp, bool | np.bool_) or not isinstance(stamp, int | float | np.number):
        raise FieldError("stamp", f"must be a finite real number, got {stamp!r}")
    value = float(stamp)
    if not math.isfinite(value):
        raise FieldError("stamp", f"must be finite, got {stamp!r}")
    return value


def _finite_vector(field: str, values: object, size: int, what: str) -> np.ndarray:
    """A read-only float copy of shape ``(size,)`` with finite entries; else ``FieldError``."""
    try:
        array = np.array(values, dtype=float)
    except (TypeError, ValueError):
        raise FieldError(field, f"{what} is not numeric: {values!r}") from None
    if array.shape != (size,):
        raise FieldError(field, f"{what} needs shape ({size},), got {array.shape}")
    if not np.all(np.isfinite(array)):
        raise FieldError(field, f"{what} has NaN or inf: {array}")
    array.flags.writeable = False
    return array


def in_stamp_order(
    measurements: Iterable[Measurement], inputs: Iterable[InputSample] = ()
) -> list[Measurement | InputSample]:
    """Measurements and commanded inputs in stamp order, a command before a measurement of the
    same stamp (it is in effect from its stamp on); otherwise the given order is kept."""
    events = [(s.stamp, 0, s) for s in inputs] + [(m.stamp, 1, m) for m in measurements]
    events.sort(key=lambda e: (e[0], e[1]))
    return [item for _, _, item in events]


def from_start(
    items: Iterable[Measurement | InputSample], t0: float
) -> list[Measurement | InputSample]:
    """What an estimator started at ``t0`` takes of the data that arrived before it started.

    Everything stamped at or after ``t0`` (in the given order), and the command in effect at
    ``t0`` (the newest earlier input) re-stamped at ``t0``, first; older data belong to before
    the start and are dropped (they are not late: nothing was processed yet). The ROS node and
    the offline bag replay both start through this, so they start on the same data.
    """
    items = list(items)
    earlier = [i for i in items if isinstance(i, InputSample) and i.stamp < t0]
    kept = [i for i in items if i.stamp >= t0]
    if not earlier:
        return kept
    in_effect = earlier[0]
    for sample in earlier:  # the newest; of equal stamps the last to arrive
        if sample.stamp >= in_effect.stamp:
            in_effect = sample
    return [InputSample(t0, in_effect.u), *kept]
