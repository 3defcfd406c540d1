"""The static calibration points file (``POINTS_FILE`` of ``crs calibrate-lighthouse static``).

A YAML file, format ``chronos-lighthouse-points/1``; SI units, rad, REP 103 frames (world x-y
floor plane, z up; body x forward, y left)::

    format: chronos-lighthouse-points/1
    photodiodes: [[-0.045, 0.015], [-0.06, 0.015], [-0.045, -0.015], [-0.06, -0.015]]
                        # optional: photodiodes 0..3 in the body frame (x, y), m; default: the
                        # Lighthouse deck of the real recordings
    stations:           # optional: one entry per base station, index = list position
      - dt1: -0.0508728 # factory light-plane tilt offsets, rad (from the station's data
        dt2: 0.0464478  # stream); optional: tilt offsets not given are fitted
    points:             # the car standing still at known poses
      - position: [0.5, -0.25]   # body origin in the world frame, m (floor, z = 0)
        yaw: 1.2                 # heading, rad; optional (omit or null: unknown, fitted)
        sweeps:                  # what each station measured there
          - station: 0
            plane1: [[0.101, 0.093, 0.128, 0.121], ...]   # one row per sweep: photodiodes
            plane2: [[-0.231, -0.240, -0.205, -0.214], ...]  # 0..3, rad; any number of rows
          - station: 1
            ...

Without ``stations`` the file gives no station geometry at all: the stations are those the
sweeps name (0 up to the largest index) and their tilt offsets are fitted. A station may be
missing at a point (out of view), and a point may have only one plane of a station. The
sweeps of a plane are averaged per photodiode (the fit uses each photodiode's angle, never the
mean over photodiodes); their spread estimates the angle noise.
:func:`load_points` validates everything and raises a one-line ``ValueError`` naming the field.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from crs_core.analysis.angles import wrap_angle
from crs_core.errors import FieldError
from crs_core.model.lighthouse import RECORDED_PHOTODIODES
from crs_core.model.sensors import N_PHOTODIODES
from crs_core.yaml_io import load_yaml

FORMAT = "chronos-lighthouse-points/1"


@dataclass(frozen=True)
class CalibrationPoint:
    """One static pose and the sweeps recorded there.

    Attributes
    ----------
    position : (x, y) of the body origin, world frame, m.
    yaw : heading, rad, or None when unknown.
    sweeps : ``(station, plane)`` -> ``(n_sweeps, 4)`` angles of photodiodes 0..3, rad.
    """

    position: tuple[float, float]
    yaw: float | None
    sweeps: Mapping[tuple[int, int], np.ndarray]

    def mean_angles(self, station: int, plane: int) -> np.ndarray | None:
        """Per-photodiode mean of the sweeps of one plane (4,), rad; None if not seen."""
        rows = self.sweeps.get((station, plane))
        if rows is None:
            return None
        first = rows[0]
        return first + np.mean(wrap_angle(rows - first), axis=0)


@dataclass(frozen=True)
class CalibrationPoints:
    """Contents of a points file.

    Attributes
    ----------
    points : the calibration points.
    tilts : per station ``(dt1, dt2)`` in rad; an entry is None when the file omits it (the
        number of stations: the file's ``stations`` list, or 1 + the largest station its
        sweeps name).
    photodiodes : photodiodes 0..3 in the body frame (x, y), m.
    """

    points: tuple[CalibrationPoint, ...]
    tilts: tuple[tuple[float | None, float | None], ...]
    photodiodes: tuple[tuple[float, float], ...] = RECORDED_PHOTODIODES

    @property
    def n_stations(self) -> int:
        return len(self.tilts)

    def subset(self, indices: list[int] | np.ndarray) -> CalibrationPoints:
        """The same file with only the points ``indices`` (in that order)."""
        return CalibrationPoints(
            tuple(self.points[i] for i in indices), self.tilts, self.photodiodes
        )

    def to_dict(self) -> dict[str, Any]:
        """The YAML mapping (module docstring)."""
        stations = []
        for dt1, dt2 in self.tilts:
            entry = {}
            if dt1 is not None:
                entry["dt1"] = float(dt1)
            if dt2 is not None:
                entry["dt2"] = float(dt2)
            stations.append(entry)
        points = []
        for point in self.points:
            by_station: dict[int, dict[str, Any]] = {}
            for (station, plane), rows in sorted(point.sweeps.items()):
                entry = by_station.setdefault(station, {"station": station})
                entry[f"plane{plane}"] = np.asarray(rows, dtype=float).tolist()
            item: dict[str, Any] = {"position": [float(v) for v in point.position]}
            if point.yaw is not None:
                item["yaw"] = float(point.yaw)
            item["sweeps"] = list(by_station.values())
            points.append(item)
        return {
            "format": FORMAT,
            "photodiodes": [[float(x), float(y)] for x, y in self.photodiodes],
            "stations": stations,
            "points": points,
        }

    def save(self, path: str | Path) -> Path:
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(yaml.safe_dump(self.to_dict(), sort_keys=False, default_flow_style=None))
        return path


def load_points(path: str | Path) -> CalibrationPoints:
    """Read and validate a points file (module docstring); ``ValueError`` naming the field."""
    path = Path(path)
    if not path.is_file():
        problem = "is a folder" if path.is_dir() else "does not exist"
        raise FieldError("POINTS_FILE", f"{path} {problem}")
    try:
        data = load_yaml(path.read_text())
    except yaml.YAMLError as error:
        problem = str(error).splitlines()[0]
        raise FieldError("POINTS_FILE", f"{path} is not valid YAML ({problem})") from None
    except (OSError, UnicodeDecodeError) as error:
        raise FieldError("POINTS_FILE", f"cannot read {path} ({error})") from None
    return points_from_dict(data)


def points_from_dict(data: Any) -> CalibrationPoints:
    """Validate the YAML mapping of a points file; :class:`~crs_core.errors.FieldError` naming
    the field."""
    if not isinstance(data, Mapping):
        raise FieldError("POINTS_FILE", "expected a mapping with stations and points")
    unknown = set(data) - {"format", "photodiodes", "stations", "points"}
    if unknown:
        raise FieldError("POINTS_FILE", f"unknown key(s) {', '.join(sorted(map(str, unknown)))}")
    if data.get("format", FORMAT) != FORMAT:
        raise FieldError("format", f"{data['format']!r}, expected {FORMAT!r}")
    photodiodes = RECORDED_PHOTODIODES
    if data.get("photodiodes") is not None:
        diodes = _numbers("photodiodes", data["photodiodes"], (N_PHOTODIODES, 2))
        photodiodes = tuple((float(x), float(y)) for x, y in diodes)
    stations = data.get("stations")
    if stations is not None and (not isinstance(stations, list) or not stations):
        raise FieldError(
            "stations", "expected a list with one entry per base station (or no stations key)"
        )
    tilts = []
    for i, entry in enumerate(stations or []):
        if entry is None:
            entry = {}
        if not isinstance(entry, Mapping):
            raise FieldError(f"stations[{i}]", f"expected a mapping (dt1, dt2), got {entry!r}")
        extra = set(entry) - {"dt1", "dt2"}
        if extra:
            raise FieldError(
                f"stations[{i}]", f"unknown key(s) {', '.join(sorted(map(str, extra)))}"
            )
        pair = []
        for key in ("dt1", "dt2"):
            value = entry.get(key)
            pair.append(
                None if value is None else float(_numbers(f"stations[{i}].{key}", value, ()))
            )
        tilts.append((pair[0], pair[1]))
    raw_points = data.get("points")
    if not isinstance(raw_points, list) or not raw_points:
        raise FieldError("points", "expected a non-empty list of points")
    listed = len(tilts) if stations is not None else None
    points = [_point(f"points[{i}]", item, listed) for i, item in enumerate(raw_points)]
    if listed is None:  # the stations are those the sweeps name
        named = 1 + max(station for point in points for station, _ in point.sweeps)
        tilts = [(None, None)] * named
    return CalibrationPoints(tuple(points), tuple(tilts), photodiodes)


def _point(name: str, item: Any, n_stations: int | None) -> CalibrationPoint:
    """One entry of ``points``; station indices below ``n_stations`` (any, when None)."""
    if not isinstance(item, Mapping):
        raise FieldError(name, f"expected a mapping (position, yaw, sweeps), got {item!r}")
    extra = set(item) - {"position", "yaw", "sweeps"}
    if extra:
        raise FieldError(name, f"unknown key(s) {', '.join(sorted(map(str, extra)))}")
    if "position" not in item:
        raise FieldError(f"{name}.position", "missing (x, y of the body origin, m)")
    position = _numbers(f"{name}.position", item["position"], (2,))
    yaw = item.get("yaw")
    if yaw is not None:
        yaw = float(_numbers(f"{name}.yaw", yaw, ()))
    raw = item.get("sweeps")
    if not isinstance(raw, list) or not raw:
        raise FieldError(f"{name}.sweeps", "expected a non-empty list of station entries")
    sweeps: dict[tuple[int, int], np.ndarray] = {}
    for j, entry in enumerate(raw):
        where = f"{name}.sweeps[{j}]"
        if not isinstance(entry, Mapping):
            raise FieldError(where, "expected a mapping (station, plane1, plane2)")
        extra = set(entry) - {"station", "plane1", "plane2"}
        if extra:
            raise FieldError(where, f"unknown key(s) {', '.join(sorted(map(str, extra)))}")
        station = entry.get("station")
        if isinstance(station, bool) or not isinstance(station, int):
            raise FieldError(f"{where}.station", f"expected a station index, got {station!r}")
        if station < 0:
            raise FieldError(f"{where}.station", f"expected a station index >= 0, got {station}")
        if n_stations is not None and station >= n_stations:
            raise FieldError(
                f"{where}.station",
                f"{station} is not one of the {n_stations} station(s) listed under stations",
            )
        planes = [k for k in ("plane1", "plane2") if entry.get(k) is not None]
        if not planes:
            raise FieldError(where, "needs plane1 and/or plane2 sweeps")
        for key in planes:
            rows = _numbers(f"{where}.{key}", entry[key], None)
            if rows.ndim == 1:
                rows = rows[None, :]
            if rows.ndim != 2 or rows.shape[1] != N_PHOTODIODES or rows.shape[0] == 0:
                raise FieldError(
                    f"{where}.{key}",
                    f"expected rows of 4 angles (rad, photodiodes 0..3), got shape {rows.shape}",
                )
            if np.any(np.abs(rows) > math.pi):
                raise FieldError(f"{where}.{key}", "angles must lie in [-pi, pi] rad")
            plane = int(key[-1])
            if (station, plane) in sweeps:
                raise FieldError(f"{where}.{key}", f"station {station} is listed twice")
            sweeps[(station, plane)] = rows
    return CalibrationPoint((float(position[0]), float(position[1])), yaw, sweeps)


def _numbers(name: str, value: Any, shape: tuple[int, ...] | None) -> np.ndarray:
    """``value`` as a finite float array of ``shape`` (any shape if None)."""
    if isinstance(value, bool | str):
        raise FieldError(name, f"expected numbers, got {value!r}")
    try:
        array = np.array(value, dtype=float)
    except (TypeError, ValueError):
        raise FieldError(name, f"expected numbers, got {value!r}") from None
    if shape is not None and array.shape != shape:
        what = "a number" if not shape else f"shape {shape}"
        raise FieldError(name, f"expected {what}, got {value!r}")
    if not np.all(np.isfinite(array)):
        raise FieldError(name, "contains non-finite values")
    return array
