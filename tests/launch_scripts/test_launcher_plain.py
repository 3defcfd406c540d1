"""Launcher: a plain (non-ROS) process runs as ``python -m module *arguments``."""

from __future__ import annotations

import pytest

from launch_scripts.launcher import Launcher, NodeSpec


def test_plain_process_gets_its_arguments_and_no_ros_args(tmp_path) -> None:
    spec = NodeSpec("echo", "json.tool", "/car1", arguments=["--help"])
    launcher = Launcher([spec], 150, tmp_path)
    launcher.start()
    assert launcher.processes["/car1/echo"].wait(timeout=20) == 0
    log = (tmp_path / "car1_echo.log").read_text()
    assert "usage:" in log and "--ros-args" not in log  # it got exactly --help
    assert not list(tmp_path.glob("*.params.yaml"))


def test_plain_process_takes_no_parameters() -> None:
    with pytest.raises(ValueError, match="takes no parameters"):
        NodeSpec("emulator", "chronos_bridge.emulator_process", parameters={"a": 1}, arguments=[])
