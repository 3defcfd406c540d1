"""Step responses of the onboard low-level loops (steering on its actuator, velocity on the car).

``python -m sim.step_response`` prints the figures of the default settings as JSON: the steering
loop on the actuator model (0.3 rad step, ideal and noisy potentiometer) and the velocity loop
on the Chronos model in the simulator (0 -> 1 m/s and 1 -> 1.5 m/s, ideal and default sensors).
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass

import numpy as np

from crs_core.control.low_level import SteeringController
from crs_core.errors import FieldError
from sim.actuators import SteeringActuator
from sim.onboard import OnboardSettings


@dataclass(frozen=True)
class StepResponse:
    """Figures of a step from ``start`` to ``target``.

    Attributes
    ----------
    rise_time : float
        10 % to 90 % of the step, s.
    time_to_90 : float
        From the step to 90 %, s.
    overshoot : float
        Largest excursion beyond the target as a fraction of the step (>= 0).
    settling_time : float
        Last time outside +-2 % of the step, s (the end if never settled).
    steady_state_error : float
        Mean of ``target - y`` over the last ``tail`` s, in the output's unit.
    """

    rise_time: float
    time_to_90: float
    overshoot: float
    settling_time: float
    steady_state_error: float


def step_metrics(
    t: np.ndarray, y: np.ndarray, start: float, target: float, tail: float = 0.2
) -> StepResponse:
    """:class:`StepResponse` of samples ``y`` at times ``t`` (step at ``t = 0``)."""
    t, y = np.asarray(t, dtype=float), np.asarray(y, dtype=float)
    fraction = (y - start) / (target - start)
    if not np.any(fraction >= 0.9):
        raise FieldError("y", "never reaches 90 % of the step")
    t10, t90 = t[np.argmax(fraction >= 0.1)], t[np.argmax(fraction >= 0.9)]
    outside = np.nonzero(np.abs(fraction - 1) > 0.02)[0]
    settle = t[min(outside[-1] + 1, t.size - 1)] if outside.size else t[0]
    last = t >= t[-1] - tail
    return StepResponse(
        rise_time=float(t90 - t10),
        time_to_90=float(t90),
        overshoot=float(max(0.0, fraction.max() - 1)),
        settling_time=float(settle),
        steady_state_error=float(target - np.mean(y[last])),
    )


def steering_step(
    settings: OnboardSettings | None = None,
    step: float = 0.3,
    start: float = 0.0,
    duration: float = 1.0,
    seed: int = 0,
) -> tuple[np.ndarray, np.ndarray]:
    """Actuator angle (rad) at each tick after a steering reference step, car not involved.

    The loop of :class:`~sim.onboard.OnboardLoop` (advance the actuator, read the
    potentiometer, run the PID) from rest at ``start``; returns ``(t, angle)``.
    """
    settings = settings or OnboardSettings()
    controller = SteeringController(settings.steering)
    actuator = SteeringActuator(settings.actuator, angle=start)
    rng = np.random.default_rng(seed)
    period = 1.0 / settings.rate_hz
    n = round(duration * settings.rate_hz)
    angles, command = np.empty(n), 0.0
    for k in range(n):
        actuator.advance(period, command)
        voltage = settings.potentiometer.read(actuator.angle, rng)
        command = controller.step(start + step, voltage)
        angles[k] = actuator.angle
    return np.arange(1, n + 1) * period, angles


def velocity_step(
    settings: OnboardSettings | None = None,
    start: float = 0.0,
    target: float = 1.0,
    duration: float = 3.0,
    ideal_sensors: bool = True,
    seed: int = 0,
):
    """Simulated run of the Chronos car straight ahead under a velocity reference step.

    Returns the :class:`~sim.result.SimulationResult` (truth ``v_x`` in ``truth_x[:, 3]``).
    """
    from crs_core.model import CarModel
    from sim.sensors import SensorSuite
    from sim.simulator import Simulator

    sensors = SensorSuite().ideal() if ideal_sensors else SensorSuite()
    simulator = Simulator(CarModel(), sensors, seed, onboard=settings or OnboardSettings())
    reference = np.array([0.0, target])
    x0 = np.array([0.0, 0.0, 0.0, start, 0.0, 0.0])
    return simulator.run(lambda t, x: reference, duration, x0, mode="velocity")


def main() -> None:
    """Print the default loops' step responses as JSON."""
    figures = {}
    for name, settings in (
        ("ideal", OnboardSettings().ideal()),
        ("noisy", OnboardSettings()),
    ):
        t, angle = steering_step(settings, duration=1.0)
        figures[f"steering 0 -> 0.3 rad, {name} potentiometer"] = asdict(
            step_metrics(t, angle, 0.0, 0.3)
        )
    for start, target in ((0.0, 1.0), (1.0, 1.5)):
        for ideal in (True, False):
            result = velocity_step(start=start, target=target, ideal_sensors=ideal)
            key = f"velocity {start} -> {target} m/s, {'ideal' if ideal else 'default'} sensors"
            metrics = step_metrics(result.truth_t, result.truth_x[:, 3], start, target, tail=1.0)
            figures[key] = asdict(metrics)
    rounded = {k: {n: round(v, 5) for n, v in f.items()} for k, f in figures.items()}
    print(json.dumps(rounded, indent=2))


if __name__ == "__main__":
    main()
