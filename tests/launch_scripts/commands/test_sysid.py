"""Tests of ``crs sysid`` and ``crs validate``: outputs, loadable YAML, one-line input errors."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
import pytest
import yaml

from crs_core.dataset import Dataset
from crs_core.model import CarModel
from launch_scripts.commands import sysid as sysid_command
from launch_scripts.output_folder import MARKER
from sim.scenarios import simulate_dataset


@pytest.fixture(scope="module")
def drive(tmp_path_factory: pytest.TempPathFactory) -> Path:
    folder = tmp_path_factory.mktemp("sysid") / "drive"
    simulate_dataset(8.0, 5).save(folder)
    return folder


@pytest.fixture(scope="module")
def sysid_out(
    drive: Path, tmp_path_factory: pytest.TempPathFactory, crs
) -> tuple[int, str, str, Path]:
    out = tmp_path_factory.mktemp("sysid") / "result"
    code, _, stderr = crs(
        ["sysid", str(drive), "--out", str(out), "--params", "rough", "--fit", "Cm1,Iz,b_car"]
    )
    return code, _, stderr, out


def test_sysid_writes_loadable_parameters_and_a_report(sysid_out):
    code, _, stderr, out = sysid_out
    assert code == 0, stderr
    assert (out / MARKER).exists()
    for name in (
        "params.yaml",
        "result.json",
        "report.md",
        "fit.png",
        "residuals.png",
        "parameters.png",
        "correlation.png",
    ):
        assert (out / name).is_file(), name
    summary = json.loads((out / "result.json").read_text())
    assert set(summary["parameters"]) == {"Cm1", "Iz", "b_car"}
    for entry in summary["parameters"].values():
        assert {"value", "std", "identifiable", "prior", "unit"} <= set(entry)
        assert entry["std"] > 0
    assert summary["iterations"] > 0 and summary["cost"] < summary["cost_initial"]
    loaded = CarModel().parameters.updated_from_yaml(out / "params.yaml")
    assert loaded.value("b_car") == pytest.approx(summary["parameters"]["b_car"]["value"])
    assert loaded.value("Df") == pytest.approx(0.65)  # the rough prior, not fitted
    # one progress line per IPOPT iteration, not IPOPT's own output
    lines = [line for line in stderr.splitlines() if line.startswith("sysid: iteration")]
    assert len(lines) >= summary["iterations"]
    assert "EXIT" not in stderr and "Ipopt" not in stderr


def test_validate_compares_prior_and_identified(drive: Path, sysid_out, tmp_path: Path, crs):
    params = sysid_out[3] / "params.yaml"
    code, _, stderr = crs(
        [
            "validate",
            str(drive),
            "--params",
            str(params),
            "--prior",
            "rough",
            "--horizon",
            "1.0",
            "--out",
            str(tmp_path / "v"),
        ]
    )
    assert code == 0, stderr
    summary = json.loads((tmp_path / "v" / "validation.json").read_text())
    assert summary["horizon_s"] == 1.0
    rmse = summary["position_rmse_m"]
    assert set(rmse) == {"prior", "identified"} and 0 < rmse["identified"] < rmse["prior"]
    assert set(summary["channel_rms"]["identified"]) >= {"wheel_fl", "yaw_rate"}
    assert (tmp_path / "v" / "validation.png").is_file()


def _short(drive: Path, folder: Path, n: int = 10, nan: bool = False) -> Path:
    dataset = Dataset.load(drive)
    y = np.full_like(dataset.y, np.nan) if nan else dataset.y
    Dataset(t=dataset.t[:n], u=dataset.u[:n], y=y[:n], x=dataset.x[:n]).save(folder)
    return folder


@pytest.mark.parametrize(
    "case, expected",
    [
        ("too_short", "dataset: 10 samples are too few"),
        ("all_nan", "dataset: y.npy is NaN everywhere"),
        ("unknown_name", "--fit: unknown parameter 'mass'"),
        ("bounds_exclude_prior", "--params: "),
        ("missing_dataset", "DATASET: dataset folder"),
        ("bad_hessian", "argument --hessian: invalid choice"),
        ("horizon_too_long", "--horizon: 50 s is longer than the dataset"),
    ],
)
def test_bad_input_is_one_line_error(case: str, expected: str, drive: Path, tmp_path: Path, crs):
    out = str(tmp_path / "out")
    argv = {
        "too_short": ["sysid", str(_short(drive, tmp_path / "short")), "--out", out],
        "all_nan": ["sysid", str(_short(drive, tmp_path / "nan", 100, nan=True)), "--out", out],
        "unknown_name": ["sysid", str(drive), "--fit", "Cm1,mass", "--out", out],
        "bounds_exclude_prior": ["sysid", str(drive), "--params", "BOUNDS", "--out", out],
        "missing_dataset": ["sysid", str(tmp_path / "nothing"), "--out", out],
        "bad_hessian": ["sysid", str(drive), "--hessian", "newton", "--out", out],
        "horizon_too_long": [
            "validate",
            str(drive),
            "--params",
            "rough",
            "--horizon",
            "50",
            "--out",
            out,
        ],
    }[case]
    if "BOUNDS" in argv:
        path = tmp_path / "bounds.yaml"
        path.write_text(yaml.safe_dump({"parameters": {"m": {"value": 0.3, "upper": 0.2}}}))
        argv[argv.index("BOUNDS")] = str(path)
    code, _, stderr = crs(argv)
    assert code == 2
    lines = stderr.strip().splitlines()
    assert len(lines) == 1 and expected in lines[0], stderr
    if case == "bounds_exclude_prior":
        assert "'m'" in lines[0] and "outside" in lines[0]
    assert not (tmp_path / "out").exists()  # nothing written before the input was checked


def test_sysid_and_validate_are_two_commands_with_their_own_handlers():
    parser = argparse.ArgumentParser()
    commands = parser.add_subparsers(dest="command")
    sysid_command.SYSID(commands)
    sysid_command.VALIDATE(commands)
    args = parser.parse_args(["sysid", "d", "--out", "o"])
    assert args.handler is sysid_command.run_sysid and args.out == Path("o")
    args = parser.parse_args(["validate", "d", "--params", "p.yaml", "--out", "o"])
    assert args.handler is sysid_command.run_validate and args.horizon == 2.0


def test_validate_a_bag_without_reference_states(tmp_path: Path, crs):
    """car2 of the bag has neither truth nor estimates: its samples' Lighthouse fixes are the
    reference, and the report says so."""
    from tests.ros4crs.bag_builders import simulated_run, two_car_bag

    bag = two_car_bag(simulated_run(), tmp_path / "bag")
    out = tmp_path / "validation"
    argv = ["validate", str(bag), "--car", "car2", "--params", "rough", "--horizon", "0.5"]
    code, printed, warned = crs([*argv, "--out", str(out)])
    assert code == 0, warned
    summary = json.loads((out / "validation.json").read_text())
    assert summary["reference"].startswith("each sample's Lighthouse fix")
    assert 0 < summary["position_rmse_m"]["identified"] < 0.5
    assert "open-loop position RMSE" in printed


def test_sysid_on_a_bag(tmp_path: Path, crs):
    """``crs sysid BAG --car car1``: the bag's samples identified, params.yaml written."""
    from tests.ros4crs.bag_builders import simulated_run, two_car_bag

    bag = two_car_bag(simulated_run(), tmp_path / "bag")
    out = tmp_path / "sysid"
    code, printed, warned = crs(
        ["sysid", str(bag), "--car", "car1", "--fit", "Cm1", "--out", str(out)]
    )
    assert code == 0, warned
    assert (out / "params.yaml").is_file() and "sysid: " in printed
    result = json.loads((out / "result.json").read_text())
    assert result["parameters"]["Cm1"]["value"] > 0
