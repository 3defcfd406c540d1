"""``crs estimate``: an EKF or MHE over a recording (dataset folder or bag), offline."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import yaml

from crs_core.errors import FieldError, parse_finite
from crs_core.estimation import INPUT_MODES, KINDS, parse_sensor_set
from launch_scripts.arguments import Command, add_model, add_out, bounded_number, command_line
from launch_scripts.output_folder import prepare_output
from launch_scripts.recording import RECORDING_HELP, add_bag_options, load_recording

if TYPE_CHECKING:
    from crs_core.dataset import Dataset
    from crs_core.model import CarModel


def parse_x0(text: str | None) -> np.ndarray | None:
    """``--x0 x,y,yaw`` or ``x,y,yaw,vx,vy,omega`` (SI units); ValueError naming ``--x0``."""
    from crs_core.estimation.offline import initial_state

    if text is None:
        return None
    try:
        values = np.array([float(v) for v in text.split(",")])
        initial_state(values)
    except ValueError:
        raise ValueError(
            f"--x0: {text!r} must be 3 (x,y,yaw) or 6 (x,y,yaw,vx,vy,omega) finite numbers "
            "separated by commas"
        ) from None
    return values


def parse_rate(text: str | None) -> float | None:
    """``--rate HZ``: a finite number > 0; ValueError naming ``--rate``."""
    if text is None:
        return None
    rate = parse_finite(text)
    if rate is None or not rate > 0:
        raise ValueError(f"--rate: must be a finite number of Hz > 0, got {text!r}")
    return rate


def estimate(args: argparse.Namespace) -> None:
    """``crs estimate``: an estimator over a dataset; estimates, diagnostics and a figure."""
    from tqdm import tqdm

    from crs_core.estimation import EkfSettings, MheSettings
    from crs_core.estimation.noise import noise_in_file
    from crs_core.estimation.offline import (
        data_span,
        dataset_model,
        estimate_dataset,
        rate_stamps,
        reference_comparison,
        stamps_within,
    )
    from crs_core.model.online import parse_online_names
    from crs_core.model.plants import plant_spec
    from launch_scripts.estimate_report import format_summary, write_figure, write_online_figure

    x0 = parse_x0(args.x0)
    rate = parse_rate(args.rate)
    online = ()
    if args.online_params is not None:
        try:
            online = parse_online_names(args.online_params)
        except FieldError as error:
            raise error.renamed("--online-params") from None
    if args.sensors != "auto":
        try:
            parse_sensor_set(args.sensors)
        except FieldError as error:
            raise error.renamed("--sensors") from None
    dataset = load_recording(args.dataset, args)
    at = None
    if args.at is not None:  # checked before --out is touched
        try:
            span = data_span(dataset, with_inputs=args.inputs != "estimated")
            at, outside = stamps_within(_stamps(args.at), *span)
        except FieldError as error:
            raise error.renamed("--at") from None
        if outside:
            print(
                f"warning: --at: {outside} of {outside + len(at)} stamps lie outside the data "
                f"({span[0]:.3f} .. {span[1]:.3f} s) and are left out",
                file=sys.stderr,
            )
    elif args.output_rate is not None:
        at = rate_stamps(dataset, args.output_rate)
    try:
        model = dataset_model(dataset, args.params, model=args.model)
    except yaml.YAMLError as error:
        problem = str(error).splitlines()[0]
        raise ValueError(f"--params: {args.params} is not valid YAML ({problem})") from None
    except KeyError as error:
        raise ValueError(f"--params: {error.args[0]}") from None
    except OSError as error:
        raise ValueError(f"--params: cannot read {args.params} ({error.strerror})") from None
    try:
        noise = noise_in_file(args.params)
    except FieldError as error:
        raise error.renamed(f"--params: {error.field}") from None
    settings = (
        MheSettings(rate_hz=rate or MheSettings().rate_hz, noise=noise, online_parameters=online)
        if args.estimator == "mhe"
        else EkfSettings(noise=noise, online_parameters=online)
    )
    try:  # the model with its online parameters, before --out is touched
        online_model = model.with_online(online, settings.online_reversion_s)
    except FieldError as error:
        raise error.renamed("--online-params") from None
    if online:
        _check_reach(online_model, dataset, args.sensors)
    out = prepare_output(Path(args.out), "estimate", args.overwrite)
    name = Path(args.dataset).resolve().name
    with tqdm(total=1000, desc=f"estimate {name}", file=sys.stderr, disable=None) as bar:
        try:
            result = estimate_dataset(
                dataset,
                args.estimator,
                args.sensors,
                model=model,
                settings=settings,
                inputs=args.inputs,
                x0=x0,
                progress=lambda fraction: bar.update(round(1000 * fraction) - bar.n),
                at=at,
            )
        except FieldError as error:  # name the option, not the argument of the function
            at_option = "--at" if args.at is not None else "--output-rate"
            options = {"x0": "--x0", "rate_hz": "--rate", "sensors": "--sensors", "at": at_option}
            raise error.renamed(options.get(error.field, error.field)) from None
    comparison = reference_comparison(result, dataset)
    result.save_npz(out / "estimates.npz")
    report = {
        "command": command_line(),
        "dataset": str(Path(args.dataset).resolve()),
        "params": str(args.params) if args.params else None,
        "model": plant_spec(model.plant),
        **result.diagnostics,
        "reference": comparison,
    }
    (out / "diagnostics.json").write_text(json.dumps(report, indent=2) + "\n")
    duration = float(result.t[-1] - result.t[0])
    title = (
        f"{name}: {args.estimator.upper()} on {result.diagnostics['sensors']}, inputs "
        f"{args.inputs}, {'blind start' if x0 is None else 'given x0'}"
    )
    write_figure(result, dataset, out / "estimate.png", title)
    print(format_summary(name, result.diagnostics, comparison, duration))
    written = "diagnostics.json, estimate.png"
    if online:
        priors = result.estimator.model.online.priors
        result.online.write_csv(out / "online_parameters.csv", result.t - result.t[0], priors)
        write_online_figure(result, out / "online_parameters.png", name)
        for parameter, final in result.diagnostics["online_parameters"].items():
            state = "informed" if final["informed"] else "not informed by the data"
            print(f"  {parameter}: {final['value']:.6g} ± {final['std']:.2g} at the end ({state})")
        written += ", online_parameters.csv, online_parameters.png"
    print(f"wrote {out / 'estimates.npz'}, {written}")


def _stamps(path: Path) -> np.ndarray:
    """``--at FILE``: the stamps in a ``.npy`` file (checked by the estimator: ``--at: ...``)."""
    try:
        return np.load(path, allow_pickle=False)
    except (OSError, ValueError, EOFError) as error:
        problem = str(error).splitlines()[0] if str(error) else type(error).__name__
        raise FieldError("--at", f"{path}: not a readable .npy array ({problem})") from None


def add_arguments(sub: argparse.ArgumentParser) -> None:
    """``crs estimate``'s arguments."""
    sub.add_argument("dataset", type=Path, help=RECORDING_HELP)
    add_bag_options(sub)
    sub.add_argument("--estimator", choices=KINDS, required=True, help="EKF or MHE")
    add_model(sub)
    sub.add_argument(
        "--sensors",
        default="auto",
        help="sensor groups joined by '+' from lh, imu, gyro, we, pose (default auto: the "
        "groups among lh, imu, gyro, we the dataset has)",
    )
    sub.add_argument(
        "--inputs",
        choices=INPUT_MODES,
        default="auto",
        help="commanded inputs: auto (use them if recorded), commanded (required), estimated "
        "(withheld; steering and torque estimated)",
    )
    sub.add_argument(
        "--x0",
        metavar="x,y,yaw[,vx,vy,omega]",
        help="initial state at the first stamp (m, rad, m/s, rad/s); default: blind start "
        "from the Lighthouse",
    )
    sub.add_argument(
        "--rate", metavar="HZ", help="MHE grid rate, Hz (default 60; the EKF has no grid)"
    )
    sub.add_argument(
        "--online-params",
        metavar="NAMES",
        help="parameters estimated online beside the state, comma-separated: model parameters "
        "(Cm1, an effect's gyro_bias, ...) or grip (both tyre peaks scaled together); writes "
        "online_parameters.csv (t, name, value, std) and online_parameters.png",
    )
    sub.add_argument(
        "--params",
        type=Path,
        help="parameter YAML applied to the model, its noise: section (crs tune-noise) to the "
        "estimator (default: the Chronos parameters with the dataset's Lighthouse geometry)",
    )
    when = sub.add_mutually_exclusive_group()
    when.add_argument(
        "--at",
        type=Path,
        metavar="TIMES.npy",
        help="estimate at these stamps (s, the recording's clock; strictly increasing; e.g. a "
        "motion-capture clock) instead of the recording's samples; stamps outside the data are "
        "left out with a warning",
    )
    when.add_argument(
        "--output-rate",
        type=bounded_number("output-rate", "Hz", 0.0),
        metavar="HZ",
        help="estimate every 1/HZ s from the first sample to the last instead",
    )
    add_out(sub, "output folder", required=True)


COMMAND = Command(
    "estimate",
    help="run an EKF or MHE over a recording (offline)",
    description="Run an EKF or MHE over a dataset folder (crs_core.dataset format) or a bag and "
    "write DIR/estimates.npz (t, x (6, N), status 0 ok / 1 degraded / 2 lost, "
    "covariance_diag), DIR/diagnostics.json and DIR/estimate.png.",
    arguments=add_arguments,
    handler=estimate,
)


def _check_reach(model: CarModel, dataset: Dataset, sensors: str) -> None:
    """Refuse (naming ``--online-params``) an online parameter no chosen sensor could inform;
    sensors that do not parse are left to the estimator's own message."""
    from crs_core.estimation.factory import check_online_reach
    from crs_core.estimation.offline import available_sensors

    try:
        chosen = available_sensors(dataset, model) if sensors == "auto" else sensors
        groups = parse_sensor_set(chosen)
    except FieldError:
        return
    try:
        check_online_reach(model, groups)
    except FieldError as error:
        raise error.renamed("--online-params") from None
