"""Backing a stuck car out: the recovery a controller that only drives forwards cannot make.

A car that came to a stand at the track's edge facing out (after an outage it entered a hairpin
too fast, coasting, and braked to a stop there) has no forward move that stays on the track, so
the MPCC, which never reverses, keeps it standing for good. :class:`StuckRecovery` notices a car
that has stood for ``stuck_after`` s while the controller was driving it and reverses it with the
steering that turns its nose towards the track's direction (reversing, a wheel steered left
turns the car right), for at most ``reverse_time`` s or until it faces along the track again,
then hands back. The reverse torque is small (about 0.4 m/s backwards at most) and the
car's own 200 ms cut-off still stops it if the link fails meanwhile.

Conventions: state ``[x_p, y_p, psi, v_x, v_y, omega]`` (m, rad, m/s, rad/s; world pose, body
velocities), command ``[delta, T]`` (rad, normalised torque), times in s on the caller's clock.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from crs_core.analysis.angles import wrap_angle
from crs_core.errors import FieldError
from crs_core.settings import Settings, positive
from crs_core.track import Track

__all__ = ["RecoverySettings", "StuckRecovery"]


@dataclass(frozen=True)
class RecoverySettings(Settings):
    """When a car counts as stuck and how it is backed out.

    Attributes
    ----------
    stuck_speed : float
        Below this speed (m/s, ``hypot(v_x, v_y)``) the car stands.
    stuck_after : float
        Standing this long (s) while driven, the car is stuck.
    reverse_torque : float
        Normalised torque of the reverse, > 0 (applied as ``-reverse_torque``).
    reverse_time : float
        Longest reverse, s.
    aligned_heading : float
        The reverse ends once the car's heading is within this of the track's, rad (and it
        has reversed at least a quarter of ``reverse_time``).
    """

    stuck_speed: float = positive(0.2)
    stuck_after: float = positive(0.5)
    reverse_torque: float = positive(0.25)
    reverse_time: float = positive(0.8)
    aligned_heading: float = 0.3

    def _check_relations(self) -> None:
        if not (math.isfinite(self.aligned_heading) and 0 < self.aligned_heading < math.pi):
            raise FieldError(
                "aligned_heading", f"must be within (0, pi) rad, got {self.aligned_heading!r}"
            )


class StuckRecovery:
    """Notices a stuck car and backs it out (see the module docstring).

    Parameters
    ----------
    track : Track
        The track raced on, in the direction of increasing arc length.
    steer_max : float
        Steering angle of the reverse, rad (full lock).
    settings : RecoverySettings, optional
    """

    def __init__(
        self, track: Track, steer_max: float, settings: RecoverySettings | None = None
    ) -> None:
        if not (math.isfinite(steer_max) and steer_max > 0):
            raise FieldError("steer_max", f"must be a finite number > 0, got {steer_max!r}")
        self.track = track
        self.steer_max = float(steer_max)
        self.settings = settings or RecoverySettings()
        #: reverses started so far
        self.count = 0
        self.reset()

    @property
    def active(self) -> bool:
        """Whether the car is being backed out."""
        return self._started is not None

    def reset(self) -> None:
        """Forget the standing time and end a reverse (the car was stopped for another reason)."""
        self._standing_since: float | None = None
        self._started: float | None = None

    def __call__(self, now: float, x: np.ndarray) -> np.ndarray | None:
        """The reverse command for state ``x`` at ``now`` while backing out, else None (the
        controller drives). Call once per control tick while the car is driven."""
        s = self.settings
        if self._started is not None:
            elapsed = now - self._started
            heading_error = self._heading_error(x)
            aligned = abs(heading_error) < s.aligned_heading and elapsed >= s.reverse_time / 4
            if elapsed >= s.reverse_time or aligned:
                self.reset()
                return None
            return self._reverse(heading_error)
        if math.hypot(x[3], x[4]) >= s.stuck_speed:
            self._standing_since = None
            return None
        if self._standing_since is None:
            self._standing_since = now
        if now - self._standing_since < s.stuck_after:
            return None
        self._started = now
        self.count += 1
        return self._reverse(self._heading_error(x))

    def _heading_error(self, x: np.ndarray) -> float:
        """The car's heading minus the track's at its projection, rad (projected only while
        standing or backing out: a global projection every tick of a racing car is waste)."""
        return float(wrap_angle(x[2] - self.track.project(x[0], x[1]).heading))

    def _reverse(self, heading_error: float) -> np.ndarray:
        """Reverse with the steering that turns the nose towards the track's direction:
        reversing, the yaw rate is ``v_x tan(delta) / L`` with ``v_x < 0``, so a car facing
        left of the track (error > 0) steers left."""
        steer = math.copysign(self.steer_max, heading_error)
        return np.array([steer, -self.settings.reverse_torque])
