"""The estimator interface shared by the EKF, the MHE, the ROS nodes, bag replay and benchmarks.

An estimator consumes the measurement stream and the commanded inputs, in any interleaving, and
returns an :class:`Estimate` of the base state ``[x, y, yaw, vx, vy, omega]`` at a requested time.
Events are processed in stamp order, ties broken by sensor name, so the same data delivered in a
different order gives the same estimate. Anything older than what was already processed is
rejected as late (counted in the diagnostics); the MHE accepts late data as long as its stamp
is still inside the window.

The base class also supervises the estimate (the same for every estimator):

* **Blind start.** ``reset(t0)`` without ``x0`` waits for the Lighthouse: sweep pairs are turned
  into pose fixes (:mod:`~crs_core.estimation.lighthouse_pose`), and a few consecutive fixes
  into a full initial state (:class:`~crs_core.estimation.initialization.PoseInitializer`).
  Until then the estimate is ``lost`` ("waiting for a Lighthouse fix").
* **Honest status** (:mod:`~crs_core.estimation.health`): every estimate says ``ok``,
  ``degraded`` or ``lost`` with the reason.
* **Re-initialisation.** When every Lighthouse sample has been rejected for
  ``HealthSettings.lost_after_s`` (the estimate and the Lighthouse disagree), no sample of any
  sensor has come for ``HealthSettings.lost_silent_s`` (the link to the car is down), or the
  state leaves the physical envelope, the estimate is ``lost`` and the estimator
  re-initialises from the Lighthouse as at a blind start.
* **Boundary.** A sensor the model does not have (``lighthouse/5/1`` on a one-station model) is
  refused with a ``ValueError`` naming it; a per-sensor time offset moves stamps to the time
  the values refer to.
"""

from __future__ import annotations

import heapq
import math
import time
from collections import Counter
from collections.abc import Iterator, Mapping
from dataclasses import dataclass, field, replace
from functools import lru_cache

import numpy as np
from numpy.typing import ArrayLike

from crs_core.errors import FieldError, parse_finite
from crs_core.estimation.health import HealthMonitor, HealthSettings
from crs_core.estimation.initialization import InitializationSettings, PoseInitializer
from crs_core.estimation.noise import EstimatorNoise
from crs_core.measurements import InputSample, Measurement, parse_lighthouse, sensor_size
from crs_core.model.online import DEFAULT_REVERSION_S
from crs_core.settings import Settings, positive

#: Sensor groups an estimator can be told to use.
SENSOR_GROUPS = ("lh", "imu", "gyro", "we", "pose")


@lru_cache(maxsize=256)  # called for every measurement, on a handful of names
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
        raise FieldError("sensors", f"{text!r} must combine {', '.join(SENSOR_GROUPS)} with '+'")
    return groups


def parse_time_offsets(text: str) -> dict[str, float]:
    """``"lh:0.004,imu:0.001"`` -> ``{"lh": 0.004, "imu": 0.001}`` (s); ``""`` -> ``{}``.

    Names are checked by :class:`EstimatorSettings`; a malformed entry is a ``ValueError``
    naming it.
    """
    offsets = {}
    for entry in filter(None, (part.strip() for part in text.split(","))):
        name, sep, value = entry.rpartition(":")
        seconds = parse_finite(value)
        if not sep or not name or seconds is None:
            raise FieldError("time_offsets", f"{entry!r} is not <sensor or group>:<seconds>")
        offsets[name] = seconds
    return offsets


def checked_initial_state(x0: ArrayLike) -> np.ndarray:
    """``x0`` as 6 finite floats, else ``ValueError`` naming it."""
    x0 = np.asarray(x0, dtype=float)
    if x0.shape != (6,) or not np.all(np.isfinite(x0)):
        raise FieldError("x0", f"needs 6 finite values, got {x0!r}")
    return x0


@dataclass(frozen=True)
class EstimatorSettings(Settings):
    """Settings every estimator of this package shares (EKF and MHE settings extend it).

    Attributes
    ----------
    noise : EstimatorNoise
        Assumed process and measurement noise.
    initial_std : tuple of float
        Initial standard deviation of ``[x, y, yaw, vx, vy, omega]`` when ``reset`` is given a
        state but no covariance (effect states: :func:`~crs_core.estimation.noise.initial_std_for`).
    time_offsets : mapping of str to float
        Per sensor (``"lighthouse/0/1"``) or sensor group (``"lh"``, ``"imu"``, ``"we"``,
        ``"gyro"``, ``"pose"``) the delay ``d`` (s) of its stamps: a value stamped ``t``
        refers to the car at ``t - d`` (the simulator's ``latency_s``). A sensor's own entry
        wins over its group's. Query estimates at least ``d`` behind the newest data (the
        estimator node's ``lag``): the EKF drops data stamped before what it processed.
    health : HealthSettings
        Thresholds of the status words and of re-initialisation.
    initialization : InitializationSettings
        How a blind start (or re-initialisation) builds its state from Lighthouse fixes.
    online_parameters : tuple of str
        Model parameters (``Cm1``, an effect's ``gyro_bias``, ...) or ``grip`` estimated online
        as slowly varying states (:mod:`crs_core.model.online`); an effect whose parameter is
        named is switched on from 0 if the model lacks it. Empty: none.
    online_reversion_s : float
        Relaxation time of the online parameters to their priors, s: their random walk's
        standard deviation per sqrt(s) is the prior's times ``sqrt(2 / online_reversion_s)``.
    """

    noise: EstimatorNoise = field(default_factory=EstimatorNoise)
    initial_std: tuple[float, ...] = (0.5, 0.5, 0.5, 1.0, 0.5, 2.0)
    time_offsets: Mapping[str, float] = field(default_factory=dict)
    health: HealthSettings = field(default_factory=HealthSettings)
    initialization: InitializationSettings = field(default_factory=InitializationSettings)
    online_parameters: tuple[str, ...] = ()
    online_reversion_s: float = positive(DEFAULT_REVERSION_S)

    def _check_relations(self) -> None:
        if len(self.initial_std) != 6 or not all(
            math.isfinite(v) and v > 0 for v in self.initial_std
        ):
            raise FieldError("initial_std", "needs 6 finite values > 0 (x, y, yaw, vx, vy, omega)")
        for key, value in self.time_offsets.items():
            if key not in SENSOR_GROUPS:
                try:
                    sensor_size(key)
                except ValueError:
                    raise FieldError(
                        "time_offsets",
                        f"{key!r} is neither a sensor nor a group ({', '.join(SENSOR_GROUPS)})",
                    ) from None
            if not (isinstance(value, int | float) and math.isfinite(value)):
                raise FieldError(f"time_offsets[{key!r}]", "must be a finite number of seconds")


@dataclass(frozen=True)
class OnlineValue:
    """An online parameter's estimate: its value and standard deviation (in the parameter's
    unit), and whether the recent data inform it (its standard deviation below
    :data:`INFORMED_FRACTION` of its prior's)."""

    value: float
    std: float
    informed: bool


#: An online parameter is informed while its standard deviation is below this share of its
#: prior's (uninformed, it relaxes to the prior's).
INFORMED_FRACTION = 0.7


@dataclass(frozen=True)
class Estimate:
    """State estimate at ``stamp`` (s).

    Attributes
    ----------
    stamp : float
        Time the estimate refers to, s.
    x : np.ndarray
        Base state ``[x, y, yaw, vx, vy, omega]`` (m, m, rad, m/s, m/s, rad/s; world pose, body
        velocities), always finite.
    covariance : np.ndarray
        Its covariance (6, 6).
    status : str
        ``ok``, ``degraded`` or ``lost`` (:mod:`~crs_core.estimation.health`).
    reason : str
        Why, when the status is not ``ok``.
    parameters : mapping of str to OnlineValue
        The online parameters of the estimation model (:mod:`crs_core.model.online`) by name;
        empty without them and while lost.
    """

    stamp: float
    x: np.ndarray
    covariance: np.ndarray
    status: str = "ok"
    reason: str = ""
    parameters: Mapping[str, OnlineValue] = field(default_factory=dict)

    @property
    def summary(self) -> str:
        """``"ok"`` or ``"<status>: <reason>"``."""
        return f"{self.status}: {self.reason}" if self.reason else self.status


@dataclass
class Diagnostics:
    """Running counters of an estimator (samples by sensor name)."""

    processed: Counter = field(default_factory=Counter)
    rejected: Counter = field(default_factory=Counter)
    ignored: Counter = field(default_factory=Counter)
    late: int = 0
    fallbacks: int = 0
    reinitializations: int = 0
    skipped_s: float = 0.0
    status: str = "ok"
    reason: str = ""
    last_solve_time_s: float = 0.0

    @property
    def last_status(self) -> str:
        """``status`` and ``reason`` in one line, as the diagnostics message carries them."""
        return f"{self.status}: {self.reason}" if self.reason else self.status

    @last_status.setter
    def last_status(self, text: str) -> None:  # estimators without supervision (peers)
        self.status, _, self.reason = text.partition(": ")


class Estimator:
    """Base class: stamp-ordered event queue, sensor selection, boundary checks, supervision.

    Subclasses implement :meth:`_estimate` (process the queue up to ``t``, return the state at
    ``t``), :meth:`_reset_state` and :meth:`current_state`, and report every sample they take
    or reject with :meth:`_accept` / :meth:`_reject` and every solver fallback with
    :meth:`_fallback_event`.

    Parameters
    ----------
    sensors : str or set of str
        Groups to use (:data:`SENSOR_GROUPS`), e.g. ``"lh+imu+we"``; measurements of other
        groups are ignored.
    model : CarModel, optional
        Estimation model: the sensors it has, and the blind-start pose solver.
    settings : EstimatorSettings, optional
    """

    def __init__(
        self,
        sensors: frozenset[str] | str,
        model=None,
        settings: EstimatorSettings | None = None,
    ) -> None:
        self.sensors = parse_sensor_set(sensors) if isinstance(sensors, str) else frozenset(sensors)
        self.diagnostics = Diagnostics()
        self._queue: list[tuple[float, int, str, int, Measurement | InputSample]] = []
        self._sequence = 0
        self._processed_until = -math.inf
        self._supervised = model is not None
        if model is None:
            return
        self.model = model
        self.settings = settings or EstimatorSettings()
        self._health = HealthMonitor(self.settings.health, "lh" in self.sensors)
        self._initializer: PoseInitializer | None = None
        self._initializer_factory = lambda: PoseInitializer(
            model,
            self.sensors,
            self.settings.noise,
            self.settings.initialization,
            self.settings.health.max_speed,
        )
        self._last_input = np.zeros(2)
        self._last_estimate: Estimate | None = None

    # --- stream in --------------------------------------------------------------------
    def add_measurement(self, measurement: Measurement) -> bool:
        """Queue a measurement; ``False`` if it is ignored (sensor not used) or late.

        Raises ``ValueError`` for a sensor of a used group that the model does not have.
        """
        if not isinstance(measurement, Measurement):
            raise TypeError("measurement: expected a crs_core.measurements.Measurement")
        group = sensor_group(measurement.sensor)
        if group not in self.sensors:
            self.diagnostics.ignored[measurement.sensor] += 1
            return False
        if not self.accepts(measurement.sensor):
            raise FieldError(
                "sensor",
                f"{measurement.sensor!r} is not a sensor of the estimator's model "
                f"({', '.join(self.model_sensors())})",
            )
        offset = self._time_offset(measurement.sensor, group)
        if offset:
            measurement = replace(measurement, stamp=measurement.stamp - offset)
        return self._push(measurement.stamp, 1, measurement.sensor, measurement)

    def add_input(self, sample: InputSample) -> bool:
        """Queue a commanded input, effective from its stamp on."""
        if not isinstance(sample, InputSample):
            raise TypeError("input: expected a crs_core.measurements.InputSample")
        return self._push(sample.stamp, 0, "", sample)

    def add(self, item: Measurement | InputSample) -> bool:
        """Queue a measurement or a commanded input (:meth:`add_measurement`, :meth:`add_input`)."""
        if isinstance(item, InputSample):
            return self.add_input(item)
        return self.add_measurement(item)

    def _time_offset(self, sensor: str, group: str) -> float:
        if not self._supervised:
            return 0.0
        offsets = self.settings.time_offsets
        return float(offsets.get(sensor, offsets.get(group, 0.0)))

    def _push(self, stamp: float, kind: int, key: str, item: Measurement | InputSample) -> bool:
        if stamp < self.late_before():
            self.diagnostics.late += 1
            return False
        heapq.heappush(self._queue, (stamp, kind, key, self._sequence, item))
        self._sequence += 1
        return True

    def _events_until(self, t: float) -> Iterator[Measurement | InputSample]:
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

    def accepts(self, sensor: str) -> bool:
        """Whether the estimator's model has this sensor (e.g. enough base stations)."""
        return True

    def model_sensors(self) -> list[str]:
        """Names of the stream sensors the model has."""
        return []

    # --- supervision --------------------------------------------------------------------
    def reset(
        self, t0: float, x0: np.ndarray | None = None, covariance: np.ndarray | None = None
    ) -> None:
        """Start over at ``t0`` from state ``x0`` (6 base states), or blind without ``x0``.

        Blind, the estimator initialises itself from the first Lighthouse (or motion-capture)
        fixes after ``t0``; until then its estimates are ``lost``.
        """
        self._queue.clear()
        self._processed_until = float(t0)
        self._health.clear()
        self._last_estimate = None
        if x0 is None:
            self._start_initializer("waiting for a Lighthouse fix")
            self._reset_state(float(t0), np.zeros(6), None)
            return
        self._initializer = None
        self._health.start(float(t0))
        self._reset_state(float(t0), checked_initial_state(x0), _checked_covariance(covariance))

    def _start_initializer(self, reason: str) -> None:
        if not self.sensors & {"lh", "pose"}:
            raise FieldError(
                "x0", "an estimator without Lighthouse or pose sensors cannot start blind; give x0"
            )
        self._initializer = self._initializer_factory()
        self._lost_reason = reason

    def estimate(self, t: float) -> Estimate:
        """Process everything stamped up to ``t`` and return the estimate at ``t``.

        The estimate is never non-finite: a state that is, or that leaves the physical
        envelope, makes the estimate ``lost`` and starts a re-initialisation.
        """
        start = time.perf_counter()
        t = float(t)
        if self._initializer is not None and not self._initialize(t):
            estimate = self._lost_estimate(t)
        else:
            full_x, full_covariance = self._estimate(t)
            x, covariance = self._car_view(full_x, full_covariance, t)
            problem = self._implausible(x, t)
            if problem:
                self.diagnostics.reinitializations += 1
                if self.sensors & {"lh", "pose"}:
                    self._start_initializer(f"{problem}; re-initialising from the Lighthouse")
                    estimate = self._lost_estimate(t)
                else:  # nothing absolute to re-initialise from: the last good estimate
                    self._lost_reason = (
                        f"{problem}; restarted from the last good estimate (no Lighthouse or "
                        "pose sensor)"
                    )
                    estimate = self._lost_estimate(t)
                    self._reset_state(t, estimate.x, None)
            else:
                status, reason = self._health.status(t)
                online = self._online_values(full_x, full_covariance)
                estimate = Estimate(t, x, covariance, status, reason, online)
        self._last_estimate = estimate
        self.diagnostics.status, self.diagnostics.reason = estimate.status, estimate.reason
        self.diagnostics.last_solve_time_s = time.perf_counter() - start
        return estimate

    def _online_values(self, x: np.ndarray, covariance: np.ndarray) -> dict[str, OnlineValue]:
        """The online parameters from the tail of the full state ``x`` and its covariance."""
        online = self.model.online
        if not len(online) or x.size != self.model.nx:
            return {}
        first = self.model.nx - len(online)
        std = np.sqrt(np.clip(np.diag(covariance)[first:], 0.0, None))
        return {
            entry.name: OnlineValue(
                float(x[first + k]),
                float(std[k]),
                bool(std[k] < INFORMED_FRACTION * entry.prior_std),
            )
            for k, entry in enumerate(online.entries)
        }

    def _initialize(self, t: float) -> bool:
        """Feed the initializer the data up to ``t``; on a fix, restart from it."""
        assert self._initializer is not None
        later: list[tuple[int, Measurement | InputSample]] = []
        fix = None
        for item in self._events_until(t):
            if fix is not None:
                later.append((0 if isinstance(item, InputSample) else 1, item))
            elif isinstance(item, InputSample):
                self._last_input = np.asarray(item.u)
            else:
                fix = self._initializer.add(item)
        if fix is None:
            return False
        self._initializer = None
        self._reset_state(fix.stamp, fix.x, fix.covariance)
        self._processed_until = fix.stamp
        self._health.record("lh", fix.stamp, True)
        self._push(fix.stamp, 0, "", InputSample(fix.stamp, self._last_input))
        for kind, item in later:
            self._push(item.stamp, kind, getattr(item, "sensor", ""), item)
        return True

    def _lost_estimate(self, t: float) -> Estimate:
        """The held guess (last good estimate, else the reset state) with a wide covariance."""
        last = self._last_estimate
        x = last.x if last is not None and last.status != "lost" else self.current_state()
        if not np.all(np.isfinite(x)):
            x = np.zeros(6)
        covariance = np.diag([1e2, 1e2, 10.0, 10.0, 10.0, 1e2])
        return Estimate(t, np.array(x, dtype=float), covariance, "lost", self._lost_reason)

    def _implausible(self, x: np.ndarray, t: float) -> str:
        """Why the state ``x`` at ``t`` cannot be trusted at all ('' if it can)."""
        h = self.settings.health
        if not np.all(np.isfinite(x)):
            return "the state became non-finite"
        if max(abs(x[3]), abs(x[4])) > h.max_speed or abs(x[5]) > h.max_yaw_rate:
            return (
                f"the state left the physical envelope (v {x[3]:.1f}, {x[4]:.1f} m/s, "
                f"omega {x[5]:.1f} rad/s)"
            )
        disagreement = self._health.disagreeing_since(t) if "lh" in self.sensors else None
        if disagreement is not None:
            return f"every Lighthouse sample rejected for {disagreement:.2f} s"
        silence = self._health.silent_for(t) if self.sensors & {"lh", "pose"} else None
        if silence is not None:
            return f"no sample of any sensor for {silence:.2f} s (is the link to the car down?)"
        return ""

    def _accept(self, sensor: str, stamp: float) -> None:
        self.diagnostics.processed[sensor] += 1
        self._health.record(sensor_group(sensor), stamp, True)

    def _reject(self, sensor: str, stamp: float, count: int = 1) -> None:
        self.diagnostics.rejected[sensor] += count
        for _ in range(count):
            self._health.record(sensor_group(sensor), stamp, False)

    def _fallback_event(self, stamp: float, reason: str) -> None:
        self.diagnostics.fallbacks += 1
        self._health.fallback(stamp, reason)

    def _car_view(
        self, x: np.ndarray, covariance: np.ndarray, t: float
    ) -> tuple[np.ndarray, np.ndarray]:
        """The car state and its covariance at ``t`` of a whole state (``nx``) and its
        covariance; a (6,) state is one."""
        if x.size != self.model.nx or self.model.car_state_is_state:
            return x[:6].copy(), covariance[:6, :6].copy()
        numeric, p, u = self.model.numeric, self.model.parameters.vector(), self._command_at(t)
        return numeric.car_state(x, u, p), numeric.car_covariance(x, covariance, u, p)

    # --- to implement -----------------------------------------------------------------
    def _estimate(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        """Process the queue up to ``t``; the state at ``t`` and its covariance: the model's
        whole state (``nx``), or the base state alone (6,) for an estimator that keeps no more."""
        raise NotImplementedError

    def _reset_state(self, t0: float, x0: np.ndarray, covariance: np.ndarray | None) -> None:
        """Restart the estimator's own state at ``t0`` (the queue is the base class's)."""
        raise NotImplementedError

    def current_state(self) -> np.ndarray:
        """The newest car state the estimator holds (6,)."""
        raise NotImplementedError

    def _command_at(self, t: float) -> np.ndarray:
        """The command in effect at ``t`` (``[steer rad, torque -]``)."""
        raise NotImplementedError


def _checked_covariance(covariance: np.ndarray | None) -> np.ndarray | None:
    if covariance is None:
        return None
    cov = np.asarray(covariance, dtype=float)
    if cov.shape != (6, 6) or not np.all(np.isfinite(cov)):
        raise FieldError("covariance", "needs a finite 6 x 6 matrix")
    if not np.all(np.diag(cov) > 0):
        raise FieldError("covariance", "its diagonal must be > 0")
    return 0.5 * (cov + cov.T)
