r"""The car's onboard firmware loop in the simulator: steering and velocity PIDs at 250 Hz.

With ``Simulator(..., onboard=OnboardSettings())`` a command is a *reference* for the car's
low-level controllers (paper Sec. VI-B), as on the real car:

* ``mode="torque"``: ``[delta_ref, T]``; the torque goes to the motor driver as it arrives,
  the steering angle is tracked by the steering PID;
* ``mode="velocity"``: ``[delta_ref, v_x_ref]``; the torque comes from the velocity PID on the
  rear wheel speeds.

Each 250 Hz tick (at ``k / rate_hz``) the loop advances the steering actuator
(:class:`~sim.actuators.SteeringActuator`) under the motor command of the previous tick, reads
the potentiometer (map, noise, ADC) and the wheel speeds (the car model's ``wheel_encoders``
output with the sensor suite's noise and bias, drawn from the loop's own random streams), runs
the PIDs and sets the applied input ``[actuator angle, T]``, held until the next tick. The car
model's command effects (offset, lags, ...) act on this applied input, after the loop.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field

import numpy as np

from crs_core.control.low_level import (
    SteeringController,
    SteeringSettings,
    VelocityController,
    VelocitySettings,
)
from crs_core.errors import FieldError
from crs_core.measurements import InputSample
from crs_core.settings import Settings, positive
from sim.actuators import (
    PotentiometerSettings,
    SteeringActuator,
    SteeringActuatorSettings,
)

#: Reference modes of a command: ``[delta, T]`` or ``[delta, v_x]``.
MODES = ("torque", "velocity")


@dataclass(frozen=True)
class OnboardSettings(Settings):
    """The simulated car's low-level loop: controllers, steering actuator, potentiometer.

    Attributes
    ----------
    steering : SteeringSettings
        Steering PID and the firmware's potentiometer calibration.
    velocity : VelocitySettings
        Velocity PID, the firmware's wheel radius and feedforward.
    actuator : SteeringActuatorSettings
        The steering motor (truth).
    potentiometer : PotentiometerSettings
        The potentiometer as the ADC reads it (truth: its own map, noise, resolution).
    rate_hz : float
        Loop rate, Hz (> 0); both PIDs must be set to it. Default 250.
    """

    steering: SteeringSettings = field(default_factory=SteeringSettings)
    velocity: VelocitySettings = field(default_factory=VelocitySettings)
    actuator: SteeringActuatorSettings = field(default_factory=SteeringActuatorSettings)
    potentiometer: PotentiometerSettings = field(default_factory=PotentiometerSettings)
    rate_hz: float = positive(250.0)

    def _check_relations(self) -> None:
        kinds = {
            "steering": SteeringSettings,
            "velocity": VelocitySettings,
            "actuator": SteeringActuatorSettings,
            "potentiometer": PotentiometerSettings,
        }
        for name, kind in kinds.items():
            if not isinstance(getattr(self, name), kind):
                raise FieldError(name, f"must be a {kind.__name__}, got {getattr(self, name)!r}")
        rate = self.rate_hz
        for name in ("steering", "velocity"):
            pid_rate = getattr(self, name).pid.rate_hz
            if pid_rate != rate:
                raise FieldError(
                    f"{name}.pid.rate_hz", f"must equal the loop's rate_hz ({rate}), got {pid_rate}"
                )

    def ideal(self) -> OnboardSettings:
        """The same loop with a noise-free, unquantised potentiometer."""
        return OnboardSettings(
            self.steering, self.velocity, self.actuator, self.potentiometer.ideal(), self.rate_hz
        )

    def to_dict(self) -> dict:
        """Plain values (for a dataset's metadata)."""
        return asdict(self)


class OnboardLoop:
    """State of the firmware loop: references, PIDs, steering actuator, applied input.

    Parameters
    ----------
    settings : OnboardSettings
        The loop and the actuator.
    wheel_noise_std, wheel_bias : array (4,)
        Noise standard deviation and bias of the wheel speeds the loop reads, rad/s.
    potentiometer_rng, wheel_rng : numpy.random.Generator
        The loop's own random streams (so it does not disturb the sensors' noise).
    """

    def __init__(
        self,
        settings: OnboardSettings,
        wheel_noise_std: np.ndarray,
        wheel_bias: np.ndarray,
        potentiometer_rng: np.random.Generator,
        wheel_rng: np.random.Generator,
    ) -> None:
        self.settings = settings
        self.period = 1.0 / settings.rate_hz
        self.steering = SteeringController(settings.steering)
        self.velocity = VelocityController(settings.velocity)
        self.actuator = SteeringActuator(settings.actuator)
        self._wheel_noise = np.asarray(wheel_noise_std, dtype=float)
        self._wheel_bias = np.asarray(wheel_bias, dtype=float)
        self._pot_rng, self._wheel_rng = potentiometer_rng, wheel_rng
        self.reference = np.zeros(2)
        self.mode = "torque"
        self.motor_command = 0.0
        self.applied = np.zeros(2)
        self.ticks = 0
        self._last_tick: float | None = None

    def next_tick(self) -> float:
        """Time of the next tick, s (``ticks / rate_hz``)."""
        return self.ticks * self.period

    def set_reference(self, u: np.ndarray, mode: str) -> np.ndarray:
        """New reference (takes effect now); returns the applied input.

        A torque reaches the motor at once; a velocity reference waits for the next tick.
        Switching to velocity mode starts the velocity PID afresh.
        """
        if mode not in MODES:
            raise FieldError("mode", f"must be one of {', '.join(MODES)}, got {mode!r}")
        if mode == "velocity" and self.mode != "velocity":
            self.velocity.reset()
        self.reference, self.mode = np.array(u, dtype=float), mode
        if mode == "torque":
            self.applied = np.array([self.applied[0], self.reference[1]])
        return self.applied.copy()

    def tick(self, t: float, wheel_speeds: np.ndarray) -> np.ndarray:
        """Run the loop at time ``t`` with the true wheel speeds (rad/s); the applied input."""
        if self._last_tick is not None:
            self.actuator.advance(t - self._last_tick, self.motor_command)
        self._last_tick = t
        self.ticks += 1
        voltage = self.settings.potentiometer.read(self.actuator.angle, self._pot_rng)
        self.motor_command = self.steering.step(self.reference[0], voltage)
        if self.mode == "velocity":
            measured = (
                np.asarray(wheel_speeds, dtype=float)
                + self._wheel_bias
                + self._wheel_noise * self._wheel_rng.standard_normal(4)
            )
            torque = self.velocity.step(self.reference[1], measured)
        else:
            torque = self.reference[1]
        self.applied = np.array([self.actuator.angle, torque])
        return self.applied.copy()


def dataset_inputs(
    references: list[InputSample], modes: list[str], applied: list[InputSample]
) -> list[InputSample]:
    """Inputs ``[delta, T]`` for a dataset of a run with the onboard loop.

    In torque mode the references themselves (the commands a recording holds; the actuator is
    hidden truth). From the first velocity reference on, ``[delta_ref, T]`` at every tick with
    ``T`` the velocity loop's torque (what the car reports), since a velocity is no torque.
    """
    first = next((i for i, m in enumerate(modes) if m == "velocity"), None)
    if first is None or not applied:
        return list(references)
    start = references[first].stamp
    stamps = np.array([s.stamp for s in references])
    samples = list(references[:first])
    for sample in applied:
        if sample.stamp < start:
            continue
        k = int(np.searchsorted(stamps, sample.stamp, side="right") - 1)
        samples.append(InputSample(sample.stamp, np.array([references[k].u[0], sample.u[1]])))
    return samples
