"""Launcher: a plain (non-ROS) process runs as ``python -m module *arguments``."""

from __future__ import annotations

import time

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


SIGNAL_LOGGER = """
import signal, sys, time
out = sys.argv[1]
def stop(*_):
    with open(out, "a") as handle:
        handle.write(f"interrupted {time.time()}\\n")
    time.sleep(0.5)  # a clean stop that takes a while (the emulator writes its truth file)
    with open(out, "a") as handle:
        handle.write(f"exited {time.time()}\\n")
    sys.exit(0)
signal.signal(signal.SIGINT, stop)
while True:
    time.sleep(0.01)
"""


def test_nodes_that_stop_first_have_exited_before_the_others_are_interrupted(tmp_path) -> None:
    """An emulated car is stopped before the host nodes: while it stops, the host still
    sends, so it never counts the host's end as a motor cut-off."""
    script = tmp_path / "logger.py"
    script.write_text(SIGNAL_LOGGER)
    logs = {name: tmp_path / f"{name}.txt" for name in ("car", "host")}
    specs = [
        NodeSpec("host", "cProfile", arguments=[str(script), str(logs["host"])]),
        NodeSpec("car", "cProfile", arguments=[str(script), str(logs["car"])], stops_first=True),
    ]
    launcher = Launcher(specs, 150, tmp_path / "logs")
    launcher.start()
    time.sleep(1.0)
    launcher.stop()
    times = {
        name: dict(line.split() for line in path.read_text().splitlines())
        for name, path in logs.items()
    }
    assert float(times["car"]["exited"]) <= float(times["host"]["interrupted"])
