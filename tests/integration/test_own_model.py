"""A model written outside crs_core, through every step a user takes, without touching the core:
``tests/own_model/linear_tyre_car.py`` (docs/own-model.md's example) is the simulated car, is
estimated with, identified from the rough prior (``crs sysid`` writes its ``model:``), validated
on another drive by that file alone (no ``--model``), and races in the launched stack, whose
estimator and controller run it while the simulated car is the dynamic bicycle."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import yaml

from launch_scripts.cli import main
from launch_scripts.sim_stack import StackOptions, run_stack

pytestmark = pytest.mark.integration

DOMAIN_OWN_MODEL = 129
OWN_MODEL = Path(__file__).resolve().parents[1] / "own_model" / "linear_tyre_car.py"
SPEC = f"{OWN_MODEL}:LinearTyreCar"
RACE_S = 30.0


def test_a_model_from_its_own_file_goes_through_every_step(tmp_path, warm_codegen):
    drives = {}
    for name, seed in (("train", 3), ("test", 4)):
        drives[name] = tmp_path / name
        argv = ["sim", "--model", SPEC, "--duration", "20", "--seed", str(seed)]
        assert main([*argv, "--out", str(drives[name])]) == 0

    estimated = tmp_path / "estimated"
    argv = ["estimate", str(drives["test"]), "--estimator", "mhe", "--model", SPEC]
    assert main([*argv, "--out", str(estimated)]) == 0
    diagnostics = json.loads((estimated / "diagnostics.json").read_text())
    assert diagnostics["model"] == SPEC
    assert diagnostics["reference"]["rmse_settled"]["position"] < 0.005

    identified = tmp_path / "identified"
    argv = ["sysid", str(drives["train"]), "--model", SPEC, "--params", "rough"]
    assert main([*argv, "--out", str(identified)]) == 0
    params = identified / "params.yaml"
    assert yaml.safe_load(params.read_text())["model"] == SPEC
    result = json.loads((identified / "result.json").read_text())
    assert {"c_front", "c_rear", "drive", "drag"} <= set(result["parameters"])

    validated = tmp_path / "validated"
    assert (
        main(["validate", str(drives["test"]), "--params", str(params), "--out", str(validated)])
        == 0
    )
    rmse = json.loads((validated / "validation.json").read_text())["position_rmse_m"]
    assert rmse["identified"] < 0.1, rmse
    refused = main(
        [
            "validate",
            str(drives["test"]),
            "--params",
            str(params),
            "--model",
            "kinematic",
            "--out",
            str(tmp_path / "no"),
        ]
    )
    assert refused != 0 and not (tmp_path / "no").exists()

    report = run_stack(
        1,
        StackOptions("mhe", params_file=params, after_start_up=True),
        RACE_S,
        tmp_path / "race",
        DOMAIN_OWN_MODEL,
    )
    assert report["node_deaths"] == []
    assert report["model"] == SPEC and report["car_truth"]["model"] == "dynamic"
    car = report["cars"]["car1"]
    assert car["laps_completed"] >= 2, car
    assert car["estimation_rmse"]["x"] < 0.005 and car["estimation_rmse"]["y"] < 0.005
