"""Effects composed onto the model: state layout, signal-chain behaviour, registry handling."""

import numpy as np
import pytest

from crs_core.model import EFFECTS, CarModel


@pytest.fixture(scope="module")
def full() -> CarModel:
    return CarModel(list(EFFECTS))


def test_all_effects_compose_and_add_their_states_and_parameters(full):
    """Every registered effect composes; lag effects append states, all add their parameters."""
    assert full.state_names[6:] == ("steer_applied", "torque_applied")
    for effect in EFFECTS.values():
        for parameter in effect.parameters:
            assert parameter.name in full.parameters
            assert full.parameters[parameter.name].group == f"effect:{effect.name}"
    assert full.numeric.f(np.zeros(8), np.zeros(2), full.parameters.vector()).shape == (8,)


def test_listing_order_does_not_change_the_signal_chain():
    """Effects are applied in registry order whatever order they are given in."""
    a = CarModel(["steering_lag", "steering_offset"])
    b = CarModel(["steering_offset", "steering_lag"])
    assert a.state_names == b.state_names and a.parameters.names == b.parameters.names


@pytest.mark.parametrize(
    "effect, tau_name, channel", [("steering_lag", "tau_steer", 0), ("motor_lag", "tau_motor", 1)]
)
def test_first_order_lag_reaches_63_percent_after_one_time_constant(effect, tau_name, channel):
    """A step command through a lag effect reaches 1 - 1/e of its value after tau."""
    model = CarModel({effect: 0.08})
    tau = model.parameters.value(tau_name)
    assert tau == 0.08
    command = np.zeros(2)
    command[channel] = 0.3
    x = model.numeric.step(
        model.initial_state(np.zeros(6)), command, model.parameters.vector(), tau
    )
    applied = model.numeric.applied_input(x, command, model.parameters.vector())
    assert applied[channel] == pytest.approx(0.3 * (1 - np.exp(-1)), rel=1e-6)


def test_steering_offset_shifts_the_applied_angle():
    """With steering_offset, the applied angle is command + delta0."""
    model = CarModel({"steering_offset": -0.03})
    applied = model.numeric.applied_input(
        np.zeros(6), np.array([0.1, 0.2]), model.parameters.vector()
    )
    np.testing.assert_allclose(applied, [0.07, 0.2], rtol=1e-14)


def test_sensor_effects_change_only_their_sensor():
    """gyro_bias shifts only the yaw-rate channel; wheel_radius_error scales only the encoders."""
    base = CarModel()
    biased = CarModel({"gyro_bias": 0.1, "wheel_radius_error": 0.001})
    x, u = np.array([0, 0, 0, 1.0, 0.02, 0.5]), np.array([0.1, 0.3])
    y0 = base.numeric.outputs(x, u, base.parameters.vector())
    y1 = biased.numeric.outputs(x, u, biased.parameters.vector())
    np.testing.assert_allclose(y1["imu"], y0["imu"] + [0, 0, 0.1], rtol=1e-14)
    r = base.parameters.value("r")
    np.testing.assert_allclose(y1["wheel_encoders"], y0["wheel_encoders"] * r / (r + 0.001))
    np.testing.assert_array_equal(y1["lighthouse/0/1"], y0["lighthouse/0/1"])


def test_input_delay_is_reported_not_modelled_as_state():
    """input_delay has no state; the model reports the delay for the simulator to apply."""
    model = CarModel({"input_delay": 0.05})
    assert model.nx == 6 and model.input_delay() == 0.05
    assert CarModel().input_delay() == 0.0


def test_unknown_effect_and_bad_value_are_rejected_by_name():
    """Unknown effects and out-of-bounds values raise errors that name them."""
    with pytest.raises(KeyError, match="tyre_wear"):
        CarModel(["tyre_wear"])
    with pytest.raises(ValueError, match="tau_steer"):
        CarModel({"steering_lag": -1.0})
