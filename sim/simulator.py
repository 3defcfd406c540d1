"""Event-driven simulation of the Chronos car with its sensors at their own rates.

Truth is the :class:`~crs_core.model.CarModel` (optionally with effects) integrated exactly
between events with RK4 substeps of at most :data:`~crs_core.model.MAX_SUBSTEP`. Events are
the application of (delayed) commands and sensor acquisitions. A :class:`SimulationSession`
advances step by step (the real-time simulator node drives one); :meth:`Simulator.run` drives
one with a controller that sees the true base state. Everything random is drawn from
generators seeded by ``(seed, sensor name)``, so a run is reproducible and changing one
sensor's settings does not reshuffle another's noise.
"""

from __future__ import annotations

import hashlib
import heapq
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
from tqdm import tqdm

from crs_core.dataset import Y_CHANNELS, Dataset, Geometry
from crs_core.measurements import InputSample, Measurement, lighthouse_sensor
from crs_core.model import CarModel
from sim.sensors import SensorSpec, SensorSuite

Controller = Callable[[float, np.ndarray], np.ndarray]

# event kinds, in the order they are handled at equal times
_APPLY, _SENSOR = 0, 1


#: Sweep angles beyond this (rad) are out of the base station's view; the host drops them.
LIGHTHOUSE_VIEW_LIMIT = 1.5


def _in_view(sensor: str, values: np.ndarray) -> bool:
    """False for a Lighthouse sweep that cannot reach a photodiode or lies outside the view."""
    if not sensor.startswith("lighthouse"):
        return True
    return bool(np.all(np.isfinite(values)) and np.all(np.abs(values) <= LIGHTHOUSE_VIEW_LIMIT))


def _rng(seed: int, name: str) -> np.random.Generator:
    digest = int.from_bytes(hashlib.sha256(name.encode()).digest()[:4], "little")
    return np.random.default_rng([seed, digest])


@dataclass
class SimulationResult:
    """What a run produced: truth, commanded inputs and the measurement stream (by stamp)."""

    model: CarModel
    sensors: SensorSuite
    seed: int
    duration: float
    truth_t: np.ndarray
    truth_x: np.ndarray
    inputs: list[InputSample]
    measurements: list[Measurement]
    extra_meta: dict = field(default_factory=dict)

    def measurements_of(self, sensor: str) -> tuple[np.ndarray, np.ndarray]:
        """Stamps ``(n,)`` and values ``(n, size)`` of one sensor."""
        items = [m for m in self.measurements if m.sensor == sensor]
        if not items:
            return np.zeros(0), np.zeros((0, 0))
        return np.array([m.stamp for m in items]), np.stack([m.values for m in items])

    def input_at(self, t: np.ndarray) -> np.ndarray:
        """Commanded input (zero-order hold) at times ``t``, shape ``(len(t), 2)``."""
        stamps = np.array([s.stamp for s in self.inputs])
        values = np.stack([s.u for s in self.inputs])
        index = np.clip(np.searchsorted(stamps, t, side="right") - 1, 0, len(stamps) - 1)
        return values[index]

    def truth_at(self, t: np.ndarray) -> np.ndarray:
        """True base state at times ``t`` (linear interpolation of the dense truth)."""
        return np.stack([np.interp(t, self.truth_t, self.truth_x[:, i]) for i in range(6)], axis=1)

    def to_dataset(self) -> Dataset:
        """Samples at the stamps of station 0's second-plane sweeps, like the real recordings.

        A sample holds the sweep pair of one rotation (both planes present), wheel speeds and yaw
        rate linearly interpolated to the stamp, the commanded input and the true state.
        """
        t1, a1 = self.measurements_of(lighthouse_sensor(0, 1))
        t2, a2 = self.measurements_of(lighthouse_sensor(0, 2))
        period = 1.0 / self.sensors.lighthouse.rate_hz
        stamps, rows = [], []
        if t1.size and t2.size:
            previous = np.searchsorted(t1, t2, side="right") - 1
            for k, j in enumerate(previous):
                if j >= 0 and t2[k] - t1[j] < period * 0.75:
                    stamps.append(t2[k])
                    rows.append(np.concatenate([a1[j], a2[k]]))
        stamps_arr = np.array(stamps)
        y = np.full((stamps_arr.size, len(Y_CHANNELS)), np.nan)
        if stamps_arr.size:
            y[:, :8] = np.stack(rows)
            for sensor, columns, source in (
                ("wheel_encoders", slice(8, 12), slice(0, 4)),
                ("imu", slice(12, 13), slice(2, 3)),
            ):
                ts, values = self.measurements_of(sensor)
                if ts.size:
                    picked = values[:, source]
                    y[:, columns] = np.stack(
                        [np.interp(stamps_arr, ts, picked[:, i]) for i in range(picked.shape[1])],
                        axis=1,
                    )
                    # no values invented across a gap (drop-out, blackout): NaN there
                    gap = 1.5 / self.sensors.spec(sensor).rate_hz
                    after = np.clip(np.searchsorted(ts, stamps_arr), 1, ts.size - 1)
                    bracket = ts[after] - ts[after - 1] if ts.size > 1 else np.zeros(1)
                    outside = (stamps_arr < ts[0]) | (stamps_arr > ts[-1])
                    y[(bracket > gap) | outside, columns] = np.nan
        meta = {
            "source": "simulated",
            "seed": self.seed,
            "duration_s": self.duration,
            "truth": {
                "effects": [e.name for e in self.model.effects],
                "parameters": {n: self.model.parameters.value(n) for n in self.model.parameters},
            },
            "sensors": self.sensors.to_dict(),
            **self.extra_meta,
        }
        return Dataset(
            t=stamps_arr,
            u=self.input_at(stamps_arr) if stamps_arr.size else np.zeros((0, 2)),
            y=y,
            x=self.truth_at(stamps_arr) if stamps_arr.size else np.zeros((0, 6)),
            geometry=Geometry.from_parameters(self.model.parameters, self.model.n_base_stations),
            meta=meta,
            measurements=self.measurements,
            inputs=self.inputs,
            truth_t=self.truth_t,
            truth_x=self.truth_x,
        )


class Simulator:
    """Simulate a car model with a sensor suite.

    Parameters
    ----------
    model : CarModel
        Truth model; its parameters (and effects) are the hidden truth.
    sensors : SensorSuite
        Rates and imperfections; ``SensorSuite().ideal()`` for noise-free sensors.
    seed : int
        Seed of every random draw.
    """

    def __init__(self, model: CarModel, sensors: SensorSuite | None = None, seed: int = 0):
        self.model = model
        self.sensors = sensors or SensorSuite()
        self.seed = int(seed)

    def session(self, x0: np.ndarray, keep_history: bool = True) -> SimulationSession:
        """A running simulation from base state ``x0`` (6,) at t = 0, advanced step by step.

        ``keep_history=False`` keeps no truth, input or measurement history (constant memory,
        for a simulator that streams its samples out, such as the ROS node); ``result()`` then
        holds only the current state.
        """
        return SimulationSession(self, x0, keep_history)

    def run(
        self,
        controller: Controller,
        duration: float,
        x0: np.ndarray,
        control_rate_hz: float = 50.0,
        progress: bool = False,
    ) -> SimulationResult:
        """Simulate ``duration`` s from base state ``x0`` (6,) under ``controller(t, x) -> u``.

        ``u`` is ``[steer (rad), torque (-)]``, held between controller ticks and delayed by the
        model's ``input_delay``; the controller is called with the true base state.
        """
        if not duration > 0:
            raise ValueError(f"duration: must be > 0, got {duration}")
        session = self.session(x0)
        with tqdm(total=duration, unit="sim s", disable=not progress, leave=False) as bar:
            for t in np.arange(0.0, duration, 1.0 / control_rate_hz):
                session.advance(t)
                session.command(controller(t, session.base_state))
                bar.n = t
                bar.refresh()
            session.advance(duration)
        return session.result()


class _SensorClock:
    """Acquisition times of one sensor: a regular grid plus jitter, generated as needed."""

    def __init__(self, spec: SensorSpec, phase: float, rng: np.random.Generator) -> None:
        self.period, self.phase, self.jitter, self.rng = (
            1.0 / spec.rate_hz,
            phase,
            spec.jitter_std_s,
            rng,
        )
        self.k = 0
        self.last = -np.inf

    def next(self) -> float:
        t = self.phase + self.k * self.period
        if self.jitter > 0:
            t += self.rng.normal(0.0, self.jitter)
        self.k += 1
        self.last = max(t, self.last + 1e-9, 0.0)
        return self.last


class SimulationSession:
    """A simulation in progress: issue commands, advance time, collect measurements.

    Events between calls are handled in time order: application of (delayed) commands first,
    then sensor acquisitions. A command takes effect at the time it is issued (plus the model's
    input delay); a sensor sample at exactly that time already sees it.
    """

    def __init__(self, simulator: Simulator, x0: np.ndarray, keep_history: bool = True) -> None:
        self.simulator = simulator
        self.keep_history = keep_history
        model, sensors, seed = simulator.model, simulator.sensors, simulator.seed
        self._numeric = model.numeric
        self._p = model.parameters.vector()
        self._delay = model.input_delay()
        self._x = model.initial_state(np.asarray(x0, dtype=float))
        self._u = np.zeros(2)
        self._now = 0.0
        self._heap: list[tuple[float, int, int, object]] = []
        self._counter = 0
        names = ["imu", "wheel_encoders"] + (["pose"] if sensors.pose is not None else [])
        phases = dict.fromkeys(names, 0.0)
        rate = sensors.lighthouse.rate_hz
        for station in range(model.n_base_stations):
            for plane in (1, 2):
                name = lighthouse_sensor(station, plane)
                names.append(name)
                phases[name] = (plane - 1) * 0.5 / rate + station * 0.13 / rate
        self._clocks = {
            n: _SensorClock(sensors.spec(n), phases[n], _rng(seed, n + "/time")) for n in names
        }
        self._rngs = {n: _rng(seed, n) for n in names}
        self._noise = {n: np.array(sensors.spec(n).noise_std) for n in names}
        self._bias = {
            n: np.array(sensors.spec(n).bias or np.zeros(self._noise[n].size)) for n in names
        }
        for name, clock in self._clocks.items():
            self._push(clock.next(), _SENSOR, name)
        self.truth_t: list[float] = [0.0]
        self.truth_x: list[np.ndarray] = [self._x[:6].copy()]
        self.inputs: list[InputSample] = []
        self.measurements: list[Measurement] = []

    @property
    def time(self) -> float:
        """Current simulation time, s."""
        return self._now

    @property
    def base_state(self) -> np.ndarray:
        """True ``[x, y, yaw, vx, vy, omega]`` now."""
        return self._x[:6].copy()

    @property
    def applied_command(self) -> np.ndarray:
        """The command acting on the car now (after any input delay)."""
        return self._u.copy()

    def _push(self, t: float, kind: int, payload: object) -> None:
        heapq.heappush(self._heap, (t, kind, self._counter, payload))
        self._counter += 1

    def command(self, u: np.ndarray) -> InputSample:
        """Issue command ``[steer, torque]`` now (validated); returns the logged sample."""
        sample = InputSample(self._now, np.asarray(u, dtype=float))
        if self.keep_history:
            self.inputs.append(sample)
        if self._delay > 0:
            self._push(self._now + self._delay, _APPLY, sample.u)
        else:
            self._u = sample.u
        return sample

    def advance(self, t: float) -> list[Measurement]:
        """Run every event before ``t`` and integrate to ``t``; returns the new measurements."""
        if t < self._now:
            raise ValueError(f"t: cannot go back in time ({t} < {self._now})")
        new: list[Measurement] = []
        while self._heap and self._heap[0][0] < t:
            event_time, kind, _, payload = heapq.heappop(self._heap)
            self._integrate_to(event_time)
            if kind == _APPLY:
                self._u = payload
            else:
                measurement = self._acquire(payload)
                self._push(self._clocks[payload].next(), _SENSOR, payload)
                if measurement is not None:
                    new.append(measurement)
        self._integrate_to(t)
        new.sort(key=lambda m: (m.stamp, m.sensor))
        if self.keep_history:
            self.measurements.extend(new)
        return new

    def _integrate_to(self, t: float) -> None:
        if t > self._now:
            self._x = self._numeric.step(self._x, self._u, self._p, t - self._now)
            self._now = t
            if not self.keep_history:  # only the current state
                self.truth_t.clear()
                self.truth_x.clear()
            self.truth_t.append(t)
            self.truth_x.append(self._x[:6].copy())

    def _acquire(self, name: str) -> Measurement | None:
        """One sample of sensor ``name`` now, or None if it is lost."""
        sensors = self.simulator.sensors
        spec, rng = sensors.spec(name), self._rngs[name]
        # draw every sample's randomness, so drop-outs do not shift later noise
        dropped = rng.random() < spec.dropout_probability
        values = self._numeric.outputs(self._x, self._u, self._p)[name]
        values = values + self._bias[name] + self._noise[name] * rng.standard_normal(values.size)
        if dropped or sensors.blacked_out(name, self._now) or not _in_view(name, values):
            return None
        return Measurement(self._now + spec.latency_s, name, values)

    def result(self) -> SimulationResult:
        """Everything so far as a :class:`SimulationResult` (duration = current time)."""
        return SimulationResult(
            model=self.simulator.model,
            sensors=self.simulator.sensors,
            seed=self.simulator.seed,
            duration=self._now,
            truth_t=np.array(self.truth_t),
            truth_x=np.array(self.truth_x),
            inputs=list(self.inputs),
            measurements=sorted(self.measurements, key=lambda m: (m.stamp, m.sensor)),
        )
