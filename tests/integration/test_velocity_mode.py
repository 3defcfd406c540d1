"""The stack with velocity references: the MPCC commands ``[delta, v_x]`` (``MODE_VELOCITY``) to
the simulated car's onboard 250 Hz loop, the estimator ignores those commands and estimates the
inputs from the sensors; a simulator without the onboard loop refuses them and keeps running.
"""

from __future__ import annotations

import time

import numpy as np
import pytest

from crs_core.track import load_demo_track
from launch_scripts.launcher import NodeSpec
from launch_scripts.sim_stack import StackOptions, analyse, read_cars, stack_nodes
from ros4crs import conversions
from ros4crs.bag_replay import read_car
from tests.integration.stack_probe import (
    LapWatch,
    assert_clean_run,
    assert_tracked_lap,
    launched,
    log_text,
    wait_for,
)

pytestmark = pytest.mark.integration

DOMAIN_VELOCITY_STACK = 119
DOMAIN_NO_ONBOARD = 120

#: Give up on the lap after this long (measured: nodes up after ~3-8 s, a ~7 s lap).
LAP_TIMEOUT_S = 120.0


def test_velocity_mode_stack_drives_a_lap(tmp_path, warm_codegen):
    """``StackOptions("mhe", output="velocity")``: simulator (``onboard: true``), MHE estimator,
    controller (MPCC, ``output: velocity``) and recorder as processes; the car completes a lap
    of DEMO_TRACK (counted on the simulator's truth from when it starts moving, as the
    ``crs launch sim`` report does), no node dies, every command on ``input`` is a
    ``MODE_VELOCITY`` one, the estimator says once that it ignores them (so its inputs are
    estimated from the sensors) and still tracks the car, and the bag analysis agrees.

    Measured (2-core machine, loaded): a lap of 6.6-6.9 s at the MPCC's speeds, RMSE x 1.2 mm,
    y 1.4 mm, yaw 11 mrad, no deadline misses.
    """
    from chronos_msgs.msg import CarInput, CarState

    track = load_demo_track()
    bag = tmp_path / "bag"
    nodes = stack_nodes(1, StackOptions("mhe", output="velocity"), bag)
    parameters = {spec.name: spec.parameters for spec in nodes}
    assert parameters["simulator"]["onboard"] is True
    assert parameters["controller"]["output"] == "velocity"
    with launched(nodes, DOMAIN_VELOCITY_STACK, tmp_path / "logs") as (launcher, probe):
        lap_done = LapWatch(track, probe.collect(CarState, "/car1/ground_truth"))
        inputs = probe.collect(CarInput, "/car1/input")
        deaths = launcher.run(LAP_TIMEOUT_S, until=lap_done)

    assert_clean_run(deaths, launcher)
    assert lap_done.counter.laps_completed >= 1, f"no lap within {LAP_TIMEOUT_S} s"

    commands = [msg for _, msg in inputs]
    assert commands and {msg.mode for msg in commands} == {CarInput.MODE_VELOCITY}
    assert all(msg.torque == 0.0 for msg in commands)
    assert max(msg.velocity for msg in commands) > 1.0  # racing, not creeping
    estimator_log = log_text(tmp_path / "logs", "/car1/estimator")
    assert estimator_log.count("velocity-mode commands carry no torque: ignored") == 1
    assert "onboard loop" in log_text(tmp_path / "logs", "/car1/simulator")

    contents = read_car(bag, "/car1")
    assert contents.inputs == [] and contents.velocity_references > 100
    report = analyse(read_cars(bag, 1), 1, track)["cars"]["car1"]
    print(f"report: {report}")
    assert_tracked_lap(report)  # a lap, RMSE under RMSE_POSITION_M and RMSE_YAW_RAD


def test_simulator_without_onboard_refuses_velocity_commands(tmp_path):
    """Without ``onboard`` a ``MODE_VELOCITY`` command is dropped with a warning naming
    ``mode`` (the car stays put) and the node keeps running: a torque command still drives."""
    from chronos_msgs.msg import CarInput, CarState

    simulator = NodeSpec("simulator", "ros4crs.simulator_node", "/car1", {"noise_free": True})
    with launched([simulator], DOMAIN_NO_ONBOARD, tmp_path / "logs") as (launcher, probe):
        truth = probe.collect(CarState, "/car1/ground_truth")
        launcher.start()
        command = probe.publisher(CarInput, "/car1/input")
        wait_for(lambda: len(truth) > 5, 60.0, "ground truth")

        def send_for(u: list[float], mode: str, seconds: float) -> float:
            start = time.time()
            while time.time() < start + seconds:
                command.publish(conversions.car_input_msg(np.array(u), time.time(), mode))
                time.sleep(0.02)
            return start

        refused = send_for([0.0, 2.0], "velocity", 1.0)
        time.sleep(0.2)
        assert max(abs(m.vx) for t, m in truth if t > refused) < 1e-6
        log = log_text(tmp_path / "logs", "/car1/simulator")
        assert "mode: 'velocity' commands need the onboard loop (parameter onboard:=true)" in log
        assert log.count("need the onboard loop") <= 3  # throttled: about one a second
        driven = send_for([0.0, 0.3], "torque", 1.0)
        wait_for(
            lambda: max(m.vx for t, m in truth if t > driven) > 0.1,
            5.0,
            "the car to drive on torque commands",
        )
        assert launcher.poll() == []
