"""Tests of the ``crs`` command line: simulate, save, report, argument validation."""

from __future__ import annotations

import contextlib
import io
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


BAD_INPUTS = [
    (["sim", "--duration", "inf"], "crs sim: error: argument --duration: 'inf': duration must be"),
    (["sim", "--duration", "1e9"], "duration must be > 0 and <= 3600 s"),
    (["sim", "--duration", "-3"], "duration must be > 0 and <= 3600 s"),
    (["sim", "--duration", "nan"], "argument --duration: 'nan'"),
    (["sim", "--blackout", "bogus:1:1"], "argument --blackout: 'bogus:1:1': sensor 'bogus'"),
    (["sim", "--blackout", "lighthouse:nan:1"], "START 'nan' is not a finite number"),
    (["sim", "--blackout", "lighthouse:1"], "expected SENSOR:START:DURATION"),
    (["sim", "--speed", "-1"], "argument --speed: '-1': speed must be > 0 and <= 5 m/s"),
    (["sim", "--stations", "0"], "argument --stations: '0': stations must be > 0"),
    (["launch", "sim", "--duration", "0"], "crs launch: error: argument --duration: '0'"),
    (["launch", "sim", "--cars", "0"], "argument --cars: '0': cars must be > 0"),
    (
        ["launch", "sim", "--output", "velocity", "--controller", "path"],
        "crs launch: error: --output: velocity needs --controller mpcc (the path controller",
    ),
    (["launch", "sim", "--output", "speed"], "crs launch: error: argument --output: invalid"),
    (["ros", "echo"], "crs ros: error: TOPIC: echo needs a topic"),
    (["ros", "hz", "/car1/input", "--window", "-1"], "argument --window: '-1': window must"),
]


@pytest.mark.parametrize(("argv", "message"), BAD_INPUTS)
def test_bad_arguments_give_one_line_and_start_nothing(
    argv: list[str], message: str, tmp_path: Path, capsys: pytest.CaptureFixture
):
    """Each bad argument: exit code 2, one line naming the argument, no output written."""
    out = tmp_path / "out"
    if argv[0] in ("sim", "launch"):
        argv = [*argv, "--out", str(out)]
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert message in err, err
    assert err.count("\n") == 1, err
    assert not out.exists()


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
    content: str, message: str, tmp_path: Path, capsys: pytest.CaptureFixture
):
    params = tmp_path / "p.yaml"
    params.write_text(content)
    out = tmp_path / "out"
    assert main(["sim", "--params", str(params), "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.startswith("crs sim: error: ") and message in err, err
    assert err.count("\n") == 1
    assert not out.exists()


@pytest.mark.parametrize(
    ("option", "content", "message"),
    [
        ("--track", "track:\n  xCoords: [1, 2]\n", "track.yCoords: required key missing"),
        ("--params", "parameters:\n  m: heavy\n", "parameter 'm': expected a number"),
    ],
)
def test_launch_checks_track_and_parameter_files_before_starting_nodes(
    option: str, content: str, message: str, tmp_path: Path, capsys: pytest.CaptureFixture
):
    """A bad --track or --params of `crs launch`: one line naming the file, nothing started or
    written (the nodes would refuse it too, but only after starting)."""
    bad = tmp_path / "bad.yaml"
    bad.write_text(content)
    out = tmp_path / "out"
    assert main(["launch", "sim", option, str(bad), "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"crs launch: error: {bad}: ") and message in err, err
    assert err.count("\n") == 1
    assert not out.exists()


def test_a_folder_as_parameter_file_is_refused(tmp_path: Path, capsys: pytest.CaptureFixture):
    assert main(["sim", "--params", str(tmp_path), "--out", str(tmp_path / "out")]) == 2
    assert "is a folder, not a parameter YAML file" in capsys.readouterr().err


def test_run_time_errors_exit_with_code_2(tmp_path: Path, capsys: pytest.CaptureFixture):
    """A missing parameter file or a zero duration returns 2 with a `crs sim: error:` line."""
    code = main(["sim", "--out", str(tmp_path / "a"), "--params", str(tmp_path / "none.yaml")])
    assert code == 2
    assert "crs sim: error:" in capsys.readouterr().err
    code = main(["sim", "--out", str(tmp_path / "b"), "--duration", "0"])
    assert code == 2
    assert "duration must be > 0" in capsys.readouterr().err


# --- crs estimate ---------------------------------------------------------------------------------
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
    small_dataset: Path, tmp_path: Path, capsys: pytest.CaptureFixture, arguments, message
):
    """Bad --x0, --rate or --sensors: exit code 2 and one line naming the option."""
    out = tmp_path / "out"
    argv = ["estimate", str(small_dataset), "--estimator", "ekf", "--out", str(out), *arguments]
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert err.startswith("crs estimate: error: ") and message in err
    assert err.count("\n") == 1 and "Traceback" not in err


def test_estimate_missing_dataset_or_unwritable_out(
    small_dataset: Path, tmp_path: Path, capsys: pytest.CaptureFixture
):
    """A missing dataset folder, or an --out inside a file: one-line errors, exit code 2."""
    assert main(["estimate", str(tmp_path / "none"), "--estimator", "ekf", "--out", "o"]) == 2
    err = capsys.readouterr().err
    assert err == f"crs estimate: error: dataset folder {tmp_path / 'none'} does not exist\n"
    (tmp_path / "file").write_text("")
    out = tmp_path / "file" / "out"
    assert main(["estimate", str(small_dataset), "--estimator", "ekf", "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"crs estimate: error: --out: cannot write to {out}")
    assert err.count("\n") == 1


def test_a_launch_that_races_too_few_laps_or_loses_a_node_fails_with_a_headline(capsys) -> None:
    from launch_scripts.commands.launch import verdict

    report = {"node_deaths": [], "cars": {"car1": {"laps_completed": 5}}}
    assert verdict(report, 3) == 0 and verdict(report, 0) == 0
    report["cars"]["car2"] = {"laps_completed": 0}
    assert verdict(report, 3) == 1
    assert "FAILED: car2 raced 0 laps, fewer than the 3 required" in capsys.readouterr().err
    report = {"node_deaths": [{"node": "/car1/estimator", "returncode": -11}], "cars": {}}
    assert verdict(report, 0) == 1
    assert "/car1/estimator died" in capsys.readouterr().err
