"""``crs sysid``, ``crs validate`` and the identification benchmark (``crs bench sysid``).

Argument parsing and file handling only; the algorithms are in :mod:`crs_core.identification`.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from crs_core.identification.data import FieData
from crs_core.identification.models import identification_model
from crs_core.identification.problem import DEFAULT_FIT, FieSettings, default_fit
from crs_core.model import CarModel
from crs_core.model.car_model import effects_in_file
from crs_core.model.plants import plant_spec
from launch_scripts.arguments import (
    Command,
    add_effect,
    add_model,
    add_out,
    add_process_scale,
    bounded_number,
)
from launch_scripts.output_folder import prepare_output
from launch_scripts.recording import RECORDING_HELP, add_bag_options, load_recording


def parse_fit(text: str | None, model: CarModel) -> tuple[str, ...]:
    """``--fit a,b,c`` (default: :func:`~crs_core.identification.problem.default_fit`, for the
    dynamic bicycle the 15 dynamics parameters, the wheel encoders' ``r`` and ``b_car``, and
    every effect parameter)."""
    if text is None:
        return default_fit(model)
    names = tuple(part.strip() for part in text.split(",") if part.strip())
    if not names:
        raise ValueError("--fit: name at least one parameter")
    for name in names:
        if name not in model.parameters:
            raise ValueError(
                f"--fit: unknown parameter {name!r} (the model has {', '.join(model.parameters)})"
            )
    if len(set(names)) != len(names):
        raise ValueError("--fit: a parameter is named twice")
    return names


def add_fit(parser: argparse.ArgumentParser, what: str) -> None:
    """``--fit a,b,c`` (:func:`parse_fit`): ``what`` they are, and the default."""
    parser.add_argument(
        "--fit",
        help=f"{what} (default: the model's own list, for the dynamic model the 15 dynamics "
        f"parameters and the wheel encoders' radius and track width, {','.join(DEFAULT_FIT)}, "
        "plus every --effect parameter)",
    )


def run_sysid(args: argparse.Namespace) -> int:
    """``crs sysid``: identify, write params.yaml, result.json, report.md and figures."""
    from crs_core.identification.report import write_sysid_report
    from crs_core.identification.solve import identify, stderr_progress

    dataset = load_recording(args.dataset, args)
    model = identification_model(dataset, args.effect or [], args.params, "--params", args.model)
    settings = FieSettings(
        fit=parse_fit(args.fit, model),
        hessian=args.hessian,
        starts=args.starts,
        process_scale=args.process_scale,
    )
    FieData.from_dataset(dataset, settings.noise)  # refuse bad data before touching --out
    out = prepare_output(args.out, "sysid", args.overwrite)
    result = identify(dataset, model, settings, progress=stderr_progress)
    summary = write_sysid_report(result, out, str(args.dataset))
    for warning in summary["warnings"]:
        print(f"warning: {warning}", file=sys.stderr)
    print(
        f"sysid: {result.solver_status}, {result.iterations} iterations, {result.time_s:.1f} s; "
        f"cost {result.cost_initial:.6g} -> {result.cost:.6g}; wrote {out}/params.yaml, "
        "result.json, report.md"
    )
    return 0


def run_validate(args: argparse.Namespace) -> int:
    """``crs validate``: open-loop predictions with --params (and --prior) on a dataset."""
    from crs_core.identification.reference import position_reference
    from crs_core.identification.report import write_validation_report
    from crs_core.identification.validation import validate

    dataset = load_recording(args.dataset, args)
    effects = list(
        dict.fromkeys([*(e for e, _, _ in args.effect or []), *effects_in_file(args.params)])
    )
    model = identification_model(dataset, effects, args.params, "--params", args.model)
    prior = None
    if args.prior is not None:
        given = identification_model(
            dataset, effects, args.prior, "--prior", plant_spec(model.plant)
        ).parameters
        # a term of --params the prior lacks is at 0 there (no term)
        absent = {
            n: 0.0 for t in model.terms for n in t.coefficient_names() if n not in given.names
        }
        prior = model.parameters.updated(
            {**{n: given.value(n) for n in given.names if n in model.parameters.names}, **absent}
        )
    span = dataset.t[-1] - dataset.t[0] if len(dataset.t) else 0.0
    if args.horizon > span:
        raise ValueError(f"--horizon: {args.horizon:g} s is longer than the dataset ({span:.2f} s)")
    out = prepare_output(args.out, "validate", args.overwrite)
    summary, predictions = validate(dataset, model, model.parameters, prior, args.horizon)
    summary["dataset"] = str(args.dataset)
    summary["params"] = str(args.params)
    summary["prior"] = None if args.prior is None else str(args.prior)
    write_validation_report(summary, predictions, position_reference(dataset).xy, out)
    rmse = summary["position_rmse_m"]
    print(
        f"validate: {summary['horizon_s']:g} s open-loop position RMSE "
        + ", ".join(f"{k} {v:.3f} m" for k, v in rmse.items())
        + f"; wrote {out}/validation.json"
    )
    return 0


def add_sysid_arguments(sub: argparse.ArgumentParser) -> None:
    """``crs sysid``'s arguments."""
    sub.add_argument("dataset", type=Path, help=RECORDING_HELP)
    add_bag_options(sub)
    add_out(sub, "output folder", required=True)
    sub.add_argument(
        "--params",
        help="prior parameter YAML ('parameters:' mapping), or 'rough' for the rough prior of "
        "the real recordings' README (default: the Chronos identified values)",
    )
    add_fit(sub, "comma-separated parameter names to identify")
    add_effect(sub, "add a model effect (repeatable)")
    add_model(sub)
    sub.add_argument(
        "--starts",
        type=bounded_number("starts", "", 1, kind=int, include_low=True),
        default=1,
        help="solver starts: the prior, then draws from it (default 1)",
    )
    sub.add_argument(
        "--hessian",
        choices=["gauss-newton", "exact"],
        default="gauss-newton",
        help="IPOPT Hessian (default gauss-newton: faster here, see the README)",
    )
    add_process_scale(
        sub,
        "factor on the estimator's process noise std for the FIE's Q (default 1.0, best on the "
        "real runs; 0.1 on simulated data, whose truth has no process noise)",
    )


def add_validate_arguments(sub: argparse.ArgumentParser) -> None:
    """``crs validate``'s arguments."""
    sub.add_argument("dataset", type=Path, help=RECORDING_HELP)
    add_bag_options(sub)
    sub.add_argument("--params", required=True, help="parameter YAML to validate (or 'rough')")
    sub.add_argument("--prior", help="a second parameter YAML shown side by side (or 'rough')")
    sub.add_argument(
        "--horizon",
        type=bounded_number("horizon", "s", 0.0),
        default=2.0,
        help="open-loop horizon, s (default 2.0, the paper's)",
    )
    add_effect(sub, "model effect (repeatable; inferred from --params)")
    add_model(sub)
    add_out(sub, "output folder", required=True)


SYSID = Command(
    "sysid",
    help="identify model parameters from a dataset (FIE, IPOPT)",
    description="Full-information estimation of the model parameters (paper Sec. IV-B) on "
    "a dataset folder or a bag: states on every sample, RK4 defects as process noise, every sensor "
    "the dataset has, priors from the parameter set. Writes OUT/params.yaml (loadable by "
    "--params of every command), result.json, report.md and figures; one progress line per "
    "IPOPT iteration on stderr.",
    arguments=add_sysid_arguments,
    handler=run_sysid,
)
VALIDATE = Command(
    "validate",
    help="open-loop prediction error of parameters on a dataset",
    description="Predict open loop over --horizon from every sample (start state from an "
    "EKF with the same parameters) and compare with the recording's reference positions "
    "(simulation truth, or on real runs the Lighthouse-based on-line estimate, not motion "
    "capture; without reference states, each sample's Lighthouse fix) and measurements. "
    "Writes OUT/validation.json, validation.md, validation.png.",
    arguments=add_validate_arguments,
    handler=run_validate,
)
