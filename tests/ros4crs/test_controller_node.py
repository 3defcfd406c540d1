"""The controller node built in this process (rclpy, no other node): its event loggers."""

from __future__ import annotations


def test_the_controller_node_logs_every_kind_of_supervisor_event() -> None:
    """Each kind has a logger, and each can be logged twice in a row (rclpy refuses a second
    severity from one call site: a stuck car's warning once killed the node)."""
    import rclpy

    from crs_core.control.supervisor import EVENT_KINDS
    from ros4crs.controller_node import ControllerNode

    rclpy.init(args=["--ros-args", "-p", "controller:=path"])
    try:
        node = ControllerNode()
        try:
            assert set(node._log) == set(EVENT_KINDS)
            for _ in range(2):
                for kind in EVENT_KINDS:
                    node._log[kind](f"test of {kind}")
        finally:
            node.destroy_node()
    finally:
        rclpy.shutdown()


def test_the_plan_and_the_solve_time_go_out_only_to_a_listener(monkeypatch) -> None:
    """An MPCC tick with an estimate publishes ``controller/plan`` (the horizon's positions, on
    the track near the car) and ``controller/solve_time`` once someone subscribes."""
    import time

    import numpy as np
    import rclpy
    from nav_msgs.msg import Path
    from rclpy.executors import SingleThreadedExecutor
    from std_msgs.msg import Float64

    from crs_core.track import load_demo_track
    from ros4crs import conversions
    from ros4crs.controller_node import ControllerNode

    monkeypatch.setenv("ROS_DOMAIN_ID", "173")  # its own (the suite's tests use others)
    rclpy.init(args=["--ros-args", "-p", "controller:=mpcc"])
    try:
        node = ControllerNode()
        listener = rclpy.create_node("listener")
        executor = SingleThreadedExecutor()
        executor.add_node(listener)
        track = load_demo_track()
        x0 = track.start_state(0.5)
        try:
            node.supervisor.observe(node.get_clock().now().nanoseconds * 1e-9, x0, "ok")
            node._control()  # nobody listens: nothing is serialised
            got: dict[str, list] = {"plan": [], "solve": []}
            listener.create_subscription(Path, "controller/plan", got["plan"].append, 10)
            listener.create_subscription(Float64, "controller/solve_time", got["solve"].append, 10)
            deadline = time.monotonic() + 10.0
            while not (got["plan"] and got["solve"]) and time.monotonic() < deadline:
                node.supervisor.observe(node.get_clock().now().nanoseconds * 1e-9, x0, "ok")
                node._control()
                executor.spin_once(timeout_sec=0.05)
            assert got["plan"] and got["solve"]
            points = conversions.plan_from_msg(got["plan"][-1])
            assert len(points) > 5
            assert np.hypot(*(points[0] - x0[:2])) < 0.2
            assert 0 < conversions.solve_time_from_msg(got["solve"][-1]) < 5.0
        finally:
            listener.destroy_node()
            node.destroy_node()
    finally:
        rclpy.shutdown()


def test_a_drive_file_makes_the_path_controller_drive_it(tmp_path) -> None:
    """``drive_file``: the supervisor runs the drive's controller with the drive's limits; a bad
    file, or a drive for the MPCC, is refused naming the parameter."""
    import pytest
    import rclpy

    from crs_core.discrepancy.drive_file import Drive, DriveController
    from ros4crs.controller_node import ControllerNode
    from ros4crs.node_support import ParameterError

    path = Drive(2.0, 1.0, 1.1, (0.1, -0.1), (0.2, 0.0), start=(0.15, -1.05, 0.0, 1.1)).save(
        tmp_path / "drive.yaml"
    )
    bad = tmp_path / "bad.yaml"
    bad.write_text("format: crs-drive/1\n")
    for arguments, error in (
        (["controller:=path", f"drive_file:={path}", "drive_after:=3.0"], None),
        (["controller:=path", f"drive_file:={bad}"], "drive_file"),
        (["controller:=mpcc", f"drive_file:={path}"], "needs controller:=path"),
    ):
        rclpy.init(args=["--ros-args", *(a for p in arguments for a in ("-p", p))])
        try:
            if error is not None:
                with pytest.raises(ParameterError, match=error):
                    ControllerNode()
                continue
            node = ControllerNode()
            try:
                assert isinstance(node.supervisor.controller, DriveController)
                assert node.supervisor.controller.lead_in_s == 3.0
                assert node.supervisor.settings.torque_min == -0.5
            finally:
                node.destroy_node()
        finally:
            rclpy.shutdown()
