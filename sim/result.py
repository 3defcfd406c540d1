"""What a simulation run produced (:class:`SimulationResult`) and its dataset."""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from crs_core.dataset import Dataset, Geometry
from crs_core.measurements import InputSample, Measurement, lighthouse_sensor
from crs_core.model import CarModel
from crs_core.stream_samples import held_at, readings, sample_stream
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
        return readings(self.measurements, sensor)

    def input_at(self, t: np.ndarray) -> np.ndarray:
        """Commanded input (zero-order hold) at times ``t``, shape ``(len(t), 2)``."""
        return held_at(self.inputs, t)

    def applied_input_at(self, t: np.ndarray) -> np.ndarray:
        """Input ``[delta, T]`` reaching the car model at times ``t``, shape ``(len(t), 2)``.

        With the onboard loop its applied input; without, the command delayed by the model's
        input delay. (The model's own actuator effects act after this.)
        """
        if not self.applied_inputs:
            return self.input_at(np.asarray(t, dtype=float) - self.model.input_delay())
        return held_at(self.applied_inputs, t)

    def truth_at(self, t: np.ndarray) -> np.ndarray:
        """True base state at times ``t`` (linear interpolation of the dense truth)."""
        return np.stack([np.interp(t, self.truth_t, self.truth_x[:, i]) for i in range(6)], axis=1)

    def to_dataset(self) -> Dataset:
        """Samples at the stamps of station 0's second-plane sweeps, like the real recordings.

        A sample holds the sweep pair of one rotation (both planes present), wheel speeds and yaw
        rate linearly interpolated to the stamp (:func:`crs_core.stream_samples.sample_stream`,
        with the simulated sensors' rates), the commanded input and the true state. With
        the onboard loop in velocity mode the input's torque is the loop's
        (:func:`sim.onboard.dataset_inputs`).
        """
        periods = {
            sensor: 1.0 / self.sensors.spec(sensor).rate_hz for sensor in ("wheel_encoders", "imu")
        }
        periods[lighthouse_sensor(0, 2)] = 1.0 / self.sensors.lighthouse.rate_hz
        samples = sample_stream(self.measurements, periods)
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
        t = samples.t
        return Dataset(
            t=t,
            u=sampled.input_at(t) if t.size else np.zeros((0, 2)),
            y=samples.y,
            x=self.truth_at(t) if t.size else np.zeros((0, 6)),
            geometry=Geometry.from_parameters(self.model.parameters, self.model.n_base_stations),
            meta=meta,
            measurements=self.measurements,
            inputs=inputs,
            truth_t=self.truth_t,
            truth_x=self.truth_x,
        )
