r"""A smooth arc-length parametrisation of a closed track centreline, for contouring control.

The track's centreline samples are joined by periodic cubic splines, re-parametrised by their
own arc length :math:`\theta` (m) into :math:`X(\theta)`, :math:`Y(\theta)` (unit speed to
about 1e-4), so position, tangent angle
:math:`\varphi(\theta)` and curvature :math:`\kappa(\theta)` are continuous (C² position) around
the whole loop, including across the start line. :math:`\theta` may be any real number (laps
unwrapped); it is reduced modulo the lap length for evaluation.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.interpolate import CubicSpline, PPoly

from crs_core.errors import FieldError
from crs_core.track import Track

__all__ = ["PathPoint", "ReferencePath"]

#: Points per track sample used to measure the spline's arc length.
_DENSITY = 20


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
        Lap length along the spline, m (within a fraction of a percent of the track's).
    half_width : float
        Half the drivable track width, m.
    """

    def __init__(self, track: Track) -> None:
        if not isinstance(track, Track):
            raise TypeError(f"track: expected a Track, got {type(track).__name__}")
        self.track = track
        self.half_width = 0.5 * float(track.width)
        s = np.append(track.arc_length, track.length)
        through_x = CubicSpline(s, np.append(track.x, track.x[0]), bc_type="periodic")
        through_y = CubicSpline(s, np.append(track.y, track.y[0]), bc_type="periodic")
        # re-parametrise by the spline's own arc length (the samples' spacing is not exactly
        # the curve's length between them): dense points, their cumulative length, splines again
        u = np.linspace(0.0, track.length, _DENSITY * track.num_points + 1)
        speed = np.hypot(through_x(u, 1), through_y(u, 1))
        sigma = np.concatenate(([0.0], np.cumsum(0.5 * (speed[1:] + speed[:-1]) * np.diff(u))))
        self.length = float(sigma[-1])
        # x, y and their first and second derivatives as one six-valued piecewise cubic (the
        # derivatives' lower-degree coefficients padded with zeros): a point costs one
        # evaluation, not six (the MPCC evaluates the path several times a call)
        points = np.column_stack((through_x(u), through_y(u)))
        xy = CubicSpline(sigma, points, bc_type="periodic")
        pieces = [
            np.pad(d.c, ((4 - d.c.shape[0], 0), (0, 0), (0, 0)))
            for d in (xy, xy.derivative(1), xy.derivative(2))
        ]
        self._curve = PPoly(np.concatenate(pieces, axis=2), xy.x, extrapolate="periodic")
        # arc length on the spline of each track sample, to map the track's projection
        self._sample_s, self._sample_sigma = s, np.interp(s, u, sigma)

    def evaluate(self, theta: ArrayLike) -> PathPoint:
        """Position, tangent angle and curvature at arc length(s) ``theta`` (m, any real).

        Raises
        ------
        ValueError
            If ``theta`` holds a non-finite value.
        """
        theta = np.asarray(theta, dtype=float)
        if not np.all(np.isfinite(theta)):
            raise FieldError("theta", "arc length must be finite")
        curve = self._curve(np.mod(theta, self.length))
        x, y, dx, dy, ddx, ddy = (curve[..., i] for i in range(6))
        speed = np.hypot(dx, dy)
        return PathPoint(
            np.asarray(x), np.asarray(y), np.arctan2(dy, dx), (dx * ddy - dy * ddx) / speed**3
        )

    @property
    def pieces(self) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """The curve as a piecewise cubic in the arc length: breakpoints ``(n + 1,)`` (m, from 0
        to :attr:`length`) and coefficients ``(4, n, 6)`` (highest power first) of ``x, y``
        and their first and second derivatives, for compiled code that evaluates the path
        (:mod:`~crs_core.control.mpcc_native`)."""
        return self._curve.x.copy(), self._curve.c.copy()

    def progress(self, x: float, y: float, near: float | None = None) -> float:
        """Arc length of the centreline point closest to ``(x, y)``, m.

        With ``near`` (an unwrapped arc length, m) the result is the lap-unwrapped value closest
        to it, and the search is local to it; without, it lies in ``[0, length)``.
        """
        hint = None
        if near is not None:
            hint = float(np.interp(near % self.length, self._sample_sigma, self._sample_s))
        projected = float(self.track.project(x, y, s_hint=hint).s)
        s = float(np.interp(projected, self._sample_s, self._sample_sigma))
        if near is None:
            return s
        return s + self.length * round((near - s) / self.length)
