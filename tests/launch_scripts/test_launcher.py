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


def test_nodes_that_name_one_process_run_in_it(tmp_path) -> None:
    """Two nodes of /car1 with ``process="pipeline"`` start as one ``ros4crs.composed``
    process, ``/car1/pipeline``, each with its own parameter file; a third, without, alone."""
    specs = [
        NodeSpec(
            "estimator", "ros4crs.estimator_node", "/car1", {"estimator": "ekf"}, process="pipeline"
        ),
        NodeSpec(
            "controller",
            "ros4crs.controller_node",
            "/car1",
            {"controller": "path"},
            process="pipeline",
        ),
        NodeSpec("echo", "json.tool", "/car1", arguments=["--help"]),
    ]
    launcher = Launcher(specs, 151, tmp_path)
    try:
        launcher.start()
        assert set(launcher.processes) == {"/car1/pipeline", "/car1/echo"}
        command = launcher.processes["/car1/pipeline"].args
        assert command[1:3] == ["-m", "ros4crs.composed"]
        assert [a.split("=")[0] for a in command[4::2]] == ["/car1/estimator", "/car1/controller"]
        assert {p.name for p in tmp_path.glob("*.params.yaml")} == {
            "car1_estimator.params.yaml",
            "car1_controller.params.yaml",
        }
    finally:
        launcher.stop()


def test_a_plain_process_shares_no_process() -> None:
    with pytest.raises(ValueError, match="shares no process"):
        NodeSpec("emulator", "chronos_bridge.emulator_process", arguments=[], process="pipeline")


SLOW_STARTER = """
import signal, sys, time
signal.signal(signal.SIGINT, lambda *_: sys.exit(0))  # the launcher's stop: at once
time.sleep(float(sys.argv[1]))
print("up", flush=True)
while True:
    time.sleep(0.01)
"""


def test_a_run_counts_its_duration_from_the_moment_every_process_has_started(tmp_path) -> None:
    """Slow imports (a loaded machine) do not eat the run: with a start-up limit the duration
    counts once the slowest process has started (a plain process: its first output), and
    from the limit on when one never does; without, from the launch."""
    script = tmp_path / "starter.py"
    script.write_text(SLOW_STARTER)
    specs = [
        NodeSpec("quick", "cProfile", arguments=[str(script), "0"]),
        NodeSpec("slow", "cProfile", arguments=[str(script), "1.5"]),
    ]
    launcher = Launcher(specs, 150, tmp_path / "logs")
    assert launcher.run(0.5, startup_limit=30.0) == []
    assert 1.5 <= launcher.startup_s < 30.0
    assert launcher.wall_at_stop >= launcher.startup_s + 0.5

    silent = [NodeSpec("silent", "cProfile", arguments=[str(script), "1000"])]
    launcher = Launcher(silent, 150, tmp_path / "logs_silent")
    assert launcher.run(0.2, startup_limit=1.0) == []
    assert launcher.startup_s is None and launcher.wall_at_stop >= 1.2

    launcher = Launcher(specs, 150, tmp_path / "logs_from_launch")
    assert launcher.run(2.5) == []
    assert launcher.startup_s is not None and 1.5 <= launcher.startup_s < 2.5
    assert launcher.wall_at_stop < launcher.startup_s + 2.5
