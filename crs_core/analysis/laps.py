"""Laps: continuous progress along a closed track, laps completed and lap times."""

from __future__ import annotations

import math

from crs_core.errors import FieldError
from crs_core.track.geometry import _as_finite_float

__all__ = ["LapCounter"]


class LapCounter:
    """Continuous progress, completed laps and lap times from successive arc lengths.

    Feed the projections ``s(t)`` of a car with :meth:`update`. Progress is unwrapped (each step
    is taken as the shortest way around the loop, so consecutive samples must move less than
    ``length / 2``) and starts at the first ``s``.

    Laps are counted at the start/finish line ``s = 0``, i.e. when the progress first reaches a
    multiple ``k * length`` of the lap length. A start away from the line (``s0 > 0``) begins
    with a partial lap: the first crossing of the line only starts lap timing, and that partial
    lap is neither counted nor timed. A start on the line (``s0 <= line_tolerance``) counts as a
    crossing at the first stamp. Each line is counted once: driving backwards over it and forward
    again does not count a lap twice. Crossing stamps are interpolated linearly between samples.

    Parameters
    ----------
    length : float
        Lap length, m (:attr:`crs_core.track.Track.length`).
    line_tolerance : float, optional
        A first ``s`` in ``[0, line_tolerance]`` m counts as starting on the line. Default 1e-3.
    """

    def __init__(self, length: float, line_tolerance: float = 1e-3) -> None:
        self.length = _as_finite_float("length", length)
        if not self.length > 0.0:
            raise FieldError("length", f"must be positive, got {self.length!r}")
        self.line_tolerance = _as_finite_float("line_tolerance", line_tolerance)
        self.reset()

    def reset(self) -> None:
        """Forget all samples, progress and laps."""
        self._stamp: float | None = None
        self._s: float = 0.0
        self._progress: float = 0.0
        self._highest_line: int = 0
        self._crossings: list[float] = []

    @property
    def progress(self) -> float:
        """Continuous progress, m, since the first sample's arc length (0 before any sample)."""
        return self._progress

    @property
    def laps_completed(self) -> int:
        """Number of full laps driven between start/finish line crossings."""
        return max(len(self._crossings) - 1, 0)

    @property
    def crossing_stamps(self) -> list[float]:
        """Stamps of the start/finish line crossings, s (interpolated)."""
        return list(self._crossings)

    @property
    def lap_times(self) -> list[float]:
        """Durations of the completed laps, s, in order."""
        return [b - a for a, b in zip(self._crossings[:-1], self._crossings[1:], strict=True)]

    def update(self, stamp: float, s: float) -> float:
        """Add one sample.

        Parameters
        ----------
        stamp : float
            Time, s; must not decrease between calls.
        s : float
            Arc length of the car's projection, m (wrapped into ``[0, length)``).

        Returns
        -------
        float
            The continuous progress after this sample, m.

        Raises
        ------
        ValueError
            If an input is not finite or the stamp decreases.
        """
        stamp = _as_finite_float("stamp", stamp)
        s = _as_finite_float("s", s) % self.length
        if self._stamp is None:
            self._stamp, self._s, self._progress = stamp, s, s
            self._highest_line = 0
            if s <= self.line_tolerance:
                self._crossings.append(stamp)
            return self._progress
        if stamp < self._stamp:
            raise FieldError(
                "stamp", f"{stamp!r} is earlier than the previous stamp {self._stamp!r}"
            )
        step = (s - self._s + 0.5 * self.length) % self.length - 0.5 * self.length
        previous = self._progress
        progress = previous + step
        line = math.floor(progress / self.length)
        while self._highest_line < line:
            self._highest_line += 1
            boundary = self._highest_line * self.length
            fraction = (boundary - previous) / step if step > 0.0 else 1.0
            fraction = min(max(fraction, 0.0), 1.0)
            self._crossings.append(self._stamp + fraction * (stamp - self._stamp))
        self._stamp, self._s, self._progress = stamp, s, progress
        return progress
