"""The honest status of an estimate: ``ok``, ``degraded`` or ``lost``, with the reason.

An estimator reports every measurement it accepted or rejected and every solver fallback to a
:class:`HealthMonitor`; the monitor answers, at the time of an estimate, which of three words
describes it:

``ok``
    The estimate is supported by its data.
``degraded``
    It is still usable but less trustworthy: within the last ``window_s`` seconds more than
    ``rejected_fraction`` of a sensor's samples were rejected, or a solver fallback happened, or
    the Lighthouse (the only absolute position reference) has not been accepted for
    ``dead_reckoning_after_s`` (the pose is dead-reckoned) or not at all since the start.
``lost``
    The estimator does not know where the car is: it is waiting for its first Lighthouse (or
    motion-capture) fix, or it is re-initialising after the Lighthouse disagreed with it for
    ``lost_after_s`` (every sweep rejected while sweeps kept arriving), or no sample of any
    sensor has come for ``lost_silent_s`` (the link to the car is down: the estimator only
    predicts from commands the car may never have received, and a Chronos car cuts its motors
    200 ms after the last one), or its state left the physical envelope.

All times are measurement stamps in seconds (the stream's clock).
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass

from crs_core.errors import FieldError
from crs_core.settings import Settings, positive, within

#: The three status words, best first.
STATUSES = ("ok", "degraded", "lost")


@dataclass(frozen=True)
class HealthSettings(Settings, prefix="health"):
    """Thresholds of :class:`HealthMonitor` (and of re-initialisation).

    Attributes
    ----------
    window_s : float
        Look-back window for rejections and fallbacks, s.
    rejected_fraction : float
        More than this fraction of one sensor's samples rejected in the window: ``degraded``.
    dead_reckoning_after_s : float
        No Lighthouse sample accepted for this long while the Lighthouse is in use: ``degraded``.
    lost_after_s : float
        Every Lighthouse sample rejected for this long (and at least ``lost_min_samples`` of
        them): ``lost``, and the estimator re-initialises from the Lighthouse.
    lost_min_samples : int
        Rejected Lighthouse samples needed before ``lost_after_s`` can declare the estimate lost
        (a short burst of outliers is not a disagreement).
    lost_silent_s : float
        No sample of any sensor for this long (s): ``lost``, and the estimator re-initialises
        from the Lighthouse once samples come again (well above the ``outages`` link preset's
        0.3 s; a Lighthouse blackout alone, with the IMU still coming, is dead reckoning).
    max_speed : float
        ``|v_x|`` or ``|v_y|`` above this (m/s) is outside the physical envelope: ``lost``.
    max_yaw_rate : float
        ``|omega|`` above this (rad/s) is outside the physical envelope: ``lost``.
    """

    window_s: float = positive(1.0)
    rejected_fraction: float = within(0.2, low=0, high=1)
    dead_reckoning_after_s: float = positive(0.25)
    lost_after_s: float = positive(0.5)
    lost_min_samples: int = 10
    lost_silent_s: float = positive(1.0)
    max_speed: float = positive(10.0)
    max_yaw_rate: float = positive(40.0)

    def _check_relations(self) -> None:
        if self.lost_min_samples < 1:
            raise FieldError("health.lost_min_samples", "must be >= 1")


class HealthMonitor:
    """Running record of accepted and rejected samples per sensor group and of fallbacks."""

    def __init__(self, settings: HealthSettings, lighthouse_in_use: bool) -> None:
        self.settings = settings
        self.lighthouse_in_use = lighthouse_in_use
        self.clear()

    def clear(self) -> None:
        """Forget everything (after a reset)."""
        self._accepted: dict[str, deque[float]] = {}
        self._rejected: dict[str, deque[float]] = {}
        self._fallbacks: deque[tuple[float, str]] = deque()
        self._last_lighthouse_accepted: float | None = None
        self._first_lighthouse_rejected: float | None = None  # start of the current run
        self._last_sample: float | None = None  # newest sample of any sensor group

    def start(self, t0: float) -> None:
        """Count silence from ``t0`` (a reset or a re-initialisation)."""
        self._last_sample = t0

    def record(self, group: str, stamp: float, accepted: bool) -> None:
        """A sample of sensor group ``group`` (``lh``, ``imu``, ...) stamped ``stamp``."""
        book = self._accepted if accepted else self._rejected
        book.setdefault(group, deque()).append(stamp)
        if self._last_sample is None or stamp > self._last_sample:
            self._last_sample = stamp
        if group != "lh":
            return
        if accepted:
            self._last_lighthouse_accepted = stamp
            self._first_lighthouse_rejected = None
        elif self._first_lighthouse_rejected is None:
            self._first_lighthouse_rejected = stamp

    def fallback(self, stamp: float, reason: str) -> None:
        self._fallbacks.append((stamp, reason))

    def disagreeing_since(self, t: float) -> float | None:
        """How long (s) every Lighthouse sample was rejected, if that counts as lost."""
        start = self._first_lighthouse_rejected
        if start is None:
            return None
        rejected = self._rejected.get("lh", ())
        recent = sum(1 for s in reversed(rejected) if s >= start)
        duration = t - start
        if duration >= self.settings.lost_after_s and recent >= self.settings.lost_min_samples:
            return duration
        return None

    def silent_for(self, t: float) -> float | None:
        """How long (s) no sample of any sensor has come, if that counts as lost."""
        last = self._last_sample
        if last is None or t - last < self.settings.lost_silent_s:
            return None
        return t - last

    def status(self, t: float) -> tuple[str, str]:
        """``("ok" | "degraded", reason)`` at time ``t`` (``lost`` is decided by the estimator)."""
        s = self.settings
        since = t - s.window_s
        for book in (self._accepted, self._rejected):
            for stamps in book.values():
                while stamps and stamps[0] < since:
                    stamps.popleft()
        while self._fallbacks and self._fallbacks[0][0] < since:
            self._fallbacks.popleft()
        reasons = []
        if self._fallbacks:
            reasons.append(
                f"{len(self._fallbacks)} solver fallback(s) in the last {s.window_s:g} s "
                f"(last: {self._fallbacks[-1][1]})"
            )
        for group, rejected in sorted(self._rejected.items()):
            total = len(rejected) + len(self._accepted.get(group, ()))
            if rejected and len(rejected) > s.rejected_fraction * total:
                reasons.append(
                    f"{group}: {len(rejected)} of {total} samples rejected in the last "
                    f"{s.window_s:g} s"
                )
        last = self._last_lighthouse_accepted
        if self.lighthouse_in_use:
            if last is None:
                reasons.append("no Lighthouse sample accepted yet (the start state is unconfirmed)")
            elif t - last > s.dead_reckoning_after_s:
                reasons.append(
                    f"no Lighthouse sample accepted for {t - last:.2f} s (dead reckoning)"
                )
        return ("degraded", "; ".join(reasons)) if reasons else ("ok", "")
