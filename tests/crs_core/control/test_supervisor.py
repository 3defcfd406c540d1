"""Tests of crs_core.control.supervisor without ROS: stale / degraded / lost estimates, the
speed-cap ramp, the prediction over the commands sent and the check of every command."""

from __future__ import annotations

import math

import numpy as np
import pytest

from crs_core.control.command_delay import CommandDelay, CommandDelaySettings
from crs_core.control.mpcc import Mpcc
from crs_core.control.overload import OverloadSettings
from crs_core.control.supervisor import STOP, Supervisor, SupervisorSettings
from crs_core.errors import FieldError
from crs_core.model import CarModel

RATE_HZ = 30.0
DT = 1.0 / RATE_HZ


class Recorder:
    """A controller returning scripted commands and recording what it was called with."""

    def __init__(self, commands=None) -> None:
        self.commands = commands
        self.calls: list[tuple[float, np.ndarray, float | None]] = []
        self.resets = 0

    def __call__(self, now, x, speed_limit):
        self.calls.append((now, np.array(x), speed_limit))
        if self.commands is None:
            return np.array([0.1, 0.2])
        return self.commands(len(self.calls) - 1)

    def reset(self) -> None:
        self.resets += 1


def state(speed: float) -> np.ndarray:
    return np.array([1.0, 2.0, 0.3, speed, 0.0, 0.0])


@pytest.mark.parametrize("speed", [1.1, 4.0])
def test_speed_cap_ramps_and_never_steps_under_a_toggling_status(speed):
    """ok for 0.5 s, then degraded / ok toggling every 100 ms for 3 s, then ok: the cap falls
    from the car's speed at the ramp rate to degraded_speed, does not rise while toggling, and
    rises at the rise rate once ok has held for ok_hold (1.5 s degraded in all: the full
    hold)."""
    settings = SupervisorSettings(
        max_speed=4.0, degraded_speed=0.5, ramp_rate=1.5, rise_rate=3.0, ok_hold=1.0
    )
    controller = Recorder()
    supervisor = Supervisor(controller, settings)
    ticks = np.arange(0.0, 9.0, DT)
    caps, kinds, statuses = [], [], []
    for now in ticks:
        toggling = 0.5 <= now < 3.5
        status = "degraded" if toggling and int((now - 0.5) / 0.1) % 2 == 0 else "ok"
        statuses.append(status)
        supervisor.observe(now - 0.02, state(speed), status)
        step = supervisor(now)
        caps.append(step.speed_cap)
        kinds += [event.kind for event in step.events]
        limit = controller.calls[-1][2]
        assert limit == (None if step.speed_cap >= 4.0 else step.speed_cap)
    caps = np.array(caps)
    change = np.diff(caps)
    ramp = settings.ramp_rate * DT + 1e-12
    assert np.all(change <= settings.rise_rate * DT + 1e-12)  # never rises faster than that
    # never falls faster than the ramp below the car's speed (a fall starts there)
    assert np.all(caps[1:] >= np.minimum(caps[:-1], speed) - ramp)
    if speed >= settings.max_speed:  # the car at full speed: no step down at all
        assert np.all(-change <= ramp)
    assert caps.min() == pytest.approx(0.5)
    toggling = (ticks >= 0.5) & (ticks < 3.5)
    assert np.all(change[toggling[1:]] <= 1e-12)  # no rise while the status toggles
    # ok from the tick after the last degraded one: up ok_hold later, at 1.5 m/s^2
    ok_from = ticks[max(k for k, s in enumerate(statuses) if s == "degraded") + 1]
    held = ticks < ok_from + 1.0 - 1e-9
    assert np.allclose(caps[held & (ticks > 3.0)], 0.5)
    rising = ~held[1:] & (caps[1:] < 4.0)
    assert rising.sum() > 25 and np.allclose(change[rising], 3.0 * DT)
    assert caps[-1] == 4.0
    assert kinds.count("degraded") == 1 and kinds.count("recovered") == 1


def test_after_a_short_degraded_episode_the_cap_rises_as_soon_as_ok_held_as_long():
    """A link outage: 2 s ok at 2 m/s, 0.1 s degraded (dead reckoning until the first
    Lighthouse sample after it), then ok: the cap falls for 0.1 s, is held for 0.1 s of ok,
    not ok_hold, and is back at full speed at the rise rate."""
    settings = SupervisorSettings(ramp_rate=1.5, rise_rate=3.0, ok_hold=1.0)
    supervisor = Supervisor(Recorder(), settings)
    caps, kinds = {}, []
    for now in np.arange(0.0, 4.0, DT):
        status = "degraded" if 2.0 <= now < 2.1 - 1e-9 else "ok"
        supervisor.observe(now - 0.02, state(2.0), status)
        step = supervisor(now)
        caps[round(now, 4)] = step.speed_cap
        kinds += [e.kind for e in step.events]
    assert kinds == ["fresh", "degraded", "recovered"]
    lowest = min(caps.values())
    # fell from the car's 2 m/s at 1.5 m/s^2 while degraded and held: about 0.2 s
    assert 1.65 < lowest < 1.8
    recovered_at = min(t for t, cap in caps.items() if t > 2.1 and cap > lowest + 1e-9)
    assert recovered_at <= 2.1 + 0.1 + 2 * DT  # held for the 0.1 s it was degraded
    assert caps[max(caps)] == settings.max_speed  # 2 -> 4 m/s within 0.7 s at 3 m/s^2


def test_a_fall_from_the_cars_speed_reaches_degraded_speed_at_the_ramp_rate():
    """1.1 m/s, degraded: the cap starts at 1.1 m/s and reaches 0.5 m/s 0.4 s later."""
    supervisor = Supervisor(Recorder(), SupervisorSettings(ramp_rate=1.5))
    caps = []
    for now in np.arange(0.0, 1.0, DT):
        supervisor.observe(now, state(1.1), "degraded")
        caps.append(supervisor(now).speed_cap)
    assert caps[0] == pytest.approx(1.1)
    reached = next(k for k, cap in enumerate(caps) if cap <= 0.5 + 1e-12)
    assert reached * DT == pytest.approx(0.6 / 1.5, abs=DT)


def test_stale_after_the_timeout_and_lost_stop_the_car_and_fresh_estimates_resume():
    controller = Recorder()
    quiet = OverloadSettings(estimate_gap=1.0)  # the overload watch's own test: test_overload
    supervisor = Supervisor(controller, SupervisorSettings(stale_timeout=0.2, overload=quiet))
    first = supervisor(0.0)
    assert not first.driving and np.array_equal(first.command, STOP) and not controller.calls
    supervisor.observe(0.0, state(1.0), "ok")
    driving = supervisor(0.1)
    assert driving.driving and driving.events[0].kind == "fresh" and controller.resets == 1
    assert np.array_equal(driving.command, [0.1, 0.2])
    assert supervisor(0.2).driving  # exactly stale_timeout old: still fresh
    stale = supervisor(0.21)
    assert not stale.driving and np.array_equal(stale.command, STOP)
    assert [e.kind for e in stale.events] == ["stale"] and "0.21 s old" in stale.events[0].message
    assert supervisor.stops == 1 and not supervisor(0.3).events  # one event per episode
    supervisor.observe(0.3, state(1.0), "ok")
    assert supervisor(0.31).driving and controller.resets == 2
    supervisor.observe(0.32, state(1.0), "lost")
    lost = supervisor(0.33)
    assert not lost.driving and "status lost" in lost.events[0].message
    assert supervisor.stops == 2


def random_bad_command(rng: np.random.Generator, output: str):
    """A command that must not leave: NaN, inf, out of range, wrong shape or not numeric."""
    kind = rng.integers(0, 7)
    steer, second = rng.uniform(-0.3, 0.3), rng.uniform(0.0, 0.9)
    if kind == 0:
        return np.array([math.nan, second]) if rng.random() < 0.5 else np.array([steer, math.nan])
    if kind == 1:
        return np.array([steer, rng.choice([math.inf, -math.inf])])
    if kind == 2:
        return np.array([rng.choice([-1, 1]) * rng.uniform(0.3401, 10.0), second])
    if kind == 3:
        high = 5.0 if output == "velocity" else 1.0
        return np.array([steer, high + rng.uniform(1e-6, 20.0)])
    if kind == 4:
        low = 0.0 if output == "velocity" else -1.0
        return np.array([steer, low - rng.uniform(1e-6, 20.0)])
    if kind == 5:
        return np.zeros(int(rng.choice([0, 1, 3])))
    return ["fast", 1.0]


@pytest.mark.parametrize("output", ["torque", "velocity"])
def test_no_nan_or_out_of_range_command_ever_leaves(output):
    """2000 ticks, a third of them with a random bad command: each is replaced by the stop
    command and counted; the good ones leave unchanged."""
    rng = np.random.default_rng(25)
    bad = rng.random(2000) < 1 / 3
    draws = [
        random_bad_command(rng, output) if b else np.array([rng.uniform(-0.34, 0.34), 0.5])
        for b in bad
    ]
    settings = SupervisorSettings(steer_max=0.34, velocity_max=5.0)
    supervisor = Supervisor(Recorder(lambda k: draws[k]), settings, output=output)
    low, high = (0.0, 5.0) if output == "velocity" else (-1.0, 1.0)
    for k in range(len(draws)):
        now = k * DT
        supervisor.observe(now, state(1.0), "ok")
        step = supervisor(now)
        u = step.command
        assert u.shape == (2,) and np.all(np.isfinite(u))
        assert abs(u[0]) <= 0.34 and low <= u[1] <= high
        if bad[k]:
            assert np.array_equal(u, STOP) and step.events[-1].kind == "rejected"
        else:
            assert np.array_equal(u, draws[k]) and not step.events[1:]
    assert supervisor.rejected_commands == int(bad.sum())
    assert supervisor.last_rejection


def test_a_controller_that_raises_is_answered_by_a_stop():
    def broken(now, x, limit):
        raise RuntimeError("solver exploded")

    supervisor = Supervisor(broken)
    supervisor.observe(0.0, state(1.0), "ok")
    step = supervisor(0.01)
    assert np.array_equal(step.command, STOP) and step.solve_time is None
    assert step.events[-1].kind == "failed" and "solver exploded" in step.events[-1].message


def test_bad_estimates_are_refused_naming_the_field():
    supervisor = Supervisor(Recorder())
    with pytest.raises(ValueError, match="x: need 6 finite"):
        supervisor.observe(0.0, [0, 0, 0, math.nan, 0, 0], "ok")
    with pytest.raises(ValueError, match="status: must be one of"):
        supervisor.observe(0.0, state(1.0), "fine")
    with pytest.raises(ValueError, match="stamp: must be finite"):
        supervisor.observe(math.inf, state(1.0), "ok")
    with pytest.raises(ValueError, match="ramp_rate"):
        SupervisorSettings(ramp_rate=0.0)


def test_prediction_over_the_commands_sent_equals_stepping_the_model_by_hand():
    """Commands sent at 30 Hz ticks; an estimate stamped between two ticks is carried to
    ``now`` under the command in effect at its stamp, then each later one from its tick."""
    model = CarModel()
    numeric, p = model.numeric, model.parameters.vector()
    commands = [np.array([0.05 * k, 0.1 + 0.05 * k]) for k in range(10)]
    supervisor = Supervisor(Recorder(lambda k: commands[k]), SupervisorSettings(), model=model)
    x0 = state(1.2)
    ticks = [k * DT for k in range(5)]
    for now in ticks[:4]:  # fresh estimates at each tick (no carrying: stamp == now)
        supervisor.observe(now, x0, "ok")
        supervisor(now)
    stamp = 0.5 * (ticks[1] + ticks[2])  # 50 ms old at the tick of 0.133 s
    supervisor.observe(stamp, x0, "ok")
    now = ticks[4]
    carried = supervisor.predicted(now)
    x = numeric.step(x0, commands[1], p, ticks[2] - stamp)
    x = numeric.step(x, commands[2], p, ticks[3] - ticks[2])
    x = numeric.step(x, commands[3], p, now - ticks[3])
    np.testing.assert_allclose(carried, x, rtol=0, atol=1e-12)
    assert np.linalg.norm(carried[:2] - x0[:2]) > 0.05  # it did move
    supervisor(now)
    assert np.array_equal(supervisor.controller.calls[-1][1], carried)
    # the first tick: nothing sent yet, the estimate is carried under the stop command
    fresh = Supervisor(Recorder(), SupervisorSettings(), model=model)
    fresh.observe(0.0, x0, "ok")
    np.testing.assert_allclose(fresh.predicted(0.04), numeric.step(x0, STOP, p, 0.04), atol=1e-12)
    no_model = Supervisor(Recorder())
    no_model.observe(0.0, x0, "ok")
    assert np.array_equal(no_model.predicted(0.04), x0)


def test_with_a_command_delay_the_estimate_is_carried_to_when_the_command_acts():
    """A command acts ``delay`` after its tick: the estimate is carried to ``now + delay``,
    each command sent acting from its own tick plus the delay; the torque of each tick's
    command is recorded for the measurement."""
    model = CarModel()
    numeric, p = model.numeric, model.parameters.vector()
    commands = [np.array([0.05 * k, 0.1 + 0.05 * k]) for k in range(10)]
    delay = CommandDelay(CommandDelaySettings(initial=0.045))
    supervisor = Supervisor(
        Recorder(lambda k: commands[k]), SupervisorSettings(), model=model, command_delay=delay
    )
    x0 = state(1.2)
    ticks = [k * DT for k in range(5)]
    for now in ticks[:4]:
        supervisor.observe(now, x0, "ok")
        supervisor(now)
    stamp = ticks[2] + 0.005
    supervisor.observe(stamp, x0, "ok")
    now = ticks[4]
    carried = supervisor.predicted(now)
    # at the stamp the car still applies the command of tick 0 (tick 1's acts from 78 ms)
    x = numeric.step(x0, commands[0], p, ticks[1] + 0.045 - stamp)
    x = numeric.step(x, commands[1], p, ticks[2] - ticks[1])
    x = numeric.step(x, commands[2], p, ticks[3] - ticks[2])
    x = numeric.step(x, commands[3], p, now - ticks[3])
    np.testing.assert_allclose(carried, x, rtol=0, atol=1e-12)
    assert delay.applied(ticks[3] + 0.04, float(commands[3][1])) == pytest.approx(0.04)


class _Mpcc(Mpcc):
    """An MPCC that records whether each call asked for hold-safe commands (and is not
    built: the supervisor only needs its type and call)."""

    def __init__(self) -> None:  # nothing of the MPCC itself is built
        self.asked: list[bool] = []
        self.status = None

    def __call__(self, x, speed_limit=None, elapsed=None, hold_safe=False):
        self.asked.append(hold_safe)
        return np.array([0.0, 0.3])

    def reset(self) -> None:
        pass


def _drive(supervisor, times, status_at, applied_at=()):
    """Tick ``supervisor`` at ``times`` with estimates of ``status_at(now)``; the car reports
    zero drive power at the ``applied_at`` times; the events' kinds."""
    kinds = []
    for now in times:
        supervisor.observe(now - 0.02, state(1.5), status_at(now))
        if any(abs(now - t) < DT / 2 for t in applied_at):
            supervisor.applied(now - 0.01, 0.0)
        kinds += [event.kind for event in supervisor(now).events]
    return kinds


def test_an_outage_while_racing_makes_the_commands_hold_safe_for_a_while():
    """Degraded estimates at the start (before 1 s of ok driving) are not an outage; 0.1 s
    degraded after 2 s of racing is: the MPCC is asked for hold-safe commands from that tick,
    for caution_memory s after it, then racing ones again."""
    controller = _Mpcc()
    supervisor = Supervisor(controller, SupervisorSettings(caution_memory=2.0))
    times = np.arange(0.0, 6.0, DT)
    kinds = _drive(
        supervisor,
        times,
        lambda now: "degraded" if now < 0.3 or 2.3 <= now < 2.4 - 1e-9 else "ok",
    )
    asked = np.array(controller.asked)
    assert kinds.count("cautious") == 1 and kinds.count("relaxed") == 1
    assert supervisor.outages == 1
    outage = int(np.argmax(times >= 2.3))
    assert not asked[:outage].any()
    assert asked[outage : outage + int(1.9 / DT)].all()
    assert not asked[-int(1.5 / DT) :].any()


def test_a_motor_cut_off_the_car_reports_is_an_outage():
    """The car reports zero drive power while it is sent a driving torque: it cut its motors
    (no reference got through for 200 ms), and the next commands are hold-safe."""
    controller = _Mpcc()
    supervisor = Supervisor(controller, SupervisorSettings(caution_memory=5.0))
    times = np.arange(0.0, 3.0, DT)
    kinds = _drive(supervisor, times, lambda now: "ok", applied_at=(2.0,))
    assert kinds.count("cautious") == 1
    assert controller.asked[int(np.argmax(times >= 2.0)) + 1]
    assert not controller.asked[int(np.argmax(times >= 1.9))]


@pytest.mark.parametrize(("mode", "expected"), [("never", False), ("always", True)])
def test_hold_safe_never_or_always_overrides_the_outages(mode: str, expected: bool):
    controller = _Mpcc()
    supervisor = Supervisor(controller, SupervisorSettings(hold_safe=mode))
    kinds = _drive(
        supervisor, np.arange(0.0, 3.0, DT), lambda now: "degraded" if 2.0 <= now < 2.1 else "ok"
    )
    assert set(controller.asked) == {expected}
    assert "cautious" not in kinds


def test_an_unknown_hold_safe_mode_names_the_field():
    with pytest.raises(FieldError) as caught:
        SupervisorSettings(hold_safe="sometimes")
    assert caught.value.field == "hold_safe"


def test_an_online_parameter_at_its_bound_slows_the_car_and_names_it():
    """grip 0.3 (its lower bound) in an ok estimate: the cap falls as for a degraded one, the
    event names the parameter; back inside its bounds, the car speeds up again."""
    supervisor = Supervisor(Recorder(), SupervisorSettings(ramp_rate=1.5), model=CarModel())
    messages = []
    for now in np.arange(0.0, 3.0, DT):
        supervisor.observe(now - 0.02, state(2.0), "ok")
        supervisor.observe_parameters({"grip": 0.3 if 1.0 <= now < 2.0 else 0.95})
        messages += [e.message for e in supervisor(now).events]
    assert any("online parameter grip at its bound: slowing" in m for m in messages), messages
    assert any(m.startswith("state estimate ok") for m in messages), messages
    with pytest.raises(ValueError, match="grip: must be finite"):
        supervisor.observe_parameters({"grip": math.nan})


def test_the_prediction_follows_the_online_parameters():
    """A weaker motor (Cm1 online at 60 %) predicts less speed gained over the commands sent
    (without an MPCC the supervisor's own model takes them at once)."""

    def speed_after(cm1: float | None) -> float:
        supervisor = Supervisor(Recorder(lambda k: np.array([0.0, 1.0])), model=CarModel())
        if cm1 is not None:
            supervisor.observe_parameters({"Cm1": cm1, "gyro_bias": 0.01})  # not in its model
        supervisor.observe(0.0, state(1.0), "ok")
        for now in np.arange(0.0, 0.3, DT):
            supervisor(now)
        return float(supervisor.predicted(0.3)[3])

    weak = 0.6 * CarModel().parameters.value("Cm1")
    assert speed_after(weak) < speed_after(None) - 0.05
