"""What a simulation run produced (:class:`SimulationResult`) and its dataset."""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from crs_core.dataset import Y_CHANNELS, Dataset, Geometry
from crs_core.measurements import InputSample, Measurement, lighthouse_sensor
from crs_core.model import CarModel
from sim.onboard import dataset_inputs
from sim.sensors import SensorSuite


@dataclass
class SimulationResult:
    """What a run produced: truth, commanded inputs and the measurement stream (by stamp).

    ``inputs`` are the commands as issued (with the onboard loop: the references, their modes
    in ``reference_modes``); ``applied_inputs`` the ``[delta, T]`` the onboard loop applied
    (from each reference's application and each tick; empty without the loop).
    """

    model: CarModel
    sensors: SensorSuite
    seed: int
    duration: float
    truth_t: np.ndarray
    truth_x: np.ndarray
    inputs: list[InputSample]
    measurements: list[Measurement]
    extra_meta: dict = field(default_factory=dict)
    applied_inputs: list[InputSample] = field(default_factory=list)
    reference_modes: list[str] = field(default_factory=list)

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

    def applied_input_at(self, t: np.ndarray) -> np.ndarray:
        """Input ``[delta, T]`` reaching the car model at times ``t``, shape ``(len(t), 2)``.

        With the onboard loop its applied input; without, the command delayed by the model's
        input delay. (The model's own actuator effects act after this.)
        """
        if not self.applied_inputs:
            return self.input_at(np.asarray(t, dtype=float) - self.model.input_delay())
        stamps = np.array([s.stamp for s in self.applied_inputs])
        values = np.stack([s.u for s in self.applied_inputs])
        index = np.clip(np.searchsorted(stamps, t, side="right") - 1, 0, len(stamps) - 1)
        return values[index]

    def truth_at(self, t: np.ndarray) -> np.ndarray:
        """True base state at times ``t`` (linear interpolation of the dense truth)."""
        return np.stack([np.interp(t, self.truth_t, self.truth_x[:, i]) for i in range(6)], axis=1)

    def to_dataset(self) -> Dataset:
        """Samples at the stamps of station 0's second-plane sweeps, like the real recordings.

        A sample holds the sweep pair of one rotation (both planes present), wheel speeds and yaw
        rate linearly interpolated to the stamp, the commanded input and the true state. With
        the onboard loop in velocity mode the input's torque is the loop's
        (:func:`sim.onboard.dataset_inputs`).
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
        inputs = self.inputs
        if self.reference_modes:
            inputs = dataset_inputs(self.inputs, self.reference_modes, self.applied_inputs)
        sampled = replace(self, inputs=inputs) if inputs is not self.inputs else self
        return Dataset(
            t=stamps_arr,
            u=sampled.input_at(stamps_arr) if stamps_arr.size else np.zeros((0, 2)),
            y=y,
            x=self.truth_at(stamps_arr) if stamps_arr.size else np.zeros((0, 6)),
            geometry=Geometry.from_parameters(self.model.parameters, self.model.n_base_stations),
            meta=meta,
            measurements=self.measurements,
            inputs=inputs,
            truth_t=self.truth_t,
            truth_x=self.truth_x,
        )
