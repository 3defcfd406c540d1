"""The steering actuator (exact steps of the motor model, the end stop, the deadband) and the
potentiometer (the map, ADC quantisation, noise)."""

from __future__ import annotations

import numpy as np
import pytest

from crs_core.control.low_level import PotentiometerMap
from sim.actuators import PotentiometerSettings, SteeringActuator, SteeringActuatorSettings


def test_actuator_exact_step_matches_fine_integration_and_stops_at_the_limit():
    settings = SteeringActuatorSettings()
    exact = SteeringActuator(settings)
    exact.rate = 1.0
    exact.advance(0.02, 0.5)
    # explicit Euler with 1e-6 s steps of theta'' = (w0 u_eff - theta') / tau
    angle, rate = 0.0, 1.0
    for _ in range(20000):
        accel = (settings.no_load_speed * (0.5 - settings.deadband) - rate) / settings.time_constant
        angle, rate = angle + 1e-6 * rate, rate + 1e-6 * accel
    assert exact.angle == pytest.approx(angle, rel=1e-4)
    assert exact.rate == pytest.approx(rate, rel=1e-4)
    for _ in range(100):
        exact.advance(0.004, 1.0)
    assert exact.angle == settings.limit and exact.rate == 0.0
    held = SteeringActuator(settings, angle=0.1)
    held.advance(0.1, settings.deadband * 0.9)  # inside the deadband: does not move
    assert held.angle == 0.1


def test_potentiometer_reads_the_map_and_quantises():
    ideal = PotentiometerSettings().ideal()
    assert ideal.read(0.2) == pytest.approx(PotentiometerMap().voltage(0.2), abs=1e-15)
    adc = PotentiometerSettings(noise_std=0.0)
    lsb = 3.3 / 4095
    value = adc.read(0.2)
    assert value / lsb == pytest.approx(round(value / lsb), abs=1e-9)
    assert abs(value - ideal.read(0.2)) <= lsb / 2 + 1e-12
    noisy = PotentiometerSettings(adc_bits=0)
    rng = np.random.default_rng(3)
    reads = np.array([noisy.read(0.0, rng) for _ in range(4000)])
    assert np.std(reads) == pytest.approx(0.002, rel=0.05)
