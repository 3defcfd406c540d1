"""The scenario building blocks: band-limited noise of the asked standard deviation, and the
joystick driver's inputs within the car's limits."""

from __future__ import annotations

import numpy as np
import pytest

from crs_core.track import load_demo_track
from sim.scenarios import JoystickDriver, SmoothNoise


def test_smooth_noise_has_its_std_and_its_band() -> None:
    noise = SmoothNoise(np.random.default_rng(4), std=0.3, band=(0.2, 2.0), terms=8)
    assert np.all((noise.frequencies >= 2 * np.pi * 0.2) & (noise.frequencies <= 2 * np.pi * 2.0))
    t = np.arange(0.0, 5000.0, 0.05)
    values = np.array([noise(tk) for tk in t])
    # a sum of 8 sinusoids of amplitude a has variance 8 a^2 / 2 over a long time
    assert np.std(values) == pytest.approx(0.3, rel=0.03)
    assert abs(np.mean(values)) < 0.01
    # band-limited: the largest step over 50 ms is at most a * sum(w) * 50 ms
    bound = noise.amplitude * noise.frequencies.sum() * 0.05
    assert np.max(np.abs(np.diff(values))) <= bound


def test_the_same_generator_state_gives_the_same_signal() -> None:
    a = SmoothNoise(np.random.default_rng(9), std=1.0)
    b = SmoothNoise(np.random.default_rng(9), std=1.0)
    c = SmoothNoise(np.random.default_rng(10), std=1.0)
    assert [a(t) for t in (0.0, 1.3, 7.0)] == [b(t) for t in (0.0, 1.3, 7.0)]
    assert a(1.3) != c(1.3)


def test_the_joystick_driver_stays_within_the_steering_and_torque_limits() -> None:
    track = load_demo_track()
    driver = JoystickDriver(track, wheelbase=0.09, seed=2, steer_noise=2.0, throttle_noise=5.0)
    start = np.array([track.x[0], track.y[0], track.heading[0], 0.5, 0.0, 0.0])
    inputs = np.array([driver(t, start) for t in np.arange(0.0, 20.0, 0.02)])
    assert np.all(np.abs(inputs[:, 0]) <= 0.34)
    assert np.all((inputs[:, 1] >= 0.0) & (inputs[:, 1] <= 1.0))
    assert np.any(inputs[:, 0] == 0.34) and np.any(inputs[:, 0] == -0.34)  # the noise saturates
    same = JoystickDriver(track, wheelbase=0.09, seed=2, steer_noise=2.0, throttle_noise=5.0)
    np.testing.assert_array_equal(same(3.0, start), driver(3.0, start))
