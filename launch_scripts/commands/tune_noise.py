"""``crs tune-noise``: the estimators' process noise fitted to a recording of the car, written
into a parameter YAML every estimator then reads."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

import yaml

from crs_core.errors import FieldError
from launch_scripts.arguments import Command, add_model, add_out, command_line
from launch_scripts.output_folder import prepare_output
from launch_scripts.recording import RECORDING_HELP, add_bag_options, load_recording


def tune_noise(args: argparse.Namespace) -> None:
    """Fit the process noise (``crs_core.estimation.noise_fit``) and write the outputs."""
    from crs_core.estimation import parse_sensor_set
    from crs_core.estimation.noise import noise_in_file, with_noise
    from crs_core.estimation.noise_fit import NoiseFitSettings, fit_process_noise
    from crs_core.estimation.offline import dataset_model
    from crs_core.yaml_io import load_yaml

    try:
        settings = NoiseFitSettings(
            groups=tuple(g.strip() for g in args.fit.split(",")), sensors=args.sensors
        )
    except FieldError as error:
        raise error.renamed("--fit") from None
    if args.sensors != "auto":
        try:
            parse_sensor_set(args.sensors)
        except FieldError as error:
            raise error.renamed("--sensors") from None
    try:
        start = noise_in_file(args.params)
    except FieldError as error:
        raise error.renamed(f"--params: {error.field}") from None
    document: dict[str, Any] = {"parameters": {}}
    if args.params is not None:
        try:
            document = load_yaml(args.params.read_text())
        except (OSError, yaml.YAMLError) as error:
            raise ValueError(f"--params: cannot read {args.params} ({error})") from None
    dataset = load_recording(args.dataset, args)
    try:
        model = dataset_model(dataset, args.params, model=args.model)
    except FieldError as error:
        raise error.renamed(f"--params: {error.field}") from None
    out = prepare_output(Path(args.out), "tune-noise", args.overwrite)
    fit = fit_process_noise(
        dataset, model, start, settings, progress=lambda line: print(f"[tune-noise] {line}")
    )
    document = with_noise(document, fit.noise, ["process_std"])
    (out / "params.yaml").write_text(
        f"# crs tune-noise: {command_line()}\n" + yaml.safe_dump(document, sort_keys=False)
    )
    report = {"command": command_line(), "dataset": str(args.dataset), **fit.to_dict()}
    (out / "noise_fit.json").write_text(json.dumps(report, indent=2))
    write_figure(report, out / "noise_fit.png")
    gain = fit.log_likelihood - fit.start_log_likelihood
    scales = ", ".join(f"{group} x {scale:.3g}" for group, scale in fit.scales.items())
    print(
        f"process_std {', '.join(f'{v:.4g}' for v in fit.noise.process_std)} ({scales}; "
        f"log-likelihood +{gain:.1f} over the start in {fit.updates} innovations); wrote "
        f"{out / 'params.yaml'}",
        file=sys.stdout,
    )


def write_figure(report: dict[str, Any], path: Path) -> None:
    """The log-likelihood over the scale of each group fitted (the chosen scale marked)."""
    from matplotlib.figure import Figure

    groups = list(report["scales"])
    fig = Figure(figsize=(5 * len(groups), 3.6), layout="constrained")
    axes = fig.subplots(1, len(groups), squeeze=False)
    for ax, group in zip(axes[0], groups, strict=True):
        points = sorted(
            (e["scale"], e["log_likelihood"]) for e in report["evaluations"] if e["group"] == group
        )
        ax.semilogx([p[0] for p in points], [p[1] for p in points], "o-")
        ax.axvline(report["scales"][group], color="k", linestyle="--", label="chosen")
        ax.set_xlabel(f"scale of the {group} process noise")
        ax.set_ylabel("innovation log-likelihood")
        ax.legend()
    fig.savefig(path, dpi=110)


def add_arguments(sub: argparse.ArgumentParser) -> None:
    """``crs tune-noise``'s arguments."""
    sub.add_argument("dataset", type=Path, help=RECORDING_HELP)
    add_bag_options(sub)
    sub.add_argument(
        "--params",
        type=Path,
        help="the car's parameter YAML (its noise: section, if any, is the start); the output "
        "is a copy of it with the fitted noise",
    )
    add_model(sub)
    sub.add_argument(
        "--fit",
        default="pose",
        help="process-noise groups fitted, comma-separated: pose (x, y, yaw), velocity (vx, vy, "
        "omega) (default pose)",
    )
    sub.add_argument(
        "--sensors",
        default="auto",
        help="sensor groups the EKF uses, joined by '+' (default auto: those the recording has)",
    )
    add_out(sub, "output folder: params.yaml, noise_fit.json, noise_fit.png", required=True)


COMMAND = Command(
    "tune-noise",
    help="fit the estimators' process noise to a recording",
    description="Choose the estimators' process noise that makes a recording most likely (the "
    "EKF's innovation log-likelihood) and write DIR/params.yaml (the --params file with a "
    "noise: section every estimator reads), DIR/noise_fit.json and DIR/noise_fit.png "
    "(docs/estimate.md).",
    arguments=add_arguments,
    handler=tune_noise,
)
