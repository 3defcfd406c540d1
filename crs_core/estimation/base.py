"""The estimator interface shared by the EKF, the MHE, the ROS nodes, bag replay and benchmarks.

An estimator consumes the measurement stream and the commanded inputs, in any interleaving, and
returns an :class:`Estimate` of the base state ``[x, y, yaw, vx, vy, omega]`` at a requested time.
Events are processed in stamp order, ties broken by sensor name, so the same data delivered in a
different order gives the same estimate. Anything older than what was already processed is
rejected as late (counted in the diagnostics); the MHE accepts late data as long as its stamp
is still inside the window.
"""

from __future__ import annotations

import heapq
import math
from abc import ABC, abstractmethod
from collections import Counter
from dataclasses import dataclass, field

import numpy as np

from crs_core.measurements import InputSample, Measurement, parse_lighthouse

#: Sensor groups an estimator can be told to use.
SENSOR_GROUPS = ("lh", "imu", "gyro", "we", "pose")


def sensor_group(sensor: str) -> str:
    """Group of a stream sensor name: ``lighthouse/0/1`` -> ``lh``, ``wheel_encoders`` -> ``we``."""
    if parse_lighthouse(sensor):
        return "lh"
    return {"imu": "imu", "gyro": "gyro", "wheel_encoders": "we", "pose": "pose"}[sensor]


def parse_sensor_set(text: str) -> frozenset[str]:
    """``"lh+imu+we"`` -> ``{"lh", "imu", "we"}`` (validated)."""
    groups = frozenset(part.strip() for part in text.split("+") if part.strip())
    unknown = groups - set(SENSOR_GROUPS)
    if unknown or not groups:
        raise ValueError(f"sensors: {text!r} must combine {', '.join(SENSOR_GROUPS)} with '+'")
    return groups


def checked_initial_state(x0: np.ndarray) -> np.ndarray:
    """``x0`` as 6 finite floats, else ``ValueError`` naming it."""
    x0 = np.asarray(x0, dtype=float)
    if x0.shape != (6,) or not np.all(np.isfinite(x0)):
        raise ValueError(f"x0: needs 6 finite values, got {x0!r}")
    return x0


class RejectionCap:
    """A cap on consecutive rejections that tells a drifted estimate from a burst of outliers.

    After ``limit`` rejections in a row of one sensor, a rejected measurement is taken anyway
    only when its normalised innovation agrees, in every channel within ``tolerance``, with the
    median of the previous ``window`` rejected ones: an estimate that drifted (during an outage)
    sees the same innovation sample after sample, a burst of wild readings does not.
    """

    def __init__(self, limit: int, window: int = 5, tolerance: float = 10.0) -> None:
        self.limit, self.window, self.tolerance = limit, window, tolerance
        self._runs: dict[str, tuple[int, list[np.ndarray]]] = {}

    def clear(self) -> None:
        self._runs.clear()

    def accepted(self, key: str) -> None:
        """A measurement of ``key`` passed its gate: its run of rejections ends."""
        self._runs.pop(key, None)

    def override(self, key: str, normalised_innovation: np.ndarray) -> bool:
        """Called for a measurement that failed its gate: True to take it anyway."""
        count, recent = self._runs.get(key, (0, []))
        innovation = np.asarray(normalised_innovation, dtype=float)
        if count >= self.limit and len(recent) == self.window:
            spread = np.abs(innovation - np.median(recent, axis=0))
            if np.all(spread < self.tolerance):
                self._runs.pop(key)
                return True
        self._runs[key] = (count + 1, [*recent, innovation][-self.window :])
        return False


@dataclass(frozen=True)
class Estimate:
    """State estimate at ``stamp`` (s): base state (6,), its covariance (6, 6), a status word."""

    stamp: float
    x: np.ndarray
    covariance: np.ndarray
    status: str = "ok"


@dataclass
class Diagnostics:
    """Running counters of an estimator."""

    processed: Counter = field(default_factory=Counter)
    rejected: Counter = field(default_factory=Counter)
    ignored: Counter = field(default_factory=Counter)
    late: int = 0
    fallbacks: int = 0
    last_status: str = "ok"
    last_solve_time_s: float = 0.0


class Estimator(ABC):
    """Base class: stamp-ordered event queue, sensor selection and boundary checks.

    Parameters
    ----------
    sensors : set of str
        Groups to use (:data:`SENSOR_GROUPS`); measurements of other groups are ignored.
    """

    def __init__(self, sensors: frozenset[str] | str) -> None:
        self.sensors = parse_sensor_set(sensors) if isinstance(sensors, str) else frozenset(sensors)
        self.diagnostics = Diagnostics()
        self._queue: list[tuple[float, int, str, int, object]] = []
        self._sequence = 0
        self._processed_until = -math.inf

    # --- stream in --------------------------------------------------------------------
    def add_measurement(self, measurement: Measurement) -> bool:
        """Queue a measurement; ``False`` if it is ignored (sensor not used) or late."""
        if not isinstance(measurement, Measurement):
            raise TypeError("measurement: expected a crs_core.measurements.Measurement")
        group = sensor_group(measurement.sensor)
        if group not in self.sensors or not self.accepts(measurement.sensor):
            self.diagnostics.ignored[measurement.sensor] += 1
            return False
        return self._push(measurement.stamp, 1, measurement.sensor, measurement)

    def add_input(self, sample: InputSample) -> bool:
        """Queue a commanded input, effective from its stamp on."""
        if not isinstance(sample, InputSample):
            raise TypeError("input: expected a crs_core.measurements.InputSample")
        return self._push(sample.stamp, 0, "", sample)

    def _push(self, stamp: float, kind: int, key: str, item: object) -> bool:
        if stamp < self.late_before():
            self.diagnostics.late += 1
            return False
        heapq.heappush(self._queue, (stamp, kind, key, self._sequence, item))
        self._sequence += 1
        return True

    def _events_until(self, t: float):
        """Pop queued events with stamp <= t in (stamp, inputs first, sensor name) order.

        Ties are resolved by content (sensor name, then arrival), so the order of delivery of
        events with different stamps or different sensors never matters.
        """
        while self._queue and self._queue[0][0] <= t:
            stamp, _, _, _, item = heapq.heappop(self._queue)
            self._processed_until = stamp
            yield item

    def late_before(self) -> float:
        """Data stamped before this are late and rejected (default: the last processed stamp)."""
        return self._processed_until

    # --- to implement -----------------------------------------------------------------
    def accepts(self, sensor: str) -> bool:
        """Whether the estimator's model has this sensor (e.g. enough base stations)."""
        return True

    @abstractmethod
    def estimate(self, t: float) -> Estimate:
        """Process everything stamped up to ``t`` and return the estimate at ``t``."""

    @abstractmethod
    def reset(self, t0: float, x0: np.ndarray, covariance: np.ndarray | None = None) -> None:
        """Start over from state ``x0`` at time ``t0``."""
