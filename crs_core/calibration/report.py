"""Calibration outputs: the geometry YAML, ``report.json`` and ``report.md``.

``geometry.yaml`` holds one top-level ``geometry:`` mapping in the format of the ``geometry``
block of ``dataset.yaml`` (:class:`crs_core.dataset.Geometry`): paste it into a dataset's
``dataset.yaml`` (or read it with ``Geometry.from_dict(yaml['geometry'])``). The figures are
drawn by :mod:`crs_core.calibration.plots`.
"""

from __future__ import annotations

import json
import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from crs_core.analysis.statistics import summary
from crs_core.calibration.evaluation import MovingFixes, PointReport, SweepRow
from crs_core.calibration.moving import MovingCalibration
from crs_core.calibration.points import CalibrationPoints
from crs_core.calibration.solver import FitResult
from crs_core.calibration.static import StaticCalibration
from crs_core.dataset import Geometry, plain
from crs_core.model.lighthouse import BaseStation


def write_geometry(
    path: Path, stations: Sequence[BaseStation], photodiodes: Sequence[tuple[float, float]]
) -> Path:
    """``geometry.yaml``: ``{geometry: <dataset.yaml geometry block>}``; returns the path."""
    block = Geometry(tuple(stations), tuple((x, y) for x, y in photodiodes)).to_dict()
    text = (
        "# Lighthouse geometry from crs calibrate-lighthouse; the 'geometry' block of "
        "dataset.yaml\n"
        + yaml.safe_dump(
            {"geometry": plain(block, nonfinite_as_none=True)},
            sort_keys=False,
            default_flow_style=None,
        )
    )
    path.write_text(text)
    return path


#: A fitted tilt offset with a larger one-sigma is reported as weakly determined, rad.
WEAK_TILT_STD = 2e-3


def _station_entry(station: BaseStation, std: np.ndarray, tilt_fitted: bool) -> dict[str, Any]:
    return {
        "position_m": list(station.position),
        "position_std_m": std[3:6].tolist(),
        "rotation": station.rotation.tolist(),
        "angles_rad": list(station.angles),
        "rotation_std_rad": std[0:3].tolist(),
        "dt1": station.dt1,
        "dt2": station.dt2,
        "tilt_fitted": bool(tilt_fitted),
        "tilt_std_rad": std[6:8].tolist(),
    }


def _station_entries(fit: FitResult) -> list[dict[str, Any]]:
    return [
        _station_entry(station, std, fitted)
        for station, std, fitted in zip(fit.stations, fit.station_std, fit.tilt_fitted, strict=True)
    ]


def _tilt_phrase(summary: dict[str, Any]) -> str:
    """How the tilt offsets were found: given, fitted (requested, or not given), or mixed."""
    fitted = [i for i, s in enumerate(summary["stations"]) if s["tilt_fitted"]]
    if not fitted:
        return "tilt offsets given"
    if len(fitted) == len(summary["stations"]):
        return "tilt offsets fitted" + ("" if summary["fit_tilt"] else " (none given)")
    return f"tilt offsets fitted for station(s) {', '.join(map(str, fitted))} (not given)"


def _weak_tilt_lines(summary: dict[str, Any]) -> list[str]:
    """A note per station whose fitted tilt offsets the data barely determine."""
    lines = []
    for i, s in enumerate(summary["stations"]):
        spread = max(s["tilt_std_rad"])
        if s["tilt_fitted"] and spread > WEAK_TILT_STD:
            lines += [
                f"Station {i}: its tilt offsets are weakly determined (± {1e3 * spread:.1f} "
                "mrad), and with them its distance: its spin axis is near the floor normal, "
                "where the symmetric tilt trades off against the distance. Give its factory "
                "tilt offsets (from the station's data stream) if you have them.",
                "",
            ]
    return lines


def _stats(values: np.ndarray) -> dict[str, float]:
    """Mean, median, p95 and max of the finite values (NaN when there are none)."""
    values = np.asarray(values, dtype=float)
    return summary(values[np.isfinite(values)], ("mean", "median", "p95", "max"))


def static_summary(
    points: CalibrationPoints,
    calibration: StaticCalibration,
    reports: list[PointReport],
    sweep: list[SweepRow],
    order: np.ndarray,
    fit_tilt: bool,
) -> dict[str, Any]:
    """Everything of a static calibration as plain JSON-able data (SI units)."""
    errors = np.array([r.position_error for r in reports])
    residuals = np.concatenate([np.ravel(list(r.angle_residuals.values())) for r in reports])
    spreads = np.array([v for r in reports for v in r.sweep_std.values()])
    return {
        "kind": "static",
        "points": len(points.points),
        "stations": _station_entries(calibration.fit),
        "fit_tilt": fit_tilt,
        "yaw_fitted": int(np.sum(~calibration.yaw_known)),
        "angle_residual_rms_rad": float(np.sqrt(np.mean(residuals**2))),
        "sweep_noise_std_rad": float(np.nanmedian(spreads)) if np.isfinite(spreads).any() else None,
        "position_error_m": _stats(errors),
        "per_point": [
            {
                "index": r.index,
                "position_m": list(r.position),
                "yaw_rad": float(calibration.yaws[r.index]),
                "yaw_known": bool(calibration.yaw_known[r.index]),
                "position_error_m": r.position_error,
                "yaw_error_rad": r.yaw_error,
                "station_position_error_m": list(r.station_errors),
                "angle_residuals_rad": {
                    f"lighthouse/{s}/{pl}": v.tolist()
                    for (s, pl), v in sorted(r.angle_residuals.items())
                },
            }
            for r in reports
        ],
        "versus_n": {
            "order": [int(i) for i in order],
            "rows": [vars(row) for row in sweep],
        },
    }


def moving_summary(
    calibration: MovingCalibration,
    fixes: MovingFixes,
    fit_offset: bool,
    fit_photodiodes: bool,
    fit_tilt: bool,
) -> dict[str, Any]:
    """Everything of a moving calibration as plain JSON-able data (SI units)."""
    obs = calibration.recording.observations
    residuals = calibration.fit.residuals
    per_sensor = {}
    for s in range(calibration.recording.n_stations):
        for plane in (1, 2):
            rows = (obs.station == s) & (obs.plane == plane)
            if rows.any():
                per_sensor[f"lighthouse/{s}/{plane}"] = {
                    "sweeps": int(rows.sum()),
                    "rms_per_diode_rad": np.sqrt(np.mean(residuals[rows] ** 2, axis=0)).tolist(),
                }
    return {
        "kind": "moving",
        "sweeps": len(obs),
        "stations": _station_entries(calibration.fit),
        "clock_offset_s": calibration.offset,
        "clock_offset_std_s": calibration.offset_std,
        "fit_offset": fit_offset,
        "fit_photodiodes": fit_photodiodes,
        "fit_tilt": fit_tilt,
        "photodiodes_m": [list(d) for d in calibration.fit.photodiodes],
        "photodiodes_std_m": calibration.fit.diode_std.reshape(4, 2).tolist(),
        "angle_residual_rms_rad": float(np.sqrt(np.mean(residuals**2))),
        "angle_residual_median_abs_rad": float(np.median(np.abs(residuals))),
        "per_sensor": per_sensor,
        "pose_fix_error_m": {**_stats(fixes.errors), "fixes": int(fixes.errors.size)},
        "pose_fix_yaw_error_rad": _stats(fixes.yaw_errors),
    }


def write_json(path: Path, summary: dict[str, Any]) -> Path:
    path.write_text(
        json.dumps(plain(summary, nonfinite_as_none=True), indent=2, allow_nan=True) + "\n"
    )
    return path


def _mm(value: float) -> str:
    return "n/a" if not math.isfinite(value) else f"{1e3 * value:.2f}"


def _station_lines(summary: dict[str, Any]) -> list[str]:
    lines = [
        "| station | position x, y, z (m) | ± (mm) | angles φ1, φ2, φ3 (rad) | dt1, dt2 (rad) |",
        "|---|---|---|---|---|",
    ]
    for i, s in enumerate(summary["stations"]):
        lines.append(
            f"| {i} | {', '.join(f'{v:.4f}' for v in s['position_m'])} | "
            f"{', '.join(f'{1e3 * v:.2f}' for v in s['position_std_m'])} | "
            f"{', '.join(f'{v:.4f}' for v in s['angles_rad'])} | {s['dt1']:.5f}, {s['dt2']:.5f} |"
        )
    return lines


def static_markdown(summary: dict[str, Any], command: str) -> str:
    """``report.md`` of a static calibration."""
    error = summary["position_error_m"]
    noise = summary["sweep_noise_std_rad"]
    lines = [
        "# Lighthouse calibration (static points)",
        "",
        f"Command: `{command}`",
        "",
        f"{summary['points']} points, {len(summary['stations'])} station(s); "
        f"{_tilt_phrase(summary)}; {summary['yaw_fitted']} yaw(s) fitted."
        " Geometry: `geometry.yaml` (the `geometry` block of `dataset.yaml`).",
        "",
        *_station_lines(summary),
        "",
        "± is one sigma from the fit (residual variance × (JᵀJ)⁻¹).",
        "",
        *_weak_tilt_lines(summary),
        f"Angle residual rms: {1e3 * summary['angle_residual_rms_rad']:.3f} mrad "
        "(mean of the sweeps at a point, per photodiode)"
        + (
            f"; per-sweep noise from the spread at the points: {1e3 * noise:.3f} mrad."
            if noise is not None
            else "."
        ),
        "",
        "Reprojected position error (pose fix from the point's sweeps with the fitted "
        f"stations vs the known position): mean {_mm(error['mean'])} mm, median "
        f"{_mm(error['median'])} mm, max {_mm(error['max'])} mm.",
        "",
        "| point | x (m) | y (m) | error (mm) | yaw error (mrad) | max angle residual (mrad) |",
        "|---|---|---|---|---|---|",
    ]
    for p in summary["per_point"]:
        worst = max(
            (abs(v) for values in p["angle_residuals_rad"].values() for v in values), default=0.0
        )
        yaw = "n/a" if not math.isfinite(p["yaw_error_rad"]) else f"{1e3 * p['yaw_error_rad']:.1f}"
        lines.append(
            f"| {p['index']} | {p['position_m'][0]:.3f} | {p['position_m'][1]:.3f} | "
            f"{_mm(p['position_error_m'])} | {yaw} | {1e3 * worst:.3f} |"
        )
    rows = summary["versus_n"]["rows"]
    if rows:
        lines += [
            "",
            "## Mean/max position error vs number of points",
            "",
            "Points added farthest-first (`versus_n.order` in report.json); for each n the "
            "stations are fitted on the first n points and every point is reprojected.",
            "",
            "| n | fitted mean (mm) | fitted max (mm) | all mean (mm) | all max (mm) | "
            "held-out mean (mm) |",
            "|---|---|---|---|---|---|",
        ]
        for r in rows:
            lines.append(
                f"| {r['n']} | {_mm(r['fitted_mean'])} | {_mm(r['fitted_max'])} | "
                f"{_mm(r['all_mean'])} | {_mm(r['all_max'])} | {_mm(r['held_out_mean'])} |"
            )
    lines += [
        "",
        "Figures: `angle_residuals.png`, `position_residuals.png`, `residual_vs_n.png`.",
        "",
    ]
    return "\n".join(lines)


def moving_markdown(summary: dict[str, Any], command: str) -> str:
    """``report.md`` of a moving calibration."""
    fix = summary["pose_fix_error_m"]
    lines = [
        "# Lighthouse calibration (moving recording)",
        "",
        f"Command: `{command}`",
        "",
        f"{summary['sweeps']} sweeps, {len(summary['stations'])} station(s). Clock offset "
        f"(motion capture minus car): {1e3 * summary['clock_offset_s']:.2f} ± "
        f"{1e3 * summary['clock_offset_std_s']:.2f} ms"
        f" ({'fitted' if summary['fit_offset'] else 'fixed'}); photodiodes "
        f"{'fitted' if summary['fit_photodiodes'] else 'given'}; {_tilt_phrase(summary)}. "
        "Geometry: `geometry.yaml`.",
        "",
        *_station_lines(summary),
        "",
        *_weak_tilt_lines(summary),
        f"Angle residual rms {1e3 * summary['angle_residual_rms_rad']:.3f} mrad, median |r| "
        f"{1e3 * summary['angle_residual_median_abs_rad']:.3f} mrad.",
        "",
        f"Pose fixes from plane pairs with the fitted geometry vs the reference ({fix['fixes']} "
        f"fixes; the two planes are ~10 ms apart, so a moving car adds its own motion): "
        f"median {_mm(fix['median'])} mm, p95 {_mm(fix['p95'])} mm, max {_mm(fix['max'])} mm.",
        "",
    ]
    if summary["fit_photodiodes"]:
        lines += [
            "| photodiode | x (m) | y (m) | ± (mm) |",
            "|---|---|---|---|",
        ]
        for k, ((x, y), (sx, sy)) in enumerate(
            zip(summary["photodiodes_m"], summary["photodiodes_std_m"], strict=True)
        ):
            lines.append(f"| {k} | {x:.4f} | {y:.4f} | {1e3 * sx:.2f}, {1e3 * sy:.2f} |")
        lines += [
            "",
            "Note: at constant speed, shifting all photodiodes forward by v·τ looks like a "
            "clock offset τ; vary the speed while recording to tell them apart.",
            "",
        ]
    lines += ["Figures: `moving_residuals.png`, `offset_scan.png` (when the offset is fitted).", ""]
    return "\n".join(lines)
