"""Overload of the control loop: when the machine cannot keep the loop's period, slow the car,
and if it must, stand it on the track.

A starved stack does not slow down by itself: its controller's ticks come late, its estimates
arrive old, and a car racing on them at full speed leaves the track before a stale estimate
stops it (which then lets it roll straight on). :class:`OverloadWatch` looks at every tick of
the loop: a tick that comes more than ``late_tick`` s after the one before, or that has seen no
new estimate for more than ``estimate_gap`` s, is *late* (not the estimate's age: an estimator
lags the data by design, up to 0.1 s for an EKF waiting for late Wi-Fi data). After a late tick
the speed limit is ``slow_speed`` (slow enough that a gap of a few hundred milliseconds, a stale
stop, or the car's motor cut-off costs centimetres); when late intervals fill more than
``stand_fraction`` of the last ``window`` s, the limit is 0: the controller brakes the car to a
stand on its path. The limit is lifted after ``hold`` s without a late tick (from a stand first
to ``slow_speed``), the hold doubling for each episode that follows the last lift within
``memory`` s. The :class:`~crs_core.control.supervisor.Supervisor` ramps its speed cap to this
limit; :attr:`OverloadWatch.late_ticks` and :attr:`OverloadWatch.episodes` say how starved a
run was.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass

from crs_core.settings import Settings, non_negative, positive, within

__all__ = ["OVERLOAD_STATES", "OverloadSettings", "OverloadWatch"]

#: The watch's states: racing, slowed after a late tick, brought to a stand.
OVERLOAD_STATES = ("ok", "slow", "stand")


@dataclass(frozen=True)
class OverloadSettings(Settings):
    """When the loop counts as starved and what the car does then.

    Attributes
    ----------
    late_tick : float
        A tick more than this after the previous one is late, s (four and a half periods of
        the MPCC's 30 Hz; its car cuts the motors after 0.2 s without a command).
    estimate_gap : float
        A tick that has seen no new estimate for longer than this is late, s (the estimators
        publish at 60 Hz: nine periods).
    slow_speed : float
        Speed limit after a late tick, m/s (a gap of 0.2 s then costs 0.2 m of open loop).
    window : float
        How far back the late intervals are summed, s.
    stand_fraction : float
        Above this fraction of ``window`` spent in late intervals the limit is 0 (the car is
        stopped on the track).
    hold : float
        The limit is lifted after this long without a late tick, s; doubled for each episode
        that begins within ``memory`` s of the last lift, up to ``hold_max``: a loop that is
        starved again and again stays slow, where a fixed hold let the car speed up between
        the gaps and meet the next one at racing speed.
    hold_max : float
        Longest hold, s.
    memory : float
        An episode this soon after the last lift counts as a repeat, s.
    warm_up : float
        Ticks this soon after the first one (the first estimate) are not judged, s: the MPCC's
        cold start and the first calls of every compiled function make a start's ticks late on
        any machine.
    period : float
        The loop's nominal period, s (0: its rate is not judged). A loop that keeps no gap
        above ``late_tick`` can still be starved: on a machine carrying six cars the
        controllers ran at half their rate, their estimates a third, and the cars raced on
        (at 0.7, two emulated cars on an idle machine, their loops at 0.63, were slowed and
        lost their lap).
    min_rate : float
        A tick after which the loop made fewer than this fraction of its nominal ticks over the
        last ``rate_window`` s is late (it slows the car; it does not count towards a stand).
    rate_window : float
        How far back the ticks are counted, s.
    """

    late_tick: float = positive(0.15)
    estimate_gap: float = positive(0.15)
    slow_speed: float = positive(1.0)
    window: float = positive(4.0)
    stand_fraction: float = within(0.3, low=0.0, high=1.0)
    hold: float = positive(2.0)
    hold_max: float = positive(32.0)
    memory: float = non_negative(20.0)
    warm_up: float = non_negative(1.0)
    period: float = non_negative(0.0)
    min_rate: float = within(0.5, low=0.0, high=1.0)
    rate_window: float = positive(1.0)


class OverloadWatch:
    """Late ticks of a control loop and the speed limit they call for.

    Parameters
    ----------
    settings : OverloadSettings, optional
    """

    def __init__(self, settings: OverloadSettings | None = None) -> None:
        self.settings = settings or OverloadSettings()
        self.state = "ok"
        #: late ticks so far
        self.late_ticks = 0
        #: times the car was slowed from racing (state ok -> slow or stand)
        self.episodes = 0
        #: times it was brought to a stand
        self.stands = 0
        self._late: deque[tuple[float, float]] = deque()  # (tick time, late interval s)
        self._last_late = -float("inf")
        self._first: float | None = None
        self._ticks: deque[float] = deque()  # tick times within rate_window
        self._lifted = -float("inf")  # when the limit was last lifted
        #: the hold in force, s (``hold``, doubled for each repeated episode)
        self.hold = self.settings.hold

    @property
    def limit(self) -> float | None:
        """The speed limit now, m/s (None: none)."""
        if self.state == "ok":
            return None
        return 0.0 if self.state == "stand" else self.settings.slow_speed

    def _slow_rate(self, now: float) -> str:
        """Why the loop's rate over the last ``rate_window`` s is too low ('' if it is not, or
        if the window does not yet lie wholly after the warm-up)."""
        s = self.settings
        ticks = self._ticks
        if s.period <= 0 or self._first is None:
            return ""
        if now - s.rate_window < self._first + s.warm_up:
            return ""
        nominal = s.rate_window / s.period
        if len(ticks) >= s.min_rate * nominal:
            return ""
        return (
            f"the controller ticked {len(ticks)} times in the last {s.rate_window:g} s, "
            f"of {nominal:.0f}"
        )

    def late_fraction(self, now: float) -> float:
        """The fraction of the last ``window`` s spent in late intervals."""
        s = self.settings
        while self._late and self._late[0][0] <= now - s.window:
            self._late.popleft()
        return min(sum(interval for _, interval in self._late) / s.window, 1.0)

    def tick(self, now: float, interval: float, since_estimate: float) -> str:
        """Take a tick at ``now`` (s), ``interval`` s after the previous one, ``since_estimate``
        s after the tick that saw the newest estimate arrive (0: this one); the reason it was
        late ('' if on time)."""
        s = self.settings
        if self._first is None:
            self._first = now
        if s.period > 0:
            self._ticks.append(now)
            while self._ticks[0] <= now - s.rate_window:
                self._ticks.popleft()
        if now - self._first < s.warm_up:
            return ""
        reason = ""
        if interval > s.late_tick:
            reason = f"the controller's tick came {interval * 1e3:.0f} ms after the last"
        elif since_estimate > s.estimate_gap:
            reason = f"no new state estimate for {since_estimate * 1e3:.0f} ms"
        else:
            reason = self._slow_rate(now)
        if reason:
            self.late_ticks += 1
            self._last_late = now
            self._late.append((now, min(interval, s.window) if interval > s.late_tick else 0.0))
        fraction = self.late_fraction(now)
        if reason and self.state == "ok":
            self.episodes += 1
            repeat = now - self._lifted < s.memory
            self.hold = min(2 * self.hold, s.hold_max) if repeat else s.hold
            self.state = "slow"
        if reason and self.state != "stand" and fraction > s.stand_fraction:
            self.stands += 1
            self.state = "stand"
        elif self.state != "ok" and now - self._last_late >= self.hold:
            # from a stand, first to the slow limit for another hold
            self.state = "slow" if self.state == "stand" else "ok"
            self._last_late = now if self.state == "slow" else self._last_late
            if self.state == "ok":
                self._lifted = now
        return reason
