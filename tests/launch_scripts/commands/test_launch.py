"""Tests of ``crs launch``: files checked before any node starts, the link options, and the
verdict on a run."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest

from launch_scripts import car_stack
from launch_scripts.car_stack import EmulatedLink
from launch_scripts.cli import main


@pytest.mark.parametrize(
    ("option", "content", "message"),
    [
        ("--track", "track:\n  xCoords: [1, 2]\n", "track.yCoords: required key missing"),
        ("--params", "parameters:\n  m: heavy\n", "parameter 'm': expected a number"),
        ("--drive", "format: crs-drive/1\nduration_s: 2\n", "segment_s: required key missing"),
    ],
)
def test_launch_checks_track_and_parameter_files_before_starting_nodes(
    option: str, content: str, message: str, tmp_path: Path, crs_refuses
):
    """A bad --track or --params of `crs launch`: one line naming the file, nothing started or
    written (the nodes would refuse it too, but only after starting)."""
    bad = tmp_path / "bad.yaml"
    bad.write_text(content)
    out = tmp_path / "out"
    err = crs_refuses(["launch", "sim", option, str(bad), "--out", str(out)])
    named = f"{option}: " if option in ("--params", "--drive") else ""
    assert err.startswith(f"crs launch: error: {named}{bad}: ") and message in err, err
    assert not out.exists()


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


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["launch", "sim", "--link", "bad"], "--link: only for crs launch car --emulate"),
        (["launch", "sim", "--link-seed", "3"], "--link-seed: only for crs launch car --emulate"),
        (
            ["launch", "car", "--car-ip", "127.0.0.1", "--link-up", "typical"],
            "--link-up: only with --emulate",
        ),
        (["launch", "car", "--emulate", "--link", "wifi"], "--link: 'wifi' is not a preset"),
        (
            ["launch", "car", "--emulate", "--link-down", "delay=3"],
            "--link-down: delay: '3' needs a unit",
        ),
        (["launch", "car", "--emulate", "--link-seed", "-1"], "link-seed must be >= 0"),
        (["bench", "link", "--presets", "clean,wifi"], "--presets: 'wifi' is not a preset"),
        (["bench", "link", "--loads", "0,17"], "--loads: 17 must be within [0, 16]"),
        (["bench", "link", "--cars", "1,1"], "--cars: '1,1' names a value twice"),
        (["bench", "stack", "--cars", "1,x"], "--cars: 'x' is not an integer"),
        (["bench", "stack", "--cars", "1,9"], "--cars: 9 must be within [1, 8]"),
        (["bench", "stack", "--cars", "1,2", "--viz"], "--cars: a list of counts runs each once"),
        (["bench", "model", "--presets", "clean"], "unrecognized arguments: --presets clean"),
    ],
)
def test_link_options_are_refused_with_one_line(
    argv: list[str], message: str, tmp_path: Path, capsys: pytest.CaptureFixture
):
    out = tmp_path / "out"
    assert main([*argv, "--out", str(out) + (".json" if argv[0] == "bench" else "")]) == 2
    err = capsys.readouterr().err
    assert message in err, err
    assert err.count("\n") == 1, err
    assert not out.exists() and not (tmp_path / "out.json").exists()


def test_launch_car_emulate_passes_the_link(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture
):
    seen: dict[str, Any] = {}

    def fake_run(*args: Any, **kwargs: Any) -> dict[str, Any]:
        seen.update(kwargs)
        return {}

    monkeypatch.setattr(car_stack, "run_car_stack", fake_run)
    monkeypatch.setattr(car_stack, "summary", lambda report, out: "done")
    argv = ["launch", "car", "--emulate", "--link", "bad", "--link-up", "typical,dup=1%"]
    assert main([*argv, "--link-seed", "7", "--out", str(tmp_path / "out")]) == 0
    assert seen["link"] == EmulatedLink("bad", "typical,dup=1%", None, 7)
    assert main(["launch", "car", "--emulate", "--out", str(tmp_path / "plain")]) == 0
    assert seen["link"] == EmulatedLink() and not seen["link"].given


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["--viz-port", "18700"], "--viz-port: only with --viz"),
        (["--viz-host", "0.0.0.0"], "--viz-host: only with --viz"),
        (["--nodes", "simulator,visualizer"], "--nodes: the visualizer runs with --viz"),
        (["--viz", "--viz-host", "lab"], "--viz-host: must be an IP address, got 'lab'"),
        (["--viz", "--viz-page-port", "8765"], "--viz-page-port: must differ from port"),
        (["--viz", "--viz-port", "0"], "--viz-port: '0': viz-port must be >= 1"),
    ],
)
def test_the_visualizer_options_are_refused_with_one_line(
    argv: list[str], message: str, tmp_path: Path, crs_refuses
):
    out = tmp_path / "out"
    assert message in crs_refuses(["launch", "sim", *argv, "--out", str(out)])
    assert not out.exists()


def test_launch_viz_passes_where_the_visualizer_serves(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
):
    from launch_scripts import sim_stack
    from launch_scripts.visualizer import VizSettings

    seen: list[Any] = []
    monkeypatch.setattr(sim_stack, "run_stack", lambda cars, options, *a: seen.append(options))
    monkeypatch.setattr(sim_stack, "summary", lambda report, out: "done")
    monkeypatch.setattr("launch_scripts.commands.launch.verdict", lambda report, laps: 0)
    argv = ["launch", "sim", "--viz", "--viz-host", "0.0.0.0", "--viz-port", "18701"]
    assert main([*argv, "--out", str(tmp_path / "a")]) == 0
    assert seen[-1].viz == VizSettings("0.0.0.0", 18701)
    assert main(["launch", "sim", "--out", str(tmp_path / "b")]) == 0
    assert seen[-1].viz is None


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["--online-params", "Cm1,,grip"], "--online-params: a comma-separated list"),
        (["--online-params", "warp"], "--online-params: no parameter 'warp'"),
        (["--car-drift", "DRIFT"], "--car-drift.drift[0].at_s: must be a finite number"),
        (["--car-drift", "MISSING"], "--car-drift.drift: cannot read"),
    ],
)
def test_online_and_drift_options_are_refused_with_one_line(
    argv: list[str], message: str, tmp_path: Path, crs_refuses
):
    drift = tmp_path / "drift.yaml"
    drift.write_text("drift:\n  - {parameter: Cm1, at_s: soon, factor: 0.9}\n")
    argv = [{"DRIFT": str(drift), "MISSING": str(tmp_path / "none.yaml")}.get(a, a) for a in argv]
    out = tmp_path / "out"
    err = crs_refuses(["launch", "sim", *argv, "--out", str(out)])
    assert message in err, err
    assert not out.exists()


def test_drive_after_needs_a_drive(tmp_path: Path, crs_refuses) -> None:
    err = crs_refuses(["launch", "sim", "--drive-after", "5", "--out", str(tmp_path / "o")])
    assert err == "crs launch: error: --drive-after: needs --drive\n"


#: The model of a file of its own, as ``--model`` takes it (loaded by path).
OWN_MODEL = "tests/own_model/linear_tyre_car.py:LinearTyreCar"


def test_the_model_options_are_in_the_help(crs) -> None:
    code, out, _ = crs(["launch", "--help"])
    assert code == 0
    flat = " ".join(out.split())
    assert "--model MODEL the estimators' and controllers' model" in flat, flat
    assert "--car-model MODEL sim, car --emulate: the simulated or emulated cars' model" in flat


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (
            ["launch", "sim", "--params", "KIN", "--model", "dynamic"],
            "--model: dynamic contradicts KIN, whose parameters are of model kinematic",
        ),
        (
            ["launch", "car", "--emulate", "--params", "KIN", "--model", OWN_MODEL],
            f"--model: {OWN_MODEL} contradicts KIN, whose parameters are of model kinematic",
        ),
        (
            ["launch", "sim", "--car-params", "KIN", "--car-model", "dynamic"],
            "--car-model: dynamic contradicts KIN, whose parameters are of model kinematic",
        ),
        (
            ["launch", "car", "--emulate", "--car-params", "KIN", "--car-model", OWN_MODEL],
            f"--car-model: {OWN_MODEL} contradicts KIN, whose parameters are of model kinematic",
        ),
        (["launch", "sim", "--model", "bogus"], "argument --model: unknown model 'bogus'"),
        (["launch", "sim", "--car-model", "no.py:Car"], "argument --car-model: no.py: no such"),
        (
            ["launch", "car", "--car-ip", "10.0.0.2", "--car-model", "kinematic"],
            "--car-model: only for simulated or emulated cars",
        ),
    ],
)
def test_a_model_that_contradicts_its_parameters_is_refused_before_the_out_is_touched(
    argv: list[str], message: str, tmp_path: Path, crs_refuses
) -> None:
    kinematic = tmp_path / "kinematic.yaml"
    kinematic.write_text("model: kinematic\nparameters:\n  m: 0.2\n")
    argv = [str(kinematic) if a == "KIN" else a for a in argv]
    out = tmp_path / "out"
    err = crs_refuses([*argv, "--out", str(out)])
    assert message.replace("KIN", str(kinematic)) in err, err
    assert not out.exists()


def test_launch_passes_the_stacks_model_and_the_cars_own(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """--model is the stack's; --car-model the cars' (by default dynamic, not --model's), each
    to the options the stack is run with; the stack's --params of a kinematic model gives the
    stack that model, and leaves the dynamic cars their defaults."""
    from launch_scripts import sim_stack

    seen: list[Any] = []
    monkeypatch.setattr(sim_stack, "run_stack", lambda cars, options, *a: seen.append(options))
    monkeypatch.setattr(sim_stack, "summary", lambda report, out: "done")
    monkeypatch.setattr("launch_scripts.commands.launch.verdict", lambda report, laps: 0)
    assert main(["launch", "sim", "--model", "kinematic", "--out", str(tmp_path / "a")]) == 0
    options = seen[-1]
    assert (options.model, options.car.model) == ("kinematic", None)
    assert (options.model_spec(), options.truth().model) == ("kinematic", "dynamic")
    argv = ["launch", "sim", "--model", OWN_MODEL, "--car-model", "kinematic"]
    assert main([*argv, "--out", str(tmp_path / "b")]) == 0
    options = seen[-1]
    assert options.model_spec() == f"{Path(OWN_MODEL.split(':')[0]).resolve()}:LinearTyreCar"
    assert options.truth().model == "kinematic"
    kinematic = tmp_path / "kinematic.yaml"
    kinematic.write_text("model: kinematic\nparameters:\n  m: 0.2\n")
    assert main(["launch", "sim", "--params", str(kinematic), "--out", str(tmp_path / "c")]) == 0
    options = seen[-1]
    assert options.model_spec() == "kinematic"
    assert (options.truth().model, options.truth().params_file) == ("dynamic", None)
