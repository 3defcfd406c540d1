r"""How good a static calibration is: angle residuals, reprojected positions, mean/max vs n.

* **Angle residuals** per point, station, plane and photodiode are re-evaluated through the
  car model with the fitted geometry (``CarModel.numeric``, i.e. ``CarModel.output_function``
  of each ``lighthouse/<s>/<l>``), independently of the fit's own chart.
* **Reprojected position error** per point (the paper's "calibration residual"): the
  :class:`~crs_core.estimation.lighthouse_pose.LighthousePoseSolver` solves the planar pose
  from the point's mean sweeps with the fitted stations (all stations that saw both planes
  together, and each station alone); the error is the distance to the known position (and the
  yaw error where the yaw is known).
* **Mean/max vs n**: points are ordered so that each added point is the one farthest from those
  already taken (the density grows evenly, as in the paper); for each n the stations are fitted
  on the first n points and every point of the file is reprojected (the fitted ones and the
  held-out ones are reported separately).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from crs_core.analysis.angles import wrap_angle
from crs_core.calibration.points import CalibrationPoints
from crs_core.calibration.static import calibrate_static
from crs_core.calibration.sweep_model import SweepModel
from crs_core.estimation.lighthouse_pose import LighthousePoseSolver
from crs_core.model import CarModel
from crs_core.model.lighthouse import BaseStation
from crs_core.model.sensors import N_PHOTODIODES


@dataclass(frozen=True)
class PointReport:
    """Residuals of one calibration point.

    Attributes
    ----------
    index : point index in the file.
    position : known (x, y), m.
    angle_residuals : ``(station, plane)`` -> (4,) measured - model, rad.
    position_error : distance of the all-station fix to the known position, m (nan: no fix).
    yaw_error : wrapped yaw error of that fix, rad (nan when the yaw is unknown or no fix).
    fix : the all-station fix ``(x, y, yaw)`` or None.
    station_errors : per station, the position error of its own fix, m (nan: no fix).
    sweep_std : per ``(station, plane)`` the std of the raw sweeps about their mean, rad
        (nan with one sweep).
    """

    index: int
    position: tuple[float, float]
    angle_residuals: dict[tuple[int, int], np.ndarray]
    position_error: float
    yaw_error: float
    fix: np.ndarray | None
    station_errors: tuple[float, ...]
    sweep_std: dict[tuple[int, int], float]


def calibrated_model(
    stations: Sequence[BaseStation], photodiodes: Sequence[tuple[float, float]]
) -> CarModel:
    """A car model with the given Lighthouse geometry."""
    model = CarModel(base_stations=list(stations))
    values = {
        f"lh_d{k}_{axis}": float(photodiodes[k][a])
        for k in range(N_PHOTODIODES)
        for a, axis in enumerate("xy")
    }
    return CarModel(base_stations=list(stations), parameters=model.parameters.updated(values))


def point_reports(
    points: CalibrationPoints,
    stations: Sequence[BaseStation],
    yaws: np.ndarray | None = None,
    model: CarModel | None = None,
) -> list[PointReport]:
    """Angle residuals and reprojected position errors of every point (module docstring).

    ``yaws`` (fitted, for points of unknown yaw) are used for the angle residuals; the
    position fix never uses them.
    """
    model = model or calibrated_model(stations, points.photodiodes)
    n = len(stations)
    # accept every fix: a poor point must show up in the report, not vanish
    solver = LighthousePoseSolver(model, angle_std=1e-3, max_rms_ratio=1e6)
    numeric, p = model.numeric, model.parameters.vector()
    reports = []
    for i, point in enumerate(points.points):
        yaw = point.yaw if point.yaw is not None else (yaws[i] if yaws is not None else 0.0)
        state = np.array([*point.position, yaw, 0.0, 0.0, 0.0])
        outputs = numeric.outputs(state, np.zeros(2), p)
        residuals, spread, means = {}, {}, {}
        for (s, plane), rows in point.sweeps.items():
            if s >= n:
                continue
            mean = point.mean_angles(s, plane)
            means[(s, plane)] = mean
            # (4,) in, (4,) out: the array branch of wrap_angle
            residuals[(s, plane)] = np.asarray(
                wrap_angle(mean - outputs[f"lighthouse/{s}/{plane}"])
            )
            spread[(s, plane)] = (
                float(np.sqrt(np.sum(wrap_angle(rows - mean) ** 2) / (rows.size - N_PHOTODIODES)))
                if rows.shape[0] > 1
                else math.nan
            )
        fix = _fix(solver, means, point.position)
        known = np.array(point.position)
        error = float(np.linalg.norm(fix.pose[:2] - known)) if fix is not None else math.nan
        yaw_error = (
            abs(float(wrap_angle(fix.pose[2] - point.yaw)))
            if fix is not None and point.yaw is not None
            else math.nan
        )
        station_errors = []
        for s in range(n):
            own = {key: value for key, value in means.items() if key[0] == s}
            single = _fix(solver, own, point.position)
            station_errors.append(
                float(np.linalg.norm(single.pose[:2] - known)) if single is not None else math.nan
            )
        reports.append(
            PointReport(
                i,
                point.position,
                residuals,
                error,
                yaw_error,
                None if fix is None else fix.pose,
                tuple(station_errors),
                spread,
            )
        )
    return reports


def _fix(solver: LighthousePoseSolver, means: dict, position):
    """Pose fix from mean sweeps (both planes of a station needed); None if not possible."""
    sweeps = {f"lighthouse/{s}/{plane}": values for (s, plane), values in means.items()}
    try:
        return solver.solve(sweeps)
    except (ValueError, np.linalg.LinAlgError):
        return None


def spread_order(positions: np.ndarray) -> np.ndarray:
    """Point order in which each next point is the farthest from those already taken.

    Starts with the two points farthest apart; ties keep the file order.
    """
    positions = np.asarray(positions, dtype=float)
    n = len(positions)
    if n <= 2:
        return np.arange(n)
    distance = np.linalg.norm(positions[:, None] - positions[None], axis=2)
    first, second = np.unravel_index(int(np.argmax(distance)), distance.shape)
    order = [int(min(first, second)), int(max(first, second))]
    nearest = np.minimum(distance[order[0]], distance[order[1]])
    while len(order) < n:
        nearest[order] = -1.0
        pick = int(np.argmax(nearest))
        order.append(pick)
        nearest = np.minimum(nearest, distance[pick])
    return np.array(order)


@dataclass(frozen=True)
class SweepRow:
    """Mean/max reprojected position error (m) with the stations fitted on ``n`` points."""

    n: int
    fitted_mean: float
    fitted_max: float
    all_mean: float
    all_max: float
    held_out_mean: float


def n_sweep(
    points: CalibrationPoints,
    counts: Sequence[int] | None = None,
    n_stations: int | None = None,
    fit_tilt: bool = False,
) -> tuple[list[SweepRow], np.ndarray]:
    """Fit on the first n points of :func:`spread_order` for each n; returns rows and the order.

    ``counts`` default: every n from the smallest that can be fitted (4; 5 with unknown yaws)
    to the number of points. Counts whose fit fails (a station seen too rarely) are skipped.
    """
    order = spread_order(np.array([p.position for p in points.points]))
    total = len(points.points)
    smallest = 4 if all(p.yaw is not None for p in points.points) else 5
    counts = list(range(min(smallest, total), total + 1)) if counts is None else list(counts)
    sweep_model = SweepModel()
    n = points.n_stations if n_stations is None else n_stations
    model = None
    rows = []
    for count in counts:
        chosen = order[:count]
        try:
            result = calibrate_static(points.subset(chosen), n, fit_tilt, sweep_model)
        except ValueError:
            continue
        model = (
            calibrated_model(result.stations, points.photodiodes)
            if model is None
            else _with_geometry(model, result.stations)
        )
        errors = np.array(
            [r.position_error for r in point_reports(points, result.stations, model=model)]
        )
        fitted, rest = errors[chosen], np.delete(errors, chosen)
        rows.append(
            SweepRow(
                count,
                float(np.nanmean(fitted)),
                float(np.nanmax(fitted)),
                float(np.nanmean(errors)),
                float(np.nanmax(errors)),
                float(np.nanmean(rest)) if rest.size else math.nan,
            )
        )
    return rows, order


def _with_geometry(model: CarModel, stations: Sequence[BaseStation]) -> CarModel:
    """``model`` (same structure, so its compiled functions are reused) with new stations."""
    from crs_core.model.chronos import base_station_parameters

    values = base_station_parameters(tuple(stations))
    return CarModel(
        base_stations=list(stations),
        parameters=model.parameters.updated({k: values.value(k) for k in values.names}),
    )


@dataclass(frozen=True)
class MovingFixes:
    """Per-pair pose fixes of a moving recording against its pose reference.

    Attributes
    ----------
    stamps : (F,) fix stamps, s (car clock).
    errors : (F,) distance of each fix to the reference pose at ``stamp + offset``, m.
    yaw_errors : (F,) wrapped yaw error, rad.
    """

    stamps: np.ndarray
    errors: np.ndarray
    yaw_errors: np.ndarray


def moving_fixes(calibration, limit: int = 2000) -> MovingFixes:
    """Pose fixes from the plane pairs of every station (at most ``limit``, evenly spread),
    solved with the fitted geometry, compared with the reference at the fitted offset."""
    from crs_core.estimation.lighthouse_pose import SweepPairer
    from crs_core.measurements import Measurement, lighthouse_sensor

    recording = calibration.recording
    model = calibrated_model(calibration.stations, calibration.fit.photodiodes)
    solver = LighthousePoseSolver(model, angle_std=1e-3, max_rms_ratio=1e6)
    pairer = SweepPairer(max_gap=0.03)
    pairs = []
    obs = recording.observations
    for k in range(len(obs)):
        sensor = lighthouse_sensor(int(obs.station[k]), int(obs.plane[k]))
        paired = pairer.add(Measurement(float(recording.stamps[k]), sensor, obs.angles[k]))
        if paired is not None:
            pairs.append(paired)
    if len(pairs) > limit:
        pairs = [pairs[i] for i in np.linspace(0, len(pairs) - 1, limit).astype(int)]
    stamps, errors, yaw_errors = [], [], []
    for stamp, sweeps in pairs:
        fix = solver.solve(sweeps, stamp)
        if fix is None:
            continue
        reference = calibration.reference_pose(np.array([stamp]))[0]
        stamps.append(stamp)
        errors.append(float(np.linalg.norm(fix.pose[:2] - reference[:2])))
        yaw_errors.append(abs(float(wrap_angle(fix.pose[2] - reference[2]))))
    return MovingFixes(np.array(stamps), np.array(errors), np.array(yaw_errors))
