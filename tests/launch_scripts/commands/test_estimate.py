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
    assert err == f"crs estimate: error: dataset folder {tmp_path / 'none'} does not exist\n"
    (tmp_path / "file").write_text("")
    out = tmp_path / "file" / "out"
    err = crs_refuses(["estimate", str(small_dataset), "--estimator", "ekf", "--out", str(out)])
    assert err.startswith(f"crs estimate: error: --out: cannot write to {out}")
