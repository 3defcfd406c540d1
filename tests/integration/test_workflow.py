"""The day, end to end, on a car that is not the model: an emulated car whose motor and front
tyres are off and whose gyro has a bias the stack's model does not have is raced by the stack
(``crs launch car --emulate --car-params --car-effect``, the default model) and recorded;
``crs discrepancy`` reads that bag (identifying the model on it first, as ``crs sysid`` does:
that command on a bag is tested in tests/launch_scripts/commands/test_sysid.py) and names the
effect with its value, and the final model closes most of the gap. (``crs bench workflow``
runs the whole day, with a second race on the result, and measures it.)"""

from __future__ import annotations

import json

import pytest
import yaml

from crs_core.model import CarModel
from crs_core.model.effects import parse_effect
from launch_scripts.car_stack import run_car_stack
from launch_scripts.cli import main
from launch_scripts.sim_stack import CarTruth, StackOptions

pytestmark = pytest.mark.integration

DOMAIN_WORKFLOW = 128
#: Not the benchmark's car: other parameters, another sign and size of the bias.
TRUTH_FACTORS = {"Df": 1.12, "Cm1": 0.85}
GYRO_BIAS = -0.18
#: Seconds raced: at 20 s the bias (then -0.12 rad/s) was fitted (-0.113 ± 0.01 rad/s) but its
#: held-out test (p = 0.012) missed the threshold of 4 candidates (0.0025); at 30 s on a slower
#: CI host it was fitted right (-0.1215 ± 0.0084) but held out gave p = 0.019: the last 30 %,
#: 9 s, hold few blocks for the held-out block test (then a t-test on the differences), and
#: a bias of that size improved them unevenly. A bias of -0.18 rad/s at 30 s: p = 6e-6 (racing
#: 50 s for a fourth block cost 55 s of the suite).
RACE_S = 30.0


def test_a_recorded_bag_names_the_hidden_effect_and_closes_the_gap(tmp_path, warm_codegen):
    defaults = CarModel().parameters
    truth = tmp_path / "truth.yaml"
    changed = {name: defaults.value(name) * f for name, f in TRUTH_FACTORS.items()}
    truth.write_text(yaml.safe_dump({"parameters": changed}))
    car = CarTruth(truth, (parse_effect(f"gyro_bias={GYRO_BIAS}"),))
    report = run_car_stack(
        1,
        StackOptions("mhe", after_start_up=True, car=car),
        RACE_S,
        tmp_path / "race",
        True,
        domain_id=DOMAIN_WORKFLOW,
        ports=(21241, 21341),
    )
    assert report["node_deaths"] == [] and report["cars"]["car1"]["laps_completed"] >= 1
    assert report["car_truth"]["effects"] == [f"gyro_bias.gyro_bias={GYRO_BIAS!r}"]
    bag = tmp_path / "race" / "bag"

    # the gyro bias against the one other effect that biases the yaw rate's residual (the
    # steering's offset); an input delay, a third candidate, took 20 of the test's 120 s
    candidates = "gyro_bias,steering_offset"
    argv = ["discrepancy", str(bag), "--candidates", candidates, "--out", str(tmp_path / "found")]
    # the parameters the car changed and the yaw inertia, not all of the dynamics' (the same
    # verdict and bias on a recorded race: 38 s instead of 50 s)
    argv += ["--fit", "Cm1,Df,Dr,Iz"]
    assert main(argv) == 0
    found = json.loads((tmp_path / "found" / "report.json").read_text())
    assert found["effects"] == ["gyro_bias"], found["headline"]
    bias = found["parameters"]["gyro_bias"]["gyro_bias"]["value"]
    assert bias == pytest.approx(GYRO_BIAS, rel=0.3), bias
    assert found["gap_after"] < 0.7 * found["gap_before"], (found["gap_before"], found["gap_after"])
    final = CarModel.from_file(tmp_path / "found" / "params.yaml")
    assert [e.name for e in final.effects] == ["gyro_bias"]  # loadable by every --params
