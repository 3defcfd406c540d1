"""Accuracy of Lighthouse calibration on simulated data (``crs bench calibration``).

Static: for each setting (sweeps averaged per point, error of the known positions) and seed, 24
points on the demo-track area (:func:`sim.static_points.grid_layout`), the recorded station,
1 mrad per sweep (the simulator's Lighthouse noise, the level of the real recordings); the
stations are fitted on the first n points (farthest-first) for n = 4..24 and every point is
reprojected (:func:`crs_core.calibration.evaluation.n_sweep`); the true station error is
reported too. Moving: simulated demo-track recordings (Lighthouse + 100 Hz motion capture
only) with a 20 ms clock offset; offset and station errors. Means over seeds.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from crs_core.calibration.evaluation import n_sweep
from crs_core.calibration.moving import calibrate_moving
from crs_core.calibration.static import calibrate_static
from crs_core.calibration.sweep_model import SweepModel
from crs_core.model.lighthouse import RECORDED_BASE_STATION
from sim.mocap_recording import simulate_mocap_recording
from sim.static_points import grid_layout, simulate_static_points

#: (sweeps per point, std of the known positions in m) of the static study.
STATIC_SETTINGS = ((1, 0.0), (20, 0.0), (1, 0.002), (20, 0.002))


def _rotation_error(rotation: np.ndarray) -> float:
    relative = rotation.T @ RECORDED_BASE_STATION.rotation
    return math.acos(max(-1.0, min(1.0, (np.trace(relative) - 1.0) / 2.0)))


def static_study(seeds: int = 5, points: int = 24) -> list[dict]:
    """Mean/max reprojected error and true station error vs n, per setting (module doc)."""
    station = RECORDED_BASE_STATION
    model = SweepModel()
    out = []
    for sweeps, position_std in STATIC_SETTINGS:
        table: dict[int, list[list[float]]] = {}
        for seed in range(seeds):
            calibration_points = simulate_static_points(
                [station],
                *grid_layout(points, seed=seed),
                sweeps=sweeps,
                seed=seed,
                position_std=position_std,
            )
            rows, order = n_sweep(calibration_points)
            for row in rows:
                fit = calibrate_static(calibration_points.subset(order[: row.n]), sweep_model=model)
                error = float(
                    np.linalg.norm(np.subtract(fit.stations[0].position, station.position))
                )
                table.setdefault(row.n, []).append(
                    [row.all_mean, row.all_max, row.fitted_mean, row.fitted_max, error]
                )
        out.append(
            {
                "sweeps_per_point": sweeps,
                "position_std_m": position_std,
                "seeds": seeds,
                "rows": [
                    dict(
                        zip(
                            (
                                "n",
                                "all_mean_m",
                                "all_max_m",
                                "fitted_mean_m",
                                "fitted_max_m",
                                "station_position_error_m",
                            ),
                            [n, *np.mean(values, axis=0).tolist()],
                            strict=True,
                        )
                    )
                    for n, values in sorted(table.items())
                ],
            }
        )
    return out


def moving_study(seeds: int = 3, duration: float = 20.0, offset: float = 0.02) -> list[dict]:
    """Offset and station errors of moving calibration per seed (module docstring)."""
    out = []
    for seed in range(seeds):
        dataset = simulate_mocap_recording(duration=duration, clock_offset=offset, seed=seed)
        for fit_photodiodes in (False, True):
            result = calibrate_moving(dataset, fit_offset=True, fit_photodiodes=fit_photodiodes)
            station = result.stations[0]
            out.append(
                {
                    "seed": seed,
                    "duration_s": duration,
                    "fit_photodiodes": fit_photodiodes,
                    "offset_true_s": offset,
                    "offset_s": result.offset,
                    "offset_error_s": abs(result.offset - offset),
                    "offset_std_s": result.offset_std,
                    "station_position_error_m": float(
                        np.linalg.norm(
                            np.subtract(station.position, RECORDED_BASE_STATION.position)
                        )
                    ),
                    "station_rotation_error_rad": _rotation_error(station.rotation),
                    "photodiode_error_max_m": float(
                        np.abs(
                            np.subtract(result.fit.photodiodes, dataset.geometry.photodiodes)
                        ).max()
                    ),
                    "sweeps": len(result.recording.observations),
                }
            )
    return out


def _setting(sweeps: int, position_std: float) -> str:
    """A static setting as the docs' table names it."""
    per_point = f"{sweeps} sweep{'s' if sweeps > 1 else ''} per point"
    known = (
        f"known positions off by {1e3 * position_std:g} mm (std)"
        if position_std
        else "exact known positions"
    )
    return f"{per_point}, {known}"


def format_markdown(result: dict[str, Any], columns: tuple[int, ...] = (4, 6)) -> str:
    """The docs' tables of a run (Markdown): per static setting the mean reprojected error over
    all points when fitted on ``columns`` and on all points, and the station's position error
    at 6 points (all mm); then the moving study's worst seed.

    Parameters
    ----------
    result : dict
        The benchmark's JSON: ``static`` (:func:`static_study`, errors in m) and ``moving``
        (:func:`moving_study`, offsets in s, errors in m).
    columns : tuple of int, optional
        The point counts shown besides all points.

    Returns
    -------
    str
        Markdown: a table and a line on the moving study.
    """
    static = result["static"]
    every = static[0]["rows"][-1]["n"]
    shown = [n for n in columns if n < every] + [every]
    lines = [
        f"Static: {every} points, mean over {static[0]['seeds']} seeds; mean reprojected "
        f"position error over all {every} points (mm) when fitted on the first n:",
        "",
        "| setting | "
        + " | ".join(f"{n} points" for n in shown)
        + " | station position error at 6 points |",
        "|---|" + "---|" * (len(shown) + 1),
    ]
    for setting in static:
        by_n = {row["n"]: row for row in setting["rows"]}
        cells = [f"{1e3 * by_n[n]['all_mean_m']:.2f}" for n in shown]
        station = by_n.get(6, {}).get("station_position_error_m")
        lines.append(
            f"| {_setting(setting['sweeps_per_point'], setting['position_std_m'])} | "
            + " | ".join(cells)
            + f" | {'–' if station is None else f'{1e3 * station:.1f} mm'} |"
        )
    moving = result.get("moving") or []
    if moving:
        parts = []
        for photodiodes in (False, True):
            runs = [r for r in moving if r["fit_photodiodes"] == photodiodes]
            if runs:
                offset = max(r["offset_error_s"] for r in runs)
                station = max(r["station_position_error_m"] for r in runs)
                what = "with the photodiodes fitted too" if photodiodes else "station and offset"
                parts.append(
                    f"{what}: offset error {1e3 * offset:.2g} ms, station position error "
                    f"{1e3 * station:.2g} mm"
                )
        first = moving[0]
        lines += [
            "",
            f"Moving: {first['duration_s']:g} s of simulated driving with a "
            f"{1e3 * first['offset_true_s']:g} ms clock offset, worst of "
            f"{len({r['seed'] for r in moving})} seeds; " + "; ".join(parts) + ".",
        ]
    return "\n".join(lines)
