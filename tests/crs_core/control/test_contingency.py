"""Tests of crs_core.control.contingency: which commands are safe to hold through an outage,
and what the filter puts in place of one that is not (the model rolled out independently)."""

from __future__ import annotations

import functools
import math

import numpy as np
import pytest

from crs_core.control.contingency import ContingencySettings, HoldSafetyFilter, braking_envelope
from crs_core.errors import FieldError
from crs_core.model import CarModel

#: Arc length where the demo track's first hairpin begins (centreline radius 0.3 m), m.
HAIRPIN = 1.1


@pytest.fixture(scope="module")
def safety(track) -> HoldSafetyFilter:
    """The filter for the firmware's bare 200 ms hold (the scenarios below are set at it; the
    default adds the command's way to the car)."""
    model = CarModel()
    settings = ContingencySettings(hold_time=0.2)
    return HoldSafetyFilter(track, model, model.parameters, 0.34, (-1.0, 1.0), 4.0, settings)


#: Time step of the independent stepping here, s.
STEP = 0.005


@functools.cache
def _model() -> CarModel:
    """The model stepped here, built once (building it takes far longer than a step)."""
    return CarModel()


def _lagged(
    x: np.ndarray, angle: float, u: np.ndarray, duration: float
) -> tuple[np.ndarray, float]:
    """State and steering angle after ``duration`` s of ``u`` from state ``x`` with the car
    steering at ``angle``: the angle follows ``u[0]`` with the settings' time constant,
    stepped here in 5 ms steps with the model's own integrator (not the filter's rollout)."""
    model = _model()
    p = model.parameters.vector()
    decay = math.exp(-STEP / ContingencySettings().steering_time_constant)
    for _ in range(round(duration / STEP)):
        angle = u[0] + (angle - u[0]) * decay
        x = model.numeric.step(x, np.array([angle, u[1]]), p, STEP)
    return x, angle


def _held(
    x: np.ndarray, u: np.ndarray, settings: ContingencySettings, angle: float | None = None
) -> tuple[np.ndarray, float]:
    """State and steering angle after ``u`` held for ``hold_time`` and coasting
    ``coast_time`` from state ``x``, the car steering at ``angle`` (default ``u[0]``)."""
    x, angle = _lagged(x, u[0] if angle is None else angle, u, settings.hold_time)
    return _lagged(x, angle, np.array([u[0], 0.0]), settings.coast_time)


def _best_recovery(held: tuple[np.ndarray, float], track) -> float:
    """The smallest largest distance from the centreline (m) any of 27 fixed recoveries (nine
    steering angles, full, half or no braking, for 0.4 s) keeps the car within from the state
    and steering angle ``held``."""
    best = math.inf
    for steer in np.linspace(-0.34, 0.34, 9):
        for torque in (-1.0, -0.5, 0.0):
            (y, angle), worst = held, 0.0
            for _ in range(16):
                u = np.array([steer, torque if y[3] > 0.5 else 0.0])
                y, angle = _lagged(y, angle, u, 0.025)
                worst = max(worst, abs(track.project(y[0], y[1]).lateral_error))
            best = min(best, worst)
    return best


@pytest.mark.parametrize(
    ("field", "value"),
    [("hold_time", -0.1), ("coast_time", math.nan), ("sample_time", 0.0), ("braking", -1.0)],
)
def test_bad_settings_name_the_field(field: str, value: float) -> None:
    with pytest.raises(FieldError) as caught:
        ContingencySettings(**{field: value})
    assert caught.value.field == field


def test_the_braking_envelope_slows_before_each_hairpin_at_the_braking_rate(track) -> None:
    """Below the top speed the envelope never falls faster ahead than braking allows
    (v^2 shrinks by at most 2 a ds), and at the hairpin it is the corner speed of its
    minimum-curvature line, between the centreline's 1.18 m/s and the top speed."""
    braking = 4.0
    envelope = braking_envelope(track, 4.0, braking, 4.0, 0.06)
    s = np.arange(0.0, track.length, 0.01)
    v = envelope(s)
    drop = v[:-1] ** 2 - v[1:] ** 2
    assert np.all(drop <= 2 * braking * 0.01 * (1 + 1e-6) + 1e-9)
    at_hairpin = float(envelope(HAIRPIN + 0.2)[0])
    assert math.sqrt(4.0 * 0.3) < at_hairpin < 2.0
    assert float(envelope(HAIRPIN - 0.8)[0]) > at_hairpin + 0.5  # faster on the straight


def test_full_throttle_towards_a_hairpin_is_replaced(safety, pose_at, track) -> None:
    """0.7 m before the hairpin at 2.3 m/s, full throttle held 200 ms and coasting would enter
    it near 2.5 m/s: not safe. The filter's command gives no throttle, and held through the
    same outage (stepped independently) it arrives no faster than the braking envelope
    allows, within the track."""
    x = pose_at(track, HAIRPIN - 0.7, 0.0, 0.0)
    x[3] = 2.3
    racing = np.array([0.0, 1.0])
    assert safety.excess(x, racing[None, :])[0] > 0
    safe = safety(x, racing)
    assert safe[1] <= 0.0
    end, _ = _held(x, safe, safety.settings)
    s_end = track.project(end[0], end[1]).s
    assert end[3] <= float(safety.envelope(s_end)[0]) + 1e-6
    assert abs(track.project(end[0], end[1]).lateral_error) <= safety.bound


def test_a_command_safe_to_hold_passes_unchanged(safety, pose_at, track) -> None:
    """Early on the long straight at 1.5 m/s, half throttle held through an outage stays on
    the track and slow enough: the command is returned as it is."""
    x = pose_at(track, 10.5, 0.0, 0.0)
    x[3] = 1.5
    command = np.array([0.02, 0.5])
    replaced = safety.replaced
    assert np.array_equal(safety(x, command), command)
    assert safety.replaced == replaced


def test_a_slow_car_is_left_to_the_controller(safety, pose_at, track) -> None:
    """At 0.3 m/s at the edge facing out no forward command is safe, and braking always is:
    filtered, such a car stood there for good. Below min_speed the command passes."""
    x = pose_at(track, 3.0, -0.15, -0.6)
    x[3] = 0.3
    command = np.array([0.34, 0.4])
    assert np.array_equal(safety(x, command), command)


def test_the_steering_held_out_of_a_bend_is_checked(safety, pose_at, track) -> None:
    """Through the hairpin at 1.4 m/s, full left lock held and coasting turns the car across
    the track: unsafe, and what replaces it keeps the car on the track when held (stepped
    independently)."""
    x = pose_at(track, HAIRPIN + 0.6, 0.0, 0.0)
    x[3] = 1.4
    command = np.array([0.34, 1.0])
    assert safety.excess(x, command[None, :])[0] > 0
    safe = safety(x, command)
    end, _ = _held(x, safe, safety.settings)
    assert abs(track.project(end[0], end[1]).lateral_error) <= safety.bound + 1e-3


def test_a_command_the_car_cannot_come_back_from_is_replaced(safety, pose_at, track) -> None:
    """Into the first bend at 1.5 m/s, turning left at 2 rad/s, 0.05 m right of the centreline:
    0.2 rad of left steering with full throttle, held and coasting, keeps the car within the
    bound (the check without a recovery passes it), but from where it ends none of 27 fixed
    recoveries keeps it there. The filter replaces it; from where its command ends one does."""
    x = pose_at(track, 0.2, -0.05, -0.2)
    x[3], x[5] = 1.5, 2.0
    command = np.array([0.2, 1.0])
    model = CarModel()
    settings = ContingencySettings(hold_time=0.2, recovery_time=0.0)
    unchecked = HoldSafetyFilter(track, model, model.parameters, 0.34, (-1.0, 1.0), 4.0, settings)
    assert unchecked.excess(x, command[None, :])[0] <= 0
    assert safety.excess(x, command[None, :])[0] > 0
    assert _best_recovery(_held(x, command, safety.settings), track) > safety.bound
    safe = safety(x, command)
    assert not np.array_equal(safe, command)
    assert _best_recovery(_held(x, safe, safety.settings), track) <= safety.bound


def test_the_steering_the_car_still_has_is_held_too(safety, pose_at, track) -> None:
    """Out of a left bend at 1.8 m/s, turning at 3 rad/s with the wheels still at 0.3 rad:
    0.1 rad and full throttle would be safe to hold if the wheels were there already, but they
    take their time (the steering loop's lag), and from where the car then ends none of 27
    fixed recoveries keeps it within the bound. The filter, told the angle, replaces it; from
    where its command ends one does."""
    x = pose_at(track, 1.6, 0.0, -0.3)
    x[3], x[5] = 1.8, 3.0
    command = np.array([0.1, 1.0])
    assert safety.excess(x, command[None, :])[0] <= 0
    assert _best_recovery(_held(x, command, safety.settings), track) <= safety.bound
    assert safety.excess(x, command[None, :], 0.3)[0] > 0
    assert _best_recovery(_held(x, command, safety.settings, 0.3), track) > safety.bound
    safe = safety(x, command, 0.3)
    assert not np.array_equal(safe, command)
    assert _best_recovery(_held(x, safe, safety.settings, 0.3), track) <= safety.bound
