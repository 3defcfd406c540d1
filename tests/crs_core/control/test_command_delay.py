"""Tests of crs_core.control.command_delay: the delay from a control tick to the car applying
its command, measured by matching the car's reports of the drive power it applies."""

from __future__ import annotations

import math

import numpy as np
import pytest

from crs_core.control.command_delay import CommandDelay, CommandDelaySettings
from crs_core.control.mpcc import Mpcc
from crs_core.control.supervisor import Supervisor
from crs_core.model import CarModel
from crs_core.track import load_demo_track
from sim.closed_loop import footprint_outside
from sim.onboard import OnboardSettings
from sim.sensors import SensorSuite
from sim.simulator import Simulator

RATE_HZ = 30.0
LOOP_S = 0.004  # the car's 250 Hz loop


def drive_link(delays: np.ndarray, torques: np.ndarray, meter: CommandDelay) -> list[float]:
    """Commands at 30 Hz ticks reach a car after ``delays`` (reordering where a later one
    arrives first); the car applies whatever arrived last from its next 4 ms step on and
    reports each change of its drive power, as the bridge does. Returns each command's true
    delay to its application."""
    ticks = np.arange(torques.size) / RATE_HZ
    applied_at = np.ceil((ticks + delays) / LOOP_S) * LOOP_S
    events = sorted(
        [(ticks[k], 0, k) for k in range(torques.size)]
        + [(applied_at[k], 1, k) for k in range(torques.size)]
    )
    applying = None
    for when, kind, k in events:
        if kind == 0:
            meter.sent(when, float(torques[k]))
        elif torques[k] != applying:
            applying = torques[k]
            meter.applied(when, float(np.float32(torques[k])))  # the wire's float32
    return list(applied_at - ticks)


def test_the_delay_of_an_in_order_link_is_measured_to_the_cars_loop():
    """40 ms to the car, then its 4 ms loop: the median delay within one loop step, and
    ``initial`` until ``min_matches`` commands have been matched."""
    meter = CommandDelay(CommandDelaySettings(initial=0.02, min_matches=5))
    assert meter.delay == 0.02
    torques = 0.3 + 0.2 * np.sin(np.arange(90) / 7.0)
    true = drive_link(np.full(90, 0.040), torques, meter)
    assert meter.matched == 90
    assert meter.delay == pytest.approx(np.median(true), abs=1e-9)
    assert 0.040 <= meter.delay <= 0.040 + LOOP_S


def test_a_reordering_link_gives_the_median_delay_and_never_matches_an_old_command_twice():
    """Bad Wi-Fi's 15 ms + |N(0, 10 ms)| down the link: commands overtake each other and an
    older one is applied again after a newer; the measured delay is the median of the commands'
    first applications, each matched once."""
    rng = np.random.default_rng(3)
    delays = 0.015 + np.abs(rng.normal(0.0, 0.010, 300))
    torques = 0.3 + 0.2 * np.sin(np.arange(300) / 7.0) + 1e-3 * rng.standard_normal(300)
    meter = CommandDelay(CommandDelaySettings(samples=301))
    true = drive_link(delays, torques, meter)
    assert meter.matched <= 300  # each command at most once
    assert meter.delay == pytest.approx(np.median(true), abs=0.003)
    assert abs(meter.delay - (0.015 + 0.010 * math.sqrt(2 / math.pi))) < 0.006


def test_zero_and_repeated_torques_and_unknown_reports_are_not_matched():
    meter = CommandDelay()
    for k, torque in enumerate([1.0, 1.0, 1.0, 0.0, 0.4]):
        meter.sent(k / RATE_HZ, torque)
    assert meter.applied(0.2, 1.0) is None  # saturated: which tick's?
    assert meter.applied(0.2, 0.0) is None  # a stopped or cut-off car applies none
    assert meter.applied(0.2, 0.7) is None  # never sent
    assert meter.applied(0.2, math.nan) is None
    assert meter.applied(0.130, 0.4) is None  # before it was sent
    assert meter.applied(0.150, 0.4) == pytest.approx(0.150 - 4 / RATE_HZ)
    assert meter.applied(0.170, 0.4) is None  # the same command again
    assert meter.matched == 1


def test_commands_older_than_max_delay_are_forgotten():
    meter = CommandDelay(CommandDelaySettings(max_delay=0.1))
    meter.sent(0.0, 0.25)
    meter.sent(0.2, 0.5)
    assert meter.applied(0.21, 0.25) is None
    assert meter.applied(0.21, 0.5) == pytest.approx(0.01)


@pytest.mark.parametrize(
    "field, value",
    [
        ("initial", -0.01),
        ("max_delay", math.nan),
        ("tolerance", -1.0),
        ("samples", 0),
        ("min_matches", 40),
    ],
)
def test_bad_settings_are_refused_naming_the_field(field, value):
    with pytest.raises(ValueError, match=field):
        CommandDelaySettings(**{field: value})


def race_behind_a_delay(measure: bool, delay: float, duration: float) -> tuple[float, float]:
    """The MPCC through the supervisor, on the true state, races a car whose commands act
    ``delay`` s after they are issued (the ``input_delay`` effect of the truth) and which
    reports the drive power its 250 Hz loop applies, as a Chronos car does. Returns the largest
    distance of the footprint outside the track (m, <= 0: inside) and, with ``measure``, the
    delay measured from the reports (s; 0 otherwise)."""
    track = load_demo_track()
    car = Simulator(
        CarModel({"input_delay": delay}), SensorSuite().ideal(), onboard=OnboardSettings()
    )
    x0 = track.start_state()
    session = car.session(x0)
    meter = CommandDelay() if measure else None
    supervisor = Supervisor(Mpcc(track), model=CarModel(), command_delay=meter)
    worst, reported, applying = -math.inf, 0, None
    for k in range(round(duration * RATE_HZ)):
        now = k / RATE_HZ
        session.advance(now)
        x = session.base_state
        worst = max(worst, footprint_outside(track, x[0], x[1], x[2], None))
        if meter is not None:  # the car's reports: each change of the power it applies
            for sample in session.applied_inputs[reported:]:
                if sample.u[1] != applying:
                    applying = sample.u[1]
                    meter.applied(sample.stamp, float(applying))
            reported = len(session.applied_inputs)
        supervisor.observe(now, x, "ok")
        session.command(supervisor(now).command)
    return worst, meter.delay if meter is not None else 0.0


def test_planning_from_when_the_command_acts_keeps_a_delayed_car_on_the_track():
    """60 ms between a tick and the car applying its command (a bad Wi-Fi downlink and a
    controller call): planned from the tick, the MPCC's car leaves the track within a lap;
    with the delay measured from the car's reports (within its 4 ms loop) it stays on."""
    compensated, measured = race_behind_a_delay(True, 0.060, 8.0)
    assert 0.060 - 1e-9 <= measured <= 0.060 + LOOP_S + 1e-9
    assert compensated <= 0.0
    uncompensated, _ = race_behind_a_delay(False, 0.060, 8.0)
    assert uncompensated > 0.0
