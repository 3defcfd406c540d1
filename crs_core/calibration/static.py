r"""Static calibration: base-station poses from sweeps recorded at known car poses.

The paper (Sec. IV-A) averages the 4 photodiode angles of a plane and fits
:math:`(\Phi, p_{bs})` to those means. Here every photodiode angle is a residual of its own
(the per-sweep noise is averaged over the sweeps recorded at a point, per photodiode), so the
diode baseline constrains the fit as well and the point yaw can be left unknown.

Method, per base station (stations are independent given the points; unknown yaws are shared
by all stations and solved jointly with them):

1. **Closed-form start** (:func:`~crs_core.calibration.sweep_model.station_from_bearings`):
   each photodiode's two plane angles give its bearing in the station frame; with the known
   floor positions of the photodiodes (point pose + body offsets) a planar DLT gives the
   station rotation and position. No prior geometry, grid or multi-start is needed. Points of
   unknown yaw enter with the mean bearing of their 4 photodiodes at the point position (the
   diode centroid is 5 cm off the body origin; the refinement removes that), and their yaw then
   starts at the best of 72 headings for the start stations.
2. **Refinement**: :class:`~crs_core.calibration.solver.LighthouseFit` on every photodiode angle
   (rotation, position; ``dt1, dt2`` with ``fit_tilt``; the unknown yaws).

At least 3 points seen by both planes of a station are needed (4 when yaws are unknown).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from crs_core.analysis.angles import wrap_angle
from crs_core.calibration.points import CalibrationPoints
from crs_core.calibration.solver import FitResult, LighthouseFit, Observations
from crs_core.calibration.sweep_model import SweepModel, bearings, station_from_bearings
from crs_core.errors import FieldError
from crs_core.model.lighthouse import BaseStation

#: Headings tried for a point of unknown yaw before the refinement.
YAW_CANDIDATES = 72


@dataclass(frozen=True)
class StaticCalibration:
    """Result of :func:`calibrate_static`.

    Attributes
    ----------
    fit : the least-squares result (stations, residuals, standard deviations).
    observations : what was fitted: one row per point, station and plane (mean angles).
    point_of : (K,) point index of each observation.
    yaws : (n_points,) yaw per point, rad (given, or fitted when unknown).
    yaw_known : (n_points,) whether the file gave the yaw.
    start : the closed-form start stations (before refinement).
    """

    fit: FitResult
    observations: Observations
    point_of: np.ndarray
    yaws: np.ndarray
    yaw_known: np.ndarray
    start: tuple[BaseStation, ...]

    @property
    def stations(self) -> tuple[BaseStation, ...]:
        return self.fit.stations


def station_tilts(
    points: CalibrationPoints, n_stations: int, fit_tilt: bool
) -> list[tuple[float, float]]:
    """``(dt1, dt2)`` per station: from the file, or 0 as a start with ``fit_tilt``."""
    tilts = []
    for s in range(n_stations):
        pair = []
        for k, value in enumerate(points.tilts[s], start=1):
            if value is None and not fit_tilt:
                raise FieldError(
                    f"stations[{s}].dt{k}",
                    "missing; give the station's factory tilt offsets or fit them (--fit-tilt)",
                )
            pair.append(0.0 if value is None else value)
        tilts.append((pair[0], pair[1]))
    return tilts


def observations_of(points: CalibrationPoints, n_stations: int) -> tuple[Observations, np.ndarray]:
    """Mean angles per point, station (< ``n_stations``) and plane, and each row's point."""
    station, plane, angles, point_of = [], [], [], []
    for i, point in enumerate(points.points):
        for s in range(n_stations):
            for pl in (1, 2):
                mean = point.mean_angles(s, pl)
                if mean is not None:
                    station.append(s)
                    plane.append(pl)
                    angles.append(mean)
                    point_of.append(i)
    observations = Observations(
        np.array(station, dtype=int),
        np.array(plane, dtype=int),
        np.array(angles, dtype=float).reshape(-1, 4),
    )
    return observations, np.array(point_of, dtype=int)


def calibrate_static(
    points: CalibrationPoints,
    n_stations: int | None = None,
    fit_tilt: bool = False,
    sweep_model: SweepModel | None = None,
) -> StaticCalibration:
    """Fit the first ``n_stations`` base stations (default: all in the file) to the points.

    Raises
    ------
    ValueError
        ``--stations`` beyond the file's stations, a missing tilt offset without ``fit_tilt``,
        or a station seen at too few points (the message names it).
    """
    n = points.n_stations if n_stations is None else int(n_stations)
    if not 1 <= n <= points.n_stations:
        raise FieldError(
            "--stations", f"POINTS_FILE lists {points.n_stations} station(s); got {n_stations}"
        )
    model = sweep_model or SweepModel()
    tilts = station_tilts(points, n, fit_tilt)
    observations, point_of = observations_of(points, n)
    yaw_known = np.array([p.yaw is not None for p in points.points])
    yaws = np.array([p.yaw if p.yaw is not None else 0.0 for p in points.points])
    positions = np.array([p.position for p in points.points])
    diodes = np.asarray(points.photodiodes, dtype=float)
    need = 3 if yaw_known.all() else 4
    start = []
    for s in range(n):
        world: list[np.ndarray] = []
        directions: list[np.ndarray] = []
        seen = 0
        for i, point in enumerate(points.points):
            a1, a2 = point.mean_angles(s, 1), point.mean_angles(s, 2)
            if a1 is None or a2 is None:
                continue
            seen += 1
            rays = bearings(a1, a2, *tilts[s])
            if yaw_known[i]:
                c, si = math.cos(yaws[i]), math.sin(yaws[i])
                rotated = diodes @ np.array([[c, si], [-si, c]])
                world.extend(positions[i] + rotated)
                directions.extend(rays)
            else:
                mean = rays.mean(axis=0)
                world.append(positions[i])
                directions.append(mean / np.linalg.norm(mean))
        if seen < need:
            raise FieldError(
                "points",
                f"station {s} has both light planes at {seen} point(s); the fit needs at "
                f"least {need}" + ("" if need == 3 else " (some yaws are unknown)"),
            )
        rotation, position = station_from_bearings(np.array(world), np.array(directions))
        start.append(BaseStation.from_rotation(rotation, tuple(position), *tilts[s]))
    unknown = np.flatnonzero(~yaw_known)
    if unknown.size:
        yaws[unknown] = _best_yaws(model, start, points, observations, point_of, unknown)
    column = {int(i): j for j, i in enumerate(unknown)}

    def poses(extra: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        current = yaws.copy()
        current[unknown] = extra
        q = np.column_stack([positions, current])[point_of]
        d = np.zeros((len(point_of), 3, unknown.size))
        for k, i in enumerate(point_of):
            if int(i) in column:
                d[k, 2, column[int(i)]] = 1.0
        return q, d

    problem = LighthouseFit(
        observations,
        start,
        points.photodiodes,
        poses,
        unknown.size,
        fit_tilt=fit_tilt,
        sweep_model=model,
    )
    fit = problem.solve(yaws[unknown])
    final = yaws.copy()
    final[unknown] = wrap_angle(fit.extra)
    return StaticCalibration(fit, observations, point_of, final, yaw_known, tuple(start))


def _best_yaws(model, start, points, observations, point_of, unknown) -> np.ndarray:
    """Per unknown-yaw point, the candidate heading with the smallest angle residual."""
    candidates = np.linspace(-math.pi, math.pi, YAW_CANDIDATES, endpoint=False)
    diodes = np.asarray(points.photodiodes, dtype=float)
    best = []
    for i in unknown:
        rows = np.flatnonzero(point_of == i)
        cost = np.zeros(candidates.size)
        x, y = points.points[i].position
        grid = np.column_stack(
            [np.full(candidates.size, x), np.full(candidates.size, y), candidates]
        )
        for k in rows:
            s, plane = observations.station[k], observations.plane[k]
            station = start[s]
            theta = np.array([0.0, 0.0, 0.0, *station.position, station.dt1, station.dt2])
            angles = model.angles(grid, theta, station.rotation, diodes)
            predicted = angles[:, (plane - 1) * 4 : plane * 4]
            residual = wrap_angle(observations.angles[k][None, :] - predicted)
            cost += np.sum(np.nan_to_num(residual, nan=math.pi) ** 2, axis=1)
        best.append(candidates[int(np.argmin(cost))])
    return np.array(best)
