"""Race-track geometry: a closed centerline with arc length, heading and curvature.

The track is stored in the CRS YAML format (key ``track`` holding ``xCoords``, ``yCoords``,
``tangentAngle``, ``arcLength``, ``curvature``, ``trackLength``, ``width_of_track``, ``x_init``,
``y_init``, ``yaw_init``). All quantities are SI: positions in m in the world frame (REP 103,
z up), angles in rad measured counter-clockwise from the world x axis, arc length in m along the
centerline in the direction of travel, curvature in 1/m (positive when the track turns left,
i.e. counter-clockwise).

Closed-loop convention
----------------------
The centerline is a closed loop of length :attr:`Track.length`. :class:`Track` holds one lap of
``N`` distinct samples with ``arc_length[0] == 0`` and ``arc_length[-1] < length``; the closing
segment runs from the last sample back to the first and covers the arc-length interval
``[arc_length[-1], length)``. Every arc length handed to this module is wrapped modulo ``length``.

The CRS files may hold more than one lap (``DEMO_TRACK.yaml`` holds two laps, 6932 samples with
``arcLength`` running to ``2 * trackLength``) or repeat the first sample at the end. On loading,
only the samples with ``arcLength < trackLength`` are kept; ``trackLength`` is authoritative for
the loop length.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import yaml
from numpy.typing import ArrayLike, NDArray
from scipy.spatial import KDTree

from crs_core.analysis.angles import wrap_angle

__all__ = [
    "DEMO_TRACK_PATH",
    "LapCounter",
    "Projection",
    "Track",
    "load_demo_track",
]

#: Packaged compact copy of the CRS demo race track (every 10th sample of ``DEMO_TRACK.yaml``).
DEMO_TRACK_PATH: Path = Path(__file__).resolve().parent / "data" / "tracks" / "demo_track.yaml"

_ARRAY_KEYS: tuple[str, ...] = ("xCoords", "yCoords", "tangentAngle", "arcLength", "curvature")
_SCALAR_KEYS: tuple[str, ...] = ("trackLength", "width_of_track", "x_init", "y_init", "yaw_init")
_FIELD_TO_KEY: dict[str, str] = {
    "x": "xCoords",
    "y": "yCoords",
    "x, y": "xCoords, yCoords",
    "heading": "tangentAngle",
    "arc_length": "arcLength",
    "length": "trackLength",
    "width": "width_of_track",
    "start_x": "x_init",
    "start_y": "y_init",
    "start_yaw": "yaw_init",
}
_MIN_POINTS = 10
#: Number of nearest samples examined by the global (KD-tree) projection.
_GLOBAL_CANDIDATES = 8


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
        raise ValueError(f"{name}: must be a sequence of numbers ({exc})") from None
    if array.ndim != 1:
        raise ValueError(f"{name}: must be one-dimensional, got shape {array.shape}")
    if not np.all(np.isfinite(array)):
        bad = int(np.flatnonzero(~np.isfinite(array))[0])
        raise ValueError(f"{name}: non-finite value {float(array[bad])!r} at index {bad}")
    return array


def _as_finite_float(name: str, value: Any) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float | np.floating | np.integer):
        raise ValueError(f"{name}: must be a number, got {value!r}")
    result = float(value)
    if not math.isfinite(result):
        raise ValueError(f"{name}: must be finite, got {result!r}")
    return result


@dataclass(frozen=True, eq=False)
class Track:
    """A closed race-track centerline.

    Construct with :meth:`from_yaml` or :func:`load_demo_track`; direct construction validates
    the same invariants (with the dataclass field names in the error messages).

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
                raise ValueError(f"{name}: has {array.size} samples, x has {n}")
        if n < _MIN_POINTS:
            raise ValueError(f"x: need at least {_MIN_POINTS} centerline samples, got {n}")
        length = _as_finite_float("length", self.length)
        width = _as_finite_float("width", self.width)
        start = [_as_finite_float(k, getattr(self, k)) for k in ("start_x", "start_y", "start_yaw")]
        s = arrays["arc_length"]
        if s[0] != 0.0:
            raise ValueError(f"arc_length: must start at 0, got {s[0]!r}")
        if np.any(np.diff(s) <= 0.0):
            bad = int(np.flatnonzero(np.diff(s) <= 0.0)[0]) + 1
            raise ValueError(f"arc_length: must be strictly increasing (index {bad})")
        if not length > s[-1]:
            raise ValueError(f"length: {length!r} must exceed the last arc length {s[-1]!r}")
        if not width > 0.0:
            raise ValueError(f"width: must be positive, got {width!r}")
        # The loop must close: the closing segment from the last sample back to the first is
        # about one sample spacing long, both in space and in arc length, and the polyline
        # length matches ``length``.
        x, y = arrays["x"], arrays["y"]
        gap = math.hypot(x[0] - x[-1], y[0] - y[-1])
        spacing = float(np.max(np.diff(s)))
        if gap > 1.5 * spacing + 1e-9:
            raise ValueError(
                f"x, y: centerline is not closed (last-to-first gap {gap:.4g} m, "
                f"sample spacing {spacing:.4g} m)"
            )
        closing = length - float(s[-1])
        if closing > 1.5 * spacing + 1e-9:
            raise ValueError(
                f"length: {length:.6g} m leaves {closing:.4g} m of arc length after the last "
                f"sample (sample spacing {spacing:.4g} m): the centerline does not close"
            )
        polyline = float(np.sum(np.hypot(np.diff(x), np.diff(y)))) + gap
        if abs(polyline - length) > 0.01 * length:
            raise ValueError(
                f"length: {length:.6g} m disagrees with the centerline polyline length "
                f"{polyline:.6g} m"
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

    # ------------------------------------------------------------------ loading
    @classmethod
    def from_yaml(cls, path: str | Path) -> Track:
        """Load a track from a CRS track YAML file.

        Parameters
        ----------
        path : str or pathlib.Path
            YAML file with a top-level key ``track`` holding ``xCoords``, ``yCoords`` (m),
            ``tangentAngle`` (rad), ``arcLength`` (m), ``curvature`` (1/m), ``trackLength`` (m),
            ``width_of_track`` (m), ``x_init``, ``y_init`` (m) and ``yaw_init`` (rad). Other keys
            (``xRate``, ``yRate``, ``trackWidth``, ``density``) are ignored.

        Returns
        -------
        Track
            One lap: samples with ``arcLength < trackLength`` (files holding several laps or a
            repeated end point are cut to one lap).

        Raises
        ------
        ValueError
            If the file is not a mapping with ``track``, a required key is missing, a list is
            not numeric or has non-finite values, the lists differ in length, there are fewer
            than 10 samples, ``arcLength`` does not start at 0 or does not increase, or the
            centerline does not close. The message names the offending field.
        OSError
            If the file cannot be read.
        """
        path = Path(path)
        with path.open("r", encoding="utf-8") as stream:
            try:
                document = yaml.safe_load(stream)
            except yaml.YAMLError as exc:
                raise ValueError(f"{path}: not valid YAML ({exc})") from None
        if not isinstance(document, dict) or not isinstance(document.get("track"), dict):
            raise ValueError(f"{path}: track: missing top-level mapping 'track'")
        data = document["track"]
        missing = [k for k in (*_ARRAY_KEYS, *_SCALAR_KEYS) if k not in data]
        if missing:
            raise ValueError(f"{path}: track.{missing[0]}: required key missing")
        arrays: dict[str, NDArray[np.float64]] = {}
        for key in _ARRAY_KEYS:
            value = data[key]
            if not isinstance(value, list) or not all(
                isinstance(v, int | float) and not isinstance(v, bool) for v in value
            ):
                raise ValueError(f"{path}: track.{key}: must be a list of numbers")
            try:
                arrays[key] = _as_float_array(f"track.{key}", value)
            except ValueError as exc:
                raise ValueError(f"{path}: {exc}") from None
        n = arrays["xCoords"].size
        for key in _ARRAY_KEYS:
            if arrays[key].size != n:
                raise ValueError(
                    f"{path}: track.{key}: has {arrays[key].size} values, xCoords has {n}"
                )
        scalars: dict[str, float] = {}
        for key in _SCALAR_KEYS:
            try:
                scalars[key] = _as_finite_float(f"track.{key}", data[key])
            except ValueError as exc:
                raise ValueError(f"{path}: {exc}") from None
        length = scalars["trackLength"]
        if not length > 0.0:
            raise ValueError(f"{path}: track.trackLength: must be positive, got {length!r}")
        s = arrays["arcLength"]
        if s[0] != 0.0:
            raise ValueError(f"{path}: track.arcLength: must start at 0, got {s[0]!r}")
        if np.any(np.diff(s) <= 0.0):
            bad = int(np.flatnonzero(np.diff(s) <= 0.0)[0]) + 1
            raise ValueError(f"{path}: track.arcLength: must be strictly increasing (index {bad})")
        # One lap; a tolerance of a micrometre drops an end point repeated at s == trackLength.
        keep = s < length - 1e-6
        if np.count_nonzero(keep) < _MIN_POINTS:
            raise ValueError(
                f"{path}: track.xCoords: need at least {_MIN_POINTS} samples in one lap, got "
                f"{np.count_nonzero(keep)}"
            )
        try:
            return cls(
                x=arrays["xCoords"][keep],
                y=arrays["yCoords"][keep],
                heading=arrays["tangentAngle"][keep],
                arc_length=s[keep],
                curvature=arrays["curvature"][keep],
                length=length,
                width=scalars["width_of_track"],
                start_x=scalars["x_init"],
                start_y=scalars["y_init"],
                start_yaw=scalars["yaw_init"],
            )
        except ValueError as exc:
            # Name the YAML key rather than the dataclass field.
            field_name, _, detail = str(exc).partition(": ")
            key = _FIELD_TO_KEY.get(field_name, field_name)
            raise ValueError(f"{path}: track.{key}: {detail}") from None

    # ------------------------------------------------------------------ queries
    @property
    def num_points(self) -> int:
        """Number of centerline samples in one lap."""
        return int(self.x.size)

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
            raise ValueError("s: arc length must be finite")
        sw = np.asarray(self.wrap_s(s_arr), dtype=float)
        x = np.interp(sw, self._s_closed, self._x_closed)
        y = np.interp(sw, self._s_closed, self._y_closed)
        heading = np.asarray(wrap_angle(np.interp(sw, self._s_closed, self._heading_closed)))
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
            raise ValueError(f"window: must be positive, got {window!r}")
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
        _, _, heading, _ = self.interpolate(s_best)
        return Projection(s=s_best, lateral_error=lateral, heading=float(heading))

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
            raise ValueError("s_sequence: arc lengths must be finite")
        return np.unwrap(s_arr, period=self.length)

    # ------------------------------------------------------------------ helpers
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


def load_demo_track() -> Track:
    """Load the packaged CRS demo race track.

    The packaged file is a compact copy (every 10th sample, 30 samples per metre, values rounded
    to 1e-6) of ``DEMO_TRACK.yaml``, the track the real Chronos cars race on in the published
    CRS experiments (BSD 2-Clause data, see ``data/tracks/LICENSE-data.txt``). Lap length
    11.568 m, drivable width 0.46 m, driven counter-clockwise.

    Returns
    -------
    Track
        The demo track.
    """
    return Track.from_yaml(DEMO_TRACK_PATH)


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
        Lap length, m (:attr:`Track.length`).
    line_tolerance : float, optional
        A first ``s`` in ``[0, line_tolerance]`` m counts as starting on the line. Default 1e-3.
    """

    def __init__(self, length: float, line_tolerance: float = 1e-3) -> None:
        self.length = _as_finite_float("length", length)
        if not self.length > 0.0:
            raise ValueError(f"length: must be positive, got {self.length!r}")
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
            raise ValueError(f"stamp: {stamp!r} is earlier than the previous stamp {self._stamp!r}")
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
