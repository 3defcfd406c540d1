"""Tests of crs_core.control.recovery: a stuck car is noticed and backed out towards facing
along the track, on the model, without ROS."""

from __future__ import annotations

import math

import numpy as np
import pytest

from crs_core.analysis.angles import wrap_angle
from crs_core.control.recovery import RecoverySettings, StuckRecovery
from crs_core.control.supervisor import Supervisor
from crs_core.errors import FieldError
from crs_core.model import CarModel

DT = 1.0 / 30.0


def heading_error(track, x: np.ndarray) -> float:
    return float(wrap_angle(x[2] - track.project(x[0], x[1]).heading))


class Standing:
    """A controller that keeps the car standing (an MPCC at the edge facing out)."""

    def __init__(self) -> None:
        self.resets = 0

    def __call__(self, now, x, speed_limit):
        return np.array([0.3, 0.0])

    def reset(self) -> None:
        self.resets += 1


@pytest.mark.parametrize("side", [1.0, -1.0])
def test_a_car_standing_at_the_edge_facing_out_is_backed_out_to_face_along(track, pose_at, side):
    """0.26 m off the centreline (outside the 0.23 m half-width), facing 1 rad further out, as
    the car stood after an outage in a hairpin: driven by a controller that keeps it standing,
    it is noticed after stuck_after, reversed with the steering that turns its nose in, and
    handed back facing within aligned_heading of the track, nearer the centreline."""
    model = CarModel()
    p = model.parameters.vector()
    controller = Standing()
    settings = RecoverySettings()
    supervisor = Supervisor(controller, recovery=StuckRecovery(track, 0.34, settings))
    x = pose_at(track, 1.0, 0.26 * side, 1.0 * side)
    start_error = abs(heading_error(track, x))
    kinds: list[tuple[float, str]] = []
    for k in range(60):
        now = k * DT
        supervisor.observe(now, x, "ok")
        step = supervisor(now)
        kinds += [(now, e.kind) for e in step.events]
        if any(kind == "unstuck" for _, kind in kinds):
            break
        if supervisor.recovery.active:
            assert step.command[1] == -settings.reverse_torque
        x = model.numeric.step(x, step.command, p, DT)
    stuck = [t for t, kind in kinds if kind == "stuck"]
    unstuck = [t for t, kind in kinds if kind == "unstuck"]
    assert stuck and stuck[0] == pytest.approx(settings.stuck_after, abs=DT)
    assert unstuck and unstuck[0] - stuck[0] <= settings.reverse_time + DT
    assert controller.resets == 2  # at the first estimate, and from cold after backing out
    # turned 0.3 rad or more towards the track's direction, and moved back onto it
    assert abs(heading_error(track, x)) < start_error - 0.3
    assert abs(track.project(x[0], x[1]).lateral_error) < 0.23


def test_a_moving_car_is_never_backed_out(track, pose_at):
    """A car rolling at walking pace through a hairpin (0.3 m/s, above stuck_speed) for 3 s,
    and one that stops for less than stuck_after, are left to the controller."""
    recovery = StuckRecovery(track, 0.34, RecoverySettings(stuck_speed=0.2, stuck_after=0.5))
    x = pose_at(track, 5.2, 0.0, 0.0)
    for k in range(90):
        x[3] = 0.3 if k % 20 else 0.0  # stops for a tick now and then
        assert recovery(k * DT, x) is None
    assert recovery.count == 0


def test_stale_estimates_reset_the_standing_time(track, pose_at):
    """A car stopped by the supervisor (stale estimates) is not stuck: the standing time starts
    again when it drives."""
    recovery = StuckRecovery(track, 0.34, RecoverySettings(stuck_after=0.5))
    supervisor = Supervisor(Standing(), recovery=recovery)
    x = pose_at(track, 1.0, 0.0, 0.0)
    supervisor.observe(0.0, x, "ok")
    for k in range(12):  # 0.4 s driven, standing
        supervisor(k * DT)
    supervisor(1.0)  # 1 s old: stale
    for k in range(12):
        now = 1.0 + k * DT
        supervisor.observe(now, x, "ok")
        assert not any(e.kind == "stuck" for e in supervisor(now).events)


@pytest.mark.parametrize(
    "field, value", [("stuck_speed", 0.0), ("reverse_time", math.nan), ("aligned_heading", 4.0)]
)
def test_bad_settings_name_the_field(field, value):
    with pytest.raises(FieldError, match=field) as error:
        RecoverySettings(**{field: value})
    assert error.value.field == field


def test_velocity_commands_cannot_back_out(track):
    with pytest.raises(ValueError, match="recovery"):
        Supervisor(Standing(), output="velocity", recovery=StuckRecovery(track, 0.34))
