"""Tests of ``crs sim``: simulate, save, report, effects and parameter files."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import yaml

from crs_core.dataset import Dataset
from launch_scripts.cli import main
from launch_scripts.output_folder import MARKER

DATASET_FILES = {"t.npy", "u.npy", "y.npy", "x.npy", "dataset.yaml", "stream.npz"}


@pytest.fixture(scope="module")
def lag_run(tmp_path_factory: pytest.TempPathFactory) -> tuple[int, Path]:
    out = tmp_path_factory.mktemp("cli") / "d"
    code = main(
        [
            "sim",
            "--duration",
            "3",
            "--seed",
            "1",
            "--out",
            str(out),
            "--effect",
            "steering_lag=0.08",
            "--noise-free",
        ]
    )
    return code, out


@pytest.fixture(scope="module")
def report_run(tmp_path_factory: pytest.TempPathFactory) -> tuple[int, Path]:
    out = tmp_path_factory.mktemp("cli") / "r"
    code = main(["sim", "--duration", "2", "--out", str(out), "--report", "--noise-free"])
    return code, out


def test_sim_writes_a_complete_dataset(lag_run: tuple[int, Path]):
    """`crs sim` exits 0 and writes t/u/y/x .npy, dataset.yaml and stream.npz."""
    code, out = lag_run
    assert code == 0
    assert {p.name for p in out.iterdir()} - {MARKER} == DATASET_FILES
    assert not (out / "report").exists()  # --report is off by default for `sim`


def test_sim_records_effect_and_settings_in_yaml(lag_run: tuple[int, Path]):
    """dataset.yaml names the hidden effect, tau_steer = 0.08, the seed and ideal sensors."""
    _, out = lag_run
    meta = yaml.safe_load((out / "dataset.yaml").read_text())
    assert meta["source"] == "simulated"
    assert meta["truth"]["effects"] == ["steering_lag"]
    assert meta["truth"]["parameters"]["tau_steer"] == 0.08
    assert meta["seed"] == 1
    assert meta["duration_s"] == 3.0
    assert meta["noise_free"] is True
    assert meta["sensors"]["lighthouse"]["noise_std"] == [0.0] * 4
    assert meta["sensors"]["lighthouse"]["dropout_probability"] == 0.0


def test_sim_dataset_loads_and_the_car_drives(lag_run: tuple[int, Path]):
    """The written dataset loads, has ~50 Hz samples over 3 s, and the true car moves forward."""
    _, out = lag_run
    data = Dataset.load(out)
    assert data.t.size == 150
    assert data.x is not None and data.truth_x is not None
    assert data.truth_t[-1] == pytest.approx(3.0, abs=0.01)
    assert np.max(data.x[:, 3]) > 0.5
    assert np.all(np.isfinite(data.y))
    assert np.all((data.u[:, 1] >= -1) & (data.u[:, 1] <= 1))


def test_report_writes_summary_and_three_plots(report_run: tuple[int, Path]):
    """`--report` writes summary.json (with sensor rates), summary.txt and three PNG files
    (path, sensors, and the estimation error over time)."""
    code, out = report_run
    assert code == 0
    report = out / "report"
    summary = json.loads((report / "summary.json").read_text())
    assert summary["duration_s"] == 2.0
    assert summary["seed"] == 0
    assert summary["effects"] == {}
    assert summary["sensors"]["imu"] == {"samples": 500, "rate_hz": 250.0}
    assert summary["sensors"]["lighthouse/0/2"]["rate_hz"] == 50.0
    assert summary["max_speed_mps"] > 0.3
    assert "real_time_factor" in summary
    assert (report / "summary.txt").read_text().startswith("Chronos simulation: 2.0 s, seed 0")
    pngs = sorted(p.name for p in report.glob("*.png"))
    assert pngs == ["estimation.png", "path.png", "sensors.png"]
    for name in pngs:
        data = (report / name).read_bytes()
        assert data[:8] == b"\x89PNG\r\n\x1a\n" and len(data) > 10_000


def test_unknown_effect_is_an_argparse_error(tmp_path: Path, capsys: pytest.CaptureFixture):
    """`--effect bogus` exits with code 2 and names the effect and the known ones."""
    assert main(["sim", "--out", str(tmp_path / "x"), "--effect", "bogus=1"]) == 2
    err = capsys.readouterr().err
    assert "unknown effect 'bogus'" in err
    assert "steering_lag" in err
    assert not (tmp_path / "x").exists()


def test_unknown_effect_parameter_is_an_argparse_error(
    tmp_path: Path, capsys: pytest.CaptureFixture
):
    """`--effect input_delay.bogus=1` exits with code 2 and lists the effect's parameters."""
    assert main(["sim", "--out", str(tmp_path / "x"), "--effect", "input_delay.bogus=1"]) == 2
    err = capsys.readouterr().err
    assert "effect 'input_delay' has no parameter 'bogus'" in err
    assert not (tmp_path / "x").exists()


@pytest.mark.parametrize(
    ("content", "message"),
    [
        ("parameters:\n  m:\n", "parameter 'm': has no value"),
        ("parameters:\n  m: {valu: 0.3}\n", "parameter 'm': unknown field(s) ['valu']"),
        ("parameters:\n  m: [1, 2\n", "not valid YAML at line"),
        ("parameters:\n  m: heavy\n", "parameter 'm': expected a number, got 'heavy'"),
        ("parameters:\n  mass: 0.3\n", "unknown parameter(s) ['mass']"),
    ],
)
def test_bad_parameter_files_are_refused_naming_the_field(
    content: str, message: str, tmp_path: Path, crs_refuses
):
    params = tmp_path / "p.yaml"
    params.write_text(content)
    out = tmp_path / "out"
    assert message in crs_refuses(["sim", "--params", str(params), "--out", str(out)])
    assert not out.exists()


def test_a_folder_as_parameter_file_is_refused(tmp_path: Path, capsys: pytest.CaptureFixture):
    assert main(["sim", "--params", str(tmp_path), "--out", str(tmp_path / "out")]) == 2
    assert "is a folder, not a parameter YAML file" in capsys.readouterr().err
