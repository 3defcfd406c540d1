"""The simulator node built in this process (rclpy, no other node): a late tick."""

from __future__ import annotations

import numpy as np
import pytest


def test_a_late_tick_cuts_the_motor_at_the_firmwares_instant(monkeypatch) -> None:
    """A starved process ticks 1 s after the car's last command: the car is integrated with the
    command's torque for the 0.2 s of the firmware's watchdog and coasts from there, as a
    session told so step by step; before, the torque drove it for the whole second."""
    import rclpy

    import ros4crs.simulator_node as simulator_node
    from ros4crs.simulator_node import SimulatorNode

    clock = [100.0]
    monkeypatch.setattr(simulator_node.time, "monotonic", lambda: clock[0])
    rclpy.init(args=["--ros-args", "-p", "noise_free:=true"])
    try:
        node = SimulatorNode()
        try:
            start = node.session.base_state.copy()
            drive = np.array([0.0, 0.8])
            node.session.command(drive)
            node._cutoff.commanded(0.0)
            clock[0] += 1.0
            node._tick()
            late = node.session.base_state
        finally:
            node.destroy_node()
    finally:
        rclpy.shutdown()
    from crs_core.model import CarModel
    from sim.simulator import Simulator

    reference = Simulator(CarModel(), seed=0).session(start, keep_history=False)
    reference.command(drive)
    reference.advance(0.2)
    reference.command(np.array([0.0, 0.0]))
    reference.advance(1.0)
    np.testing.assert_allclose(late, reference.base_state, atol=1e-9)
    assert late[3] == pytest.approx(reference.base_state[3])
