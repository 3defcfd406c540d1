"""Tests of the onboard low-level loop in the simulator (sim.onboard)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from crs_core.control.low_level import PIDSettings, SteeringSettings
from crs_core.errors import FieldError
from crs_core.model import CarModel
from sim import SensorSpec, SensorSuite, Simulator
from sim.actuators import PotentiometerSettings, SteeringActuatorSettings
from sim.onboard import OnboardSettings
from sim.step_response import steering_step, step_metrics, velocity_step

IDEAL = SensorSuite().ideal()


@pytest.fixture(scope="module")
def model() -> CarModel:
    return CarModel()


# --- steering step response (actuator + PID, defaults) --------------------------------------------
@pytest.mark.parametrize("ideal", [True, False])
def test_steering_step_response_is_fast_well_damped_and_exact(ideal: bool):
    settings = OnboardSettings().ideal() if ideal else OnboardSettings()
    t, angle = steering_step(settings, step=0.3, duration=1.5)
    m = step_metrics(t, angle, 0.0, 0.3)
    assert 0.08 <= m.time_to_90 <= 0.15  # a servo of realistic speed
    assert m.rise_time < 0.12
    assert m.overshoot < 0.10
    assert m.settling_time < 0.3
    assert abs(m.steady_state_error) < (5e-4 if ideal else 2e-3)  # noise: 2 mV ~ 1 mrad
    # the other way, from an off-centre start
    t, angle = steering_step(settings, step=-0.4, start=0.2, duration=1.5)
    m = step_metrics(t, angle, 0.2, -0.2)
    assert m.overshoot < 0.10 and abs(m.steady_state_error) < 2e-3


# --- in the simulator -----------------------------------------------------------------------------
def test_velocity_reference_is_tracked_on_the_chronos_model():
    """Default sensors (noisy wheel speeds): steady state within 2 % of 1 m/s and 1.5 m/s."""
    for start, target in ((0.0, 1.0), (1.0, 1.5)):
        result = velocity_step(start=start, target=target, duration=3.0, ideal_sensors=False)
        m = step_metrics(result.truth_t, result.truth_x[:, 3], start, target, tail=1.0)
        assert abs(m.steady_state_error) < 0.02 * target
        assert m.overshoot < 0.10
        assert m.time_to_90 < 0.5
        torque = np.array([s.u[1] for s in result.applied_inputs])
        assert np.all(np.abs(torque) <= 1.0)


def test_measured_speed_is_the_rear_axle_formula_and_equals_the_true_vx(model: CarModel):
    """In a turn, the loop's v_x = r (Omega_rl + Omega_rr) / 2 is the true v_x exactly."""
    session = Simulator(model, IDEAL, seed=0, onboard=OnboardSettings().ideal()).session(
        np.array([0.0, 0.0, 0.0, 0.8, 0.0, 0.0])
    )
    session.command([0.25, 1.2], mode="velocity")
    r = model.parameters.value("r")
    p = model.parameters.vector()
    for k in range(1, 200):
        session.advance(k * 0.004 + 1e-6)  # just past tick k
        if k % 20:
            continue
        loop = session.onboard
        assert loop.ticks == k + 1
        x = session._x  # the state at the tick (no sensor event between tick and now)
        wheels = model.numeric.outputs(x, session.applied_command, p)["wheel_encoders"]
        assert loop.velocity.speed == pytest.approx(r * (wheels[2] + wheels[3]) / 2, abs=5e-3)
    vx_truth = session.base_state[3]
    assert session.base_state[5] > 0.5  # really turning
    assert session.onboard.velocity.speed == pytest.approx(vx_truth, abs=5e-3)


def test_torque_mode_matches_the_old_behaviour_up_to_the_steering_lag(model: CarModel):
    def controller(t, x):
        return np.array([0.2 * np.sin(2 * t), 0.3 + 0.1 * np.cos(3 * t)])

    x0 = np.array([0.0, 0.0, 0.0, 0.5, 0.0, 0.0])
    old = Simulator(model, IDEAL, seed=1).run(controller, 3.0, x0)
    new = Simulator(model, IDEAL, seed=1, onboard=OnboardSettings().ideal()).run(
        controller, 3.0, x0
    )
    t = np.arange(0.1, 3.0, 0.004)
    reference, applied = new.input_at(t), new.applied_input_at(t)
    np.testing.assert_array_equal(applied[:, 1], reference[:, 1])  # torque passes straight
    np.testing.assert_array_equal(new.input_at(t), old.input_at(t))  # references logged as now
    lag = np.abs(applied[:, 0] - reference[:, 0])
    assert 1e-4 < np.max(lag) < 0.06  # the actuator lags a little behind 50 Hz references
    # the same path within a few centimetres after 3 s, velocities within 2 %
    assert np.hypot(*(new.truth_x[-1, :2] - old.truth_x[-1, :2])) < 0.05
    assert new.truth_x[-1, 3] == pytest.approx(old.truth_x[-1, 3], rel=0.02)
    assert new.reference_modes == ["torque"] * len(new.inputs)
    assert (
        old.applied_inputs == [] and old.reference_modes == [] and "onboard" not in old.extra_meta
    )
    np.testing.assert_array_equal(old.applied_input_at(t), old.input_at(t))


def test_option_off_leaves_a_seeded_run_unchanged(model: CarModel):
    """The numbers of this seeded run before the onboard loop existed (commit 02d27d6)."""

    def controller(t, x):
        return np.array([0.2 * np.sin(2 * t), 0.3 + 0.1 * np.cos(3 * t)])

    sensors = SensorSuite(imu=SensorSpec(250.0, (0.5, 0.5, 0.05), bias=(0.1, -0.2, 0.03)))
    x0 = np.array([0.0, 0.0, 0.0, 0.5, 0.0, 0.0])
    result = Simulator(model, sensors, seed=11).run(controller, 3.0, x0)
    expected = [
        1.5716788275982747,
        2.3766964107359314,
        -0.20628625420626762,
        1.4569671034388305,
        -0.019675773496656217,
        -0.955540184541702,
    ]
    np.testing.assert_allclose(result.truth_x[-1], expected, rtol=1e-10, atol=1e-12)
    assert len(result.measurements) == 1708 and result.truth_t.size == 1052
    total = sum(float(m.values.sum()) for m in result.measurements)
    assert total == pytest.approx(208426.20757133394, rel=1e-10)
    assert sum(m.stamp for m in result.measurements) == pytest.approx(2477.539260792917, rel=1e-12)
    again = Simulator(model, sensors, seed=11, onboard=None).run(controller, 3.0, x0)
    np.testing.assert_array_equal(again.truth_x, result.truth_x)


def test_input_delay_postpones_the_reference_and_the_loop_follows_it():
    model = CarModel({"input_delay": 0.05})
    session = Simulator(model, IDEAL, seed=0, onboard=OnboardSettings().ideal()).session(
        np.zeros(6)
    )
    session.command([0.2, 0.4])
    session.advance(0.049)
    assert session.applied_command[1] == 0.0 and session.onboard.actuator.angle == 0.0
    session.advance(0.051)
    assert session.applied_command[1] == 0.4
    session.advance(0.3)
    assert session.onboard.actuator.angle == pytest.approx(0.2, abs=0.01)


def test_velocity_mode_dataset_holds_the_loop_torque_and_streaming_keeps_no_history(
    model: CarModel,
):
    result = velocity_step(start=0.5, target=1.0, duration=1.0)
    data = result.to_dataset()
    if data.t.size:
        assert np.all(np.abs(data.u[:, 1]) <= 1.0)
        assert not np.allclose(data.u[:, 1], 1.0)  # a torque, not the velocity reference
    stamps = np.array([s.stamp for s in data.inputs])
    torque = np.array([s.u[1] for s in data.inputs])
    np.testing.assert_array_equal(torque, result.applied_input_at(stamps)[:, 1])
    assert np.all([s.u[0] == 0.0 for s in data.inputs])  # the steering reference
    assert torque[-1] < 0.5  # at speed: the feedforward's torque, not 1 m/s
    assert result.extra_meta["onboard"]["rate_hz"] == 250.0
    session = Simulator(model, IDEAL, onboard=OnboardSettings()).session(
        np.zeros(6), keep_history=False
    )
    session.command([0.1, 0.5], mode="velocity")
    session.advance(1.0)
    assert session.inputs == [] and session.applied_inputs == []
    assert session.base_state[3] == pytest.approx(0.5, abs=0.05)


def test_bad_modes_and_settings_are_refused_naming_the_field(model: CarModel):
    plain = Simulator(model, IDEAL).session(np.zeros(6))
    with pytest.raises(
        FieldError, match=r"^mode: 'velocity' references need the onboard loop"
    ) as error:
        plain.command([0.0, 1.0], mode="velocity")
    assert error.value.field == "mode"
    onboard = Simulator(model, IDEAL, onboard=OnboardSettings()).session(np.zeros(6))
    with pytest.raises(FieldError, match=r"^mode: must be one of") as error:
        onboard.command([0.0, 1.0], mode="speed")
    assert error.value.field == "mode"
    with pytest.raises(FieldError, match=r"^onboard: ") as error:
        Simulator(model, IDEAL, onboard={"rate_hz": 250})
    assert error.value.field == "onboard"
    slow = SteeringSettings(pid=PIDSettings(kp=1.0, rate_hz=100.0))
    with pytest.raises(FieldError, match=r"^steering\.pid\.rate_hz: ") as error:
        OnboardSettings(steering=slow)
    assert error.value.field == "steering.pid.rate_hz"
    with pytest.raises(FieldError, match=r"^rate_hz: ") as error:
        OnboardSettings(rate_hz=-1.0)
    assert error.value.field == "rate_hz"
    with pytest.raises(FieldError, match=r"^actuator: ") as error:
        OnboardSettings(actuator=None)
    assert error.value.field == "actuator"
    with pytest.raises(FieldError, match=r"^time_constant: ") as error:
        SteeringActuatorSettings(time_constant=0.0)
    assert error.value.field == "time_constant"
    with pytest.raises(FieldError, match=r"^deadband: ") as error:
        SteeringActuatorSettings(deadband=1.0)
    assert error.value.field == "deadband"
    with pytest.raises(FieldError, match=r"^noise_std: ") as error:
        PotentiometerSettings(noise_std=-0.001)
    assert error.value.field == "noise_std"
    with pytest.raises(FieldError, match=r"^adc_bits: ") as error:
        replace(PotentiometerSettings(), adc_bits=2.5)
    assert error.value.field == "adc_bits"
