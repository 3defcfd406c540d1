"""The dataset samples of a measurement stream: the 13 channels the real recordings have.

A sample is taken at every second-plane sweep of Lighthouse station 0 that has a first-plane
sweep of the same rotation before it (less than three quarters of a rotation earlier); it holds
the eight sweep angles of that pair, and the wheel speeds and the yaw rate linearly interpolated
to its stamp (NaN where that sensor has no data around the stamp: before its first reading, after
its last, or inside a gap longer than 1.5 of its periods, so that no value is invented across a
drop-out). The yaw rate is the IMU's, or the gyro's where the stream has no IMU.

This is how the simulator writes its datasets (:meth:`sim.result.SimulationResult.to_dataset`)
and how a bag becomes a dataset (:mod:`ros4crs.bag_dataset`): one sampling for both.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from crs_core.dataset import Y_CHANNELS
from crs_core.errors import FieldError
from crs_core.measurements import InputSample, Measurement, lighthouse_sensor

__all__ = [
    "StreamSamples",
    "held_at",
    "interpolated_at",
    "nominal_period",
    "readings",
    "sample_stream",
]

#: A first-plane sweep pairs with a second-plane sweep less than this many rotations earlier.
PAIR_WITHIN_ROTATIONS = 0.75
#: A sensor gap longer than this many of its periods is not interpolated across.
GAP_PERIODS = 1.5


@dataclass(frozen=True)
class StreamSamples:
    """Samples of a stream.

    Attributes
    ----------
    t : np.ndarray
        Sample stamps ``(N,)``, s, increasing: the second-plane sweeps of station 0.
    y : np.ndarray
        Samples ``(N, 13)`` per :data:`~crs_core.dataset.Y_CHANNELS` (rad, rad/s; NaN: not
        available).
    """

    t: np.ndarray
    y: np.ndarray


def nominal_period(stamps: np.ndarray) -> float:
    """The median interval between successive distinct ``stamps`` (s); ``nan`` with fewer than
    two."""
    steps = np.diff(np.unique(np.asarray(stamps, dtype=float)))
    return float(np.median(steps)) if steps.size else float("nan")


def readings(measurements: Sequence[Measurement], sensor: str) -> tuple[np.ndarray, np.ndarray]:
    """Stamps ``(n,)`` (sorted) and values ``(n, size)`` of one sensor."""
    items = sorted((m for m in measurements if m.sensor == sensor), key=lambda m: m.stamp)
    if not items:
        return np.zeros(0), np.zeros((0, 0))
    return np.array([m.stamp for m in items]), np.stack([m.values for m in items])


def interpolated_at(
    t: np.ndarray, stamps: np.ndarray, values: np.ndarray, period: float | None = None
) -> np.ndarray:
    """``values`` (n, k) at ``stamps`` linearly interpolated to ``t`` (N,), shape (N, k): NaN
    before the first stamp, after the last and inside gaps longer than :data:`GAP_PERIODS` of
    ``period`` (s; default :func:`nominal_period` of ``stamps``)."""
    t = np.asarray(t, dtype=float)
    out = np.full((t.size, values.shape[1]), np.nan)
    if stamps.size == 0 or t.size == 0:
        return out
    out[:] = np.stack([np.interp(t, stamps, values[:, i]) for i in range(values.shape[1])], axis=1)
    gap = GAP_PERIODS * (nominal_period(stamps) if period is None else period)
    after = np.clip(np.searchsorted(stamps, t), 1, stamps.size - 1)
    bracket = stamps[after] - stamps[after - 1] if stamps.size > 1 else np.zeros(1)
    outside = (t < stamps[0]) | (t > stamps[-1])
    out[(bracket > gap) | outside] = np.nan
    return out


def held_at(samples: Sequence[InputSample], t: np.ndarray) -> np.ndarray:
    """The inputs ``[steer, torque]`` in force at ``t`` (zero-order hold), shape ``(N, 2)``;
    before the first input, the first."""
    if not samples:
        raise FieldError("inputs", "no inputs to hold")
    stamps = np.array([s.stamp for s in samples])
    values = np.stack([s.u for s in samples])
    index = np.clip(np.searchsorted(stamps, t, side="right") - 1, 0, len(stamps) - 1)
    return values[index]


def sample_stream(
    measurements: Sequence[Measurement], periods: Mapping[str, float] | None = None
) -> StreamSamples:
    """The samples of ``measurements`` (any order).

    Parameters
    ----------
    measurements : sequence of Measurement
        The stream; station 0's two Lighthouse planes give the stamps.
    periods : mapping, optional
        Nominal period (s) per sensor name (``lighthouse/0/2``, ``wheel_encoders``, ``imu``,
        ``gyro``) where it is known (a simulator's rates); otherwise each is the median interval
        of the sensor's stamps.
    """
    periods = periods or {}
    t1, a1 = readings(measurements, lighthouse_sensor(0, 1))
    t2, a2 = readings(measurements, lighthouse_sensor(0, 2))
    stamps: list[float] = []
    rows: list[np.ndarray] = []
    if t1.size and t2.size:
        rotation = periods.get(lighthouse_sensor(0, 2), nominal_period(t2))
        previous = np.searchsorted(t1, t2, side="right") - 1
        for k, j in enumerate(previous):
            if j >= 0 and t2[k] - t1[j] < rotation * PAIR_WITHIN_ROTATIONS:
                stamps.append(t2[k])
                rows.append(np.concatenate([a1[j], a2[k]]))
    t = np.array(stamps)
    y = np.full((t.size, len(Y_CHANNELS)), np.nan)
    if t.size:
        y[:, :8] = np.stack(rows)
        ts, values = readings(measurements, "wheel_encoders")
        if ts.size:
            y[:, 8:12] = interpolated_at(t, ts, values, periods.get("wheel_encoders"))
        for sensor, column in (("imu", 2), ("gyro", 0)):  # the IMU's yaw rate, else the gyro's
            ts, values = readings(measurements, sensor)
            if ts.size:
                rate = values[:, column : column + 1]
                y[:, 12:13] = interpolated_at(t, ts, rate, periods.get(sensor))
                break
    return StreamSamples(t, y)
