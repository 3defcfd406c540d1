"""Online parameters as model states: the states stand in for the parameters exactly, relax
to their priors, and bad names are refused with the field named."""

from __future__ import annotations

import pickle

import numpy as np
import pytest

from crs_core.errors import FieldError
from crs_core.model import CarModel
from crs_core.model.online import (
    EFFECT_REVERSION_FACTOR,
    GRIP,
    OnlineParameters,
    parse_online_names,
)

X = np.array([0.3, -0.2, 0.4, 1.4, 0.1, 1.2])
U = np.array([0.2, 0.4])


def _plain(values: dict[str, float], effects=("gyro_bias",)) -> CarModel:
    base = CarModel(dict.fromkeys(effects))
    return CarModel(dict.fromkeys(effects), parameters=base.parameters.updated(values))


def test_states_at_their_priors_give_the_plain_model():
    plain = CarModel({"gyro_bias": 0.03})
    online = plain.with_online(("Cm1", "gyro_bias", "grip"), 60.0)
    assert online.state_names[-3:] == ("online_Cm1", "online_gyro_bias", "online_grip")
    x = online.initial_state(X)
    assert x[-3:] == pytest.approx([plain.parameters.value("Cm1"), 0.03, 1.0])
    p = online.parameters.vector()
    xdot = online.dynamics_function(x, U, p).full().ravel()
    assert xdot[:6] == pytest.approx(plain.dynamics_function(X, U, p).full().ravel())
    assert xdot[6:] == pytest.approx(0.0)  # at the prior nothing relaxes
    for sensor in ("imu", "wheel_encoders", "lighthouse/0/1"):
        got = online.output_function(sensor)(x, U, p).full().ravel()
        assert got == pytest.approx(plain.output_function(sensor)(X, U, p).full().ravel())


def test_a_state_away_from_its_prior_acts_as_that_parameter_and_relaxes():
    online = CarModel({"gyro_bias": 0.0}).with_online(("Cm1", "gyro_bias", "grip"), 60.0)
    defaults = online.parameters
    cm1, grip, bias = 0.8 * defaults.value("Cm1"), 0.85, 0.07
    changed = _plain(
        {
            "Cm1": cm1,
            "Df": grip * defaults.value("Df"),
            "Dr": grip * defaults.value("Dr"),
            "gyro_bias": bias,
        }
    )
    x = np.concatenate([X, [cm1, bias, grip]])
    p = online.parameters.vector()
    xdot = online.dynamics_function(x, U, p).full().ravel()
    expected = changed.dynamics_function(X, U, changed.parameters.vector()).full().ravel()
    assert xdot[:6] == pytest.approx(expected)
    # d theta / dt = -(theta - prior) / T, T four times as long for an effect's parameter
    priors = np.array([defaults.value("Cm1"), 0.0, 1.0])
    reversion = np.array([60.0, 60.0 * EFFECT_REVERSION_FACTOR, 60.0])
    assert xdot[6:] == pytest.approx(-(np.array([cm1, bias, grip]) - priors) / reversion)
    assert online.online.process_std["online_gyro_bias"] == pytest.approx(
        0.05 * np.sqrt(2 / (60.0 * EFFECT_REVERSION_FACTOR))
    )
    gyro = online.output_function("imu")(x, U, p).full().ravel()[2]
    assert gyro == pytest.approx(X[5] + bias)


def test_with_online_switches_an_effect_on_from_zero_and_keeps_the_values():
    plain = _plain({"Cm1": 0.9}, effects=())
    online = plain.with_online(("gyro_bias",), 30.0)
    assert [e.name for e in online.effects] == ["gyro_bias"]
    assert online.parameters.value("gyro_bias") == 0.0
    assert online.parameters.value("Cm1") == 0.9
    # the prior follows the parameter vector: --params moves it without a rebuild
    copy = pickle.loads(pickle.dumps(online))
    assert copy.state_names == online.state_names and copy.online.reversion_s == 30.0


def test_random_walk_and_prior_std_follow_the_prior():
    online = OnlineParameters(("Cm1", GRIP), CarModel().parameters, 50.0)
    assert online.prior_std["online_grip"] == pytest.approx(0.1)
    cm1_prior_std = CarModel().parameters["Cm1"].prior_std
    assert online.process_std["online_Cm1"] == pytest.approx(cm1_prior_std * np.sqrt(2 / 50.0))


def test_an_effect_parameter_is_as_uncertain_as_the_effects_nominal_size():
    """Not as its identification prior (a quarter of its range: 0.25 rad/s for the gyro bias),
    whose random walk follows the noise."""
    model = CarModel(["gyro_bias", "steering_lag"])
    assert model.parameters["gyro_bias"].prior_std == pytest.approx(0.25)
    online = OnlineParameters(("gyro_bias", "tau_steer"), model.parameters, 120.0)
    assert online.priors["gyro_bias"][1] == pytest.approx(0.05)
    tau = model.parameters["tau_steer"]
    assert online.priors["tau_steer"][1] == pytest.approx(min(tau.prior_std, 0.05))


@pytest.mark.parametrize(
    ("names", "effects", "message"),
    [
        (("Cm9",), (), r"no parameter 'Cm9' \(known: .*Cm1"),
        (("gyro_bias",), (), "a parameter of the effect gyro_bias, which the model does not have"),
        (("Df", GRIP), (), "Df and grip together: grip scales Df and Dr"),
    ],
)
def test_bad_names_are_refused_naming_the_field(names, effects, message):
    with pytest.raises(FieldError, match=message) as error:
        CarModel(effects, online_parameters=names)
    assert error.value.field == "online_parameters"


@pytest.mark.parametrize(
    ("text", "message"),
    [("", "comma-separated"), ("Cm1,,grip", "comma-separated"), ("Cm1,Cm1", "Cm1 named twice")],
)
def test_name_lists_are_parsed_strictly(text, message):
    with pytest.raises(FieldError, match=message):
        parse_online_names(text)
    assert parse_online_names(" Cm1, grip ") == ("Cm1", "grip")


def test_a_reversion_time_must_be_positive():
    with pytest.raises(FieldError, match="online_reversion_s"):
        CarModel(online_parameters=("Cm1",), online_reversion_s=0.0)
