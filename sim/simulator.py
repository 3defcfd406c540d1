"""Event-driven simulation of the Chronos car with its sensors at their own rates.

Truth is the :class:`~crs_core.model.CarModel` (optionally with effects) integrated exactly
between events with RK4 substeps of at most :data:`~crs_core.model.MAX_SUBSTEP`. Events are
controller ticks, application of delayed commands, and sensor acquisitions. The controller sees
the true base state (the closed-loop runner with an estimator in the loop comes with the
estimators). Everything random is drawn from generators seeded by ``(seed, sensor name)``, so a
run is reproducible and changing one sensor's settings does not reshuffle another's noise.
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
from sim.sensors import SensorSuite, sample_times

Controller = Callable[[float, np.ndarray], np.ndarray]

# event kinds, in the order they are handled at equal times
_APPLY, _CONTROL, _SENSOR = 0, 1, 2


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
        self._p = model.parameters.vector()

    def _schedule(self, duration: float) -> list[tuple[float, str]]:
        """Acquisition times of every sensor sample."""
        events = []
        for name in ("imu", "wheel_encoders", "pose"):
            if name == "pose" and self.sensors.pose is None:
                continue
            spec = self.sensors.spec(name)
            times = sample_times(spec, duration, 0.0, _rng(self.seed, name + "/time"))
            events += [(t, name) for t in times]
        spec = self.sensors.lighthouse
        for station in range(self.model.n_base_stations):
            for plane in (1, 2):
                name = lighthouse_sensor(station, plane)
                phase = (plane - 1) * 0.5 / spec.rate_hz + station * 0.13 / spec.rate_hz
                times = sample_times(spec, duration, phase, _rng(self.seed, name + "/time"))
                events += [(t, name) for t in times]
        return events

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
        numeric = self.model.numeric
        delay = self.model.input_delay()
        x = self.model.initial_state(x0)
        u_active = np.zeros(2)
        heap: list[tuple[float, int, int, object]] = []
        counter = 0
        schedule = self._schedule(duration)
        for t, name in schedule:
            heap.append((t, _SENSOR, counter, name))
            counter += 1
        for t in np.arange(0.0, duration, 1.0 / control_rate_hz):
            heap.append((t, _CONTROL, counter, None))
            counter += 1
        heapq.heapify(heap)
        rngs = {name: _rng(self.seed, name) for name in sorted({n for _, n in schedule})}
        noise = {name: np.array(self.sensors.spec(name).noise_std) for name in rngs}
        bias = {
            name: np.array(self.sensors.spec(name).bias or np.zeros(noise[name].size))
            for name in rngs
        }
        truth_t, truth_x = [0.0], [x[:6].copy()]
        inputs: list[InputSample] = []
        measurements: list[Measurement] = []
        now = 0.0
        bar = tqdm(total=duration, unit="sim s", disable=not progress, leave=False)
        while heap:
            t, kind, _, payload = heapq.heappop(heap)
            if t >= duration:
                continue
            if t > now:
                x = numeric.step(x, u_active, self._p, t - now)
                bar.update(t - now)
                now = t
                truth_t.append(now)
                truth_x.append(x[:6].copy())
            if kind == _CONTROL:
                u = np.asarray(controller(now, x[:6].copy()), dtype=float)
                sample = InputSample(now, u)
                inputs.append(sample)
                if delay > 0:
                    heapq.heappush(heap, (now + delay, _APPLY, counter, sample.u))
                    counter += 1
                else:
                    u_active = sample.u
            elif kind == _APPLY:
                u_active = payload
            else:
                name = payload
                spec = self.sensors.spec(name)
                rng = rngs[name]
                # draw every sample's randomness, so drop-outs do not shift later noise
                dropped = rng.random() < spec.dropout_probability
                values = numeric.outputs(x, u_active, self._p)[name]
                values = values + bias[name] + noise[name] * rng.standard_normal(values.size)
                if dropped or self.sensors.blacked_out(name, now) or not _in_view(name, values):
                    continue
                measurements.append(Measurement(now + spec.latency_s, name, values))
        bar.close()
        measurements.sort(key=lambda m: (m.stamp, m.sensor))
        return SimulationResult(
            model=self.model,
            sensors=self.sensors,
            seed=self.seed,
            duration=duration,
            truth_t=np.array(truth_t),
            truth_x=np.array(truth_x),
            inputs=inputs,
            measurements=measurements,
        )
