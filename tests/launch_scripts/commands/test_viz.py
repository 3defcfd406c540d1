"""``crs viz``: the visualizer node's command line from the options, and one-line errors. The
node itself is driven by tests/integration/test_visualizer.py."""

from __future__ import annotations

from pathlib import Path

import pytest

from launch_scripts.cli import main, make_parser
from launch_scripts.commands.viz import node_arguments


def _args(*argv: str):
    return make_parser().parse_args(["viz", *argv])


def test_the_options_become_the_nodes_parameters(tmp_path: Path):
    assert node_arguments(_args()) == [
        "crs-viz",
        "--ros-args",
        "-r",
        "__node:=visualizer",
        "-p",
        "host:=127.0.0.1",
        "-p",
        "port:=8765",
        "-p",
        "page_port:=8766",
    ]
    track = tmp_path / "track.yaml"
    track.write_text("")
    argv = ["--host", "0.0.0.0", "--port", "18705", "--cars", "/car2, car1", "--track", str(track)]
    command = node_arguments(_args(*argv))
    assert command[5:] == [
        "host:=0.0.0.0",
        "-p",
        "port:=18705",
        "-p",
        "page_port:=8766",
        "-p",
        "cars:=car2,car1",
        "-p",
        f"track_file:={track.resolve()}",
    ]


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["--host", "lab-pc"], "--host: must be an IP address, got 'lab-pc'"),
        (["--page-port", "8765"], "--page-port: must differ from port"),
        (["--cars", "car1,car1"], "--cars: 'car1,car1' names a car twice"),
        (["--cars", "car-1"], "--cars: 'car-1' is not a car namespace"),
        (["--track", "missing.yaml"], "--track: missing.yaml: no such file"),
    ],
)
def test_bad_options_are_refused_with_one_line(argv, message, crs_refuses):
    assert message in crs_refuses(["viz", *argv])


def test_layout_writes_the_foxglove_layout_of_the_cars_and_refuses_to_overwrite(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    import json

    out = tmp_path / "three.json"
    assert main(["viz", "--layout", str(out), "--cars", "car1,car2,car3"]) == 0
    assert "wrote" in capsys.readouterr().out
    text = out.read_text()
    assert all(f"/viz/car{i}/status.status" in text for i in (1, 2, 3))
    assert json.loads(text)["version"] == 1
    assert main(["viz", "--layout", str(out)]) == 2
    assert "--layout" in capsys.readouterr().err
    assert main(["viz", "--layout", str(tmp_path / "x.json"), "--cars", "car1,car1"]) == 2
    assert "--cars" in capsys.readouterr().err
