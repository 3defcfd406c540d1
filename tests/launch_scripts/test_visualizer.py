"""The visualizer node of a launched stack: its settings and where it goes. No process starts."""

from __future__ import annotations

from pathlib import Path

import pytest

from crs_core.errors import FieldError
from launch_scripts.car_stack import car_nodes
from launch_scripts.sim_stack import StackOptions, stack_nodes
from launch_scripts.stack_part import StackPart
from launch_scripts.visualizer import VizSettings


def test_the_settings_serve_this_machine_only_unless_told():
    assert VizSettings().parameters() == {"host": "127.0.0.1", "port": 8765, "page_port": 8766}
    for fields, message in (
        ({"host": "localhost"}, "host: must be an IP address"),
        ({"port": 70000}, "port: must be in 1..65535"),
        ({"port": 9000, "page_port": 9000}, "page_port: must differ from port"),
    ):
        with pytest.raises(FieldError, match=message):
            VizSettings(**fields)


def test_both_stacks_add_the_visualizer_with_viz_and_the_track(tmp_path: Path):
    track = tmp_path / "track.yaml"
    viz = VizSettings("0.0.0.0", 18701, 18702)
    sim = stack_nodes(2, StackOptions("ekf", track_file=track, viz=viz), tmp_path / "bag")
    assert sim[-1].full_name == "/visualizer"
    assert sim[-1].module == "ros4crs.visualizer_node"
    assert sim[-1].parameters == {
        "host": "0.0.0.0",
        "port": 18701,
        "page_port": 18702,
        "cars": "car1,car2",
        "track_file": str(track.resolve()),
    }
    assert "/visualizer" not in [s.full_name for s in stack_nodes(1, StackOptions("ekf"), Path())]
    car = car_nodes(1, StackOptions("ekf", viz=viz), Path("bag"), tmp_path, emulate=True)
    assert [s.full_name for s in car][-3:] == ["/recorder", "/visualizer", "/car1/emulator"]


def test_the_visualizer_is_a_node_name_of_a_part():
    viz = VizSettings()
    part = StackPart(("visualizer",))
    nodes = stack_nodes(1, StackOptions("ekf", part=part, viz=viz), Path("bag"))
    assert [s.full_name for s in nodes] == ["/visualizer"]
    elsewhere = StackOptions("ekf", part=StackPart(("simulator",)), viz=viz)
    assert "/visualizer" not in [s.full_name for s in stack_nodes(1, elsewhere, Path("bag"))]
