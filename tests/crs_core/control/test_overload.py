"""The overload watch: late ticks slow the car, a loop late most of the time stands it, a loop
on time again lifts the limit; and the supervisor ramps its cap to that limit."""

from __future__ import annotations

import re

import numpy as np
import pytest

from crs_core.control.overload import OverloadSettings, OverloadWatch
from crs_core.control.supervisor import Supervisor, SupervisorSettings
from crs_core.errors import FieldError

PERIOD = 1 / 30


def test_on_time_ticks_with_fresh_estimates_set_no_limit():
    watch = OverloadWatch()
    for k in range(300):
        assert watch.tick(k * PERIOD, PERIOD, 0.0) == ""
    assert watch.state == "ok" and watch.limit is None and watch.late_ticks == 0


def test_one_late_tick_slows_the_car_until_the_loop_has_kept_its_period_for_hold():
    settings = OverloadSettings(late_tick=0.1, hold=3.0, slow_speed=0.6, warm_up=0.0)
    watch = OverloadWatch(settings)
    now = 0.0
    for _ in range(30):
        now += PERIOD
        watch.tick(now, PERIOD, 0.0)
    now += 0.15
    reason = watch.tick(now, 0.15, 0.0)
    assert "150 ms after the last" in reason
    assert watch.state == "slow" and watch.limit == 0.6 and watch.episodes == 1
    late_at = now
    while now < late_at + 3.0 - PERIOD:
        now += PERIOD
        watch.tick(now, PERIOD, 0.0)
        assert watch.state == "slow"
    now += 2 * PERIOD
    watch.tick(now, PERIOD, 0.0)
    assert watch.state == "ok" and watch.limit is None


def test_an_on_time_tick_without_a_new_estimate_for_long_is_late():
    watch = OverloadWatch(OverloadSettings(estimate_gap=0.1, warm_up=0.0))
    assert watch.tick(1.0, PERIOD, 0.09) == ""
    assert "no new state estimate for 120 ms" in watch.tick(1.0, PERIOD, 0.12)
    assert watch.state == "slow"


def test_an_estimate_that_lags_by_design_is_not_late():
    """Estimates stamped 0.1 s before the tick (an EKF's adaptive lag) but arriving at every
    tick: no late tick."""
    supervisor = Supervisor(Driver(), SupervisorSettings())
    x = np.array([0.0, 0.0, 0.0, 1.0, 0.0, 0.0])
    now = 0.0
    for _ in range(200):
        now += PERIOD
        supervisor.observe(now - 0.1, x, "ok")
        supervisor(now)
    assert supervisor.overload.late_ticks == 0 and supervisor.overload.state == "ok"


def test_a_loop_late_most_of_the_time_stands_the_car():
    """Ticks every 0.2 s (a starved process): after enough of the 2 s window is late the limit
    is 0; the late fraction counts each late tick's interval once."""
    watch = OverloadWatch(
        OverloadSettings(late_tick=0.1, window=2.0, stand_fraction=0.25, warm_up=0.0)
    )
    now, states = 0.0, []
    for _ in range(4):
        now += 0.2
        watch.tick(now, 0.2, 0.0)
        states.append(watch.state)
    assert states == ["slow", "slow", "stand", "stand"]  # 0.6 s of 2 s late: over a quarter
    assert watch.limit == 0.0 and watch.stands == 1
    assert watch.late_fraction(now) == pytest.approx(0.4)
    assert watch.late_fraction(now + 5.0) == 0.0  # the window forgets


def test_the_first_second_is_not_judged():
    """The start's ticks (a cold MPCC, first calls of compiled code) are late on any machine:
    within ``warm_up`` of the first tick, no late tick counts."""
    watch = OverloadWatch(OverloadSettings(warm_up=1.0))
    assert watch.tick(10.0, 0.0, 0.0) == "" and watch.tick(10.5, 0.5, 0.0) == ""
    assert watch.state == "ok" and watch.late_ticks == 0
    assert "500 ms after the last" in watch.tick(11.0, 0.5, 0.0)


def test_settings_are_checked():
    with pytest.raises(FieldError, match="stand_fraction"):
        OverloadSettings(stand_fraction=1.5)
    with pytest.raises(FieldError, match="late_tick"):
        OverloadSettings(late_tick=0.0)


class Driver:
    """A controller that drives at the speed limit it is given (the car's speed follows)."""

    def __init__(self) -> None:
        self.limits: list[float | None] = []

    def __call__(self, now: float, x: np.ndarray, limit: float | None) -> np.ndarray:
        self.limits.append(limit)
        return np.array([0.0, 0.5])


def test_the_supervisor_ramps_to_the_overload_limit_and_back():
    """A car at 2.5 m/s whose estimator stalls for 0.15 s: the cap falls from the car's speed to
    0.6 m/s at the ramp rate, stays there while the loop keeps its period for ``hold`` s, then
    rises; the events say so."""
    driver = Driver()
    overload = OverloadSettings(estimate_gap=0.1, hold=2.0, slow_speed=0.6)
    settings = SupervisorSettings(overload=overload, ramp_rate=1.5)
    supervisor = Supervisor(driver, settings)
    fast = np.array([0.0, 0.0, 0.0, 2.5, 0.0, 0.0])
    now, caps, kinds = 0.0, {}, []
    stall = (1.0, 1.15)
    stamp = 0.0
    while now < 5.0:
        now = round(now + PERIOD, 6)
        if not stall[0] <= now <= stall[1]:
            stamp = now - 0.03
            supervisor.observe(stamp, fast, "ok")
        step = supervisor(now)
        caps[now] = step.speed_cap
        kinds += [e.kind for e in step.events]
    assert kinds == ["fresh", "starved", "fed"]
    after_stall = [cap for t, cap in caps.items() if stall[0] < t < stall[1] + 2.0]
    assert min(after_stall) == pytest.approx(0.6)
    first_low = min(t for t, cap in caps.items() if cap <= 0.6 + 1e-9)
    assert first_low - stall[0] == pytest.approx((2.5 - 0.6) / 1.5, abs=0.15)
    assert caps[max(caps)] > 0.6  # lifted after the hold
    assert supervisor.overload.episodes == 1 and supervisor.overload.late_ticks >= 1


def test_a_standing_car_is_not_backed_out_as_stuck():
    """While the watch stands the car, or slows it after a stand, the stuck recovery (a car
    standing while driven) stays quiet: it would reverse a car that was stopped on purpose."""
    from crs_core.control.recovery import StuckRecovery
    from crs_core.track import load_demo_track

    track = load_demo_track()
    start = track.start_state(0.0)
    recovery = StuckRecovery(track, 0.34)
    overload = OverloadSettings(late_tick=0.1, window=2.0, stand_fraction=0.25, warm_up=0.0)
    supervisor = Supervisor(Driver(), SupervisorSettings(overload=overload), recovery=recovery)
    now = 0.0
    for _ in range(60):  # 12 s of ticks 0.2 s apart with fresh estimates: late ticks
        now += 0.2
        supervisor.observe(now - 0.01, start, "ok")
        supervisor(now)
    assert supervisor.overload.state == "stand"
    assert recovery.count == 0 and not recovery.active
    # on time again: the stand lifts to the slow limit; the car, still standing while it
    # starts off slowly, is not taken for stuck either (it was reversed on a starved loop)
    while supervisor.overload.state == "stand":
        now += 1 / 30
        supervisor.observe(now - 0.01, start, "ok")
        supervisor(now)
    assert supervisor.overload.state == "slow"
    for _ in range(60):
        now += 1 / 30
        supervisor.observe(now - 0.01, start, "ok")
        supervisor(now)
    assert supervisor.overload.state == "slow"
    assert recovery.count == 0 and not recovery.active


def test_a_standing_car_is_braked_not_controlled():
    """Once the cap has fallen to zero in the stand state, the controller is no longer called:
    the command is the stop command (it would otherwise steer on estimates gone astray)."""
    driver = Driver()
    overload = OverloadSettings(late_tick=0.1, window=2.0, stand_fraction=0.25, warm_up=0.0)
    supervisor = Supervisor(driver, SupervisorSettings(overload=overload))
    slow = np.array([0.0, 0.0, 0.0, 0.3, 0.0, 0.0])
    now, commands = 0.0, []
    for _ in range(40):  # ticks 0.2 s apart: late
        now += 0.2
        supervisor.observe(now - 0.01, slow, "ok")
        commands.append(supervisor(now).command)
    assert supervisor.overload.state == "stand" and supervisor.speed_cap == 0.0
    calls = len(driver.limits)
    supervisor.observe(now, slow, "ok")
    assert np.array_equal(supervisor(now + 0.2).command, [0.0, 0.0])
    assert len(driver.limits) == calls


def test_a_repeated_episode_doubles_the_hold_and_a_stand_lifts_to_slow_first():
    """Starved again within ``memory`` of the last lift: the hold doubles (2, 4, 8 s); from a
    stand the limit goes to ``slow_speed`` for another hold before it is lifted."""
    watch = OverloadWatch(OverloadSettings(late_tick=0.1, hold=2.0, memory=20.0, warm_up=0.0))
    now = 0.0

    def late() -> None:
        nonlocal now
        now += 0.15
        watch.tick(now, 0.15, 0.0)

    def on_time_until_ok() -> float:
        nonlocal now
        start = now
        while watch.state != "ok":
            now += PERIOD
            watch.tick(now, PERIOD, 0.0)
        return now - start

    holds = []
    for _ in range(3):
        late()
        holds.append(watch.hold)
        on_time_until_ok()
    assert holds == [2.0, 4.0, 8.0]
    now += 30.0  # long after the last lift: a new episode starts from the base hold
    watch.tick(now, PERIOD, 0.0)
    late()
    assert watch.hold == 2.0
    stand = OverloadWatch(
        OverloadSettings(late_tick=0.1, window=2.0, stand_fraction=0.25, hold=1.0, warm_up=0.0)
    )
    t = 0.0
    for _ in range(5):
        t += 0.2
        stand.tick(t, 0.2, 0.0)
    assert stand.state == "stand"
    states = []
    for _ in range(90):  # 3 s on time
        t += PERIOD
        stand.tick(t, PERIOD, 0.0)
        states.append(stand.state)
    assert states[0] == "stand" and "slow" in states and states[-1] == "ok"
    assert states.index("ok") > states.index("slow")


def test_a_loop_at_a_third_of_its_rate_without_long_gaps_slows_the_car_but_does_not_stand_it():
    """Ticks 100 ms apart (a 30 Hz loop at a third of its rate, none late by ``late_tick``):
    late by the rate once the rate window lies past the warm-up, the car slowed, never stood;
    back at full rate the limit is lifted after the hold."""
    settings = OverloadSettings(period=PERIOD, warm_up=1.0, hold=2.0)
    watch = OverloadWatch(settings)
    now, reasons = 0.0, []
    while now < 6.0:
        now += 3 * PERIOD
        reasons.append(watch.tick(now, 3 * PERIOD, 0.0))
    assert all(r == "" for r in reasons[:9])  # warm-up, then the first full window
    assert re.search(r"ticked (9|10|11) times in the last 1 s, of 30", reasons[-1])
    assert watch.state == "slow" and watch.stands == 0
    while now < 9.5:
        now += PERIOD
        watch.tick(now, PERIOD, 0.0)
    assert watch.state == "ok"


def test_a_loop_at_two_thirds_of_its_rate_is_not_late():
    watch = OverloadWatch(OverloadSettings(period=PERIOD, warm_up=0.0))
    now = 0.0
    for _ in range(200):
        now += 1.5 * PERIOD
        assert watch.tick(now, 1.5 * PERIOD, 0.0) == ""
    assert watch.state == "ok"


def test_without_a_period_the_rate_is_not_judged():
    watch = OverloadWatch(OverloadSettings(warm_up=0.0))
    now = 0.0
    for _ in range(100):
        now += 0.12
        assert watch.tick(now, 0.12, 0.0) == ""
