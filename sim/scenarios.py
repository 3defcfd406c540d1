"""Standard driving scenarios for tests and benchmarks."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from crs_core.control.path_following import PathFollower, PathFollowerSettings
from crs_core.dataset import Dataset
from crs_core.errors import FieldError
from crs_core.model import CarModel
from crs_core.track import Track, load_demo_track

if TYPE_CHECKING:
    from sim.drift import DriftSchedule
    from sim.sensors import SensorSuite
    from sim.simulator import SimulationResult


class SmoothNoise:
    """Band-limited random signal: a sum of sinusoids with random frequency and phase.

    ``std`` is the signal's standard deviation; frequencies are uniform in ``band`` (Hz).
    """

    def __init__(self, rng: np.random.Generator, std: float, band=(0.2, 2.0), terms: int = 8):
        self.frequencies = rng.uniform(*band, terms) * 2 * np.pi
        self.phases = rng.uniform(0, 2 * np.pi, terms)
        self.amplitude = std * np.sqrt(2.0 / terms)

    def __call__(self, t: float) -> float:
        return float(self.amplitude * np.sin(self.frequencies * t + self.phases).sum())


class JoystickDriver:
    """A human-like driver: follows the track with jittery steering and throttle.

    Pure pursuit at ``v_ref`` plus band-limited steering noise (rad) and a relative throttle
    noise, like a person with a joystick. The inputs it produced are what an estimator is fed
    as the open-loop input record.
    """

    def __init__(
        self,
        track: Track,
        wheelbase: float,
        seed: int,
        v_ref: float = 1.3,
        steer_noise: float = 0.05,
        throttle_noise: float = 0.25,
    ) -> None:
        rng = np.random.default_rng([seed, 7])
        settings = PathFollowerSettings(v_ref=v_ref, a_lat_max=4.0, lookahead_min=0.15)
        self.follower = PathFollower(track, wheelbase, settings)
        self.steer_noise = SmoothNoise(rng, steer_noise)
        self.throttle_noise = SmoothNoise(rng, throttle_noise, band=(0.1, 1.0))

    def __call__(self, t: float, x: np.ndarray) -> np.ndarray:
        steer, torque = self.follower(t, x)
        steer = np.clip(steer + self.steer_noise(t), -0.34, 0.34)
        torque = np.clip(torque * (1 + self.throttle_noise(t)), 0.0, 1.0)
        return np.array([steer, torque])


#: Drivers of :func:`simulate_dataset`.
DRIVERS = ("path", "joystick")
#: Process-noise scale of an FIE on data from :func:`simulate_dataset`: the simulated truth has
#: no process noise, so the fit may trust the model more than on real data (whose default is 1).
SIM_PROCESS_SCALE = 0.1


def simulate_dataset(
    duration: float,
    seed: int,
    model: CarModel | None = None,
    driver: str = "path",
    sensors: SensorSuite | None = None,
    drift: DriftSchedule | None = None,
) -> Dataset:
    """A closed-loop simulated dataset on DEMO_TRACK (truth: ``model``, default Chronos, changed
    over time by ``drift``; ``sensors``, default :class:`~sim.sensors.SensorSuite`).

    ``driver``: ``"path"`` the path follower at 1 m/s, ``"joystick"`` a
    :class:`JoystickDriver` (jittery steering and throttle, 1.3 m/s, seeded by ``seed``).
    """
    from sim.sensors import SensorSuite
    from sim.simulator import Simulator

    if driver not in DRIVERS:
        raise FieldError("driver", f"one of {DRIVERS}, got {driver!r}")
    model = model or CarModel()
    track = load_demo_track()
    wheelbase = model.parameters.value("lf") + model.parameters.value("lr")
    if driver == "path":
        controller = PathFollower(track, wheelbase, PathFollowerSettings(v_ref=1.0))
    else:
        controller = JoystickDriver(track, wheelbase, seed)
    x0 = track.start_state()
    simulator = Simulator(model, sensors or SensorSuite(), seed=seed, drift=drift)
    return simulator.run(controller, duration, x0).to_dataset()


def standard_drive(seed: int, duration: float = 20.0, blackouts=()) -> SimulationResult:
    """The standard open-loop drive: joystick-like inputs on DEMO_TRACK, default sensor noise."""
    from sim.sensors import SensorSuite
    from sim.simulator import Simulator

    track = load_demo_track()
    model = CarModel()
    wheelbase = model.parameters.value("lf") + model.parameters.value("lr")
    x0 = track.start_state()
    simulator = Simulator(model, SensorSuite(blackouts=tuple(blackouts)), seed=seed)
    return simulator.run(JoystickDriver(track, wheelbase, seed), duration, x0)
