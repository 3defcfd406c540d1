r"""A smooth arc-length parametrisation of a closed track centreline, for contouring control.

The track's centreline samples are joined by periodic cubic splines :math:`X(\theta)`,
:math:`Y(\theta)` in the arc length :math:`\theta` (m) of the samples, so position, tangent angle
:math:`\varphi(\theta)` and curvature :math:`\kappa(\theta)` are continuous (C² position) around
the whole loop, including across the start line. :math:`\theta` may be any real number (laps
unwrapped); it is reduced modulo the lap length for evaluation.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.interpolate import CubicSpline

from crs_core.track import Track

__all__ = ["PathPoint", "ReferencePath"]


class PathPoint:
    """Reference-path values at one or more arc lengths (arrays of the query's shape).

    Attributes
    ----------
    x, y : numpy.ndarray
        Centreline position, m, world frame.
    heading : numpy.ndarray
        Tangent angle :math:`\\varphi`, rad, world frame, in :math:`[-\\pi, \\pi]`.
    curvature : numpy.ndarray
        Signed curvature, 1/m, positive for a left turn.
    """

    __slots__ = ("curvature", "heading", "x", "y")

    def __init__(
        self,
        x: NDArray[np.float64],
        y: NDArray[np.float64],
        heading: NDArray[np.float64],
        curvature: NDArray[np.float64],
    ) -> None:
        self.x, self.y, self.heading, self.curvature = x, y, heading, curvature


class ReferencePath:
    """Periodic cubic-spline centreline of a :class:`~crs_core.track.Track`.

    Parameters
    ----------
    track : Track
        The closed track; its samples and lap length define the splines.

    Attributes
    ----------
    length : float
        Lap length, m.
    half_width : float
        Half the drivable track width, m.
    """

    def __init__(self, track: Track) -> None:
        if not isinstance(track, Track):
            raise TypeError(f"track: expected a Track, got {type(track).__name__}")
        self.track = track
        self.length = float(track.length)
        self.half_width = 0.5 * float(track.width)
        s = np.append(track.arc_length, track.length)
        self._x = CubicSpline(s, np.append(track.x, track.x[0]), bc_type="periodic")
        self._y = CubicSpline(s, np.append(track.y, track.y[0]), bc_type="periodic")

    def evaluate(self, theta: ArrayLike) -> PathPoint:
        """Position, tangent angle and curvature at arc length(s) ``theta`` (m, any real).

        Raises
        ------
        ValueError
            If ``theta`` holds a non-finite value.
        """
        theta = np.asarray(theta, dtype=float)
        if not np.all(np.isfinite(theta)):
            raise ValueError("theta: arc length must be finite")
        s = np.mod(theta, self.length)
        dx, dy = self._x(s, 1), self._y(s, 1)
        ddx, ddy = self._x(s, 2), self._y(s, 2)
        speed = np.hypot(dx, dy)
        return PathPoint(
            np.asarray(self._x(s)),
            np.asarray(self._y(s)),
            np.arctan2(dy, dx),
            np.asarray((dx * ddy - dy * ddx) / speed**3),
        )

    def progress(self, x: float, y: float, near: float | None = None) -> float:
        """Arc length of the centreline point closest to ``(x, y)``, m.

        With ``near`` (an unwrapped arc length, m) the result is the lap-unwrapped value closest
        to it, and the search is local to it; without, it lies in ``[0, length)``.
        """
        hint = None if near is None else float(self.track.wrap_s(near))
        s = float(self.track.project(x, y, s_hint=hint).s)
        if near is None:
            return s
        return s + self.length * round((near - s) / self.length)
