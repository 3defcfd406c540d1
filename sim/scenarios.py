"""Standard driving scenarios for tests and benchmarks."""

from __future__ import annotations

import numpy as np

from crs_core.control.path_following import PathFollower, PathFollowerSettings
from crs_core.track import Track


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
