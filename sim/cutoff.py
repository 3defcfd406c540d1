"""The car's link watchdog: the firmware cuts the drive motor when the commands stop.

A Chronos car that received no valid reference for :data:`DISCONNECT_THRESHOLD_S` (200 ms,
the firmware's ``CONFIG_DISCONNECT_THRESHOLD_MS``) sets its drive torque to 0 and keeps its
steering reference (the linkage stands still), until the next valid reference. It starts cut
(no reference yet). The car emulator (:mod:`chronos_bridge.emulator`) and the simulator node
both run this one watchdog, so a simulated car stops when its controller or its link goes
silent, as the real one does. Times are s on the caller's clock (never decreasing).
"""

from __future__ import annotations

import math

from crs_core.errors import FieldError

__all__ = ["DISCONNECT_THRESHOLD_S", "MotorCutoff"]

#: No reference for this long cuts the motors (``CONFIG_DISCONNECT_THRESHOLD_MS``), s.
DISCONNECT_THRESHOLD_S = 0.2


class MotorCutoff:
    """Whether the drive motor is cut, from the times of the valid commands.

    Parameters
    ----------
    threshold : float
        Silence that cuts the motor, s (> 0).

    Attributes
    ----------
    cut : bool
        The motor is cut (from the start until the first command, and after each silence).
    cuts : int
        Times the silence cut the motor (the start not counted).
    last_command : float or None
        Time of the last valid command, s (None: none yet).
    """

    def __init__(self, threshold: float = DISCONNECT_THRESHOLD_S) -> None:
        if not (math.isfinite(threshold) and threshold > 0):
            raise FieldError("threshold", f"must be a finite number > 0, got {threshold!r}")
        self.threshold = float(threshold)
        self.cut = True
        self.cuts = 0
        self.last_command: float | None = None

    def commanded(self, now: float) -> bool:
        """A valid command arrived at ``now``; True when it ends a cut (the car drives again)."""
        self.last_command = now
        ended = self.cut
        self.cut = False
        return ended

    def expired(self, now: float) -> bool:
        """True at the first check at or after ``threshold`` s of silence (the motor is cut
        from here, until the next command), else False."""
        if self.cut or self.last_command is None:
            return False
        if now - self.last_command >= self.threshold - 1e-9:
            self.cut = True
            self.cuts += 1
            return True
        return False
