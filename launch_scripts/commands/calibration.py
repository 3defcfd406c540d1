"""``crs calibrate-lighthouse``: Lighthouse base-station calibration (argument parsing only).

``static POINTS_FILE --out DIR [--stations N] [--fit-tilt]``: base stations from sweeps at
known static poses (format: :mod:`crs_core.calibration.points`).
``moving DATASET --out DIR [--fit-offset] [--fit-photodiodes] [--fit-tilt]``: from a recording
with a motion-capture pose reference (:mod:`crs_core.calibration.moving`).
``simulate-points FILE`` and ``simulate-moving --out DIR`` write simulated inputs for both.
Every mode writes ``geometry.yaml`` (the ``geometry`` block of ``dataset.yaml``), ``report.md``,
``report.json`` and PNG figures.

:data:`COMMAND` declares the command and its modes for :mod:`launch_scripts.cli`.
"""

from __future__ import annotations

import argparse
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from crs_core.dataset import Geometry
from launch_scripts.arguments import (
    Command,
    add_out,
    add_simulated_stations,
    bounded_number,
    command_line,
)
from launch_scripts.output_folder import prepare_output, prepare_output_file
from launch_scripts.recording import RECORDING_HELP, add_bag_options, load_recording

NAME = "calibrate-lighthouse"


def _add_fit_tilt(parser: argparse.ArgumentParser) -> None:
    """``--fit-tilt`` (static and moving)."""
    parser.add_argument(
        "--fit-tilt",
        action="store_true",
        help="also fit the tilt offsets dt1, dt2 that the geometry / POINTS_FILE gives (those it "
        "does not give are always fitted)",
    )


def _add_offset(parser: argparse.ArgumentParser, default: float, help_text: str) -> None:
    """``--offset``: the motion-capture clock minus the car's, s, in [-1, 1]."""
    offset = bounded_number("offset", "s", -1.0, 1.0, include_low=True)
    parser.add_argument("--offset", type=offset, default=default, help=help_text)


def _static_arguments(sub: argparse.ArgumentParser) -> None:
    """``static``'s arguments."""
    sub.add_argument(
        "points_file",
        type=Path,
        metavar="POINTS_FILE",
        help="YAML, format chronos-lighthouse-points/1 (see the README)",
    )
    add_out(sub, "output folder", required=True)
    sub.add_argument(
        "--stations",
        type=bounded_number("stations", "", 1, 16, int, include_low=True),
        help="calibrate stations 0..N-1 (default: every station in the file, or every station "
        "its sweeps name)",
    )
    _add_fit_tilt(sub)
    sub.add_argument(
        "--no-sweep", action="store_true", help="skip the mean/max-vs-number-of-points study"
    )


def _moving_arguments(sub: argparse.ArgumentParser) -> None:
    """``moving``'s arguments."""
    sub.add_argument(
        "dataset",
        type=Path,
        metavar="DATASET",
        help=RECORDING_HELP + ", with motion-capture poses",
    )
    add_bag_options(sub)
    add_out(sub, "output folder", required=True)
    sub.add_argument(
        "--fit-offset",
        action="store_true",
        help="fit the clock offset (motion capture minus car), s",
    )
    _add_offset(sub, 0.0, "clock offset, s: fixed, or the start with --fit-offset (default 0)")
    sub.add_argument(
        "--max-offset",
        type=bounded_number("max-offset", "s", 0.0, 1.0, include_low=True),
        default=0.25,
        help="search range of --fit-offset, +-s (default 0.25)",
    )
    sub.add_argument(
        "--fit-photodiodes",
        action="store_true",
        help="also fit the photodiode positions (body frame)",
    )
    _add_fit_tilt(sub)


def _simulate_points_arguments(sub: argparse.ArgumentParser) -> None:
    """``simulate-points``'s arguments."""
    sub.add_argument("file", type=Path, metavar="FILE", help="points YAML to write")
    sub.add_argument(
        "--points",
        type=bounded_number("points", "", 1, 1000, int, include_low=True),
        default=24,
        help="number of points (default 24)",
    )
    add_simulated_stations(sub, "base stations, 1..8 (default 1: the recorded one)")
    sub.add_argument(
        "--sweeps",
        type=bounded_number("sweeps", "", 1, 10000, int, include_low=True),
        default=20,
        help="sweeps per plane at each point (default 20)",
    )
    sub.add_argument(
        "--position-std",
        type=bounded_number("position-std", "m", 0.0, 1.0, include_low=True),
        default=0.0,
        help="error of the written positions, m (default 0)",
    )
    sub.add_argument("--unknown-yaw", action="store_true", help="do not write the yaws")
    sub.add_argument("--seed", type=int, default=0, help="noise and layout seed (default 0)")
    sub.add_argument("--overwrite", action="store_true", help="replace an existing FILE")


def _simulate_moving_arguments(sub: argparse.ArgumentParser) -> None:
    """``simulate-moving``'s arguments."""
    add_out(sub, "dataset folder", required=True)
    sub.add_argument(
        "--duration",
        type=bounded_number("duration", "s", 1.0, 600.0, include_low=True),
        default=20.0,
        help="simulated time, s (default 20)",
    )
    _add_offset(sub, 0.02, "motion-capture clock minus car clock, s (default 0.02)")
    add_simulated_stations(sub, "base stations, 1..8 (default 1)")
    sub.add_argument("--seed", type=int, default=0, help="noise seed (default 0)")


def _write_calibration(
    out: Path,
    stations: Sequence[Any],
    photodiodes: Any,
    summary: dict[str, Any],
    markdown: Callable[[dict[str, Any], str], str],
    headline: str,
) -> Path:
    """A calibration's OUT/geometry.yaml, report.json and report.md (``markdown`` of the
    summary); print ``headline`` and where they are; return ``out``."""
    from crs_core.calibration.report import write_geometry, write_json

    write_geometry(out / "geometry.yaml", stations, photodiodes)
    Geometry(tuple(stations), tuple(photodiodes)).parameters().to_yaml(out / "params.yaml")
    write_json(out / "report.json", summary)
    (out / "report.md").write_text(markdown(summary, command_line()))
    print(headline)
    print(
        f"geometry: {out / 'geometry.yaml'} (--geometry), as parameters {out / 'params.yaml'} "
        f"(--params)  report: {out / 'report.md'}"
    )
    return out


def run_static(args: argparse.Namespace) -> Path:
    """The ``static`` mode; returns the output folder."""
    from crs_core.calibration.evaluation import n_sweep, point_reports, spread_order
    from crs_core.calibration.plots import static_figures
    from crs_core.calibration.points import load_points
    from crs_core.calibration.report import static_markdown, static_summary
    from crs_core.calibration.static import calibrate_static

    points = load_points(args.points_file)
    if args.stations is not None and args.stations > points.n_stations:
        raise ValueError(
            f"--stations: POINTS_FILE lists {points.n_stations} station(s); got {args.stations}"
        )
    calibration = calibrate_static(points, args.stations, args.fit_tilt)
    out = prepare_output(args.out, NAME, args.overwrite)
    reports = point_reports(points, calibration.stations, calibration.yaws)
    if args.no_sweep or len(points.points) < 5:
        rows, order = [], spread_order(np.array([p.position for p in points.points]))
    else:
        rows, order = n_sweep(points, None, args.stations, args.fit_tilt)
    summary = static_summary(points, calibration, reports, rows, order, args.fit_tilt)
    static_figures(out, summary, [r.fix for r in reports])
    error = summary["position_error_m"]
    headline = (
        f"calibrated {len(calibration.stations)} station(s) from {len(points.points)} points: "
        f"angle rms {1e3 * summary['angle_residual_rms_rad']:.3f} mrad, reprojected position "
        f"error mean {1e3 * error['mean']:.2f} mm, max {1e3 * error['max']:.2f} mm"
    )
    return _write_calibration(
        out, calibration.stations, points.photodiodes, summary, static_markdown, headline
    )


def run_moving(args: argparse.Namespace) -> Path:
    """The ``moving`` mode; returns the output folder."""
    from crs_core.calibration.evaluation import moving_fixes
    from crs_core.calibration.moving import calibrate_moving
    from crs_core.calibration.plots import moving_figures
    from crs_core.calibration.report import moving_markdown, moving_summary

    if abs(args.offset) > args.max_offset:
        raise ValueError(
            f"--offset: {args.offset} s lies outside +-{args.max_offset} s (--max-offset)"
        )
    dataset = load_recording(args.dataset, args)
    calibration = calibrate_moving(
        dataset,
        fit_offset=args.fit_offset,
        fit_photodiodes=args.fit_photodiodes,
        fit_tilt=args.fit_tilt,
        max_offset=args.max_offset,
        offset=args.offset,
    )
    out = prepare_output(args.out, NAME, args.overwrite)
    fixes = moving_fixes(calibration)
    summary = moving_summary(
        calibration, fixes, args.fit_offset, args.fit_photodiodes, args.fit_tilt
    )
    moving_figures(out, calibration, fixes)
    headline = (
        f"calibrated {len(calibration.stations)} station(s) from {summary['sweeps']} sweeps: "
        f"clock offset {1e3 * calibration.offset:.2f} ± {1e3 * calibration.offset_std:.2f} ms, "
        f"angle rms {1e3 * summary['angle_residual_rms_rad']:.3f} mrad, pose-fix error median "
        f"{1e3 * summary['pose_fix_error_m']['median']:.2f} mm"
    )
    return _write_calibration(
        out, calibration.stations, calibration.fit.photodiodes, summary, moving_markdown, headline
    )


def run_simulate_points(args: argparse.Namespace) -> Path:
    """The ``simulate-points`` mode; returns the points file."""
    from crs_core.calibration.report import write_geometry
    from crs_core.model.chronos import default_base_stations
    from crs_core.model.lighthouse import RECORDED_PHOTODIODES
    from sim.static_points import grid_layout, simulate_static_points

    if args.file.suffix not in (".yaml", ".yml"):
        raise ValueError(f"FILE: {args.file} should end in .yaml")
    truth = args.file.with_name(args.file.stem + "_truth.yaml")
    prepare_output_file(args.file, args.overwrite, "FILE")
    prepare_output_file(truth, args.overwrite, "FILE")
    stations = default_base_stations(args.stations)
    positions, yaws = grid_layout(args.points, seed=args.seed)
    points = simulate_static_points(
        stations,
        positions,
        yaws,
        sweeps=args.sweeps,
        seed=args.seed,
        yaw_known=not args.unknown_yaw,
        position_std=args.position_std,
    )
    points.save(args.file)
    write_geometry(truth, stations, RECORDED_PHOTODIODES)
    print(f"points: {args.file}  true geometry: {truth}")
    return args.file


def run_simulate_moving(args: argparse.Namespace) -> Path:
    """The ``simulate-moving`` mode; returns the dataset folder."""
    from crs_core.model.chronos import default_base_stations
    from sim.mocap_recording import simulate_mocap_recording

    out = prepare_output(args.out, NAME, args.overwrite)
    dataset = simulate_mocap_recording(
        duration=args.duration,
        clock_offset=args.offset,
        stations=list(default_base_stations(args.stations)),
        seed=args.seed,
    )
    dataset.save(out)
    print(
        f"dataset: {out}  ({len(dataset.measurements or [])} measurements, clock offset "
        f"{1e3 * args.offset:.1f} ms; true geometry in dataset.yaml)"
    )
    return out


COMMAND = Command(
    NAME,
    help="calibrate Lighthouse base stations (static points or a moving recording)",
    description=__doc__.split("\n\n")[1] if __doc__ else None,
    subcommands=(
        Command(
            "static",
            help="base stations from sweeps at known static poses",
            description="Fit every base station (rotation, position; the tilt offsets dt1, dt2 "
            "the file does not give, all of them with --fit-tilt) to the sweeps recorded at "
            "known car poses, using every photodiode angle. The file need give no station "
            "geometry: without its stations list the stations are those its sweeps name. Writes "
            "DIR/geometry.yaml (for --geometry), params.yaml (the same as parameters, for "
            "--params), report.md, report.json, angle_residuals.png, position_residuals.png, "
            "residual_vs_n.png.",
            arguments=_static_arguments,
            handler=run_static,
        ),
        Command(
            "moving",
            help="base stations (and clock offset, photodiodes) from a recording with mocap poses",
            description="Fit the base stations to every sweep of a recording (dataset folder or "
            "bag) that holds motion-capture poses (sensor 'pose'); inputs, IMU and encoders may "
            "be absent. Its geometry may give the photodiodes alone (geometry: {photodiodes: "
            "[[x, y] x 4]}, a bag's through --geometry): no prior station geometry is needed; "
            "tilt offsets it does not give are fitted. Writes DIR/geometry.yaml (for "
            "--geometry), params.yaml (the same as parameters, for --params), report.md, "
            "report.json, moving_residuals.png and, with --fit-offset, offset_scan.png.",
            arguments=_moving_arguments,
            handler=run_moving,
        ),
        Command(
            "simulate-points",
            help="write a simulated POINTS_FILE (and its true geometry)",
            description="Simulate the car standing at N well-spread poses on the demo-track "
            "area with the simulator's Lighthouse noise (1 mrad per sweep); writes FILE and "
            "FILE's stem + '_truth.yaml' (the true geometry).",
            arguments=_simulate_points_arguments,
            handler=run_simulate_points,
        ),
        Command(
            "simulate-moving",
            help="write a simulated recording with mocap poses and a clock offset",
            description="Drive the demo track in the simulator and write a dataset folder with "
            "only Lighthouse sweeps and motion-capture poses (100 Hz, 0.5 mm), the "
            "motion-capture clock --offset s ahead of the car's.",
            arguments=_simulate_moving_arguments,
            handler=run_simulate_moving,
        ),
    ),
    dest="mode",
)
