"""The command delay: how long after a control tick the car applies that tick's command,
measured from the car's own reports of the torque it applies.

A command is computed from the estimate carried forward to the tick (:class:`Supervisor`),
but it acts later: the controller's call, the transport to the bridge, the Wi-Fi downlink
(15-40 ms on a bad link, against about 1 ms on a loopback) and the car's 250 Hz loop. A
controller that plans from the state at the tick steers from where the car was; on the bad
Wi-Fi preset that weaved the car from one edge of the track to the other (1.3-2.8 s off the
track in 40 s). :class:`CommandDelay` measures the delay on the running link: every command's
torque is recorded with its tick, and every report that the car applies a new drive power
(``input/applied``, stamped by the car's clock) is matched to the one command sent with that
torque. The delay is the median of the last matches; until there are enough of them (the
simulator and the velocity mode report none) it is ``initial``.

A torque matches when it is within ``tolerance`` of the applied power (the float32 of the
wire) and no other command of the last ``max_delay`` s is; zero (a stopped or cut-off car
applies none) and a torque repeated over several ticks (saturated) never match, and a command
is matched once (a reordered older command applied again says nothing of the delay).

Times in s: ticks on the controller's clock, applied stamps on the car's (synchronised to the
host, as the estimator's).
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass

import numpy as np

from crs_core.errors import FieldError
from crs_core.settings import Settings, non_negative

__all__ = ["CommandDelay", "CommandDelaySettings"]


@dataclass(slots=True)
class _Sent:
    """A command sent: its tick (s), its torque, and whether an application matched it."""

    tick: float
    torque: float
    matched: bool = False


@dataclass(frozen=True)
class CommandDelaySettings(Settings):
    """How the command delay is measured.

    Attributes
    ----------
    initial : float
        Delay used until ``min_matches`` commands have been matched, s (about a controller
        call plus a loopback: the simulator applies a command when it arrives).
    max_delay : float
        Longest delay that can be matched, s; commands older than this are forgotten.
    samples : int
        The delay is the median of this many last matches.
    min_matches : int
        Matches needed before the measurement replaces ``initial``.
    tolerance : float
        Largest difference between a command's torque and the applied power that matches
        (normalised torque; the wire carries float32).
    """

    initial: float = non_negative(0.02)
    max_delay: float = non_negative(0.15)
    samples: int = 31
    min_matches: int = 5
    tolerance: float = non_negative(1e-6)

    def _check_relations(self) -> None:
        if not self.initial <= self.max_delay:
            raise FieldError(
                "initial", f"must not exceed max_delay ({self.max_delay:g} s), got {self.initial!r}"
            )
        for name in ("samples", "min_matches"):
            value = getattr(self, name)
            if not (isinstance(value, int) and value >= 1):
                raise FieldError(name, f"must be an integer >= 1, got {value!r}")
        if self.min_matches > self.samples:
            raise FieldError(
                "min_matches", f"must not exceed samples ({self.samples}), got {self.min_matches}"
            )


class CommandDelay:
    """The delay from a control tick to the car applying that tick's command (s).

    Parameters
    ----------
    settings : CommandDelaySettings, optional
    """

    def __init__(self, settings: CommandDelaySettings | None = None) -> None:
        self.settings = settings or CommandDelaySettings()
        self._sent: deque[_Sent] = deque()
        self._matches: deque[float] = deque(maxlen=self.settings.samples)
        #: commands matched to an application so far
        self.matched = 0

    @property
    def delay(self) -> float:
        """The delay to compensate, s: the median of the last matches, ``initial`` before
        ``min_matches`` of them."""
        if len(self._matches) < self.settings.min_matches:
            return self.settings.initial
        return float(np.median(self._matches))

    def sent(self, tick: float, torque: float) -> None:
        """Record that the command of the tick at ``tick`` (s) carries ``torque``."""
        self._sent.append(_Sent(float(tick), float(torque)))
        horizon = float(tick) - self.settings.max_delay
        while self._sent and self._sent[0].tick < horizon:
            self._sent.popleft()

    def applied(self, stamp: float, torque: float) -> float | None:
        """Take the car's report that from ``stamp`` (s, car clock) it applies drive power
        ``torque``; returns the delay of the command it matched (None: none, several, or one
        matched before: a late duplicate or a reordered older command applied again)."""
        s = self.settings
        if not (math.isfinite(stamp) and math.isfinite(torque)) or abs(torque) <= s.tolerance:
            return None
        candidates = [sent for sent in self._sent if abs(sent.torque - torque) <= s.tolerance]
        if len(candidates) != 1:
            return None
        (command,) = candidates
        delay = stamp - command.tick
        if command.matched or not 0.0 <= delay <= s.max_delay:
            return None
        command.matched = True
        self._matches.append(delay)
        self.matched += 1
        return delay
