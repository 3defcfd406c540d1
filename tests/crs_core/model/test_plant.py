"""Tests of the model interface (crs_core.model.plant, plants): the derived sensors against the
dynamic bicycle's own, a model loaded from a file by path, and the one-line refusals."""

from __future__ import annotations

import pickle
import re
from pathlib import Path

import casadi as ca
import numpy as np
import pytest
import yaml

from crs_core.errors import FieldError
from crs_core.model import CarModel
from crs_core.model.bicycle import DynamicBicycle, cornering_stiffness, friction_force
from crs_core.model.plants import load_plant, model_in_file, plant_spec, resolve_model
from crs_core.model.terms import Term

OWN_MODEL = Path(__file__).resolve().parents[2] / "own_model" / "linear_tyre_car.py"
OWN_SPEC = f"{OWN_MODEL}:LinearTyreCar"


class SensorlessBicycle(DynamicBicycle):
    """The dynamic bicycle without its own IMU and encoders: the suite derives them."""

    name = "sensorless"

    def sensors(self, x, u, P):
        return {}


def random_states(model: CarModel, n: int, seed: int = 0) -> list[tuple[np.ndarray, np.ndarray]]:
    rng = np.random.default_rng(seed)
    out = []
    for _ in range(n):
        car = rng.uniform([-2, -2, -3, 0.3, -0.3, -3], [2, 2, 3, 3, 0.3, 3])
        u = rng.uniform([-0.35, -0.2], [0.35, 1.0])
        out.append((model.initial_state(car, u), u))
    return out


def test_derived_imu_and_encoders_equal_the_dynamic_bicycles_own():
    """The IMU derived from the car state's rate (d v/dt - omega x v) is the specific force the
    dynamic bicycle writes from its axle forces; the default encoders are its no-skid speeds."""
    own, derived = CarModel(), CarModel(model=SensorlessBicycle())
    p = own.parameters.vector()
    for x, u in random_states(own, 20):
        mine, theirs = own.numeric.outputs(x, u, p), derived.numeric.outputs(x, u, p)
        np.testing.assert_allclose(theirs["imu"], mine["imu"], rtol=1e-9, atol=1e-9)
        np.testing.assert_allclose(theirs["wheel_encoders"], mine["wheel_encoders"], atol=1e-12)


def test_the_dynamic_model_is_unchanged_by_the_interface():
    """The default model is the dynamic bicycle, with its states as the car state."""
    model = CarModel()
    assert isinstance(model.plant, DynamicBicycle) and model.car_state_is_state
    assert not CarModel(model="kinematic").car_state_is_state
    assert model.state_names == ("x", "y", "yaw", "vx", "vy", "omega") and model.tag == "base"
    x, u = random_states(model, 1)[0]
    np.testing.assert_array_equal(model.numeric.car_state(x, u, model.parameters.vector()), x)


def test_the_kinematic_model_turns_at_the_geometric_yaw_rate():
    """Rolling without slip: omega = v_x tan(delta) / (l_f + l_r) at every speed and steer."""
    model = CarModel(model="kinematic")
    assert model.state_names == ("x", "y", "yaw", "v")
    p, P = model.parameters.vector(), model.parameters.value
    for speed, steer in ((0.5, 0.1), (2.0, -0.3), (-1.0, 0.2)):
        x = np.array([0.0, 0.0, 0.4, speed])
        car = model.numeric.car_state(x, np.array([steer, 0.0]), p)
        assert car[5] == pytest.approx(car[3] * np.tan(steer) / (P("lf") + P("lr")), rel=1e-12)
        assert np.hypot(car[3], car[4]) == pytest.approx(abs(speed), rel=1e-12)
        back = model.initial_state(car, [steer, 0.0])
        assert back[3] == pytest.approx(speed, rel=1e-12)


def test_the_kinematic_model_is_the_dynamic_ones_limit_without_understeer():
    r"""In a gentle steady turn the dynamic bicycle's yaw rate per speed is the linear single
    track's :math:`\delta / (L + K v_x^2)`, with the understeer gradient
    :math:`K = m (l_r / C_F - l_f / C_R) / L` of its cornering stiffnesses; the kinematic
    bicycle's is :math:`\tan\delta / L` at every speed: the two agree as the speed goes to 0."""
    dynamic, kinematic = CarModel(), CarModel(model="kinematic")
    P = dynamic.parameters.value
    length = P("lf") + P("lr")
    front = cornering_stiffness(P("Df"), P("Cf"), P("Bf"))
    rear = cornering_stiffness(P("Dr"), P("Cr"), P("Br"))
    gradient = P("m") * (P("lr") / front - P("lf") / rear) / length
    steer = 0.02
    for speed in (0.3, 0.75, 1.2):
        torque = float(friction_force(speed, lambda n: P(n))) / (P("Cm1") - P("Cm2") * speed)
        u = np.array([steer, torque])
        x = dynamic.initial_state([0, 0, 0, speed, 0, 0], u)
        for _ in range(300):
            x = dynamic.numeric.step(x, u, dynamic.parameters.vector(), 0.01)
        per_speed = x[5] / x[3]
        assert per_speed == pytest.approx(steer / (length + gradient * x[3] ** 2), rel=0.02)
        car = kinematic.numeric.car_state(
            np.array([0, 0, 0, x[3]]), u, kinematic.parameters.vector()
        )
        assert car[5] / car[3] == pytest.approx(np.tan(steer) / length, rel=1e-12)
    # the departure at 1.2 m/s: K v^2 / L of the kinematic model's yaw rate
    assert gradient * 1.2**2 / length > 0.2


def test_a_model_from_a_file_loads_by_path_and_pickles_by_its_spec():
    model = CarModel(["gyro_bias"], model=OWN_SPEC)
    assert model.plant.name == "linear_tyre" and plant_spec(model.plant) == OWN_SPEC
    assert "c_front" in model.parameters.names and model.state_names[:2] == ("px", "py")
    copy = pickle.loads(pickle.dumps(model))
    x, u = random_states(model, 1)[0]
    p = model.parameters.vector()
    np.testing.assert_array_equal(copy.numeric.f(x, u, p), model.numeric.f(x, u, p))
    assert model.tag.startswith("linear_tyre")


@pytest.mark.parametrize(
    ("spec", "message"),
    [
        ("bicycle", "unknown model 'bicycle' (built in: dynamic, kinematic"),
        ("/nonexistent/m.py:M", "/nonexistent/m.py: no such file"),
        (f"{OWN_MODEL}:Nothing", "has no Plant subclass Nothing"),
        (f"{OWN_MODEL}:SPEED_FLOOR", "has no Plant subclass SPEED_FLOOR"),
        ("no_such_package.models:M", "no_such_package.models: No module named"),
        ("m.py:", "is not FILE.py:CLASS or MODULE:CLASS"),
    ],
)
def test_a_bad_model_spec_is_refused_in_one_line(spec, message):
    with pytest.raises(FieldError, match=r"^--model: ") as error:
        load_plant(spec)
    assert message in str(error.value) and "\n" not in str(error.value)


def test_a_file_that_fails_to_import_is_named(tmp_path):
    broken = tmp_path / "broken.py"
    broken.write_text("raise RuntimeError('no tyres here')\n")
    with pytest.raises(FieldError, match=r"broken\.py: RuntimeError: no tyres here"):
        load_plant(f"{broken}:Anything")


def test_a_plant_with_wrong_shapes_is_refused(tmp_path):
    source = tmp_path / "short.py"
    source.write_text(
        "import casadi as ca\n"
        "from crs_core.model.kinematic import KinematicBicycle\n"
        "class Short(KinematicBicycle):\n"
        "    name = 'short'\n"
        "    def derivative(self, x, u, P):\n"
        "        return ca.vertcat(x[3], 0.0)\n"
    )
    with pytest.raises(FieldError, match=r"short\.derivative\(\) gives 2 values for 4 states"):
        CarModel(model=f"{source}:Short")


def test_a_plant_without_its_pose_first_is_refused():
    class TurnedAround(SensorlessBicycle):
        name = "turned"
        states = (("vx", "m/s"), ("x", "m"), ("y", "m"), ("yaw", "rad"), ("vy", "m/s"))

    with pytest.raises(FieldError, match=r"^model: model turned\.states: the first three must"):
        CarModel(model=TurnedAround())


def test_what_a_model_lacks_is_named():
    with pytest.raises(FieldError, match="model kinematic has no state vy"):
        CarModel(terms=[Term("drift", "vy", (("vx",),))], model="kinematic")
    # a term in the car state's variables is the same whatever the plant's states are
    slip = Term("slip", "wheel_speeds", (("torque", "vx"),), coefficients=(2.0,))
    CarModel(terms=[slip], model="kinematic")


def test_online_parameters_are_those_the_model_has():
    with pytest.raises(FieldError, match="'grip' scales the tyre peaks Df, Dr, which the model"):
        CarModel(model="kinematic", online_parameters=["grip"])
    with pytest.raises(FieldError, match="no parameter 'Df'"):
        CarModel(model="kinematic", online_parameters=["Df"])
    assert CarModel(model="kinematic", online_parameters=["Cm1"]).state_names[-1] == "online_Cm1"


def test_the_parameter_file_names_its_model(tmp_path):
    file = tmp_path / "params.yaml"
    file.write_text(yaml.safe_dump({"model": "kinematic", "parameters": {"m": 0.25}}))
    assert model_in_file(file) == "kinematic"
    model = CarModel.from_file(file)
    assert model.plant.name == "kinematic" and model.parameters.value("m") == 0.25
    assert resolve_model(None, file) == "kinematic"
    refusal = rf"^--model: dynamic contradicts {re.escape(str(file))}, whose"
    with pytest.raises(FieldError, match=refusal):
        resolve_model("dynamic", file)
    with pytest.raises(FieldError, match="contradicts"):
        CarModel.from_file(file, model="dynamic")
    file.write_text(yaml.safe_dump({"model": 3, "parameters": {}}))
    with pytest.raises(FieldError, match=r"model: must be a model name or FILE\.py:CLASS"):
        model_in_file(file)


def test_a_model_is_a_casadi_definition_all_through():
    """Every derived expression of a model from outside is one CasADi graph in x, u, p."""
    model = CarModel(model=OWN_SPEC)
    for name, expression in model.output_expressions.items():
        free = ca.symvar(expression)
        allowed = {str(s) for s in ca.symvar(ca.vertcat(model.x_sym, model.u_sym, model.p_sym))}
        assert {str(s) for s in free} <= allowed, name
