"""Outlier gating that still lets a drifted estimate recover (shared by the EKF and the MHE)."""

from __future__ import annotations

import numpy as np


class RejectionCap:
    """A cap on consecutive rejections that tells a drifted estimate from a burst of outliers.

    After ``limit`` rejections in a row of one sensor, a rejected measurement is taken anyway
    only when its normalised innovation agrees, in every channel within ``tolerance``, with the
    median of the previous ``window`` rejected ones: an estimate that drifted (during an outage)
    sees the same innovation sample after sample, a burst of wild readings does not.
    """

    def __init__(self, limit: int, window: int = 5, tolerance: float = 10.0) -> None:
        self.limit, self.window, self.tolerance = limit, window, tolerance
        self._runs: dict[str, tuple[int, list[np.ndarray]]] = {}

    def clear(self) -> None:
        self._runs.clear()

    def accepted(self, key: str) -> None:
        """A measurement of ``key`` passed its gate: its run of rejections ends."""
        self._runs.pop(key, None)

    def override(self, key: str, normalised_innovation: np.ndarray) -> bool:
        """Called for a measurement that failed its gate: True to take it anyway."""
        count, recent = self._runs.get(key, (0, []))
        innovation = np.asarray(normalised_innovation, dtype=float)
        if count >= self.limit and len(recent) == self.window:
            spread = np.abs(innovation - np.median(recent, axis=0))
            if np.all(spread < self.tolerance):
                self._runs.pop(key)
                return True
        self._runs[key] = (count + 1, [*recent, innovation][-self.window :])
        return False
