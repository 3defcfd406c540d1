"""Tests of ``crs estimate``: estimates, diagnostics, figure, summary and one-line errors."""

from __future__ import annotations

import contextlib
import io
import json
from pathlib import Path

import numpy as np
import pytest

from crs_core.dataset import Dataset
from launch_scripts.cli import main
from launch_scripts.output_folder import MARKER


@pytest.fixture(scope="module")
def small_dataset(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("cli") / "drive"
    assert main(["sim", "--duration", "3", "--seed", "2", "--out", str(out)]) == 0
    return out


@pytest.fixture(scope="module")
def estimate_run(small_dataset: Path, tmp_path_factory: pytest.TempPathFactory):
    out = tmp_path_factory.mktemp("cli") / "estimates"
    printed = io.StringIO()
    with contextlib.redirect_stdout(printed):
        code = main(["estimate", str(small_dataset), "--estimator", "mhe", "--out", str(out)])
    return code, out, printed.getvalue()


def test_estimate_writes_estimates_diagnostics_and_figure(estimate_run, small_dataset: Path):
    """`crs estimate` exits 0 and writes estimates.npz on the dataset's stamps, JSON and PNG."""
    code, out, _ = estimate_run
    assert code == 0
    assert {p.name for p in out.iterdir()} - {MARKER} == {
        "estimates.npz",
        "diagnostics.json",
        "estimate.png",
    }
    dataset = Dataset.load(small_dataset)
    with np.load(out / "estimates.npz") as data:
        np.testing.assert_array_equal(data["t"], dataset.t)
        assert data["x"].shape == (6, dataset.t.size)
        assert data["covariance_diag"].shape == (6, dataset.t.size)
        assert set(np.unique(data["status"])) <= {0, 1, 2}
        assert data["status"][0] == 2  # blind: lost until the first Lighthouse fix
        error = np.hypot(*(data["x"][:2] - dataset.x[:, :2].T))
    assert np.max(error[dataset.t >= 2.0]) < 0.01
    report = json.loads((out / "diagnostics.json").read_text())
    assert report["estimator"] == "mhe" and report["start"] == "blind"
    assert report["sensors"] == "lh+imu+we"  # auto: what the simulated stream has
    assert report["time_to_first_fix_s"] < 1.0
    assert report["reference"]["reference"] == "simulation truth"
    assert report["reference"]["rmse"]["position"] < 0.01
    png = (out / "estimate.png").read_bytes()
    assert png[:8] == b"\x89PNG\r\n\x1a\n" and len(png) > 20_000


def test_estimate_prints_a_short_summary(estimate_run):
    """The summary names the status counts, the reference (simulation truth) and the files."""
    _, _, printed = estimate_run
    assert "status: ok" in printed and "first fix after" in printed
    assert "RMSE vs simulation truth" in printed
    assert "estimates.npz" in printed


@pytest.mark.parametrize(
    ("arguments", "message"),
    [
        (["--x0", "1,2"], "--x0: '1,2' must be 3 (x,y,yaw) or 6"),
        (["--x0", "1,nan,0"], "--x0: '1,nan,0' must be 3"),
        (["--x0", "a,b,c"], "--x0: 'a,b,c' must be 3"),
        (["--rate", "0"], "--rate: must be a finite number of Hz > 0, got '0'"),
        (["--rate", "inf"], "--rate: must be a finite number of Hz > 0"),
        (["--sensors", "lh+sonar"], "--sensors: 'lh+sonar' must combine"),
        (["--sensors", "pose"], "sensors: the dataset has no data for pose"),
        (["--online-params", "Cm1,,grip"], "--online-params: a comma-separated list"),
        (["--online-params", "Cm9"], "--online-params: no parameter 'Cm9' (known: "),
        (["--online-params", "Df,grip"], "--online-params: Df and grip together"),
        (
            ["--sensors", "lh+imu", "--online-params", "Cm1,wheel_radius_error"],
            "--online-params: wheel_radius_error: neither the car's motion nor what the sensors "
            "imu+lh read depends on it",
        ),
    ],
)
def test_estimate_bad_arguments_are_one_line_errors(
    small_dataset: Path, tmp_path: Path, crs_refuses, arguments, message
):
    """Bad --x0, --rate or --sensors: exit code 2 and one line naming the option."""
    out = tmp_path / "out"
    argv = ["estimate", str(small_dataset), "--estimator", "ekf", "--out", str(out), *arguments]
    assert message in crs_refuses(argv)


def test_estimate_missing_dataset_or_unwritable_out(
    small_dataset: Path, tmp_path: Path, crs_refuses
):
    """A missing dataset folder, or an --out inside a file: one-line errors, exit code 2."""
    err = crs_refuses(["estimate", str(tmp_path / "none"), "--estimator", "ekf", "--out", "o"])
    assert (
        err == f"crs estimate: error: DATASET: dataset folder {tmp_path / 'none'} does not exist\n"
    )
    (tmp_path / "file").write_text("")
    out = tmp_path / "file" / "out"
    err = crs_refuses(["estimate", str(small_dataset), "--estimator", "ekf", "--out", str(out)])
    assert err.startswith(f"crs estimate: error: --out: cannot write to {out}")


def test_estimate_a_bag_at_a_fixed_rate_and_at_given_stamps(tmp_path: Path, crs, crs_refuses):
    """A bag is a recording too (its car named); --output-rate and --at choose the stamps; those
    outside the data are left out with a warning that counts them, and none inside is refused."""
    from tests.ros4crs.bag_builders import simulated_run, two_car_bag

    bag = two_car_bag(simulated_run(), tmp_path / "bag")
    geometry = Dataset(np.zeros(1), None, np.zeros((1, 13))).save(tmp_path / "g") / "dataset.yaml"
    base = ["estimate", str(bag), "--car", "car1", "--geometry", str(geometry), "--estimator"]
    base.append("ekf")
    code, printed, warned = crs([*base, "--output-rate", "100", "--out", str(tmp_path / "fast")])
    assert code == 0, warned
    saved = np.load(tmp_path / "fast" / "estimates.npz")
    np.testing.assert_allclose(np.diff(saved["t"]), 0.01, rtol=0, atol=1e-6)
    assert "RMSE vs simulation truth" in printed
    stamps = saved["t"][10:20] + 0.003
    np.save(tmp_path / "at.npy", stamps)
    code, _, warned = crs([*base, "--at", str(tmp_path / "at.npy"), "--out", str(tmp_path / "at")])
    assert code == 0, warned
    np.testing.assert_array_equal(np.load(tmp_path / "at" / "estimates.npz")["t"], stamps)
    # one stamp 13 ms past the end (a motion-capture clock): estimated at the others
    np.save(tmp_path / "past.npy", np.append(stamps, saved["t"][-1] + 0.013 + 0.02))
    past = [*base, "--at", str(tmp_path / "past.npy"), "--out", str(tmp_path / "past")]
    code, _, warned = crs(past)
    assert code == 0 and "warning: --at: 1 of 11 stamps lie outside the data" in warned, warned
    np.testing.assert_array_equal(np.load(tmp_path / "past" / "estimates.npz")["t"], stamps)
    np.save(tmp_path / "late.npy", saved["t"][-2:] + 10.0)
    late = [*base, "--at", str(tmp_path / "late.npy"), "--out", str(tmp_path / "late")]
    assert "--at: " in crs_refuses(late) and "no stamp lies inside the data" in crs_refuses(late)
    both = [*base, "--at", "x.npy", "--output-rate", "5", "--out", str(tmp_path / "both")]
    assert "not allowed with argument" in crs_refuses(both)


def test_online_parameters_are_written_with_their_priors_first(small_dataset: Path, tmp_path: Path):
    """--online-params: a CSV of t, name, value, std (each parameter's prior first, then a row
    per parameter per estimate), the figure, and the final values in the diagnostics."""
    import csv

    out = tmp_path / "online"
    # the names and input mode of tests/crs_core/estimation/test_online.py: its compiled EKF
    argv = ["estimate", str(small_dataset), "--estimator", "ekf", "--inputs", "commanded"]
    argv += ["--x0", "0,0,0", "--online-params", "Cm1,gyro_bias,grip", "--out", str(out)]
    printed = io.StringIO()
    with contextlib.redirect_stdout(printed):
        assert main(argv) == 0
    rows = list(csv.DictReader((out / "online_parameters.csv").open()))
    assert list(rows[0]) == ["t", "name", "value", "std"]
    assert [r["name"] for r in rows[:3]] == ["Cm1", "gyro_bias", "grip"]
    assert {r["t"] for r in rows[:3]} == {"0.0000"}
    assert float(rows[1]["value"]) == 0.0 and float(rows[1]["std"]) == 0.05  # the prior
    n = Dataset.load(small_dataset).t.size
    assert len(rows) == 3 + 3 * n
    report = json.loads((out / "diagnostics.json").read_text())
    assert set(report["online_parameters"]) == {"Cm1", "gyro_bias", "grip"}
    with np.load(out / "estimates.npz") as data:
        assert list(data["online_names"]) == ["Cm1", "gyro_bias", "grip"]
        assert data["online_value"].shape == (3, n)
    assert (out / "online_parameters.png").read_bytes()[:4] == b"\x89PNG"
    assert "gyro_bias: " in printed.getvalue() and "online_parameters.csv" in printed.getvalue()
