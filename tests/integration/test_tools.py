"""``crs ros topics|echo|hz``: the stand-ins for the ros2 CLI against a running simulator."""

from __future__ import annotations

import pytest
from stack_probe import Probe, wait_for

from launch_scripts.launcher import Launcher, NodeSpec
from ros4crs import tools

pytestmark = pytest.mark.integration

DOMAIN = 108


def test_topics_echo_and_rate_of_a_running_simulator(tmp_path, monkeypatch, warm_codegen):
    """The tools list the simulator's topics with their types, echo a wheel-speed message and
    measure the 250 Hz IMU stream (within 20 %) from another process's graph."""
    from sensor_msgs.msg import Imu

    launcher = Launcher(
        [NodeSpec("simulator", "ros4crs.simulator_node", "/car1", {"seed": 3})],
        DOMAIN,
        tmp_path / "logs",
    )
    monkeypatch.setenv("ROS_DOMAIN_ID", str(DOMAIN))
    monkeypatch.setenv("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    probe = Probe(DOMAIN)
    imu = probe.collect(Imu, "/car1/sensors/imu")
    try:
        launcher.start()
        wait_for(lambda: len(imu) > 50, 60.0, "the simulator's IMU stream")
        topics = dict(tools.list_topics(wait=2.0))
        assert topics["/car1/sensors/imu"] == "sensor_msgs/msg/Imu"
        assert topics["/car1/sensors/lighthouse"] == "chronos_msgs/msg/LighthouseSweep"
        (message,) = tools.echo("/car1/sensors/wheel_speeds", count=1, timeout=10.0)
        assert message.front_left == message.front_left  # a real, finite reading
        rate = tools.rate("/car1/sensors/imu", window=2.0, timeout=10.0)
        assert rate["rate_hz"] == pytest.approx(250.0, rel=0.2)
    finally:
        launcher.stop()
        probe.close()
