"""``crs ros topics|echo|hz``: the stand-ins for the ros2 CLI against a running simulator."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from pathlib import Path

import pytest

from launch_scripts.launcher import Launcher, NodeSpec
from ros4crs import tools
from tests.integration.stack_probe import Probe, launched, wait_for

pytestmark = pytest.mark.integration

DOMAIN = 108
DOMAIN_REPEATED = 109
ROOT = Path(__file__).resolve().parents[2]


def test_topics_echo_and_rate_of_a_running_simulator(tmp_path, monkeypatch, warm_codegen):
    """The tools list the simulator's topics with their types, echo a wheel-speed message and
    measure the 250 Hz IMU stream (within 20 %) from another process's graph (the simulator
    publishing one message per reading: ``sensor_messages: each``)."""
    from sensor_msgs.msg import Imu

    simulator = NodeSpec(
        "simulator", "ros4crs.simulator_node", "/car1", {"seed": 3, "sensor_messages": "each"}
    )
    monkeypatch.setenv("ROS_DOMAIN_ID", str(DOMAIN))
    monkeypatch.setenv("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    with launched([simulator], DOMAIN, tmp_path / "logs") as (launcher, probe):
        imu = probe.collect(Imu, "/car1/sensors/imu")
        launcher.start()
        wait_for(lambda: len(imu) > 50, 60.0, "the simulator's IMU stream")
        topics = dict(tools.list_topics(wait=2.0))
        assert topics["/car1/sensors/imu"] == "sensor_msgs/msg/Imu"
        assert topics["/car1/sensors/lighthouse"] == "chronos_msgs/msg/LighthouseSweep"
        (message,) = tools.echo("/car1/sensors/wheel_speeds", count=1, timeout=10.0)
        assert message.front_left == message.front_left  # a real, finite reading
        rate = tools.rate("/car1/sensors/imu", window=2.0, timeout=10.0)
        assert rate["rate_hz"] == pytest.approx(250.0, rel=0.2)


def test_tools_see_the_node_on_every_one_of_repeated_calls(tmp_path, warm_codegen):
    """8 ``crs ros topics`` calls and a ``crs ros hz`` call in a row, each a new process with
    the default discovery wait, all see the simulator: a running node's reply to a new
    process's first announcement is often lost (Fast DDS), so that process finds the node only
    at the node's next announcement, which the launcher makes come every 0.25 s instead of 3 s.
    The simulator publishes its readings in 10 ms batches (the default): 100 a second.

    The ``topics`` calls carry the repetition: each waits 1 s, so with 3 s announcements each
    would miss the node whenever its reply was lost (4-7 of 12-20 calls missed it before the
    fix: :mod:`ros4crs.discovery`). ``hz`` waits up to its 5 s timeout for the
    publisher, longer than even the 3 s period, so a second call could not miss the node for
    that reason either: one shows the rate from a new process."""
    from chronos_msgs.msg import SensorBatch

    launcher = Launcher(
        [NodeSpec("simulator", "ros4crs.simulator_node", "/car1", {"seed": 3})],
        DOMAIN_REPEATED,
        tmp_path / "logs",
    )
    env = dict(os.environ, ROS_DOMAIN_ID=str(DOMAIN_REPEATED))
    env["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"

    def crs_ros(*args: str) -> str:
        command = [sys.executable, "-m", "launch_scripts.cli", "ros", *args]
        done = subprocess.run(
            command, env=env, cwd=ROOT, capture_output=True, text=True, timeout=60
        )
        assert done.returncode == 0, done.stderr[-2000:]
        return done.stdout

    expected = ["/car1/sensors/batch  [chronos_msgs/msg/SensorBatch]", "/car1/ground_truth  ["]
    probe = Probe(DOMAIN_REPEATED)
    batches = probe.collect(SensorBatch, "/car1/sensors/batch")
    try:
        launcher.start()
        try:
            wait_for(lambda: len(batches) > 20, 60.0, "the simulator's sensor batches")
        finally:
            probe.close()  # its subscription would show /car1/sensors/batch in the listings too
        started = time.monotonic()
        listings = [crs_ros("topics") for _ in range(8)]
        rate = json.loads(crs_ros("hz", "/car1/sensors/batch", "--window", "1"))
        seconds = time.monotonic() - started
        misses = [i for i, text in enumerate(listings) if not all(t in text for t in expected)]
        assert not misses, f"calls {misses} of 8 missed /car1 topics:\n{listings[misses[0]]}"
        assert rate["rate_hz"] == pytest.approx(100.0, rel=0.2)
        assert launcher.poll() == []
        print(f"9 tool calls in {seconds:.1f} s")
    finally:
        launcher.stop()
