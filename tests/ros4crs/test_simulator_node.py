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


def test_a_drifting_car_publishes_its_drifted_parameters_with_the_ground_truth(
    tmp_path, monkeypatch
) -> None:
    """With ``drift_file`` the node publishes the parameters the schedule changes, as they are,
    on ``ground_truth/parameters`` beside each ground truth: ``Cm1`` at its start before the
    first command, and 0.8 of it from 1 s after the first command on."""
    import rclpy

    import ros4crs.simulator_node as simulator_node
    from chronos_msgs.msg import OnlineParameters
    from crs_core.model import CarModel
    from ros4crs import conversions
    from ros4crs.simulator_node import SimulatorNode

    drift = tmp_path / "drift.yaml"
    drift.write_text("drift:\n  - {parameter: Cm1, at_s: 1.0, factor: 0.8}\n")
    clock = [100.0]
    monkeypatch.setattr(simulator_node.time, "monotonic", lambda: clock[0])
    monkeypatch.setenv("ROS_DOMAIN_ID", "176")  # its own
    rclpy.init(args=["--ros-args", "-p", "noise_free:=true", "-p", f"drift_file:={drift}"])
    sent: list[OnlineParameters] = []
    try:
        node = SimulatorNode()
        try:
            publisher = node._truth_parameters
            assert publisher is not None
            assert publisher.topic_name.endswith(conversions.TOPICS["truth_parameters"])
            monkeypatch.setattr(publisher, "publish", sent.append)
            for seconds in (0.1, 0.2):  # no command yet
                clock[0] = 100.0 + seconds
                node._tick()
            node._on_input(conversions.CarCommand(100.3, np.array([0.0, 0.3])))
            for seconds in (0.3, 1.5, 2.0):
                clock[0] = 100.0 + seconds
                node._tick()
        finally:
            node.destroy_node()
    finally:
        rclpy.shutdown()
    values = [conversions.online_parameters_from_msg(m)[1]["Cm1"] for m in sent]
    start = CarModel().parameters.value("Cm1")
    assert values[0].value == start and values[0].std == 0.0
    assert values[-1].value == pytest.approx(0.8 * start)
