"""``crs plan-drive``: design a drive that decides the parameters a recording left open.

Argument parsing, files and the figure only; the design is
:mod:`crs_core.discrepancy.drive_design`, the drive file :mod:`crs_core.discrepancy.drive_file`.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from crs_core.errors import FieldError
from launch_scripts.arguments import (
    Command,
    add_evaluations,
    add_out,
    add_process_scale,
    add_seed,
    add_track,
    bounded_number,
)
from launch_scripts.output_folder import prepare_output

if TYPE_CHECKING:
    from crs_core.model import CarModel


def parse_open(text: str) -> tuple[str, ...]:
    """``--open a,b,c``: the names, each once."""
    names = tuple(part.strip() for part in text.split(",") if part.strip())
    if not names:
        raise FieldError("--open", "name at least one parameter")
    if len(set(names)) != len(names):
        raise FieldError("--open", "a parameter is named twice")
    return names


def load_result(path: Path) -> dict[str, Any] | None:
    """The ``result.json`` of ``crs sysid`` beside a ``params.yaml`` (None without one)."""
    result = path.parent / "result.json"
    if not result.is_file():
        return None
    try:
        document = json.loads(result.read_text())
        names = document["correlation"]["names"]
        std = [document["parameters"][n]["std"] for n in names]
        matrix = np.asarray(document["correlation"]["matrix"], dtype=float)
    except (ValueError, KeyError, TypeError) as error:
        raise FieldError(str(result), f"not a crs sysid result.json ({error})") from None
    return {"path": str(result), "names": names, "std": std, "correlation": matrix}


def design_inputs(
    params: Path, open_text: str
) -> tuple[CarModel, tuple[str, ...], tuple[str, ...], np.ndarray, str]:
    """What a design starts from: the model of ``params`` with the open effects added, the open
    names, the parameters fitted, their prior covariance (the identification's beside
    ``params`` when there is one) and where that came from. Errors name ``--params`` or
    ``--open``."""
    from crs_core.discrepancy.drive_design import (
        planned_fit,
        prior_covariance,
        prior_from,
        with_open_effects,
    )
    from crs_core.identification.problem import check_fit
    from crs_core.model import CarModel
    from crs_core.model.bicycle import DynamicBicycle
    from crs_core.model.car_model import effects_in_file

    if params.is_dir():
        raise FieldError("--params", f"{params} is a folder, not a parameter YAML")
    model = CarModel.from_file(params, effects_in_file(params))
    if not isinstance(model.plant, DynamicBicycle):
        raise FieldError(
            "--params",
            f"plan-drive designs drives that tell the dynamic bicycle's tyres apart; model "
            f"{model.plant.name} has no tyres",
        )
    open_names = parse_open(open_text)
    try:
        model = with_open_effects(model, open_names)
    except FieldError as error:
        raise error.renamed("--open") from None
    fit = planned_fit(model, open_names)
    try:
        check_fit(model, fit)  # what the FIE cannot fit, no drive decides
    except FieldError as error:
        raise error.renamed("--open") from None
    result = load_result(params)
    if result is not None:
        prior = prior_from(model, fit, result["names"], result["std"], result["correlation"])
        source = f"{result['path']} (the identification's sigmas and correlations)"
    else:
        prior = prior_covariance(model, fit)
        source = f"{params} (each parameter's prior_std, no correlations)"
    return model, open_names, fit, prior, source


def run_plan_drive(args: argparse.Namespace) -> int:
    """``crs plan-drive``: design, then write drive.yaml, report.json and drive.png."""
    from crs_core.discrepancy.drive_design import DesignSettings, design_drive
    from crs_core.discrepancy.drive_reach import drive_summary
    from crs_core.track import load_demo_track
    from crs_core.track.yaml_file import read_track

    model, open_names, fit, prior, source = design_inputs(args.params, args.open)
    track = read_track(args.track) if args.track else load_demo_track()
    settings = DesignSettings(
        duration_s=args.duration,
        segment_s=args.segment,
        v_ref=args.v_ref,
        process_scale=args.process_scale,
        evaluations=args.evaluations,
        seed=args.seed,
    )
    out = prepare_output(args.out, "plan-drive", args.overwrite)

    def progress(count: int, best: float) -> None:
        if count % 50 == 0:
            print(f"plan-drive: {count} drives, best {best:.4f}", file=sys.stderr, flush=True)

    design = design_drive(model, fit, open_names, prior, track, settings, progress)
    design.drive.save(out / "drive.yaml")
    summary = drive_summary(design, model, track, settings.track_margin)
    report = {
        "params": str(args.params),
        "prior": source,
        "open": list(open_names),
        "fit": list(fit),
        **summary,
    }
    (out / "report.json").write_text(json.dumps(report, indent=2))
    plot_drive(design, track, out / "drive.png")
    for name, row in summary["sigma"].items():
        print(f"plan-drive: {name}: sigma {row['before']:.4g} -> {row['after']:.4g} (predicted)")
    limited = ", ".join(summary["limited_by"]) or "nothing"
    print(
        f"plan-drive: rear grip {summary['grip_used_max']['rear']:.2f}, rear peak slip "
        f"{summary['peak_slip_fraction_max']['rear']:.2f}; limited by {limited}; wrote "
        f"{out}/drive.yaml, report.json, drive.png"
    )
    return 0


def plot_drive(design: Any, track: Any, path: Path) -> None:
    """The drive's path on the track and its commands over time."""
    from matplotlib.figure import Figure

    samples = design.samples
    fig = Figure(figsize=(11, 4.2))
    ax, bx = fig.subplots(1, 2)
    left, right = track.borders()
    for edge in (left, right):
        ax.plot(*np.vstack([edge, edge[:1]]).T, color="0.5", lw=0.8)
    ax.plot(samples.x[:, 0], samples.x[:, 1], lw=1.2, label="drive (model)")
    ax.plot(*samples.x[0, :2], "o", color="C2", label="start")
    out = ~samples.in_view
    if out.any():
        ax.plot(samples.x[out, 0], samples.x[out, 1], "x", color="C3", label="out of view")
    ax.set_aspect("equal")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.legend(loc="best", fontsize=8)
    bx.plot(samples.t, samples.u[:, 0], label="steer (rad)")
    bx.plot(samples.t, samples.u[:, 1], label="torque (-)")
    bx.plot(samples.t, samples.x[:, 3], label="v_x (m/s)", alpha=0.7)
    bx.set_xlabel("t (s)")
    bx.legend(loc="best", fontsize=8)
    sigma = design.sigma(after=False), design.sigma()
    title = ", ".join(f"{n} σ {sigma[0][n]:.3g}→{sigma[1][n]:.3g}" for n in design.open)
    fig.suptitle(f"{design.drive.kind} drive: {title}", fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def add_plan_drive_arguments(sub: argparse.ArgumentParser) -> None:
    """``crs plan-drive``'s arguments."""
    sub.add_argument(
        "--params",
        type=Path,
        required=True,
        help="parameter YAML of the model (a crs sysid params.yaml: its result.json beside it "
        "gives the sigmas and correlations)",
    )
    sub.add_argument(
        "--open",
        required=True,
        help="comma-separated parameters to decide, e.g. Dr,Br,tau_motor (an effect's "
        "parameter switches the effect on at its default)",
    )
    add_out(sub, "output folder", required=True)
    add_track(sub)
    sub.add_argument(
        "--duration",
        type=bounded_number("duration", "s", 0.5, 60.0),
        default=8.0,
        help="length of the drive, s (default 8)",
    )
    sub.add_argument(
        "--segment",
        type=bounded_number("segment", "s", 0.05, 10.0),
        default=0.25,
        help="each command offset held this long, s (default 0.25)",
    )
    sub.add_argument(
        "--v-ref",
        type=bounded_number("v-ref", "m/s", 0.2, 5.0),
        default=1.2,
        help="the path follower's speed reference during the drive, m/s (default 1.2)",
    )
    add_evaluations(sub, "the search")
    add_process_scale(
        sub,
        "the FIE's process-noise scale the prediction assumes (default 1.0, real data; 0.1 "
        "for simulated)",
    )
    add_seed(sub, "seed of the search's random starts")


COMMAND = Command(
    "plan-drive",
    help="design a drive that decides open parameters (D-optimal, on the track)",
    description="Design a drive (the path follower plus command offsets) that decides the "
    "--open parameters of the model in --params: D-optimal over them with the others refitted, "
    "the FIE's information predicted from the model's Jacobians, staying on the track and in "
    "the Lighthouse's view. Writes OUT/drive.yaml (for crs launch --drive), report.json "
    "(sigma before / after per open parameter, grip and peak slip reached, what limited the "
    "drive) and drive.png.",
    arguments=add_plan_drive_arguments,
    handler=run_plan_drive,
)
