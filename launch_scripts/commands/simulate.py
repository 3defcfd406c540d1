"""``crs sim`` and ``crs demo``: the ROS-free simulator with the path follower in the loop."""

from __future__ import annotations

import argparse
import sys
import time
from collections.abc import Sequence
from functools import partial
from pathlib import Path

from crs_core.control.path_following import PathFollowerSettings
from crs_core.errors import FieldError
from crs_core.model import EFFECTS, CarModel
from crs_core.model.effects import effect_spec
from crs_core.model.plants import load_plant, resolve_model
from launch_scripts.arguments import (
    Command,
    add_duration,
    add_effect,
    add_model,
    add_out,
    add_seed,
    add_simulated_stations,
    add_track,
    argument_type,
    bounded_number,
)
from launch_scripts.output_folder import prepare_output
from sim.sensors import SensorSuite, parse_blackout

#: The effects and their parameters (name, unit, default), for ``--help``.
EFFECTS_EPILOG = "effects (--effect NAME[.PARAM][=VALUE]; parameter, unit, default):\n" + "\n".join(
    f"  {effect.name:20s} "
    + "; ".join(f"{p.name} [{p.unit}] {p.value:g}: {p.description}" for p in effect.parameters)
    for effect in EFFECTS.values()
)


def build_model(
    effects: Sequence[tuple[str, str | None, float | None]],
    stations: int,
    params_yaml: Path | None,
    option: str = "--params",
    model: str | None = None,
) -> CarModel:
    """The car model ``model`` (a spec; by default the one ``params_yaml`` names, else the
    dynamic bicycle) with ``effects``, ``stations`` base stations and the parameters of
    ``params_yaml`` (``None``: the model's defaults); a bad file names ``option``, a model
    that contradicts it ``--model``."""
    plant = load_plant(resolve_model(model, params_yaml))
    try:
        return CarModel.from_file(params_yaml, effect_spec(effects), stations, plant)
    except (ValueError, KeyError) as error:
        message = error.args[0] if isinstance(error, KeyError) else str(error)
        raise FieldError(option, str(message)) from None


def simulate(args: argparse.Namespace) -> Path:
    """Run the closed-loop simulation and write the dataset (and report) to ``args.out``."""
    from crs_core.control.path_following import PathFollower
    from crs_core.track import load_demo_track, read_track
    from sim.report import write_report
    from sim.simulator import Simulator

    track = read_track(args.track) if args.track else load_demo_track()
    model = build_model(args.effect or [], args.stations, args.params, model=args.model)
    out = prepare_output(args.out, args.command, args.overwrite)
    sensors = SensorSuite(blackouts=tuple(args.blackout or ()))
    if args.noise_free:
        sensors = sensors.ideal()
    wheelbase = model.parameters.value("lf") + model.parameters.value("lr")
    controller = PathFollower(track, wheelbase, PathFollowerSettings(v_ref=args.speed))
    x0 = track.start_state()
    simulator = Simulator(model, sensors, seed=args.seed)
    started = time.perf_counter()
    result = simulator.run(controller, args.duration, x0, progress=sys.stderr.isatty())
    elapsed = time.perf_counter() - started
    result.extra_meta["noise_free"] = bool(args.noise_free)
    result.to_dataset().save(out)
    print(
        f"dataset: {out}  ({len(result.measurements)} measurements, "
        f"{args.duration / elapsed:.0f}x real time)"
    )
    if args.report:
        report = write_report(
            result, track, out / "report", {"real_time_factor": round(args.duration / elapsed, 1)}
        )
        print(f"report:  {report}/summary.txt, path.png, sensors.png, estimation.png")
        print((report / "summary.txt").read_text(), end="")
    return out


def add_arguments(sub: argparse.ArgumentParser, duration: float, demo: bool) -> None:
    """``crs sim``'s and ``crs demo``'s arguments: ``demo`` writes to out/demo and its report by
    default."""
    add_duration(sub, duration, "simulated time")
    add_seed(sub)
    add_out(
        sub,
        "output folder" + (" (default out/demo)" if demo else ""),
        required=not demo,
        default="out/demo",
    )
    sub.add_argument(
        "--noise-free", action="store_true", help="ideal sensors (no noise, bias, drop-outs)"
    )
    add_effect(
        sub,
        "hidden truth effect (repeatable); NAME=VALUE sets its first parameter, NAME alone "
        "uses the default; the effects and parameters are listed below",
    )
    sub.add_argument(
        "--blackout",
        type=argument_type(parse_blackout),
        action="append",
        metavar="SENSOR:START:DURATION",
        help="no samples of SENSOR (lighthouse, lighthouse/<station>, imu, wheel_encoders, "
        "gyro, pose) from START for DURATION, s of simulated time (repeatable), e.g. "
        "lighthouse:10:1.127",
    )
    add_simulated_stations(sub, "Lighthouse base stations, 1..8 (default 1)")
    add_model(
        sub,
        "the simulated car's model: dynamic (default), kinematic, or FILE.py:CLASS "
        "(docs/own-model.md); by default the one --params names",
    )
    sub.add_argument(
        "--speed",
        type=bounded_number("speed", "m/s", 0.0, 5.0),
        default=PathFollowerSettings.v_ref,
        help="reference speed of the path follower, m/s "
        f"(default {PathFollowerSettings.v_ref}, at most 5)",
    )
    sub.add_argument(
        "--params",
        type=Path,
        help="parameter YAML applied to the simulated car (a top-level 'parameters:' "
        "mapping of name: value; default: the Chronos parameters)",
    )
    add_track(sub)
    sub.add_argument(
        "--report",
        action=argparse.BooleanOptionalAction,
        default=demo,
        help=f"write OUT/report/ (default: {'on' if demo else 'off'})",
    )


def _simulation_command(name: str, help_text: str, duration: float) -> Command:
    """``sim`` or ``demo``: the same simulation, ``demo`` with defaults and a report."""
    return Command(
        name,
        help=help_text,
        description=f"{help_text[0].upper()}{help_text[1:]}: the ROS-free simulator "
        "(noisy sensors at their own rates) with the path follower in the loop; writes a "
        "dataset folder (crs_core.dataset format) and, with --report, OUT/report/ "
        "(summary.txt, summary.json, path.png, sensors.png, estimation.png).",
        arguments=partial(add_arguments, duration=duration, demo=name == "demo"),
        handler=simulate,
        epilog=EFFECTS_EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )


SIM = _simulation_command("sim", "simulate the car on a track and save a dataset", 30.0)
DEMO = _simulation_command("demo", "the main job: a few laps of DEMO_TRACK with a report", 40.0)
