"""``crs calibrate-lighthouse``: end-to-end runs and the bad-input table."""

from __future__ import annotations

import argparse
import copy
import json
import shutil
from pathlib import Path

import numpy as np
import pytest
import yaml

from crs_core.dataset import Dataset, Geometry
from crs_core.model import CarModel
from launch_scripts.commands.calibration import COMMAND
from launch_scripts.output_folder import MARKER


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="crs")
    COMMAND(parser.add_subparsers(dest="command", required=True))
    return parser


def _run(*argv: str):
    args = _parser().parse_args(list(argv))
    return args.handler(args)


@pytest.fixture(scope="module")
def points_file(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("cal") / "points.yaml"
    _run("calibrate-lighthouse", "simulate-points", str(path), "--points", "8", "--seed", "3")
    return path


@pytest.fixture(scope="module")
def recording(tmp_path_factory: pytest.TempPathFactory) -> Path:
    folder = tmp_path_factory.mktemp("cal") / "rec"
    _run(
        "calibrate-lighthouse",
        "simulate-moving",
        "--out",
        str(folder),
        "--duration",
        "8",
        "--offset",
        "0.02",
        "--seed",
        "2",
    )
    return folder


def test_static_writes_geometry_report_and_figures(points_file: Path, tmp_path: Path):
    out = tmp_path / "static"
    _run("calibrate-lighthouse", "static", str(points_file), "--out", str(out))
    expected = {
        "geometry.yaml",
        "params.yaml",
        "report.md",
        "report.json",
        "angle_residuals.png",
        "position_residuals.png",
        "residual_vs_n.png",
        MARKER,
    }
    assert {p.name for p in out.iterdir()} == expected
    geometry = Geometry.from_dict(yaml.safe_load((out / "geometry.yaml").read_text())["geometry"])
    truth = Geometry.from_dict(
        yaml.safe_load(points_file.with_name("points_truth.yaml").read_text())["geometry"]
    )
    offset = np.subtract(geometry.base_stations[0].position, truth.base_stations[0].position)
    assert np.linalg.norm(offset) < 3e-3
    # the same geometry as parameters, for --params of every command and node
    model = CarModel.from_file(out / "params.yaml")
    np.testing.assert_allclose(
        model.parameters.value("bs0_x"), geometry.base_stations[0].position[0]
    )
    summary = json.loads((out / "report.json").read_text())
    assert summary["position_error_m"]["mean"] < 3e-3
    assert [row["n"] for row in summary["versus_n"]["rows"]] == [4, 5, 6, 7, 8]
    assert len(summary["per_point"]) == 8


def test_moving_recovers_the_clock_offset(recording: Path, tmp_path: Path):
    out = tmp_path / "moving"
    _run("calibrate-lighthouse", "moving", str(recording), "--out", str(out), "--fit-offset")
    summary = json.loads((out / "report.json").read_text())
    assert abs(summary["clock_offset_s"] - 0.02) < 2e-3
    assert (out / "offset_scan.png").exists() and (out / "moving_residuals.png").exists()
    truth = Dataset.load(recording).geometry.base_stations[0].position
    assert np.linalg.norm(np.subtract(summary["stations"][0]["position_m"], truth)) < 5e-3


def test_moving_from_the_deck_layout_alone(recording: Path, tmp_path: Path, crs, crs_refuses):
    """A recording whose geometry gives the photodiodes only: the stations and their tilt
    offsets are calibrated; an estimator on it is refused until then, naming the stations."""
    deck = tmp_path / "deck"
    shutil.copytree(recording, deck)
    meta = yaml.safe_load((deck / "dataset.yaml").read_text())
    meta["geometry"] = {"photodiodes": meta["geometry"]["photodiodes"]}
    (deck / "dataset.yaml").write_text(yaml.safe_dump(meta))
    refused = crs_refuses(
        ["estimate", str(deck), "--estimator", "ekf", "--out", str(tmp_path / "e")]
    )
    assert "geometry.base_stations: the dataset's geometry gives no base stations" in refused
    out = tmp_path / "moving"
    argv = ["calibrate-lighthouse", "moving", str(deck), "--fit-offset", "--out", str(out)]
    code, printed, errors = crs(argv)
    assert code == 0, errors
    summary = json.loads((out / "report.json").read_text())
    truth = Dataset.load(recording).geometry.base_stations[0].position
    assert np.linalg.norm(np.subtract(summary["stations"][0]["position_m"], truth)) < 5e-3
    assert "(--params)" in printed and (out / "params.yaml").exists()


def _edit(points_file: Path, tmp_path: Path, change) -> Path:
    data = yaml.safe_load(points_file.read_text())
    data = copy.deepcopy(data)
    change(data)
    path = tmp_path / "edited.yaml"
    path.write_text(yaml.safe_dump(data))
    return path


def _set(path: tuple, value):
    def change(data):
        target = data
        for key in path[:-1]:
            target = target[key]
        target[path[-1]] = value

    return change


def _drop(path: tuple):
    def change(data):
        target = data
        for key in path[:-1]:
            target = target[key]
        del target[path[-1]]

    return change


STATIC_CASES = [
    ("format", _set(("format",), "other/1"), r"^format: 'other/1', expected"),
    ("unknown key", _set(("colour",), 1), r"^POINTS_FILE: unknown key\(s\) colour"),
    (
        "stations not a list",
        _set(("stations",), {}),
        r"^stations: expected a list with one entry per base station \(or no stations key\)",
    ),
    ("tilt text", _set(("stations", 0, "dt2"), "x"), r"^stations\[0\]\.dt2: expected numbers"),
    ("photodiodes", _set(("photodiodes",), [[0, 0]]), r"^photodiodes: expected shape \(4, 2\)"),
    ("no points", _set(("points",), []), r"^points: expected a non-empty list"),
    (
        "position",
        _set(("points", 0, "position"), [1, 2, 3]),
        r"^points\[0\]\.position: expected shape \(2,\)",
    ),
    ("position missing", _drop(("points", 1, "position")), r"^points\[1\]\.position: missing"),
    ("yaw", _set(("points", 0, "yaw"), "north"), r"^points\[0\]\.yaw: expected numbers"),
    (
        "station index",
        _set(("points", 0, "sweeps", 0, "station"), 3),
        r"^points\[0\]\.sweeps\[0\]\.station: 3 is not one of the 1 station",
    ),
    (
        "plane width",
        _set(("points", 2, "sweeps", 0, "plane1"), [[0.1, 0.2, 0.3]]),
        r"^points\[2\]\.sweeps\[0\]\.plane1: expected rows of 4 angles",
    ),
    (
        "plane nan",
        _set(("points", 2, "sweeps", 0, "plane2"), [[0.1, float("nan"), 0.3, 0.4]]),
        r"^points\[2\]\.sweeps\[0\]\.plane2: contains non-finite values",
    ),
    (
        "angle range",
        _set(("points", 2, "sweeps", 0, "plane2"), [[0.1, 4.0, 0.3, 0.4]]),
        r"^points\[2\]\.sweeps\[0\]\.plane2: angles must lie in",
    ),
    (
        "no planes",
        _set(("points", 0, "sweeps", 0), {"station": 0}),
        r"^points\[0\]\.sweeps\[0\]: needs plane1 and/or plane2",
    ),
    (
        "too few points",
        lambda d: d.update(points=d["points"][:2]),
        r"^points: station 0 has both light planes at 2 point\(s\); the fit needs at least 3",
    ),
]


@pytest.mark.parametrize(
    ("change", "message"), [c[1:] for c in STATIC_CASES], ids=[c[0] for c in STATIC_CASES]
)
def test_static_bad_points_file(points_file: Path, tmp_path: Path, change, message):
    """Every malformed field: one-line ValueError naming it; no output folder is made."""
    path = _edit(points_file, tmp_path, change)
    out = tmp_path / "out"
    with pytest.raises(ValueError, match=message) as error:
        _run("calibrate-lighthouse", "static", str(path), "--out", str(out))
    assert "\n" not in str(error.value)
    assert not out.exists()


def test_static_bad_arguments(points_file: Path, tmp_path: Path):
    not_yaml = tmp_path / "bad.yaml"
    not_yaml.write_text("points: [unclosed\n")
    a_file = tmp_path / "file.txt"
    a_file.write_text("mine")
    cases = [
        (
            [str(tmp_path / "missing.yaml"), "--out", str(tmp_path / "o1")],
            r"^POINTS_FILE: .*missing\.yaml does not exist",
        ),
        ([str(not_yaml), "--out", str(tmp_path / "o2")], r"^POINTS_FILE: .* is not valid YAML"),
        (
            [str(points_file), "--out", str(tmp_path / "o3"), "--stations", "2"],
            r"^--stations: POINTS_FILE lists 1 station\(s\); got 2",
        ),
        ([str(points_file), "--out", str(a_file)], r"^--out: .* is a file"),
    ]
    for argv, message in cases:
        with pytest.raises(ValueError, match=message):
            _run("calibrate-lighthouse", "static", *argv)


def test_moving_bad_inputs(recording: Path, tmp_path: Path):
    no_pose = tmp_path / "no_pose"
    dataset = Dataset.load(recording)
    dataset.measurements = [m for m in dataset.measurements if m.sensor != "pose"]
    dataset.save(no_pose)
    cases = [
        ([str(no_pose), "--fit-offset"], ValueError, r"^pose: the dataset has no motion-capture"),
        ([str(recording), "--offset", "0.5"], ValueError, r"^--offset: 0.5 s lies outside"),
        ([str(tmp_path / "nothing")], ValueError, r"^DATASET: dataset folder .* does not exist"),
    ]
    for argv, kind, message in cases:
        with pytest.raises(kind, match=message):
            _run("calibrate-lighthouse", "moving", *argv, "--out", str(tmp_path / "o"))
        assert not (tmp_path / "o").exists()


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (
            ["static", "p.yaml", "--out", "o", "--stations", "0"],
            "--stations: '0': stations must be >= 1",
        ),
        (["static", "p.yaml", "--out", "o", "--stations", "two"], "--stations: 'two' is not"),
        (
            ["moving", "d", "--out", "o", "--max-offset", "nan"],
            "--max-offset: 'nan': max-offset must be",
        ),
        (["simulate-points", "p.yaml", "--sweeps", "0"], "--sweeps: '0': sweeps must be >= 1"),
    ],
)
def test_argument_types_name_the_option(argv, message, capsys):
    with pytest.raises(SystemExit):
        _parser().parse_args(["calibrate-lighthouse", *argv])
    assert message in capsys.readouterr().err


def test_moving_from_a_mocap_bag_and_the_deck_layout(recording: Path, tmp_path: Path, crs):
    """The 8 s motion-capture recording as a bag (its readings in the stack's sensor batches)
    and a --geometry that gives the photodiodes only: the station comes back."""
    from types import SimpleNamespace

    from tests.ros4crs.bag_builders import stack_messages, write_bag

    dataset = Dataset.load(recording)
    run = SimpleNamespace(measurements=dataset.measurements, inputs=[], truth_t=[], truth_x=[])
    messages = stack_messages(run, truth=False)  # type: ignore[arg-type]
    bag = write_bag(tmp_path / "bag", sorted(messages, key=lambda m: m[2]))
    deck = tmp_path / "deck.yaml"
    diodes = [list(p) for p in dataset.geometry.photodiodes]
    deck.write_text(yaml.safe_dump({"geometry": {"photodiodes": diodes}}))
    out = tmp_path / "cal"
    argv = ["calibrate-lighthouse", "moving", str(bag), "--geometry", str(deck), "--fit-offset"]
    code, _, errors = crs([*argv, "--out", str(out)])
    assert code == 0, errors
    station = Geometry.from_file(out / "geometry.yaml").base_stations[0]
    truth = dataset.geometry.base_stations[0].position
    assert np.linalg.norm(np.subtract(station.position, truth)) < 5e-3
