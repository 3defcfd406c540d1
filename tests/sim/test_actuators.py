"""The steering actuator (exact steps of the motor model, the end stop, the deadband) and the
potentiometer (the map, ADC quantisation, noise)."""

from __future__ import annotations

import numpy as np
import pytest

from crs_core.control.low_level import PotentiometerMap
from crs_core.errors import FieldError
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


def test_settings_word_their_errors_as_every_settings_class_and_store_floats():
    with pytest.raises(FieldError, match=r"^no_load_speed: must be a finite number > 0, got -1$"):
        SteeringActuatorSettings(no_load_speed=-1)
    with pytest.raises(FieldError, match=r"^deadband: must be within \[0, 1\), got 1$"):
        SteeringActuatorSettings(deadband=1)
    with pytest.raises(FieldError, match=r"^adc_bits: must be within \[0, 24\], got 25$"):
        PotentiometerSettings(adc_bits=25)
    with pytest.raises(FieldError, match=r"^adc_bits: must be an integer, got True$"):
        PotentiometerSettings(adc_bits=True)
    actuator = SteeringActuatorSettings(no_load_speed=7, deadband=0, limit=np.float32(0.25))
    assert {type(value) for value in vars(actuator).values()} == {float}
    potentiometer = PotentiometerSettings(noise_std=0, adc_bits=np.int64(10), adc_reference=5)
    assert (type(potentiometer.noise_std), type(potentiometer.adc_reference)) == (float, float)
    assert potentiometer.adc_bits == 10 and not isinstance(potentiometer.adc_bits, float)
