"""Tests of crs_core.model.effects: effects composed onto the model (state layout, signal-chain
behaviour, registry handling) and effects named on a command line or in a node parameter
(``NAME[.PARAM]=VALUE``)."""

import re

import numpy as np
import pytest

from crs_core.measurements import lighthouse_sensor
from crs_core.model import EFFECTS, CarModel
from crs_core.model.effects import effect_spec, parse_effect
from sim import SensorSuite, Simulator


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


# --- the four effects added for the discrepancy workflow ------------------------------------------
#: Effect -> its parameters at a clearly non-null test value.
NEW_EFFECTS = {
    "gyro_scale": {"gyro_scale_error": 0.1},
    "steering_gain": {"steering_gain_error": 0.2},
    "torque_deadzone": {"torque_deadzone": 0.1},
    "lighthouse_offset": {"lh_plane1_offset": 0.004, "lh_plane2_offset": -0.007},
}
#: Effect -> (outputs it changes, whether it changes the dynamics).
FOOTPRINT = {
    "gyro_scale": ({"imu", "gyro"}, False),
    "steering_gain": ({"imu", "wheel_encoders"}, True),
    "torque_deadzone": ({"imu"}, True),
    "lighthouse_offset": ({f"lighthouse/{s}/{k}" for s in (0, 1) for k in (1, 2)}, False),
}
STATIONS = 2  # the lighthouse effects must act on every station


def random_points(n: int = 5, seed: int = 3) -> list[tuple[np.ndarray, np.ndarray]]:
    """States near the track origin (inside the Lighthouse view) and inputs, moving forward."""
    rng = np.random.default_rng(seed)
    points = []
    for _ in range(n):
        x = np.array(
            [
                rng.uniform(-0.3, 0.3),
                rng.uniform(-0.3, 0.3),
                rng.uniform(-np.pi, np.pi),
                rng.uniform(0.2, 2.0),
                rng.uniform(-0.1, 0.1),
                rng.uniform(-2.0, 2.0),
            ]
        )
        points.append((x, np.array([rng.uniform(-0.3, 0.3), rng.uniform(-0.5, 0.8)])))
    return points


def evaluate(model: CarModel, x: np.ndarray, u: np.ndarray) -> tuple[np.ndarray, dict]:
    """(state after 20 ms, all outputs) of ``model`` at its own parameter values."""
    p = model.parameters.vector()
    return model.numeric.step(x, u, p, 0.02), model.numeric.outputs(x, u, p)


@pytest.fixture(scope="module")
def base() -> CarModel:
    return CarModel(n_base_stations=STATIONS)


@pytest.fixture(scope="module", params=list(NEW_EFFECTS))
def effect_model(request) -> tuple[str, CarModel]:
    name = request.param
    return name, CarModel({name: NEW_EFFECTS[name]}, n_base_stations=STATIONS)


def test_new_effects_are_registered_with_documented_parameters():
    """Names, units, defaults and bounds as specified; appended after the original six."""
    assert list(EFFECTS)[:6] == [
        "steering_offset",
        "input_delay",
        "steering_lag",
        "motor_lag",
        "gyro_bias",
        "wheel_radius_error",
    ]
    assert list(EFFECTS)[6:] == list(NEW_EFFECTS)
    expected = {
        "gyro_scale_error": ("-", 0.05, -0.3, 0.3),
        "steering_gain_error": ("-", 0.1, -0.5, 0.5),
        "torque_deadzone": ("-", 0.05, 0.0, 0.3),
        "lh_plane1_offset": ("rad", 0.003, -0.05, 0.05),
        "lh_plane2_offset": ("rad", 0.003, -0.05, 0.05),
    }
    found = {
        p.name: (p.unit, p.value, p.lower, p.upper)
        for name in NEW_EFFECTS
        for p in EFFECTS[name].parameters
    }
    assert found == expected
    for name in NEW_EFFECTS:
        assert EFFECTS[name].description and not EFFECTS[name].states
        assert [p.name for p in EFFECTS[name].parameters] == list(NEW_EFFECTS[name])


@pytest.mark.parametrize("name", list(NEW_EFFECTS))
def test_new_effect_at_zero_is_the_base_model(name: str, base: CarModel):
    """Nested: with its parameters at 0, step and every output equal the base model's."""
    null = CarModel({name: dict.fromkeys(NEW_EFFECTS[name], 0.0)}, n_base_stations=STATIONS)
    assert null.nx == base.nx and set(null.outputs) == set(base.outputs)
    for x, u in random_points():
        x_null, y_null = evaluate(null, x, u)
        x_base, y_base = evaluate(base, x, u)
        np.testing.assert_allclose(x_null, x_base, rtol=1e-13, atol=1e-14)
        for sensor, y in y_base.items():
            assert np.all(np.isfinite(y)), sensor
            np.testing.assert_allclose(y_null[sensor], y, rtol=1e-13, atol=1e-14, err_msg=sensor)


def test_new_effect_changes_its_footprint_and_nothing_else(effect_model, base: CarModel):
    """Each effect changes exactly the outputs (and dynamics) it acts on, nothing else."""
    name, model = effect_model
    changed, dynamics = FOOTPRINT[name]
    for x, u in random_points():
        x_model, y_model = evaluate(model, x, u)
        x_base, y_base = evaluate(base, x, u)
        moved_differently = not np.allclose(x_model, x_base, rtol=1e-9, atol=0)
        assert moved_differently == dynamics
        for sensor, y in y_base.items():
            if sensor in changed:
                assert not np.allclose(y_model[sensor], y, rtol=1e-9, atol=0), sensor
            else:
                np.testing.assert_allclose(y_model[sensor], y, rtol=1e-13, err_msg=sensor)


def test_gyro_scale_scales_the_yaw_rate_by_exactly_one_plus_s(base: CarModel):
    """gyro_scale_error=0.1: IMU and gyro yaw rate read 1.1 omega; a_x, a_y unchanged."""
    model = CarModel({"gyro_scale": 0.1}, n_base_stations=STATIONS)
    for x, u in random_points():
        _, y = evaluate(model, x, u)
        _, y0 = evaluate(base, x, u)
        np.testing.assert_allclose(y["imu"], y0["imu"] * [1, 1, 1.1], rtol=1e-14)
        np.testing.assert_allclose(y["gyro"], [1.1 * x[5]], rtol=1e-14)


def test_steering_gain_acts_like_a_scaled_steering_command(base: CarModel):
    """steering_gain_error=k: dynamics and outputs equal the base model's at (1 + k) delta."""
    model = CarModel({"steering_gain": 0.2}, n_base_stations=STATIONS)
    p, p0 = model.parameters.vector(), base.parameters.vector()
    for x, u in random_points():
        scaled = np.array([1.2 * u[0], u[1]])
        np.testing.assert_allclose(model.numeric.f(x, u, p), base.numeric.f(x, scaled, p0))
        np.testing.assert_allclose(model.numeric.applied_input(x, u, p), scaled, rtol=1e-15)
        y, y0 = model.numeric.outputs(x, u, p), base.numeric.outputs(x, scaled, p0)
        for sensor in y0:
            np.testing.assert_allclose(y[sensor], y0[sensor], rtol=1e-13, err_msg=sensor)


@pytest.mark.parametrize(
    ("torque", "limit", "tolerance"),
    [
        (0.0025, 0.0, 1e-5),  # |T| << T0: (almost) nothing reaches the motor
        (-0.0025, 0.0, 1e-5),
        (0.6, 0.55, 1e-10),  # |T| >> T0: T - T0 sign(T)
        (-0.8, -0.75, 1e-10),
    ],
)
def test_torque_deadzone_removes_the_dead_band(torque, limit, tolerance, base: CarModel):
    """torque_deadzone=T0=0.05: the dynamics are the base model's at T - T0 tanh(T / T0), which
    is ~0 inside the band and T - T0 sign(T) far outside it; steering passes unchanged."""
    model = CarModel({"torque_deadzone": 0.05}, n_base_stations=STATIONS)
    p, p0 = model.parameters.vector(), base.parameters.vector()
    transformed = torque - 0.05 * np.tanh(torque / (0.05 + 1e-6))
    assert transformed == pytest.approx(limit, abs=tolerance)
    for x, _ in random_points():
        u = np.array([0.1, torque])
        applied = model.numeric.applied_input(x, u, p)
        np.testing.assert_allclose(applied, [0.1, transformed], rtol=1e-15, atol=1e-17)
        np.testing.assert_allclose(
            model.numeric.f(x, u, p), base.numeric.f(x, applied, p0), rtol=1e-14, atol=1e-15
        )


def test_torque_deadzone_is_smooth_and_odd_in_the_command():
    """The applied torque is odd, strictly increasing and 0 at 0 (no kink, no flat piece)."""
    model = CarModel({"torque_deadzone": 0.1})
    p = model.parameters.vector()
    commands = np.linspace(-1, 1, 401)
    applied = np.array([model.numeric.applied_input(np.zeros(6), [0.0, t], p)[1] for t in commands])
    np.testing.assert_allclose(applied, -applied[::-1], rtol=0, atol=1e-15)
    assert np.all(np.diff(applied) > 0) and applied[200] == 0.0


def test_lighthouse_offset_shifts_each_plane_by_its_offset(base: CarModel):
    """Plane 1 of every station reads + lh_plane1_offset, plane 2 + lh_plane2_offset."""
    model = CarModel({"lighthouse_offset": NEW_EFFECTS["lighthouse_offset"]}, STATIONS)
    offsets = {"1": 0.004, "2": -0.007}
    for x, u in random_points():
        _, y = evaluate(model, x, u)
        _, y0 = evaluate(base, x, u)
        for station in range(STATIONS):
            for plane, offset in offsets.items():
                sensor = f"lighthouse/{station}/{plane}"
                np.testing.assert_allclose(y[sensor] - y0[sensor], offset, rtol=1e-12, atol=1e-15)


# --- the new effects as hidden truth in the simulator ---------------------------------------------
def constant(steer: float, torque: float):
    command = np.array([steer, torque])
    return lambda t, x: command.copy()


def simulate(model: CarModel, steer: float = 0.1, torque: float = 0.3, duration: float = 1.5):
    return Simulator(model, SensorSuite().ideal(), seed=0).run(
        constant(steer, torque), duration, np.zeros(6)
    )


def truth_at(result, stamps: np.ndarray) -> np.ndarray:
    index = np.searchsorted(result.truth_t, stamps - 1e-12)
    np.testing.assert_allclose(result.truth_t[index], stamps, rtol=0, atol=1e-12)
    return result.truth_x[index]


def test_simulated_gyro_reads_scaled_true_yaw_rate():
    """Hidden gyro_scale_error=0.1: the recorded yaw rate is exactly 1.1 x the true one."""
    result = simulate(CarModel({"gyro_scale": {"gyro_scale_error": 0.1}}))
    stamps, imu = result.measurements_of("imu")
    omega = truth_at(result, stamps)[:, 5]
    assert np.max(np.abs(omega)) > 0.5
    np.testing.assert_allclose(imu[:, 2], 1.1 * omega, rtol=1e-12, atol=1e-12)


def test_simulated_steering_gain_drives_like_a_larger_command():
    """Hidden steering_gain_error=0.2 with 0.1 rad commanded drives like base with 0.12 rad."""
    gained = simulate(CarModel({"steering_gain": 0.2}))
    scaled = simulate(CarModel(), steer=0.12)
    plain = simulate(CarModel())
    np.testing.assert_allclose(gained.truth_x, scaled.truth_x, rtol=1e-12, atol=1e-12)
    assert gained.truth_x[-1, 2] > 1.1 * plain.truth_x[-1, 2] > 0  # turned more


def test_simulated_torque_deadzone_holds_back_small_commands():
    """Hidden torque_deadzone=0.2: a 0.1 command barely moves the car; 0.5 drives like 0.3."""
    model = CarModel({"torque_deadzone": 0.2})
    small, base_small = simulate(model, torque=0.1), simulate(CarModel(), torque=0.1)
    assert np.max(small.truth_x[:, 3]) < 0.2 * np.max(base_small.truth_x[:, 3])
    large = simulate(model, torque=0.5)
    equivalent = simulate(CarModel(), torque=0.5 - 0.2 * np.tanh(0.5 / (0.2 + 1e-6)))
    np.testing.assert_allclose(large.truth_x, equivalent.truth_x, rtol=1e-12, atol=1e-12)
    assert large.truth_x[-1, 0] < simulate(CarModel(), torque=0.5).truth_x[-1, 0]


def test_simulated_lighthouse_angles_carry_the_plane_offsets():
    """Hidden lighthouse_offset: recorded angles minus the base model's are the plane offsets."""
    offsets = {"lh_plane1_offset": 0.01, "lh_plane2_offset": -0.02}
    result = simulate(CarModel({"lighthouse_offset": offsets}))
    base_model = CarModel()
    p = base_model.parameters.vector()
    for plane, offset in ((1, 0.01), (2, -0.02)):
        sensor = lighthouse_sensor(0, plane)
        stamps, angles = result.measurements_of(sensor)
        assert stamps.size > 50
        expected = [
            base_model.numeric.outputs(x, np.array([0.1, 0.3]), p)[sensor]
            for x in truth_at(result, stamps)
        ]
        np.testing.assert_allclose(angles - np.array(expected), offset, rtol=0, atol=1e-12)


# --- effects named on a command line or in a node parameter: NAME[.PARAM]=VALUE -------------------


@pytest.mark.parametrize(
    ("text", "expected"),
    [
        ("gyro_bias", ("gyro_bias", None, None)),
        ("steering_lag=0.08", ("steering_lag", "tau_steer", 0.08)),
        ("steering_lag.tau_steer=0.1", ("steering_lag", "tau_steer", 0.1)),
        ("input_delay=0", ("input_delay", "input_delay", 0.0)),
        ("gyro_scale=0.1", ("gyro_scale", "gyro_scale_error", 0.1)),
        ("steering_gain=-0.2", ("steering_gain", "steering_gain_error", -0.2)),
        ("torque_deadzone", ("torque_deadzone", None, None)),
        ("lighthouse_offset=0.02", ("lighthouse_offset", "lh_plane1_offset", 0.02)),
        (
            "lighthouse_offset.lh_plane2_offset=0.01",
            ("lighthouse_offset", "lh_plane2_offset", 0.01),
        ),
    ],
)
def test_parse_effect_forms(text: str, expected: tuple):
    """NAME, NAME=VALUE and NAME.PARAM=VALUE parse to (effect, parameter, value)."""
    assert parse_effect(text) == expected


def test_parse_effect_rejects_non_numbers():
    """A value that is not a finite number is a ValueError naming the effect."""
    with pytest.raises(ValueError, match="effect 'steering_lag': 'slow'"):
        parse_effect("steering_lag=slow")


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("bogus", "unknown effect 'bogus'; known: steering_offset"),
        ("steering_lag.tau=0.1", "effect 'steering_lag' has no parameter 'tau'"),
        ("steering_lag=nan", "effect 'steering_lag': 'nan' is not a finite number"),
    ],
)
def test_parse_effect_errors_name_what_is_wrong(text: str, message: str):
    with pytest.raises(ValueError, match=re.escape(message)):
        parse_effect(text)


def test_effect_spec_merges_parameters_per_effect():
    parsed = [parse_effect(t) for t in ("gyro_bias", "steering_lag=0.08", "motor_lag")]
    parsed.append(("steering_lag", "tau_steer", 0.1))
    assert effect_spec(parsed) == {
        "gyro_bias": None,
        "steering_lag": {"tau_steer": 0.1},
        "motor_lag": None,
    }


def test_parsed_lighthouse_offset_builds_a_model_with_both_plane_offsets():
    """Both parameters of a two-parameter effect can be set from the command-line form."""
    spec = effect_spec(
        parse_effect(t)
        for t in ("lighthouse_offset=0.02", "lighthouse_offset.lh_plane2_offset=-0.01")
    )
    assert spec == {"lighthouse_offset": {"lh_plane1_offset": 0.02, "lh_plane2_offset": -0.01}}
    model = CarModel(spec)
    assert model.parameters.value("lh_plane1_offset") == 0.02
    assert model.parameters.value("lh_plane2_offset") == -0.01


def test_a_parameter_names_the_effect_it_belongs_to():
    from crs_core.model.effects import effect_of_parameter

    assert effect_of_parameter("gyro_bias") == "gyro_bias"
    assert effect_of_parameter("lh_plane2_offset") == "lighthouse_offset"
    assert effect_of_parameter("Cm1") is None
