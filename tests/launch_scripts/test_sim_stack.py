"""``stack_nodes(cars, StackOptions(..., output=...), bag)``: what the velocity-reference stack
sets on each node."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from launch_scripts.sim_stack import StackOptions, stack_nodes, write_drift_truth


def _parameters(output: str, cars: int = 2) -> dict[str, dict]:
    nodes = stack_nodes(cars, StackOptions("ekf", output=output), Path("/tmp/unused-bag"))
    return {f"{spec.namespace}/{spec.name}": spec.parameters for spec in nodes}


def test_torque_stack_leaves_the_node_defaults():
    parameters = _parameters("torque")
    assert "onboard" not in parameters["/car1/simulator"]
    assert "output" not in parameters["/car1/controller"]


def test_velocity_stack_runs_the_onboard_loop_and_commands_velocities_on_every_car():
    parameters = _parameters("velocity")
    for car in ("/car1", "/car2"):
        assert parameters[f"{car}/simulator"]["onboard"] is True
        assert parameters[f"{car}/controller"]["output"] == "velocity"
        assert parameters[f"{car}/controller"]["controller"] == "mpcc"
        assert "onboard" not in parameters[f"{car}/estimator"]


@pytest.mark.parametrize(
    ("arguments", "message"),
    [
        ({"output": "speed"}, "output: must be one of torque, velocity, got 'speed'"),
        ({"output": "velocity", "controller": "path"}, "output: velocity needs the mpcc"),
        ({"estimator": "ukf"}, "estimator: must be ekf or mhe, got 'ukf'"),
        ({"record": "some"}, "record: must be one of all, estimates, sensors, got 'some'"),
    ],
)
def test_bad_options_are_refused(arguments: dict, message: str):
    """The options' own checks when they are made, the simulated stack's when it is built."""
    with pytest.raises(ValueError, match=message):
        stack_nodes(1, StackOptions(**{"estimator": "ekf", **arguments}), Path("/tmp/unused-bag"))


def test_car_controllers_plan_hold_safe_and_simulated_ones_only_when_told(tmp_path: Path):
    """Over Wi-Fi or a Zenoh link an outage can come at any time: the car stack's controllers,
    and those of a part of the simulated stack joined to the others by Zenoh, plan hold-safe
    commands from the start; the simulated stack's on one machine keep the node's default
    (after the first outage) unless asked (``crs launch --hold-safe``)."""
    from launch_scripts.car_stack import car_nodes
    from launch_scripts.stack_part import StackPart
    from ros4crs.zenoh.session import ZenohSettings

    def controllers(nodes) -> list[dict]:
        return [spec.parameters for spec in nodes if spec.name == "controller"]

    mhe = StackOptions("mhe")
    car = controllers(car_nodes(2, mhe, tmp_path / "bag", tmp_path, True))
    assert [p["hold_safe"] for p in car] == ["always", "always"]
    assert "hold_safe" not in controllers(stack_nodes(1, mhe, tmp_path / "bag"))[0]
    told = stack_nodes(1, StackOptions("mhe", hold_safe="never"), tmp_path / "bag")
    assert controllers(told)[0]["hold_safe"] == "never"
    far = StackPart(("estimator", "controller"), ZenohSettings("client", connect=("tcp/a:1",)))
    linked = stack_nodes(1, StackOptions("mhe", part=far), tmp_path / "bag")
    assert controllers(linked)[0]["hold_safe"] == "always"


def test_simulated_cars_are_their_own_truth_or_the_stacks_model(tmp_path: Path):
    """The simulators get the car's own parameter file and effects (as the node parses them:
    the same model), the estimators and controllers the stack's."""
    from crs_core.model.effects import effect_spec, parse_effect
    from launch_scripts.sim_stack import CarTruth
    from ros4crs.simulator_node import parse_effects

    stack, truth = tmp_path / "model.yaml", tmp_path / "truth.yaml"
    effects = (parse_effect("steering_lag=0.06"), parse_effect("gyro_bias"))
    car = CarTruth(truth, effects)
    nodes = stack_nodes(1, StackOptions("ekf", params_file=stack, car=car), tmp_path / "bag")
    parameters = {spec.name: spec.parameters for spec in nodes}
    assert parameters["simulator"]["params_file"] == str(truth.resolve())
    assert parse_effects(parameters["simulator"]["effects"]) == effect_spec(effects)
    assert parameters["estimator"]["params_file"] == str(stack.resolve())
    assert parameters["controller"]["params_file"] == str(stack.resolve())
    plain_nodes = stack_nodes(1, StackOptions("ekf", params_file=stack), tmp_path)
    plain = {s.name: s.parameters for s in plain_nodes}
    assert plain["simulator"]["params_file"] == str(stack.resolve())
    assert "effects" not in plain["simulator"]
    assert car.described() == {
        "model": None,
        "params_file": str(truth),
        "effects": ["steering_lag.tau_steer=0.06", "gyro_bias"],
        "drift_file": None,
    }


def test_the_car_stack_takes_the_shared_options_as_it_runs_them(tmp_path: Path):
    """``hold_safe`` given reaches the car stack's controllers (else ``always``); ``onboard``
    (the emulated and real cars run their onboard loop anyway) changes nothing; a track is
    refused (the emulator starts on DEMO_TRACK)."""
    from launch_scripts.car_stack import car_nodes

    def specs(options: StackOptions) -> list[tuple]:
        nodes = car_nodes(1, options, tmp_path / "bag", tmp_path, True)
        return [(n.name, n.namespace, n.parameters, n.arguments) for n in nodes]

    told = {n[0]: n[2] for n in specs(StackOptions("mhe", hold_safe="after_outage"))}
    assert told["controller"]["hold_safe"] == "after_outage"
    assert specs(StackOptions("mhe", onboard=True)) == specs(StackOptions("mhe"))
    with pytest.raises(ValueError, match=r"^track_file: the car stack races DEMO_TRACK"):
        car_nodes(1, StackOptions("mhe", track_file=tmp_path / "t.yaml"), tmp_path, tmp_path, True)


def test_online_parameters_reach_the_estimators_and_the_drift_the_simulators(tmp_path: Path):
    from launch_scripts.sim_stack import CarTruth

    drift = tmp_path / "drift.yaml"
    options = StackOptions("mhe", online_parameters=("Cm1", "grip"), car=CarTruth(drift_file=drift))
    parameters = {s.name: s.parameters for s in stack_nodes(1, options, tmp_path / "bag")}
    assert parameters["estimator"]["online_parameters"] == "Cm1,grip"
    assert parameters["simulator"]["drift_file"] == str(drift.resolve())
    plain = {s.name: s.parameters for s in stack_nodes(1, StackOptions("mhe"), tmp_path / "b")}
    assert "online_parameters" not in plain["estimator"] and "drift_file" not in plain["simulator"]
    assert CarTruth(drift_file=drift).emulator_arguments() == ["--drift", str(drift.resolve())]


def test_the_run_folder_gets_each_cars_online_parameters_from_its_first_command(tmp_path: Path):
    """t counts from the car's first command; each parameter's prior first (the stack model's),
    then a row per parameter per message."""
    import csv

    import numpy as np

    from crs_core.estimation.base import OnlineValue
    from crs_core.measurements import InputSample
    from crs_core.model import CarModel
    from launch_scripts.sim_stack import write_online_parameters
    from ros4crs.bag_replay import BagContents

    contents = BagContents([], [InputSample(10.0, np.zeros(2))], [], [], 0)
    contents.online_parameters = [
        (10.5, {"Cm1": OnlineValue(0.9, 0.05, True)}),
        (10.6, {"Cm1": OnlineValue(0.88, 0.04, True)}),
    ]
    silent = BagContents([], [InputSample(10.0, np.zeros(2))], [], [], 0)
    written = write_online_parameters({"car1": contents, "car2": silent}, tmp_path, None)
    assert written == [tmp_path / "online_parameters_car1.csv"]
    rows = list(csv.reader(written[0].open()))
    prior = CarModel().parameters["Cm1"]
    assert rows == [
        ["t", "name", "value", "std"],
        ["0.0000", "Cm1", repr(prior.value), repr(prior.prior_std)],
        ["0.5000", "Cm1", "0.9", "0.05"],
        ["0.6000", "Cm1", "0.88", "0.04"],
    ]


def test_the_summary_gives_each_cars_online_parameters_at_the_end(tmp_path: Path):
    from launch_scripts.sim_stack import summary

    car = {
        "laps_completed": 3,
        "lap_times_s": [6.8, 6.5, 6.6],
        "online_parameters": {"Cm1": {"value": 0.83502, "std": 0.0223, "informed": True}},
    }
    text = summary({"cars": {"car1": car}, "cpu_percent": {}}, tmp_path)
    assert "  online at the end: Cm1 0.835 ± 0.022" in text.splitlines()


def test_a_drifting_simulators_truth_is_written_like_an_emulated_cars(tmp_path: Path):
    """``truth_carN.npz`` of a car whose bag holds ``ground_truth/parameters``: ``t`` and
    ``x`` of its ground truth, ``drift_<name>`` at those stamps; none for a car without."""
    from ros4crs.bag_replay import BagContents

    truth = [(10.0 + 0.02 * k, np.full(6, float(k))) for k in range(4)]
    drifted = [(10.0, {"Cm1": 1.0}), (10.04, {"Cm1": 0.9})]
    contents = {
        "car1": BagContents([], [], [], truth, 0, truth_parameters=drifted),
        "car2": BagContents([], [], [], truth, 0),
    }
    (path,) = write_drift_truth(contents, tmp_path)
    assert path == tmp_path / "truth_car1.npz"
    with np.load(path) as log:
        np.testing.assert_allclose(log["t"], [10.0, 10.02, 10.04, 10.06])
        np.testing.assert_allclose(log["drift_Cm1"], [1.0, 0.95, 0.9, 0.9])
        assert log["x"].shape == (4, 6)


def test_a_drive_reaches_every_cars_controller_as_its_file(tmp_path: Path):
    drive = tmp_path / "drive.yaml"
    options = StackOptions("ekf", controller="path", drive_file=drive, drive_after=30.0)
    nodes = stack_nodes(2, options, Path("/tmp/unused-bag"))
    controllers = [spec.parameters for spec in nodes if spec.name == "controller"]
    assert len(controllers) == 2
    for parameters in controllers:
        assert parameters["controller"] == "path"
        assert parameters["drive_file"] == str(drive.resolve())
        assert parameters["drive_after"] == 30.0


def test_every_node_gets_its_model_the_simulators_the_cars_own(tmp_path: Path):
    """The estimators and controllers of every car get the stack's model, the simulators the
    cars' (the dynamic one unless told, whatever the stack's); the cars take the stack's
    parameter file only when it is of their model."""
    from launch_scripts.sim_stack import CarTruth

    own = Path("tests/own_model/linear_tyre_car.py").resolve()

    def models(options: StackOptions) -> dict[str, tuple[str, str | None]]:
        nodes = stack_nodes(2, options, tmp_path / "bag")
        return {
            f"{spec.namespace}/{spec.name}": (
                spec.parameters["model"],
                spec.parameters.get("params_file"),
            )
            for spec in nodes
            if spec.name in ("simulator", "estimator", "controller")
        }

    default = models(StackOptions("ekf"))
    assert len(default) == 6 and set(default.values()) == {("dynamic", None)}
    given = models(StackOptions("mhe", model=f"{own}:LinearTyreCar"))
    for car in ("/car1", "/car2"):
        assert given[f"{car}/estimator"] == given[f"{car}/controller"]
        assert given[f"{car}/estimator"] == (f"{own}:LinearTyreCar", None)
        assert given[f"{car}/simulator"] == ("dynamic", None)
    kinematic = tmp_path / "kinematic.yaml"
    kinematic.write_text("model: kinematic\nparameters:\n  m: 0.2\n")
    by_file = models(StackOptions("ekf", params_file=kinematic))
    assert by_file["/car2/estimator"] == ("kinematic", str(kinematic.resolve()))
    assert by_file["/car2/simulator"] == ("dynamic", None)  # not a file of its model
    told = models(StackOptions("ekf", params_file=kinematic, car=CarTruth(model="kinematic")))
    assert told["/car1/simulator"] == ("kinematic", str(kinematic.resolve()))
    with pytest.raises(ValueError, match=r"^--car-model: dynamic contradicts"):
        models(StackOptions("ekf", car=CarTruth(kinematic, model="dynamic")))
