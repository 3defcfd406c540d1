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
