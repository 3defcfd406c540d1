r"""Static calibration: base-station poses from sweeps recorded at known car poses.

The paper (Sec. IV-A) averages the 4 photodiode angles of a plane and fits
:math:`(\Phi, p_{bs})` to those means. Here every photodiode angle is a residual of its own
(the per-sweep noise is averaged over the sweeps recorded at a point, per photodiode), so the
diode baseline constrains the fit as well and the point yaw can be left unknown.

Method, per base station (stations are independent given the points; unknown yaws are shared
by all stations and solved jointly with them):

1. **Closed-form start** (:func:`~crs_core.calibration.sweep_model.start_station`): each
   photodiode's two plane angles give its bearing in the station frame; with the known floor
   positions of the photodiodes (point pose + body offsets) a planar DLT gives the station
   rotation and position. No prior geometry, grid or multi-start is needed; unknown tilt
   offsets start from the DLT's homography. Points of unknown yaw enter with the mean angles of
   their 4 photodiodes at the point position (the diode centroid is 5 cm off the body origin;
   the refinement removes that), and their yaw then starts at the best of 72 headings for the
   start stations.
2. **Refinement**: :class:`~crs_core.calibration.solver.LighthouseFit` on every photodiode angle
   (rotation, position; ``dt1, dt2`` of the stations the file gives no tilt offsets for, of
   every station with ``fit_tilt``; the unknown yaws).

The tilt offsets are fitted rather than held at 0 when unknown: at 0 instead of the recorded
station's -0.051/+0.046 rad the fitted station moves by 0.15 m (angle residuals 17 mrad instead
of 0.2), while fitted they come back within 0.1 mrad (24 points of 20 sweeps) and the station
within 0.5 mm, as with the true values. They are weakest (one-sigma ~5 mrad, the position's
~5 mm) for a station whose spin axis is near the floor normal (standing upright low beside the
track), where the symmetric tilt trades off against the distance; the reported one-sigma says
so.

At least 3 points seen by both planes of a station are needed (4 when yaws are unknown).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from crs_core.analysis.angles import wrap_angle
from crs_core.calibration.points import CalibrationPoints
from crs_core.calibration.solver import FitResult, LighthouseFit, Observations
from crs_core.calibration.sweep_model import SweepModel, start_station
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


def station_tilts(points: CalibrationPoints, n_stations: int) -> list[tuple[float, float] | None]:
    """``(dt1, dt2)`` per station as the file gives them, rad; None when it lacks either (then
    both are fitted)."""
    tilts: list[tuple[float, float] | None] = []
    for s in range(n_stations):
        dt1, dt2 = points.tilts[s]
        tilts.append(None if dt1 is None or dt2 is None else (dt1, dt2))
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

    Parameters
    ----------
    points : the points file (:mod:`crs_core.calibration.points`); it need give no station
        geometry: the stations are those its sweeps name, and tilt offsets it lacks are fitted.
    n_stations : calibrate stations ``0..n_stations-1`` only.
    fit_tilt : fit every station's tilt offsets, also those the file gives.
    sweep_model : the compiled sweep model (built when not given).

    Raises
    ------
    ValueError
        ``--stations`` beyond the file's stations, a station seen at too few points, or a fit
        that did not converge (a :class:`~crs_core.errors.FieldError` naming ``--stations`` or
        ``points``).
    """
    n = points.n_stations if n_stations is None else int(n_stations)
    if not 1 <= n <= points.n_stations:
        raise FieldError(
            "--stations", f"POINTS_FILE lists {points.n_stations} station(s); got {n_stations}"
        )
    model = sweep_model or SweepModel()
    tilts = station_tilts(points, n)
    free = [fit_tilt or pair is None for pair in tilts]
    observations, point_of = observations_of(points, n)
    yaw_known = np.array([p.yaw is not None for p in points.points])
    yaws = np.array([p.yaw if p.yaw is not None else 0.0 for p in points.points])
    positions = np.array([p.position for p in points.points])
    diodes = np.asarray(points.photodiodes, dtype=float)
    need = 3 if yaw_known.all() else 4
    start = []
    for s in range(n):
        world: list[np.ndarray] = []
        alpha1: list[np.ndarray] = []
        alpha2: list[np.ndarray] = []
        seen = 0
        for i, point in enumerate(points.points):
            a1, a2 = point.mean_angles(s, 1), point.mean_angles(s, 2)
            if a1 is None or a2 is None:
                continue
            seen += 1
            if yaw_known[i]:
                c, si = math.cos(yaws[i]), math.sin(yaws[i])
                world.extend(positions[i] + diodes @ np.array([[c, si], [-si, c]]))
                alpha1.extend(a1)
                alpha2.extend(a2)
            else:  # the diodes' mean angles, seen at the point position
                world.append(positions[i])
                alpha1.append(a1[0] + np.mean(wrap_angle(a1 - a1[0])))
                alpha2.append(a2[0] + np.mean(wrap_angle(a2 - a2[0])))
        if seen < need:
            raise FieldError(
                "points",
                f"station {s} has both light planes at {seen} point(s); the fit needs at "
                f"least {need}" + ("" if need == 3 else " (some yaws are unknown)"),
            )
        start.append(start_station(np.array(world), np.array(alpha1), np.array(alpha2), tilts[s]))
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
        fit_tilt=free,
        sweep_model=model,
    )
    fit = problem.solve(yaws[unknown])
    fit.require_converged("points", "mean sweeps", "check the points' positions and yaws")
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
