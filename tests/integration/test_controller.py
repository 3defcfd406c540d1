"""The controller node drives on fresh estimates and stops the car when they go stale."""

from __future__ import annotations

import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from crs_core.track import load_demo_track
from launch_scripts.launcher import Launcher, NodeSpec
from ros4crs import conversions
from tests.integration.stack_probe import launched, log_text, wait_for

pytestmark = pytest.mark.integration

DOMAIN = 107


def _start_state() -> np.ndarray:
    """The car at the DEMO_TRACK start pose at 1 m/s: the estimate the tests publish."""
    track = load_demo_track()
    return track.start_state(1.0)


@contextmanager
def _controller(
    tmp_path: Path, parameters: dict[str, Any]
) -> Iterator[tuple[Launcher, Any, list, Any]]:
    """A started controller node in ``/car1`` with ``parameters``, and a probe collecting its
    inputs: ``(launcher, probe, inputs, publisher of /car1/estimate/state)``."""
    from chronos_msgs.msg import CarInput, CarState

    node = NodeSpec("controller", "ros4crs.controller_node", "/car1", parameters)
    with launched([node], DOMAIN, tmp_path / "logs") as (launcher, probe):
        inputs = probe.collect(CarInput, "/car1/input")
        launcher.start()
        yield launcher, probe, inputs, probe.publisher(CarState, "/car1/estimate/state")


def test_controller_stops_the_car_when_the_estimate_goes_stale(tmp_path):
    """While estimates arrive (stamped now, the car at the start pose at 1 m/s) the controller
    commands torque; 0.2 s after they stop (its ``stale_timeout``) it commands zero torque (the
    steering of its plan), and says so in its log; when estimates return it drives again."""
    state = _start_state()
    with _controller(tmp_path, {"stale_timeout": 0.2}) as (launcher, probe, inputs, publisher):

        def publish_for(seconds: float) -> None:
            end = time.monotonic() + seconds
            while time.monotonic() < end:
                publisher.publish(conversions.car_state_msg(state, time.time()))
                time.sleep(0.01)

        def torques_since(t0: float) -> list[float]:
            return [msg.torque for received, msg in inputs if received > t0]

        # the node warms its MPCC up before it subscribes (estimates sent earlier are lost)
        wait_for(lambda: probe.subscribers_of("/car1/estimate/state"), 30.0, "the controller")
        publish_for(1.0)
        driving = wait_for(lambda: torques_since(time.time() - 0.5), 5.0, "inputs while fresh")
        assert max(driving) > 0.05
        stopped_at = time.time()
        time.sleep(0.6)  # estimates stop: stale after 0.2 s
        late = [(m.steer, m.torque) for received, m in inputs if received > stopped_at + 0.35]
        # no torque; the steering of the plan it had (Mpcc.stop), within the limits
        assert late and all(abs(steer) <= 0.34 and torque == 0.0 for steer, torque in late)
        assert "stale: stopping the car" in log_text(tmp_path / "logs", "/car1/controller")
        resumed = time.time()
        publish_for(0.5)
        # driving again: the controller's own commands, capped at the overload watch's speed
        # after the gap (braking the estimated 1 m/s, or driving), no longer the stop command
        assert max(abs(t) for t in torques_since(resumed + 0.2)) > 0.05
        assert "the loop is starved" in log_text(tmp_path / "logs", "/car1/controller")
        assert launcher.poll() == []


def test_controller_slows_down_on_a_degraded_and_stops_on_a_lost_estimate(tmp_path):
    """Fresh estimates with status ``degraded`` (the car at 1 m/s): the controller aims at its
    ``degraded_speed`` (0.3 m/s) and commands less torque than for ``ok``, saying so once;
    status ``lost``: zero torque, as for a stale estimate."""
    state = _start_state()
    parameters = {"stale_timeout": 0.2, "degraded_speed": 0.3}
    with _controller(tmp_path, parameters) as (launcher, probe, inputs, publisher):

        def inputs_while(status: str, seconds: float) -> list[tuple[float, float]]:
            start = time.time()
            end = time.monotonic() + seconds
            while time.monotonic() < end:
                publisher.publish(conversions.car_state_msg(state, time.time(), status=status))
                time.sleep(0.01)
            # the last half of the window: the controller has seen the status by then
            return [(m.steer, m.torque) for t, m in inputs if t > start + seconds / 2]

        wait_for(lambda: probe.subscribers_of("/car1/estimate/state"), 30.0, "the controller")
        ok = inputs_while("ok", 1.0)
        degraded = inputs_while("degraded", 1.0)
        lost = inputs_while("lost", 1.0)
        assert ok and degraded and lost
        assert np.mean([t for _, t in degraded]) < np.mean([t for _, t in ok]) - 0.05
        assert all(abs(steer) <= 0.34 and torque == 0.0 for steer, torque in lost)
        log = log_text(tmp_path / "logs", "/car1/controller")
        assert "state estimate degraded: slowing to 0.3 m/s" in log
        assert launcher.poll() == []
