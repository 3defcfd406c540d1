"""The real-time policy around a controller: stale / degraded / lost estimates, the speed cap,
delay compensation over the commands sent, and a check of every command before it leaves.

:class:`Supervisor` is what a control loop (the ROS controller node, a closed-loop study) calls
once per tick. It holds the newest state estimate ``(stamp, x, status)`` and decides:

* **Stale or lost** (no estimate yet, one older than ``stale_timeout``, or status ``lost``):
  the stop command (straight wheels, zero torque; in velocity mode a zero velocity reference),
  so the car rolls to a stop; each such episode is counted in :attr:`Supervisor.stops`. The MPCC
  keeps its plan through a gap of up to half its horizon (:meth:`Mpcc.stop`).
* **Fresh**: the controller's command for the estimate carried forward with the model and the
  commands sent since its stamp to when the command will act: ``now`` plus the command delay
  measured on the link (:class:`~crs_core.control.command_delay.CommandDelay`; the estimate is
  tens of ms old when it arrives, the command acts tens of ms after the tick), under a
  **speed cap** that ramps, never steps. While the status is ``degraded`` the cap falls at
  ``ramp_rate`` to ``degraded_speed``, starting from the lower of the current cap and the car's
  speed (a step from 4 to 0.5 m/s at 1.1 m/s gave full-lock steering and braking into reverse
  in an offline closed loop; a 1.5 m/s^2 ramp kept ``v_x >= 0.49`` m/s). It rises back at
  ``rise_rate`` once the status has stayed ``ok`` as long as it was degraded since the cap began
  to fall, ``ok_hold`` s at most: an estimator at the edge, toggling degraded / ok several times
  a second, keeps the car slow, while the few degraded ticks of a link outage (dead reckoning
  until the first Lighthouse sample after it) cost no more than themselves. Waiting a fixed
  1 s there kept a car that came out of a 300 ms outage at 0.5 m/s for another 1.3 s.
* **Hold-safe after an outage**: once the link has shown an outage (a degraded estimate after
  ``ok_before_outage`` s of driving on an ok one: the host stopped receiving the car; or the
  car reporting zero drive power while it was sent a driving torque: it cut its motors, the
  commands stopped reaching it), the MPCC is asked for hold-safe plans
  (:mod:`~crs_core.control.contingency`) for ``caution_memory`` s after the last one: a
  command held through the next outage must not carry the car into a corner too fast. A
  clean link costs nothing; ``hold_safe`` ``"always"`` or ``"never"`` overrides.
* **A stuck car is backed out** (with a :class:`~crs_core.control.recovery.StuckRecovery`):
  standing for half a second while driven, it reverses towards facing along the track, then the
  controller starts over from cold.
* **Every command is checked**: finite, steering within ``±steer_max``, torque within
  ``[torque_min, torque_max]`` (velocity mode: the reference within ``[0, velocity_max]``). A
  bad one is replaced by the stop command, counted in :attr:`Supervisor.rejected_commands` and
  reported with its reason: no NaN or out-of-range value ever leaves a controller.

What happened at a tick is returned as data (:class:`SupervisorStep` with its
:class:`SupervisorEvent` list) for the caller to log; the supervisor itself never logs.

Conventions: state ``[x_p, y_p, psi, v_x, v_y, omega]`` (m, m, rad, m/s, m/s, rad/s; world pose,
body velocities), command ``[delta, T]`` (rad, normalised torque) or ``[delta, v_x]`` (rad, m/s),
times in s on the caller's clock.
"""

from __future__ import annotations

import math
import time
from collections import deque
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike

from crs_core.control.command_delay import CommandDelay
from crs_core.control.mpcc import OUTPUTS, Mpcc
from crs_core.control.overload import OverloadSettings, OverloadWatch
from crs_core.control.recovery import StuckRecovery
from crs_core.errors import FieldError
from crs_core.model import CarModel
from crs_core.model.online import at_bound, model_values
from crs_core.settings import Settings, non_negative, positive

__all__ = [
    "EVENT_KINDS",
    "HOLD_SAFE_MODES",
    "STATUSES",
    "Supervisor",
    "SupervisorEvent",
    "SupervisorSettings",
    "SupervisorStep",
]

#: Statuses an estimate can carry (:mod:`crs_core.estimation.health`).
STATUSES = ("ok", "degraded", "lost")
#: Kinds of :class:`SupervisorEvent`.
EVENT_KINDS = (
    "stale",
    "fresh",
    "degraded",
    "recovered",
    "controller",
    "failed",
    "rejected",
    "stuck",
    "unstuck",
    "cautious",
    "relaxed",
    "starved",
    "standing",
    "fed",
)
#: A speed cap this low (m/s) while the overload watch stands the car: it is braked to a stand
#: (:meth:`Supervisor._brake`) instead of controlled.
STANDING_CAP = 0.05
#: When the MPCC is asked for hold-safe plans (:attr:`SupervisorSettings.hold_safe`).
HOLD_SAFE_MODES = ("after_outage", "always", "never")
#: The stop command: straight wheels and zero torque (velocity mode: a zero reference).
STOP = np.array([0.0, 0.0])
STOP.flags.writeable = False


@dataclass(frozen=True)
class SupervisorSettings(Settings):
    """Limits and timings of :class:`Supervisor`.

    Attributes
    ----------
    stale_timeout : float
        An estimate older than this (s) is stale: the car is stopped. Also how far back the
        commands sent are kept for the prediction.
    degraded_speed : float
        Speed cap while the estimate is ``degraded``, m/s.
    max_speed : float
        Speed cap at full speed, m/s: the controller's own top speed (the MPCC's
        ``progress_speed_max``, the path follower's ``v_ref``); at this cap the controller is
        called without a limit.
    ramp_rate : float
        Rate at which the speed cap falls, m/s^2 (1.5 m/s^2 kept ``v_x >= 0.49`` m/s offline
        where a step from 4 to 0.5 m/s at 1.1 m/s braked the car into reverse).
    rise_rate : float
        Rate at which the speed cap rises again, m/s^2 (a rising cap only allows speed: the
        car's own acceleration is the limit).
    ok_hold : float
        Longest time (s) the status must have stayed ``ok`` before the cap rises: the wait is
        the time the status was degraded since the cap began to fall, up to this.
    steer_max : float
        Largest steering command magnitude, rad.
    torque_min, torque_max : float
        Range of the normalised torque command (negative brakes); must contain 0.
    velocity_max : float
        Velocity mode: largest velocity reference, m/s (references are within ``[0, this]``).
    hold_safe : {"after_outage", "always", "never"}
        When the MPCC plans commands safe to hold through an outage of the link:
        ``after_outage`` (for ``caution_memory`` s after the link showed one), ``always`` or
        ``never`` (see the module docstring).
    caution_memory : float
        How long after the link's last outage the plans stay hold-safe, s.
    ok_before_outage : float
        A degraded estimate counts as an outage after this long driving on ok ones, s (the
        estimator's first estimates are degraded until the Lighthouse is accepted).
    overload : OverloadSettings
        When the loop counts as starved (late ticks, old estimates) and how slow the car goes
        then (:mod:`~crs_core.control.overload`).
    """

    stale_timeout: float = positive(0.2)
    degraded_speed: float = positive(0.5)
    max_speed: float = positive(4.0)
    ramp_rate: float = positive(1.5)
    rise_rate: float = positive(3.0)
    ok_hold: float = non_negative(1.0)
    steer_max: float = positive(0.34)
    torque_min: float = -1.0
    torque_max: float = 1.0
    velocity_max: float = non_negative(5.0)
    hold_safe: str = "after_outage"
    caution_memory: float = non_negative(60.0)
    ok_before_outage: float = non_negative(1.0)
    overload: OverloadSettings = field(default_factory=OverloadSettings)

    def _check_relations(self) -> None:
        if self.hold_safe not in HOLD_SAFE_MODES:
            raise FieldError(
                "hold_safe", f"must be one of {', '.join(HOLD_SAFE_MODES)}, got {self.hold_safe!r}"
            )
        if not self.degraded_speed <= self.max_speed:
            raise FieldError(
                "degraded_speed",
                f"must not exceed max_speed ({self.max_speed:g} m/s), got {self.degraded_speed!r}",
            )
        if not (
            math.isfinite(self.torque_min)
            and math.isfinite(self.torque_max)
            and self.torque_min <= 0.0 <= self.torque_max
        ):
            raise FieldError(
                "torque_min, torque_max",
                "must be finite with torque_min <= 0 <= torque_max, got "
                f"{self.torque_min!r}, {self.torque_max!r}",
            )


@dataclass(frozen=True)
class SupervisorEvent:
    """Something a tick did that the caller may log.

    Attributes
    ----------
    kind : str
        ``"stale"`` (the car is being stopped), ``"fresh"`` (driving again), ``"degraded"`` (the
        cap starts ramping down), ``"recovered"`` (the cap starts ramping back up),
        ``"controller"`` (the MPCC did not solve: fallback or stop), ``"failed"`` (the controller
        raised), ``"rejected"`` (a bad command was replaced by the stop command), ``"stuck"``
        (the car stands: backing it out), ``"unstuck"`` (the controller drives again),
        ``"cautious"`` (an outage: hold-safe plans from now on), ``"relaxed"`` (no outage for
        ``caution_memory`` s: racing plans again), ``"starved"`` (the loop ran late: slowing),
        ``"standing"`` (late most of the time: stopping on the track) or ``"fed"`` (on time
        again: the overload limit is lifted).
    message : str
        One line saying what and why.
    """

    kind: str
    message: str


@dataclass(frozen=True)
class SupervisorStep:
    """The decision of one tick.

    Attributes
    ----------
    command : numpy.ndarray
        The command to send, shape (2,), finite and within the limits.
    driving : bool
        False while the estimate is stale or lost (the command is the stop command).
    speed_cap : float
        The speed cap of this tick, m/s (``max_speed``: none in effect).
    events : tuple of SupervisorEvent
        What changed or went wrong at this tick.
    solve_time : float or None
        Wall time of the controller's call, s (None: not called, or it raised).
    """

    command: np.ndarray
    driving: bool
    speed_cap: float
    events: tuple[SupervisorEvent, ...]
    solve_time: float | None


class Supervisor:
    """Runs a controller on the newest estimate, safely.

    Parameters
    ----------
    controller : Mpcc or callable
        The MPCC, or a controller called as ``controller(now, x, speed_limit) -> u`` (the
        :class:`~crs_core.control.path_following.PathFollower`), reset (``controller.reset()``,
        if it has one) when driving resumes after a stop.
    settings : SupervisorSettings, optional
    model : CarModel, optional
        Prediction model: the estimate is carried forward to ``now`` with it and the commands
        sent (its parameter values). None: the estimate is used as it is.
    output : {"torque", "velocity"}
        What the commands are: ``[delta, T]`` or ``[delta, v_x]`` (the MPCC only).
    recovery : StuckRecovery, optional
        Backs a stuck car out (torque commands only; a velocity reference cannot reverse).
    command_delay : CommandDelay, optional
        Measures how long after a tick its command acts (fed by the caller with the car's
        reports, :meth:`CommandDelay.applied`); the estimate is carried that far beyond the
        tick. None: to the tick.
    """

    def __init__(
        self,
        controller: Mpcc | Callable[[float, np.ndarray, float | None], np.ndarray],
        settings: SupervisorSettings | None = None,
        model: CarModel | None = None,
        output: str = "torque",
        recovery: StuckRecovery | None = None,
        command_delay: CommandDelay | None = None,
    ) -> None:
        if output not in OUTPUTS:
            raise ValueError(f"output: must be one of {', '.join(OUTPUTS)}, got {output!r}")
        if recovery is not None and output != "torque":
            raise ValueError("recovery: backs out with torque commands only")
        self.recovery = recovery
        self.command_delay = command_delay
        self.controller = controller
        self.settings = settings or SupervisorSettings()
        self.output = output
        self._mpcc = controller if isinstance(controller, Mpcc) else None
        self._model = model
        self._numeric = model.numeric if model is not None else None
        self._p = model.parameters.vector() if model is not None else None
        self._model_parameters = model.parameters if model is not None else None
        #: the newest online parameter estimates (by name; empty: none)
        self.online: dict[str, float] = {}
        #: the online parameters at their bound in the newest estimates
        self.at_bound: tuple[str, ...] = ()
        #: the model inputs of the commands sent in the last ``stale_timeout`` s: (time, input)
        self._sent: deque[tuple[float, np.ndarray]] = deque()
        self._latest: tuple[float, np.ndarray, str] | None = None
        self._stale = True
        self._limited = False  # the cap is held at or ramping to degraded_speed
        self._ok_since: float | None = None
        self._degraded_for = 0.0  # s degraded since the cap began to fall
        self._last_tick: float | None = None
        #: the speed cap in effect, m/s
        self.speed_cap = self.settings.max_speed
        #: stop episodes (stale or lost estimates) so far
        self.stops = 0
        #: commands replaced by the stop command because they were non-finite or out of range
        self.rejected_commands = 0
        #: why the last rejected command was rejected ('' none yet)
        self.last_rejection = ""
        #: until when (s) the MPCC plans hold-safe after the last outage (-inf: not cautious)
        self.cautious_until = -math.inf
        #: outages seen (degraded estimates while driving, motor cut-offs the car reported)
        self.outages = 0
        self._ok_driving_since: float | None = None
        self._pending_events: list[SupervisorEvent] = []
        #: late ticks of the loop and the speed limit they call for
        self.overload = OverloadWatch(self.settings.overload)
        self._watched_stamp = -math.inf  # the newest estimate's stamp the watch has seen
        self._estimate_tick = -math.inf  # the tick that saw it arrive

    def observe(self, stamp: float, x: ArrayLike, status: str) -> None:
        """Take a state estimate: base state ``x`` (6,) at ``stamp`` (s) with its ``status``.

        The newest one to arrive is used (estimates come in stamp order from one estimator).
        Raises ``ValueError`` naming the field for a non-finite stamp or state or an unknown
        status.
        """
        stamp = float(stamp)
        if not math.isfinite(stamp):
            raise ValueError(f"stamp: must be finite, got {stamp!r}")
        state = np.array(x, dtype=float)
        if state.shape != (6,) or not np.all(np.isfinite(state)):
            raise ValueError(f"x: need 6 finite states, got {state.tolist()}")
        if status not in STATUSES:
            raise ValueError(f"status: must be one of {', '.join(STATUSES)}, got {status!r}")
        self._latest = (stamp, state, status)

    def observe_parameters(self, values: Mapping[str, float]) -> None:
        """Take the estimator's newest online parameter estimates (by name): the MPCC's model
        moves toward them at its ``parameter_rate``, the prediction to when a command acts
        uses them, and one at its bound makes the car slow down as for a degraded estimate."""
        for name, value in values.items():
            if not math.isfinite(value):
                raise ValueError(f"{name}: must be finite, got {value!r}")
        self.online = dict(values)
        parameters = self._model_parameters
        self.at_bound = tuple(
            name for name, value in values.items()
            if parameters is not None and at_bound(name, value, parameters)
        )  # fmt: skip

    def _use_online(self, dt: float) -> None:
        """The MPCC's and the prediction's parameters toward :attr:`online`."""
        if not self.online:
            return
        if self._mpcc is not None:
            used = self._mpcc.use_parameters(self.online, dt)
        elif self._model_parameters is not None:
            used = model_values(self._model_parameters, self.online)
        else:
            return
        if self._p is not None and self._model_parameters is not None:
            names = self._model_parameters.names
            for name, value in used.items():
                self._p[names.index(name)] = value

    def __call__(self, now: float) -> SupervisorStep:
        """Decide the command to send at ``now`` (s) and record it as sent."""
        dt = 0.0 if self._last_tick is None else max(now - self._last_tick, 0.0)
        self._last_tick = now
        events, self._pending_events = self._pending_events, []
        solve_time = None
        why = self._stale_reason(now)
        self._watch_link(now, why, events)
        self._watch_overload(now, dt, events)
        if why:
            if not self._stale:
                self.stops += 1
                events.append(
                    SupervisorEvent("stale", f"state estimate is stale: stopping the car ({why})")
                )
            self._stale = True
            self._ok_since = None
            if self.recovery is not None:
                self.recovery.reset()
            u = self._stop(keep_plan=True, reason="state estimate stale or lost")
        else:
            if self._stale:
                events.append(SupervisorEvent("fresh", "state estimate is fresh: driving"))
                if self._mpcc is None:
                    self._reset_controller()
            self._stale = False
            self._use_online(dt)
            x = self.predicted(now)
            self._update_cap(now, dt, float(x[3]), events)
            s = self.settings
            limit = self.speed_cap if self.speed_cap < s.max_speed else None
            backing_out = self._backing_out(now, x, events)
            if backing_out is not None:
                u = backing_out
            elif self.overload.state == "stand" and self.speed_cap <= STANDING_CAP:
                u = self._brake(x, "the loop is starved: standing on the track")
            else:
                u, solve_time = self._command(now, x, limit, dt, events)
            problem = self._problem(u)
            if problem:
                self.rejected_commands += 1
                self.last_rejection = problem
                events.append(
                    SupervisorEvent(
                        "rejected",
                        f"command rejected, stopping instead ({self.rejected_commands} so far): "
                        f"{problem}",
                    )
                )
                u = self._stop(keep_plan=False, reason=f"command rejected: {problem}")
        self._sent.append((now, self._model_input(u)))
        while len(self._sent) > 1 and self._sent[1][0] <= now - self.settings.stale_timeout:
            self._sent.popleft()
        if self.command_delay is not None and self.output == "torque":
            self.command_delay.sent(now, float(u[1]))
        return SupervisorStep(u, not self._stale, self.speed_cap, tuple(events), solve_time)

    def applied(self, stamp: float, torque: float) -> None:
        """Take the car's report that it now applies drive power ``torque`` (from ``stamp``, s,
        the car's clock): measured into the command delay (if any), and a zero power while the
        car was being sent a driving torque is a motor cut-off, an outage of the link."""
        if self.command_delay is not None:
            self.command_delay.applied(stamp, torque)
        if torque != 0.0 or self._last_tick is None or not self._sent:
            return
        if self._driving_ok_for(self._last_tick) and self._sent[-1][1][1] != 0.0:
            self._outage(self._last_tick, "the car cut its motors", self._pending_events)

    def hold_safe(self, now: float) -> bool:
        """Whether the MPCC plans hold-safe at ``now`` (s): the setting, or after an outage."""
        mode = self.settings.hold_safe
        return mode == "always" or (mode == "after_outage" and now < self.cautious_until)

    def predicted(self, now: float) -> np.ndarray:
        """The newest estimate carried forward to when a command issued at ``now`` acts (``now``
        plus the command delay, if measured), with the model and the commands sent since its
        stamp, each acting from its own tick plus that delay (the estimate is tens of ms old:
        the estimator's lag and the transport; on an emulated lap the state carried to the tick
        is 3.9 mm from the truth (median; 54 mm not carried), and the commands' history matters
        once estimates are older than a control period); as it is without a model. Only the
        last ``stale_timeout`` s are carried over."""
        if self._latest is None:
            raise ValueError("no estimate observed yet")
        stamp, x, _ = self._latest
        delay = self.command_delay.delay if self.command_delay is not None else 0.0
        target = now + delay
        if self._numeric is None or self._p is None or target <= stamp:
            return x
        t = max(stamp, target - self.settings.stale_timeout)
        sent = self._sent
        assert self._model is not None
        acting = [
            u for k, (_, u) in enumerate(sent) if k + 1 >= len(sent) or sent[k + 1][0] + delay > t
        ]
        u = acting[0] if acting else STOP
        x = self._model.initial_state(x, u)  # the car state as the model's state
        for k, (_issued, u) in enumerate(sent):
            until = sent[k + 1][0] + delay if k + 1 < len(sent) else target
            if until <= t:
                continue  # replaced before the estimate's stamp
            x = self._numeric.step(x, u, self._p, until - t)
            t = until
        if t < target:  # no command sent yet (the first tick)
            u = STOP
            x = self._numeric.step(x, STOP, self._p, target - t)
        return self._numeric.car_state(x, u, self._p)

    # --- steps ---------------------------------------------------------------------------
    def _stale_reason(self, now: float) -> str:
        """Why the newest estimate cannot be driven on at ``now`` ('' if it can)."""
        if self._latest is None:
            return "none received yet"
        stamp, _, status = self._latest
        if status == "lost":
            return "status lost"
        if now - stamp > self.settings.stale_timeout:
            return f"{now - stamp:.2f} s old, over {self.settings.stale_timeout:g} s"
        return ""

    def _driving_ok_for(self, now: float) -> bool:
        """Whether the car has been driven on ok estimates for ``ok_before_outage`` s."""
        since = self._ok_driving_since
        return since is not None and now - since >= self.settings.ok_before_outage

    def _watch_link(self, now: float, stale_reason: str, events: list) -> None:
        """Notice an outage in the estimates (a stale or degraded one after driving on ok
        ones) and the end of caution; at each tick, before the decision."""
        status = None if self._latest is None else self._latest[2]
        if stale_reason or status != "ok":
            if self._driving_ok_for(now):
                self._outage(now, f"the state estimate is {stale_reason or status}", events)
            self._ok_driving_since = None
        elif self._ok_driving_since is None:
            self._ok_driving_since = now
        if math.isfinite(self.cautious_until) and now >= self.cautious_until:
            self.cautious_until = -math.inf
            events.append(
                SupervisorEvent(
                    "relaxed",
                    f"no link outage for {self.settings.caution_memory:g} s: racing plans again",
                )
            )

    def _watch_overload(self, now: float, dt: float, events: list) -> None:
        """Take this tick into the overload watch (its interval, and how long since a tick saw
        a new estimate) and say when its limit changes; not before the first estimate."""
        if self._latest is None:
            return
        if self._latest[0] != self._watched_stamp:
            self._watched_stamp, self._estimate_tick = self._latest[0], now
        before = self.overload.state
        reason = self.overload.tick(now, dt, now - self._estimate_tick)
        state = self.overload.state
        if state == before:
            return
        o = self.overload.settings
        if before == "stand":
            message = (
                f"the loop kept its period for {self.overload.hold:g} s: driving again at "
                f"{o.slow_speed:g} m/s"
            )
            events.append(SupervisorEvent("fed", message))
        elif state == "slow":
            message = f"the loop is starved ({reason}): slowing to {o.slow_speed:g} m/s"
            events.append(SupervisorEvent("starved", message))
        elif state == "stand":
            message = (
                f"the loop is starved, late {100 * self.overload.late_fraction(now):.0f} % of "
                f"the last {o.window:g} s ({reason}): stopping on the track"
            )
            events.append(SupervisorEvent("standing", message))
        else:
            message = (
                f"the loop kept its period for {self.overload.hold:g} s: overload limit lifted"
            )
            events.append(SupervisorEvent("fed", message))

    def _outage(self, now: float, why: str, events: list) -> None:
        """An outage of the link at ``now`` (s): hold-safe plans for ``caution_memory`` s."""
        self.outages += 1
        if self._mpcc is None or self.settings.hold_safe != "after_outage":
            return  # only the MPCC plans hold-safe
        if now >= self.cautious_until:
            events.append(
                SupervisorEvent(
                    "cautious",
                    f"link outage ({why}): planning commands safe to hold through the next one "
                    f"for {self.settings.caution_memory:g} s",
                )
            )
        self.cautious_until = now + self.settings.caution_memory

    def _degraded_reason(self) -> str:
        if self.at_bound:
            return f"online parameter {', '.join(self.at_bound)} at its bound"
        return "state estimate degraded"

    def _update_cap(self, now: float, dt: float, speed: float, events: list) -> None:
        """Ramp the speed cap for a fresh estimate of status ``self._latest[2]``; the car's
        (predicted) speed ``speed`` (m/s) is where a fall starts when it is below the cap."""
        if self._latest is None:
            raise ValueError("no estimate observed yet")
        s = self.settings
        status = "degraded" if self.at_bound else self._latest[2]
        if status == "degraded":
            self._ok_since = None
            if self._limited:
                self._degraded_for += dt
            else:
                self._limited = True
                self._degraded_for = 0.0
                self.speed_cap = min(self.speed_cap, max(speed, s.degraded_speed))
                events.append(
                    SupervisorEvent(
                        "degraded",
                        f"{self._degraded_reason()}: slowing to {s.degraded_speed:g} m/s "
                        f"(at {s.ramp_rate:g} m/s^2)",
                    )
                )
        elif self._limited:
            if self._ok_since is None:
                self._ok_since = now
            hold = min(s.ok_hold, self._degraded_for)
            if now - self._ok_since >= hold:
                self._limited = False
                events.append(
                    SupervisorEvent(
                        "recovered",
                        f"state estimate ok for {now - self._ok_since:.2f} s after "
                        f"{self._degraded_for:.2f} s degraded: back to full speed "
                        f"(at {s.rise_rate:g} m/s^2)",
                    )
                )
        before = self.speed_cap
        if self._limited:
            self.speed_cap = max(self.speed_cap - s.ramp_rate * dt, s.degraded_speed)
        else:
            self.speed_cap = min(self.speed_cap + s.rise_rate * dt, s.max_speed)
        limit = self.overload.limit
        if limit is not None and self.speed_cap > limit:  # falls from the car's speed, if lower
            start = min(before, max(speed, limit))
            self.speed_cap = min(self.speed_cap, max(start - s.ramp_rate * dt, limit))

    def _backing_out(self, now: float, x: np.ndarray, events: list) -> np.ndarray | None:
        """The recovery's reverse command while it backs a stuck car out, else None; the
        controller starts over from cold once it ends."""
        if self.recovery is None:
            return None
        if self.overload.state != "ok":  # standing on purpose, or starting from it slowly
            self.recovery.reset()
            return None
        was_active = self.recovery.active
        u = self.recovery(now, x)
        if u is not None and not was_active:
            s = self.recovery.settings
            events.append(
                SupervisorEvent(
                    "stuck",
                    f"the car has stood for {s.stuck_after:g} s: reversing to face along the "
                    f"track (backed out {self.recovery.count} time(s) so far)",
                )
            )
        elif u is None and was_active:
            events.append(SupervisorEvent("unstuck", "backed out: driving again"))
            self._reset_controller()
        return u

    def _reset_controller(self) -> None:
        """Make the controller start over (``controller.reset()``, if it has one)."""
        reset = getattr(self.controller, "reset", None)
        if reset is not None:
            reset()

    def _command(
        self, now: float, x: np.ndarray, limit: float | None, elapsed: float, events: list
    ) -> tuple[np.ndarray, float | None]:
        """The controller's command and its call's wall time (None if it raised); the MPCC
        carries its plan on by the ``elapsed`` s since the last tick, hold-safe when
        :meth:`hold_safe` says so at ``now``."""
        started = time.perf_counter()
        controller = self.controller
        try:
            if isinstance(controller, Mpcc):  # (then self._mpcc)
                u = controller(x, limit, elapsed, self.hold_safe(now))
                status = controller.status
                if status is not None and status.mode != "solved":
                    events.append(
                        SupervisorEvent("controller", f"MPCC {status.mode}: {status.reason}")
                    )
            else:
                u = controller(now, x, limit)
        except (ValueError, RuntimeError) as error:
            events.append(SupervisorEvent("failed", f"controller failed: {error}"))
            return self._stop(keep_plan=False, reason=f"controller failed: {error}"), None
        return u, time.perf_counter() - started

    def _problem(self, u: object) -> str:
        """Why command ``u`` must not leave ('' if it may)."""
        try:
            command = np.asarray(u, dtype=float)
        except (TypeError, ValueError):
            return f"not numeric: {u!r}"
        if command.shape != (2,):
            return f"needs shape (2,), got {command.shape}"
        if not np.all(np.isfinite(command)):
            return f"not finite: {command.tolist()}"
        s = self.settings
        steer, second = float(command[0]), float(command[1])
        if abs(steer) > s.steer_max:
            return f"steering {steer:.4g} rad outside ±{s.steer_max:g} rad"
        if self.output == "velocity":
            if not 0.0 <= second <= s.velocity_max:
                return f"velocity {second:.4g} m/s outside [0, {s.velocity_max:g}] m/s"
        elif not s.torque_min <= second <= s.torque_max:
            return f"torque {second:.4g} outside [{s.torque_min:g}, {s.torque_max:g}]"
        return ""

    def _stop(self, keep_plan: bool, reason: str) -> np.ndarray:
        """Zero torque and straight wheels: without a fresh estimate the car's speed is not
        known, so it rolls to a stop rather than being braked (which could reverse it). In
        velocity mode: straight wheels and a zero velocity reference (the car's velocity PID
        brakes it to a stand, on its own wheel speeds). With ``keep_plan`` the MPCC keeps its
        plan for a short gap in the estimates, and its steering (see :meth:`Mpcc.stop`)."""
        if self._mpcc is not None:
            return self._mpcc.stop(None, reason, keep_plan=keep_plan)
        return STOP.copy()

    def _brake(self, x: np.ndarray, reason: str) -> np.ndarray:
        """Brake the car of (predicted) state ``x`` to a stand where it is: the MPCC's stop
        (``-brake_gain v_x`` until it stands, the plan's steering while it has one); without
        the MPCC, the stop command. The controller is not asked: a starved loop's controller
        would keep correcting towards its path, on estimates that have gone astray."""
        if self._mpcc is None:
            return STOP.copy()
        return self._mpcc.stop(x, reason, keep_plan=True)

    def _model_input(self, u: np.ndarray) -> np.ndarray:
        """The model input ``[delta, T]`` of command ``u`` (for the prediction): ``u`` itself
        in torque mode; for a velocity reference the first input of the MPCC's plan (the torque
        it expects the car's velocity PID to apply), zero torque without a plan."""
        if self.output == "torque":
            return np.array(u, dtype=float)
        plan = self._mpcc.plan if self._mpcc is not None else None
        return plan[1][0, :2].copy() if plan is not None else np.array([u[0], 0.0])
