"""Tests of crs_core.control.low_level: PID law, anti-windup, potentiometer map, settings."""

from __future__ import annotations

import numpy as np
import pytest

from crs_core.control.low_level import (
    PID,
    MotorFeedforward,
    PIDSettings,
    PotentiometerMap,
    SteeringController,
    SteeringSettings,
    VelocityController,
    VelocitySettings,
    rear_axle_speed,
)
from crs_core.errors import FieldError
from crs_core.model.chronos import dynamics_parameters

DT = 1 / 250


def test_pid_saturates_and_freezes_the_integral_while_pushing_into_the_limit():
    """Hand-computed: kp = 1, ki = 10, limits +-1, 250 Hz."""
    pid = PID(PIDSettings(kp=1.0, ki=10.0))
    # e = 2: trial 2 + 10 * 0.004 * 2 = 2.08 > 1 with e > 0: integral frozen, output clipped
    assert pid.step(2.0, 0.0) == 1.0
    assert pid.integral == 0.0
    assert pid.step(2.0, 0.0) == 1.0 and pid.integral == 0.0
    # e = 0.5: inside the limits, integral 0.02, output 0.52
    assert pid.step(0.5, 0.0) == pytest.approx(0.52, abs=1e-15)
    assert pid.integral == pytest.approx(0.02, abs=1e-15)
    # e = -3: saturated low but the error pushes down further: frozen at 0.02
    assert pid.step(-3.0, 0.0) == -1.0
    assert pid.integral == pytest.approx(0.02, abs=1e-15)


def test_pid_integrates_when_the_error_drives_the_output_back_inside():
    """Saturated high by the feedforward, a negative error still unwinds the integral."""
    pid = PID(PIDSettings(kp=0.0, ki=10.0))
    pid.integral = 0.5
    out = pid.step(0.0, 1.0, feedforward=2.0)  # trial 2 + 0.5 - 0.04 > 1 but e < 0
    assert out == 1.0
    assert pid.integral == pytest.approx(0.46, abs=1e-15)


def test_pid_integral_limit_and_integration_band():
    pid = PID(PIDSettings(kp=0.0, ki=100.0, output_min=-10, output_max=10, integral_limit=0.5))
    for _ in range(10):  # 100 * 0.004 * 1 = 0.4 per step, clamped at 0.5
        pid.step(1.0, 0.0)
    assert pid.integral == 0.5 and pid.output == 0.5
    banded = PID(PIDSettings(kp=1.0, ki=10.0, integration_band=0.1))
    banded.step(0.5, 0.0)  # |e| = 0.5 > 0.1: no integration
    assert banded.integral == 0.0
    banded.step(0.05, 0.0)  # inside the band: 10 * 0.004 * 0.05
    assert banded.integral == pytest.approx(0.002, abs=1e-15)


def test_filtered_derivative_on_measurement_matches_hand_values():
    """kd = 1, tau = 0.01 s: d1 = -1 / (tau + dt), d2 = tau d1 / (tau + dt)."""
    pid = PID(
        PIDSettings(kp=0.0, kd=1.0, derivative_time_constant=0.01, output_min=-1e3, output_max=1e3)
    )
    assert pid.step(5.0, 0.0) == 0.0  # no previous measurement, no reference kick
    d1 = -1.0 / (0.01 + DT)
    assert pid.step(5.0, 1.0) == pytest.approx(d1, rel=1e-12)
    assert pid.step(5.0, 1.0) == pytest.approx(0.01 * d1 / (0.01 + DT), rel=1e-12)
    plain = PID(PIDSettings(kp=0.0, kd=2.0, output_min=-1e3, output_max=1e3))
    plain.step(0.0, 0.0)
    assert plain.step(0.0, 0.1) == pytest.approx(-2.0 * 0.1 / DT, rel=1e-12)
    plain.reset()
    assert plain.step(0.0, 7.0) == 0.0


@pytest.mark.parametrize(
    "table",
    [
        PotentiometerMap(),
        PotentiometerMap((2.5, 0.8), (-0.3, 0.3)),  # linear, decreasing voltage
        PotentiometerMap((0.5, 1.0, 2.2, 3.0), (-0.4, -0.1, 0.2, 0.4)),
    ],
)
def test_potentiometer_map_round_trip_inside_and_beyond_the_table(table: PotentiometerMap):
    angles = np.linspace(-0.5, 0.5, 101)
    np.testing.assert_allclose(table.angle(table.voltage(angles)), angles, atol=1e-12)
    voltages = np.linspace(0.2, 3.2, 77)
    np.testing.assert_allclose(table.voltage(table.angle(voltages)), voltages, atol=1e-12)
    for v, a in zip(table.voltages, table.angles, strict=True):
        assert table.angle(v) == pytest.approx(a, abs=1e-15)
    assert isinstance(table.angle(1.65), float)


def test_default_potentiometer_map_is_centred_and_monotone():
    table = PotentiometerMap()
    assert table.angle(1.65) == 0.0
    assert np.all(np.diff(table.angle(np.linspace(0, 3.3, 200))) > 0)


def test_rear_axle_speed_is_r_times_mean_rear_wheel_speed():
    assert rear_axle_speed(np.array([9.0, 9.0, 50.0, 70.0]), 0.02) == pytest.approx(1.2)
    with pytest.raises(FieldError, match=r"^wheel_speeds: "):
        rear_axle_speed(np.array([1.0, 2.0, np.nan, 3.0]), 0.02)


def test_feedforward_defaults_are_the_chronos_values_and_balance_the_drive():
    params = dynamics_parameters()
    assert MotorFeedforward.from_parameters(params) == MotorFeedforward()
    ff = MotorFeedforward()
    assert ff.torque(0.0) == 0.0
    for v in (0.5, 1.0, 2.5, -1.0):
        T = ff.torque(v)
        drive = (ff.cm1 - ff.cm2 * v) * T
        drag = np.sign(v) * (ff.cd2 * v**2 + ff.cd0) + ff.cd1 * v
        assert drive == pytest.approx(drag, rel=1e-12)
    assert MotorFeedforward(scale=0.0).torque(2.0) == 0.0


def test_velocity_controller_adds_the_feedforward_and_measures_the_rear_axle():
    settings = VelocitySettings(pid=PIDSettings(kp=2.0))
    controller = VelocityController(settings)
    wheels = np.array([0.0, 0.0, 1.0 / 0.0175, 1.0 / 0.0175])  # rear axle at 1 m/s
    T = controller.step(1.2, wheels)
    assert controller.speed == pytest.approx(1.0)
    assert T == pytest.approx(MotorFeedforward().torque(1.2) + 2.0 * 0.2)
    assert controller.step(5.0, wheels) == 1.0  # feedforward and PID within the limits


def test_steering_controller_reads_the_map_and_clips_the_reference():
    settings = SteeringSettings(pid=PIDSettings(kp=1.0), angle_limit=0.3)
    controller = SteeringController(settings)
    table = settings.potentiometer
    u = controller.step(0.9, table.voltage(0.1))
    assert controller.angle == pytest.approx(0.1, abs=1e-12)
    assert u == pytest.approx(0.3 - 0.1, abs=1e-12)  # reference clipped to 0.3


@pytest.mark.parametrize(
    ("make", "field"),
    [
        (lambda: PIDSettings(kp=-1.0), "kp"),
        (lambda: PIDSettings(kp=1.0, ki=float("nan")), "ki"),
        (lambda: PIDSettings(kp=1.0, kd="x"), "kd"),
        (lambda: PIDSettings(kp=1.0, output_min=1.0, output_max=0.0), "output_max"),
        (lambda: PIDSettings(kp=1.0, derivative_time_constant=-0.1), "derivative_time_constant"),
        (lambda: PIDSettings(kp=1.0, integral_limit=0.0), "integral_limit"),
        (lambda: PIDSettings(kp=1.0, integration_band=-1.0), "integration_band"),
        (lambda: PIDSettings(kp=1.0, rate_hz=0.0), "rate_hz"),
        (lambda: PotentiometerMap((1.0, 1.0, 2.0), (-0.1, 0.0, 0.1)), "voltages"),
        (lambda: PotentiometerMap((1.0, 2.0), (0.1, -0.1)), "angles"),
        (lambda: PotentiometerMap((1.0, 2.0, 3.0), (0.1, 0.2)), "angles"),
        (lambda: PotentiometerMap((1.0,), (0.1,)), "voltages"),
        (lambda: SteeringSettings(angle_limit=0.0), "angle_limit"),
        (lambda: SteeringSettings(pid=None), "pid"),
        (lambda: VelocitySettings(wheel_radius=-0.01), "wheel_radius"),
        (lambda: VelocitySettings(feedforward=1.0), "feedforward"),
        (lambda: MotorFeedforward(cm1=0.0), "cm1"),
        (lambda: MotorFeedforward(cd2=-0.1), "cd2"),
        (lambda: MotorFeedforward(scale=1.5), "scale"),
    ],
)
def test_invalid_settings_raise_value_error_naming_the_field(make, field: str):
    with pytest.raises(FieldError, match=rf"^{field}: ") as error:
        make()
    assert error.value.field == field


def test_settings_word_their_errors_as_every_settings_class_and_store_floats():
    with pytest.raises(FieldError, match=r"^kp: must be a finite number >= 0, got -1$"):
        PIDSettings(kp=-1)
    with pytest.raises(FieldError, match=r"^integral_limit: must be a finite number > 0, got 0$"):
        PIDSettings(kp=1, integral_limit=0)
    with pytest.raises(FieldError, match=r"^scale: must be within \[0, 1\], got 1.5$"):
        MotorFeedforward(scale=1.5)
    pid = PIDSettings(kp=5, ki=np.float32(2.0), integral_limit=1, rate_hz=100)
    values = (pid.kp, pid.ki, pid.integral_limit, pid.rate_hz, pid.integration_band)
    assert [type(value) for value in values] == [float, float, float, float, type(None)]
    assert type(VelocitySettings(wheel_radius=1).wheel_radius) is float
    assert type(SteeringSettings(angle_limit=1).angle_limit) is float
    assert type(MotorFeedforward(cm1=1).cm1) is float
