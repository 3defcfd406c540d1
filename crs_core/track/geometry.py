"""Race-track geometry: a closed centerline with arc length, heading and curvature.

All quantities are SI: positions in m in the world frame (REP 103, z up), angles in rad measured
counter-clockwise from the world x axis, arc length in m along the centerline in the direction
of travel, curvature in 1/m (positive when the track turns left, i.e. counter-clockwise). Tracks
are read from the CRS YAML format by :mod:`crs_core.track.yaml_file`.

Closed-loop convention
----------------------
The centerline is a closed loop of length :attr:`Track.length`. :class:`Track` holds one lap of
``N`` distinct samples with ``arc_length[0] == 0`` and ``arc_length[-1] < length``; the closing
segment runs from the last sample back to the first and covers the arc-length interval
``[arc_length[-1], length)``. Every arc length handed to this module is wrapped modulo ``length``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.spatial import KDTree

from crs_core.analysis.angles import wrap_angle
from crs_core.errors import FieldError

__all__ = ["Projection", "Track"]

#: Fewest centerline samples of a track.
_MIN_POINTS = 10
#: Number of nearest samples examined by the global (KD-tree) projection.
_GLOBAL_CANDIDATES = 8


def _check_arc_length(name: str, s: NDArray[np.float64]) -> None:
    """Arc lengths start at 0 and increase strictly; ``ValueError`` naming ``name`` if not."""
    if s[0] != 0.0:
        raise FieldError(name, f"must start at 0, got {s[0]!r}")
    if np.any(np.diff(s) <= 0.0):
        bad = int(np.flatnonzero(np.diff(s) <= 0.0)[0]) + 1
        raise FieldError(name, f"must be strictly increasing (index {bad})")


@dataclass(frozen=True)
class Projection:
    """Closest point of the track centerline to a query point.

    Attributes
    ----------
    s : float
        Arc length of the closest centerline point, m, in ``[0, length)``. Refined by projecting
        onto the local centerline segment, so it varies continuously between samples.
    lateral_error : float
        Signed distance from the centerline to the query point, m; positive to the LEFT of the
        direction of travel (REP 103: y left).
    heading : float
        Track heading (tangent angle) at ``s``, rad in ``[-pi, pi)``, world frame.
    """

    s: float
    lateral_error: float
    heading: float


def _as_float_array(name: str, values: ArrayLike) -> NDArray[np.float64]:
    try:
        array = np.array(values, dtype=float)
    except (TypeError, ValueError) as exc:
        raise FieldError(name, f"must be a sequence of numbers ({exc})") from None
    if array.ndim != 1:
        raise FieldError(name, f"must be one-dimensional, got shape {array.shape}")
    if not np.all(np.isfinite(array)):
        bad = int(np.flatnonzero(~np.isfinite(array))[0])
        raise FieldError(name, f"non-finite value {float(array[bad])!r} at index {bad}")
    return array


def _as_finite_float(name: str, value: Any) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float | np.floating | np.integer):
        raise FieldError(name, f"must be a number, got {value!r}")
    result = float(value)
    if not math.isfinite(result):
        raise FieldError(name, f"must be finite, got {result!r}")
    return result


@dataclass(frozen=True, eq=False)
class Track:
    """A closed race-track centerline.

    Read one with :func:`~crs_core.track.yaml_file.read_track` or
    :func:`~crs_core.track.yaml_file.load_demo_track`; direct construction validates the same
    invariants (with the dataclass field names in the error messages).

    Attributes
    ----------
    x, y : numpy.ndarray
        Centerline sample positions, m, world frame, shape ``(N,)``, one lap, no repeated end
        point.
    heading : numpy.ndarray
        Tangent angle of the centerline at the samples, rad, world frame (counter-clockwise from
        the world x axis), wrapped to ``[-pi, pi)``.
    arc_length : numpy.ndarray
        Arc length ``s`` of the samples, m, strictly increasing, ``arc_length[0] == 0`` and
        ``arc_length[-1] < length``.
    curvature : numpy.ndarray
        Signed centerline curvature at the samples, 1/m, positive for a left (counter-clockwise)
        turn.
    length : float
        Length of one lap, m; arc length wraps modulo this value.
    width : float
        Drivable width of the track, m (CRS ``width_of_track``; half of it on each side of the
        centerline).
    start_x, start_y, start_yaw : float
        Start pose: position, m, and yaw, rad, world frame.
    """

    x: NDArray[np.float64]
    y: NDArray[np.float64]
    heading: NDArray[np.float64]
    arc_length: NDArray[np.float64]
    curvature: NDArray[np.float64]
    length: float
    width: float
    start_x: float = 0.0
    start_y: float = 0.0
    start_yaw: float = 0.0
    # Closed-loop copies with the first sample appended at s = length (heading unwrapped).
    _s_closed: NDArray[np.float64] = field(init=False, repr=False)
    _x_closed: NDArray[np.float64] = field(init=False, repr=False)
    _y_closed: NDArray[np.float64] = field(init=False, repr=False)
    _heading_closed: NDArray[np.float64] = field(init=False, repr=False)
    _curvature_closed: NDArray[np.float64] = field(init=False, repr=False)
    _tree: KDTree = field(init=False, repr=False)

    def __post_init__(self) -> None:
        arrays = {}
        for name in ("x", "y", "heading", "arc_length", "curvature"):
            arrays[name] = _as_float_array(name, getattr(self, name))
        n = arrays["x"].size
        for name, array in arrays.items():
            if array.size != n:
                raise FieldError(name, f"has {array.size} samples, x has {n}")
        if n < _MIN_POINTS:
            raise FieldError("x", f"need at least {_MIN_POINTS} centerline samples, got {n}")
        length = _as_finite_float("length", self.length)
        width = _as_finite_float("width", self.width)
        start = [_as_finite_float(k, getattr(self, k)) for k in ("start_x", "start_y", "start_yaw")]
        s = arrays["arc_length"]
        _check_arc_length("arc_length", s)
        if not length > s[-1]:
            raise FieldError("length", f"{length!r} must exceed the last arc length {s[-1]!r}")
        if not width > 0.0:
            raise FieldError("width", f"must be positive, got {width!r}")
        # The loop must close: the closing segment from the last sample back to the first is
        # about one sample spacing long, both in space and in arc length, and the polyline
        # length matches ``length``.
        x, y = arrays["x"], arrays["y"]
        gap = math.hypot(x[0] - x[-1], y[0] - y[-1])
        spacing = float(np.max(np.diff(s)))
        if gap > 1.5 * spacing + 1e-9:
            raise FieldError(
                "x, y",
                f"centerline is not closed (last-to-first gap {gap:.4g} m, "
                f"sample spacing {spacing:.4g} m)",
            )
        closing = length - float(s[-1])
        if closing > 1.5 * spacing + 1e-9:
            raise FieldError(
                "length",
                f"{length:.6g} m leaves {closing:.4g} m of arc length after the last "
                f"sample (sample spacing {spacing:.4g} m): the centerline does not close",
            )
        polyline = float(np.sum(np.hypot(np.diff(x), np.diff(y)))) + gap
        if abs(polyline - length) > 0.01 * length:
            raise FieldError(
                "length",
                f"{length:.6g} m disagrees with the centerline polyline length {polyline:.6g} m",
            )

        setter = object.__setattr__
        for name, array in arrays.items():
            if name == "heading":
                array = np.asarray(wrap_angle(array), dtype=float)
            array.setflags(write=False)
            setter(self, name, array)
        setter(self, "length", length)
        setter(self, "width", width)
        for key, value in zip(("start_x", "start_y", "start_yaw"), start, strict=True):
            setter(self, key, value)

        def closed(array: NDArray[np.float64], last: float) -> NDArray[np.float64]:
            out = np.append(array, last)
            out.setflags(write=False)
            return out

        setter(self, "_s_closed", closed(s, length))
        setter(self, "_x_closed", closed(x, float(x[0])))
        setter(self, "_y_closed", closed(y, float(y[0])))
        heading = np.unwrap(np.append(self.heading, self.heading[0]))
        heading.setflags(write=False)
        setter(self, "_heading_closed", heading)
        setter(self, "_curvature_closed", closed(arrays["curvature"], float(self.curvature[0])))
        setter(self, "_tree", KDTree(np.column_stack((x, y))))

    # ------------------------------------------------------------------ queries
    @property
    def num_points(self) -> int:
        """Number of centerline samples in one lap."""
        return int(self.x.size)

    def start_state(self, speed: float = 0.0) -> NDArray[np.float64]:
        """The car's state on the start pose, rolling straight ahead at ``speed`` (m/s):
        ``[x, y, yaw, v_x, v_y, omega]`` (m, rad, m/s, rad/s; world position and yaw, body
        velocities)."""
        return np.array([self.start_x, self.start_y, self.start_yaw, speed, 0.0, 0.0])

    def borders(self) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Left and right track edges (N, 2), m: the centerline moved by half the width along
        its normal (left in the direction of travel first)."""
        normal = np.stack([-np.sin(self.heading), np.cos(self.heading)], axis=1)
        centre = np.stack([self.x, self.y], axis=1)
        half = np.asarray(self.width, dtype=float).reshape(-1, 1) / 2
        return centre + half * normal, centre - half * normal

    def wrap_s(self, s: ArrayLike) -> NDArray[np.float64] | float:
        """Wrap arc length(s) into ``[0, length)``.

        Parameters
        ----------
        s : array_like
            Arc length(s), m; any real value.

        Returns
        -------
        float or numpy.ndarray
            ``s`` modulo ``length``, m; a float for a scalar input.
        """
        if isinstance(s, float | int):  # a scalar without numpy's per-call cost (a car's pose)
            value = float(s) % self.length
            return 0.0 if value >= self.length else value
        wrapped = np.mod(np.asarray(s, dtype=float), self.length)
        # np.mod can return ``length`` itself for tiny negative inputs.
        wrapped = np.where(wrapped >= self.length, 0.0, wrapped)
        return float(wrapped) if wrapped.ndim == 0 else wrapped

    def interpolate(
        self, s: ArrayLike
    ) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
        """Centerline point, heading and curvature at arc length(s).

        Linear interpolation between samples on the closed loop; ``s`` wraps modulo ``length``
        and the heading is interpolated on the unwrapped angle, so it has no jump at ``+-pi``.

        Parameters
        ----------
        s : array_like
            Arc length(s), m; any real value (wrapped).

        Returns
        -------
        x, y : numpy.ndarray
            Centerline position, m, world frame, same shape as ``s``.
        heading : numpy.ndarray
            Track heading, rad in ``[-pi, pi)``, world frame.
        curvature : numpy.ndarray
            Curvature, 1/m, positive for a left turn.

        Raises
        ------
        ValueError
            If ``s`` contains non-finite values.
        """
        s_arr = np.asarray(s, dtype=float)
        if not np.all(np.isfinite(s_arr)):
            raise FieldError("s", "arc length must be finite")
        sw = np.asarray(self.wrap_s(s_arr), dtype=float)
        x = np.interp(sw, self._s_closed, self._x_closed)
        y = np.interp(sw, self._s_closed, self._y_closed)
        heading = np.asarray(self._heading_at(sw))
        curvature = np.interp(sw, self._s_closed, self._curvature_closed)
        return x, y, heading, curvature

    def project(
        self, px: float, py: float, s_hint: float | None = None, window: float = 0.5
    ) -> Projection:
        """Project a point onto the centerline.

        Parameters
        ----------
        px, py : float
            Query point, m, world frame.
        s_hint : float, optional
            Arc length near which the answer is expected, m (e.g. the previous projection of a
            moving car). Only the centerline within ``+-window`` of it is searched. If the
            closest point found lies on the edge of that window (the car has left it) or farther
            than half the track width from the query point, a global search is made instead.
        window : float, optional
            Half-width of the local search window, m. Default 0.5.

        Returns
        -------
        Projection
            Arc length of the closest point (refined onto the local segment), signed lateral
            error (positive to the left of the direction of travel) and the track heading there.

        Raises
        ------
        ValueError
            If an input is not finite or ``window`` is not positive.
        """
        px = _as_finite_float("px", px)
        py = _as_finite_float("py", py)
        window = _as_finite_float("window", window)
        if not window > 0.0:
            raise FieldError("window", f"must be positive, got {window!r}")
        n = self.num_points
        if s_hint is None or 2.0 * window >= self.length:
            segments = self._global_candidates(px, py)
            best = self._closest_on_segments(px, py, segments)
        else:
            hint = float(self.wrap_s(_as_finite_float("s_hint", s_hint)))
            lo = self._unwrapped_index(hint - window)
            hi = self._unwrapped_index(hint + window)
            segments = np.arange(lo, hi + 1) % n
            best = self._closest_on_segments(px, py, segments)
            if best[3] in (0, segments.size - 1) or best[2] > 0.5 * self.width:
                best = self._closest_on_segments(px, py, self._global_candidates(px, py))
        s_best, lateral = best[0], best[1]
        return Projection(s=s_best, lateral_error=lateral, heading=float(self._heading_at(s_best)))

    def progress_unwrapped(self, s_sequence: ArrayLike) -> NDArray[np.float64]:
        """Unwrap a sequence of arc lengths into continuous progress.

        Parameters
        ----------
        s_sequence : array_like
            Successive arc lengths, m (e.g. projections of a moving car), each in
            ``[0, length)``. Consecutive samples must move less than ``length / 2``.

        Returns
        -------
        numpy.ndarray
            Continuous progress, m, starting at ``s_sequence[0]``; it increases by ``length`` for
            each lap driven forward.
        """
        s_arr = np.asarray(s_sequence, dtype=float)
        if not np.all(np.isfinite(s_arr)):
            raise FieldError("s_sequence", "arc lengths must be finite")
        return np.unwrap(s_arr, period=self.length)

    # ------------------------------------------------------------------ helpers
    def _heading_at(self, wrapped: float | NDArray[np.float64]) -> NDArray[np.float64] | float:
        """Track heading (rad, in ``[-pi, pi)``) at arc length(s) already in ``[0, length)``:
        the unwrapped heading interpolated linearly."""
        return wrap_angle(np.interp(wrapped, self._s_closed, self._heading_closed))

    def _unwrapped_index(self, s: float) -> int:
        """Index (counting on past ``N`` for later laps) of the segment holding arc length s."""
        laps = math.floor(s / self.length)
        within = s - laps * self.length
        index = int(np.searchsorted(self.arc_length, within, side="right")) - 1
        return laps * self.num_points + max(index, 0)

    def _global_candidates(self, px: float, py: float) -> NDArray[np.int64]:
        k = min(_GLOBAL_CANDIDATES, self.num_points)
        _, nearest = self._tree.query((px, py), k=k)
        nearest = np.atleast_1d(nearest)
        n = self.num_points
        return np.unique(np.concatenate((nearest, (nearest - 1) % n)))

    def _closest_on_segments(
        self, px: float, py: float, segments: NDArray[np.int64]
    ) -> tuple[float, float, float, int]:
        """Closest point on the given closed-loop segments.

        Returns ``(s, signed lateral error, distance, position of the best segment in
        segments)``.
        """
        ax = self._x_closed[segments]
        ay = self._y_closed[segments]
        dx = self._x_closed[segments + 1] - ax
        dy = self._y_closed[segments + 1] - ay
        len2 = dx * dx + dy * dy
        safe = np.where(len2 > 0.0, len2, 1.0)
        t = np.clip(((px - ax) * dx + (py - ay) * dy) / safe, 0.0, 1.0)
        t = np.where(len2 > 0.0, t, 0.0)
        fx = ax + t * dx
        fy = ay + t * dy
        dist2 = (px - fx) ** 2 + (py - fy) ** 2
        i = int(np.argmin(dist2))
        seg = int(segments[i])
        s0 = self._s_closed[seg]
        s = float(self.wrap_s(s0 + t[i] * (self._s_closed[seg + 1] - s0)))
        cross = dx[i] * (py - fy[i]) - dy[i] * (px - fx[i])
        distance = math.sqrt(float(dist2[i]))
        lateral = math.copysign(distance, cross) if cross != 0.0 else 0.0
        return s, lateral, distance, i
