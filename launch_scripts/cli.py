"""The ``crs`` command line.

``crs sim`` / ``crs demo`` (simulator, no ROS), ``crs estimate`` (EKF or MHE over a recorded
dataset), ``crs consistency`` (sensor models vs the real recordings), ``crs bench
model|estimation`` (JSON benchmarks), ``crs launch sim`` (the ROS 2
stack in simulation), ``crs bag check|repair`` (cut-off bags) and ``crs ros topics|echo|hz``
(small stand-ins for the ``ros2`` CLI).
ROS is imported only by the commands that need it.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import yaml

from chronos_bridge.emulator_process import add_command as add_car_emulator_command
from chronos_bridge.impairment import PRESET_NAMES, SPEC_HELP
from crs_core.estimation import INPUT_MODES, KINDS, parse_sensor_set
from crs_core.model import EFFECTS, CarModel
from crs_core.model.effects import effect_spec, parse_effect
from launch_scripts.arguments import OVERWRITE_HELP, argument_type, bounded_number
from launch_scripts.calibration_command import add_commands as add_calibration_commands
from launch_scripts.discrepancy_command import add_commands as add_discrepancy_commands
from launch_scripts.link_benchmark import parse_counts, parse_presets
from launch_scripts.output_folder import prepare_output, prepare_output_file
from launch_scripts.sim_stack import RECORD_SETS
from launch_scripts.sysid_command import add_commands as add_sysid_commands
from sim.bench.machine import REAL_DATA
from sim.sensors import SensorSuite, parse_blackout

#: Longest simulation or launch the CLI accepts, s (the simulator keeps every sample).
MAX_DURATION_S = 3600.0

#: The effects and their parameters (name, unit, default), for ``--help``.
EFFECTS_EPILOG = "effects (--effect NAME[.PARAM][=VALUE]; parameter, unit, default):\n" + "\n".join(
    f"  {effect.name:20s} "
    + "; ".join(f"{p.name} [{p.unit}] {p.value:g}: {p.description}" for p in effect.parameters)
    for effect in EFFECTS.values()
)


def build_model(
    effects: Sequence[tuple[str, str | None, float | None]], stations: int, params_yaml: Path | None
) -> CarModel:
    spec = effect_spec(effects)
    model = CarModel(spec, n_base_stations=stations)
    if params_yaml is not None:
        model = CarModel(spec, stations, model.parameters.updated_from_yaml(params_yaml))
    return model


def simulate(args: argparse.Namespace) -> Path:
    """Run the closed-loop simulation and write the dataset (and report) to ``args.out``."""
    from crs_core.control.path_following import PathFollower, PathFollowerSettings
    from crs_core.track import load_demo_track, read_track
    from sim.report import write_report
    from sim.simulator import Simulator

    track = read_track(args.track) if args.track else load_demo_track()
    model = build_model(args.effect or [], args.stations, args.params)
    out = prepare_output(Path(args.out), args.command, args.overwrite)
    sensors = SensorSuite(blackouts=tuple(args.blackout or ()))
    if args.noise_free:
        sensors = sensors.ideal()
    wheelbase = model.parameters.value("lf") + model.parameters.value("lr")
    controller = PathFollower(track, wheelbase, PathFollowerSettings(v_ref=args.speed))
    x0 = np.array([track.start_x, track.start_y, track.start_yaw, 0.0, 0.0, 0.0])
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
    try:
        rate = float(text)
    except ValueError:
        rate = math.nan
    if not (math.isfinite(rate) and rate > 0):
        raise ValueError(f"--rate: must be a finite number of Hz > 0, got {text!r}")
    return rate


def estimate(args: argparse.Namespace) -> None:
    """``crs estimate``: an estimator over a dataset; estimates, diagnostics and a figure."""
    from tqdm import tqdm

    from crs_core.dataset import Dataset
    from crs_core.estimation.offline import dataset_model, estimate_dataset, reference_comparison
    from launch_scripts.estimate_report import format_summary, write_figure

    x0 = parse_x0(args.x0)
    rate = parse_rate(args.rate)
    if args.sensors != "auto":
        try:
            parse_sensor_set(args.sensors)
        except ValueError as error:
            raise ValueError(f"--sensors: {str(error).partition(': ')[2]}") from None
    dataset = Dataset.load(args.dataset)
    try:
        model = dataset_model(dataset, args.params)
    except yaml.YAMLError as error:
        problem = str(error).splitlines()[0]
        raise ValueError(f"--params: {args.params} is not valid YAML ({problem})") from None
    except KeyError as error:
        raise ValueError(f"--params: {error.args[0]}") from None
    except OSError as error:
        raise ValueError(f"--params: cannot read {args.params} ({error.strerror})") from None
    out = prepare_output(Path(args.out), "estimate", args.overwrite)
    name = Path(args.dataset).resolve().name
    with tqdm(total=1000, desc=f"estimate {name}", file=sys.stderr, disable=None) as bar:
        try:
            result = estimate_dataset(
                dataset,
                args.estimator,
                args.sensors,
                model=model,
                inputs=args.inputs,
                x0=x0,
                rate_hz=rate,
                progress=lambda fraction: bar.update(round(1000 * fraction) - bar.n),
            )
        except ValueError as error:  # name the option, not the argument of the function
            field, _, message = str(error).partition(": ")
            options = {"x0": "--x0", "rate_hz": "--rate", "sensors": "--sensors"}
            raise ValueError(f"{options.get(field, field)}: {message}") from None
    comparison = reference_comparison(result, dataset)
    result.save_npz(out / "estimates.npz")
    report = {
        "command": "crs " + " ".join(sys.argv[1:]),
        "dataset": str(Path(args.dataset).resolve()),
        "params": str(args.params) if args.params else None,
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
    print(f"wrote {out / 'estimates.npz'}, diagnostics.json, estimate.png")


def consistency(args: argparse.Namespace) -> None:
    """Real-data consistency of the sensor models (median / p95 error per channel)."""
    from crs_core.analysis.consistency import channel_errors
    from crs_core.dataset import Dataset

    if args.out:
        prepare_output_file(args.out, args.overwrite)
    if not args.data and not REAL_DATA.is_dir():
        raise ValueError(
            f"--data: no dataset given, and the real recordings are not at {REAL_DATA} (they "
            "come with the project's shared data); pass --data DATASET_FOLDER"
        )
    folders = args.data or sorted(p for p in REAL_DATA.iterdir() if p.is_dir())
    rows = {}
    for folder in folders:
        rows[Path(folder).name] = channel_errors(Dataset.load(folder))
    text = json.dumps({"command": " ".join(sys.argv), "runs": rows}, indent=2)
    if args.out:
        Path(args.out).write_text(text)
    print(f"{'channel':18s}" + "".join(f"{name[-12:]:>26s}" for name in rows))
    for channel in next(iter(rows.values())):
        cells = "".join(
            f"{r[channel]['median']:12.4g} /{r[channel]['p95']:11.4g}" for r in rows.values()
        )
        print(f"{channel:18s}{cells}")
    print("(median / p95 of |recorded - model(recorded state)|; rad for Lighthouse, rad/s else)")


def bench(args: argparse.Namespace) -> None:
    """``crs bench WHAT`` (model, estimation, stack, sysid, discrepancy, control): JSON."""
    from sim.bench.machine import machine
    from sim.bench.model import model_benchmark

    for option, value, benches in (
        ("--presets", args.presets, ("link",)),
        ("--loads", args.loads, ("link",)),
        ("--cars", args.cars, ("stack", "link")),
    ):
        if value is not None and args.what not in benches:
            raise ValueError(f"{option}: only for crs bench {' and '.join(benches)}")
    if args.what == "stack" and args.cars is not None and len(args.cars) != 1:
        raise ValueError("--cars: crs bench stack takes one number of cars")
    if args.resume and args.what != "discrepancy":
        raise ValueError("--resume: only for the discrepancy benchmark")
    if args.resume and not args.out:
        raise ValueError("--resume: needs --out FILE (the run to continue)")
    if args.out:
        prepare_output_file(args.out, args.overwrite or args.resume)
    if args.what == "model":
        result = model_benchmark()
        text = json.dumps(result, indent=2)
        print(text)
    elif args.what == "sysid":
        from sim.bench.sysid import sysid_benchmark

        result = {"command": "crs " + " ".join(sys.argv[1:]), **sysid_benchmark(None, args.seeds)}
        text = json.dumps(result, indent=2)
        print(text)
    elif args.what == "discrepancy":
        from sim.bench.discrepancy import discrepancy_benchmark, markdown

        result = {
            "command": "crs " + " ".join(sys.argv[1:]),
            **discrepancy_benchmark(
                args.out,
                seeds=args.seeds,
                clean_seeds=args.clean_seeds,
                progress=lambda line: print(f"discrepancy bench: {line}", file=sys.stderr),
                speed_run=not args.no_speed,
                resume=args.resume,
            ),
        }
        text = json.dumps(result, indent=2)
        print(json.dumps({k: result[k] for k in ("summary", "wall_time_s") if k in result}))
        print(markdown(result["cases"]))
    elif args.what == "control":
        from sim.bench.control import control_benchmark, format_table

        result = {
            "command": "crs " + " ".join(sys.argv[1:]),
            **control_benchmark(
                progress=lambda line: print(f"control bench: {line}", file=sys.stderr)
            ),
        }
        text = json.dumps(result, indent=2)
        print(format_table(result))
    elif args.what == "bridge":
        from launch_scripts.bridge_benchmark import bridge_benchmark, format_table

        runs = Path(args.out).with_suffix("") if args.out else Path("out/bench/bridge")
        work = prepare_output(runs.with_name(runs.name + "_runs"), "bench", args.overwrite)
        result = bridge_benchmark(args.duration, work, args.estimator, args.seed)
        result = {"machine": machine(), "command": "crs " + " ".join(sys.argv[1:]), **result}
        text = json.dumps(result, indent=2)
        print(format_table(result))
        print(f"runs (reports, figures, bags, emulator logs): {work}")
    elif args.what == "stack":
        from launch_scripts.stack_benchmark import format_table, stack_benchmark

        runs = Path(args.out).with_suffix("") if args.out else Path("out/bench/stack")
        work = prepare_output(runs.with_name(runs.name + "_runs"), "bench", args.overwrite)
        cars = args.cars[0] if args.cars else 1
        result = stack_benchmark(cars, args.estimator, args.duration, args.repeats, args.load, work)
        result = {"machine": machine(), "command": "crs " + " ".join(sys.argv[1:]), **result}
        text = json.dumps(result, indent=2)
        print(format_table(result))
        print(f"runs (reports, figures, bags): {work}")
    elif args.what == "link":
        from launch_scripts.link_benchmark import PRESET_NAMES, format_table, link_benchmark

        runs = Path(args.out).with_suffix("") if args.out else Path("out/bench/link")
        work = prepare_output(runs.with_name(runs.name + "_runs"), "bench", args.overwrite)
        result = link_benchmark(
            work,
            presets=args.presets or PRESET_NAMES,
            loads=args.loads if args.loads is not None else (0, 1, 2),
            car_counts=args.cars or (1, 2),
            duration=args.duration,
            seed=args.seed,
        )
        result = {"machine": machine(), "command": "crs " + " ".join(sys.argv[1:]), **result}
        text = json.dumps(result, indent=2)
        print(format_table(result))
        print(f"runs (reports, figures, bags, emulator logs): {work}")
    else:
        from sim.bench.estimation import format_table, run_all

        folders = sorted(p for p in REAL_DATA.iterdir() if p.is_dir()) if REAL_DATA.is_dir() else []
        plots = Path(args.out).parent / "estimation_plots" if args.out else None
        rows = run_all(tuple(range(args.seeds)), folders, plots, peers=not args.no_peers)
        result = {"machine": machine(), "command": "crs " + " ".join(sys.argv[1:]), "rows": rows}
        text = json.dumps(result, indent=2)
        print(format_table(rows))
    if args.out:
        Path(args.out).write_text(text)
        print(f"JSON: {args.out}")


def launch(args: argparse.Namespace) -> None:
    """``crs launch sim``: the ROS 2 stack in simulation, then ``report.json``; ``crs launch
    car --emulate | --car-ip IP``: the same against cars over UDP (emulated or real)."""
    from crs_core.track import read_track
    from launch_scripts.sim_stack import run_stack, summary

    if args.scenario == "car":
        return launch_car(args)
    for option, given in (("--emulate", args.emulate), ("--car-ip", args.car_ip)):
        if given:
            raise ValueError(f"{option}: only for crs launch car")
    for option, given in _link_options(args):
        if given is not None:
            raise ValueError(
                f"{option}: only for crs launch car --emulate (the simulator has no radio link)"
            )

    # the nodes check these too, but a mistake is cheaper to hear before four processes start
    if args.output == "velocity" and args.controller != "mpcc":
        raise ValueError(
            f"--output: velocity needs --controller mpcc (the {args.controller} controller "
            "commands torque)"
        )
    if args.track is not None:
        read_track(args.track)
    if args.params is not None:
        build_model([], 1, args.params)
    prepare_output(Path(args.out), "launch", args.overwrite)
    report = run_stack(
        args.cars,
        args.estimator,
        args.duration,
        args.out,
        args.domain,
        args.seed,
        blind_start=args.blind_start,
        record=args.record,
        track_file=args.track,
        params_file=args.params,
        controller=args.controller,
        output=args.output,
    )
    print(summary(report, Path(args.out)))
    return _verdict(report, args.require_laps)


def _verdict(report: dict, require_laps: int) -> int:
    """0, or 1 with a headline on stderr when a node died or a car raced fewer than
    ``require_laps`` laps (``--require-laps``; 0: no requirement)."""
    failures = [f"{d['node']} died" for d in report.get("node_deaths", [])]
    if require_laps > 0:
        failures += [
            f"{name} raced {car['laps_completed']} laps, fewer than the {require_laps} required"
            for name, car in report["cars"].items()
            if car["laps_completed"] < require_laps
        ]
    if not failures:
        return 0
    print(f"crs launch: FAILED: {'; '.join(failures)}", file=sys.stderr)
    return 1


def _link_options(args: argparse.Namespace) -> list[tuple[str, object]]:
    """``crs launch``'s link options and their values (None: not given)."""
    return [
        ("--link", args.link),
        ("--link-up", args.link_up),
        ("--link-down", args.link_down),
        ("--link-seed", args.link_seed),
    ]


def launch_car(args: argparse.Namespace) -> None:
    """``crs launch car (--emulate | --car-ip IP[,IP...])``: the stack against cars over UDP
    (emulated cars: ``--link``, ``--link-up``, ``--link-down``, ``--link-seed`` impair their
    link like Wi-Fi)."""
    from launch_scripts.car_stack import EmulatedLink, parse_car_ips, run_car_stack, summary

    if args.emulate == (args.car_ip is not None):
        raise ValueError("car: needs either --emulate or --car-ip IP (a real car), not both")
    if not args.emulate:
        for option, given in _link_options(args):
            if given is not None:
                raise ValueError(
                    f"{option}: only with --emulate (a real car's link is the real Wi-Fi; "
                    "impair it with the router, not here)"
                )
    link = EmulatedLink(args.link, args.link_up, args.link_down, args.link_seed)
    link.arguments(1)  # checks the specs and the seed before anything starts
    car_ips = None
    if args.car_ip is not None:
        car_ips = parse_car_ips(args.car_ip)
        if args.cars not in (1, len(car_ips)):
            raise ValueError(
                f"--cars: {args.cars} cars with {len(car_ips)} --car-ip address(es); give one "
                "address per car (IP,IP,...)"
            )
        args.cars = len(car_ips)
    if args.track is not None:
        raise ValueError("--track: crs launch car races DEMO_TRACK (where the emulator starts)")
    if args.output == "velocity" and args.controller != "mpcc":
        raise ValueError(
            f"--output: velocity needs --controller mpcc (the {args.controller} controller "
            "commands torque)"
        )
    if args.params is not None:
        build_model([], 1, args.params)
    prepare_output(Path(args.out), "launch", args.overwrite)
    report = run_car_stack(
        args.cars,
        args.estimator,
        args.duration,
        Path(args.out),
        args.emulate,
        car_ips,
        args.domain,
        args.seed,
        record=args.record,
        controller=args.controller,
        output=args.output,
        blind_start=args.blind_start,
        params_file=args.params,
        link=link,
    )
    print(summary(report, Path(args.out)))
    return _verdict(report, args.require_laps)


def bag_tool(args: argparse.Namespace) -> int:
    """``crs bag check|repair``: what a (cut-off) bag holds; a complete copy of it."""
    from ros4crs.bag_repair import check, repair

    if args.tool == "check":
        report = check(args.bag)
        print(report.describe())
        return 0 if report.complete else 1
    if args.out is None:
        raise ValueError("--out: repair needs --out NEW_BAG (a folder that does not exist yet)")
    if args.out.exists():
        raise ValueError(f"--out: {args.out} exists; the repaired bag goes to a new folder")
    report = repair(args.bag, args.out)
    if not report.complete:
        print(f"warning: {report.warning}")
    print(f"wrote {args.out}: {report.messages} messages on {len(report.topics)} topics")
    return 0


def ros_tool(args: argparse.Namespace) -> None:
    """``crs ros topics|echo|hz``."""
    if args.tool in ("echo", "hz") and not args.topic:
        raise ValueError(f"TOPIC: {args.tool} needs a topic, e.g. crs ros {args.tool} /car1/input")
    from ros4crs import tools

    if args.tool == "topics":
        for name, msgtype in tools.list_topics(args.wait):
            print(f"{name}  [{msgtype}]")
    elif args.tool == "echo":
        for message in tools.echo(args.topic, args.count, args.timeout):
            print(message)
    else:
        print(json.dumps(tools.rate(args.topic, args.window, args.timeout)))


class OneLineParser(argparse.ArgumentParser):
    """Argument errors as one line, ``crs <cmd>: error: <argument>: <reason>``, exit code 2."""

    def error(self, message: str):  # type: ignore[override]
        self.exit(2, f"{self.prog}: error: {message} (see {self.prog} --help)\n")


def make_parser() -> argparse.ArgumentParser:
    parser = OneLineParser(prog="crs", description=__doc__)
    commands = parser.add_subparsers(dest="command", required=True)
    for name, help_text, duration in (
        ("sim", "simulate the car on a track and save a dataset", 30.0),
        ("demo", "the main job: a few laps of DEMO_TRACK with a report", 40.0),
    ):
        sub = commands.add_parser(
            name,
            help=help_text,
            description=f"{help_text[0].upper()}{help_text[1:]}: the ROS-free simulator "
            "(noisy sensors at their own rates) with the path follower in the loop; writes a "
            "dataset folder (crs_core.dataset format) and, with --report, OUT/report/ "
            "(summary.txt, summary.json, path.png, sensors.png, estimation.png).",
            epilog=EFFECTS_EPILOG,
            formatter_class=argparse.RawDescriptionHelpFormatter,
        )
        sub.add_argument(
            "--duration",
            type=bounded_number("duration", "s", 0.0, MAX_DURATION_S),
            default=duration,
            help=f"simulated time, s (default {duration:g}, at most {MAX_DURATION_S:g})",
        )
        sub.add_argument("--seed", type=int, default=0, help="seed of all noise (default 0)")
        sub.add_argument(
            "--out",
            required=name == "sim",
            default="out/demo",
            help="output folder" + (" (default out/demo)" if name == "demo" else ""),
        )
        sub.add_argument(
            "--noise-free", action="store_true", help="ideal sensors (no noise, bias, drop-outs)"
        )
        sub.add_argument(
            "--effect",
            type=argument_type(parse_effect),
            action="append",
            metavar="NAME[.PARAM][=VALUE]",
            help="hidden truth effect (repeatable); NAME=VALUE sets its first parameter, NAME "
            "alone uses the default; the effects and parameters are listed below",
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
        sub.add_argument(
            "--stations",
            type=bounded_number("stations", "", 0, 8, int),
            default=1,
            help="Lighthouse base stations, 1..8 (default 1)",
        )
        sub.add_argument(
            "--speed",
            type=bounded_number("speed", "m/s", 0.0, 5.0),
            default=1.0,
            help="reference speed of the path follower, m/s (default 1.0, at most 5)",
        )
        sub.add_argument(
            "--params",
            type=Path,
            help="parameter YAML applied to the simulated car (a top-level 'parameters:' "
            "mapping of name: value; default: the Chronos parameters)",
        )
        sub.add_argument("--track", type=Path, help="track YAML (CRS format; default: DEMO_TRACK)")
        sub.add_argument(
            "--report",
            action=argparse.BooleanOptionalAction,
            default=name == "demo",
            help=f"write OUT/report/ (default: {'on' if name == 'demo' else 'off'})",
        )
        sub.add_argument("--overwrite", action="store_true", help=OVERWRITE_HELP)
        sub.set_defaults(handler=simulate)
    sub = commands.add_parser(
        "estimate",
        help="run an EKF or MHE over a recorded dataset (offline)",
        description="Run an EKF or MHE over a dataset folder (crs_core.dataset format) and "
        "write DIR/estimates.npz (t, x (6, N), status 0 ok / 1 degraded / 2 lost, "
        "covariance_diag), DIR/diagnostics.json and DIR/estimate.png.",
    )
    sub.add_argument("dataset", type=Path, help="dataset folder")
    sub.add_argument("--overwrite", action="store_true", help=OVERWRITE_HELP)
    sub.add_argument("--estimator", choices=KINDS, required=True, help="EKF or MHE")
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
        "--params",
        type=Path,
        help="parameter YAML applied to the model (default: the Chronos parameters with the "
        "dataset's Lighthouse geometry)",
    )
    sub.add_argument("--out", type=Path, required=True, help="output folder")
    sub.set_defaults(handler=estimate)
    sub = commands.add_parser(
        "consistency",
        help="sensor models vs. the real recordings",
        description="Replay recorded states through the sensor models and print the error per "
        "channel (median / p95).",
    )
    sub.add_argument(
        "--data",
        type=Path,
        action="append",
        help=f"dataset folder (repeatable; default: the real recordings in {REAL_DATA})",
    )
    sub.add_argument("--out", type=Path, help="also write the table as JSON to this file")
    sub.add_argument("--overwrite", action="store_true", help="replace an existing --out file")
    sub.set_defaults(handler=consistency)
    sub = commands.add_parser(
        "bench",
        help="benchmarks that print JSON",
        description="model: model evaluation speed and the simulator's real-time factor (s). "
        "estimation: EKF / MHE accuracy and speed on simulated runs (and on the real "
        f"recordings in {REAL_DATA} when present), with peers (filterpy, do-mpc); ~11 min. "
        "stack: the launched ROS 2 stack (crs launch sim) per car: laps, estimation RMSE, "
        "deadline misses, re-initialisations, latencies, and CPU and peak memory per node; "
        "--load K busy processes beside it; the runs go to <out without .json>_runs/. "
        "bridge: crs launch sim (direct simulator) and crs launch car --emulate (the emulated "
        "car over loopback UDP through the bridge) for the same --duration and --seed, side by "
        "side: laps, RMSE, deadline misses, latencies (sensor packet -> estimate -> command "
        "packet), bridge counts, CPU per process; ~2 x duration + 30 s. "
        "link: crs launch car --emulate over a Wi-Fi-like link, every --presets x --loads "
        "(busy loops beside the race) x --cars, one --duration race each: laps, mean flying "
        "lap (and its ratio to the clean run), seconds off the track (the emulator's truth "
        "and the car's footprint), motor cut-offs, estimation RMSE, QP failures, "
        "re-initialisations, sensor -> command latency, per outage the cut-off and the time "
        "to race again, CPU per process, and the issue's targets per run; a Markdown table; "
        "~24 x (duration + 30 s) for the full matrix. "
        "sysid: identification speed (a real run, 3000 simulated samples), real-data "
        "cross-validation (run 1 <-> run 2) and the simulated coverage study (--seeds, "
        "default 5; 10 for the README figures); ~10 min. "
        "discrepancy: every registry effect hidden at two magnitudes, the steering gain at "
        "three (--seeds runs each, every effect once before any twice) and --clean-seeds clean "
        "runs (every third with mismatched sensor noise): the confusion table, false-alarm "
        "rate, parameter accuracy, gap before / after, and the time of one run on 60 s of data "
        "(--no-speed skips it); ~1 h with --seeds 1 (41 cases, 20 s training runs). "
        "control: the MPCC's solve time (N = 40, 30 Hz) against an IPOPT peer on the same "
        "problem, the QP solvers (HPIPM, qpOASES, OSQP, qrqp), and 5-lap races on the true "
        "state and with the MHE, with and without a 1.127 s Lighthouse blackout per lap, on a "
        "mismatched car and with velocity references; ~5 min.",
    )
    sub.add_argument(
        "what",
        choices=[
            "model",
            "estimation",
            "stack",
            "bridge",
            "link",
            "sysid",
            "discrepancy",
            "control",
        ],
        help="which benchmark",
    )
    sub.add_argument("--out", type=Path, help="also write the JSON to this file")
    sub.add_argument("--overwrite", action="store_true", help="replace an existing --out file")
    sub.add_argument(
        "--seeds",
        type=bounded_number("seeds", "", 0, 50, int),
        default=5,
        help="estimation: seeds per row; sysid: seeds of the coverage study (default 5)",
    )
    sub.add_argument(
        "--clean-seeds",
        type=bounded_number("clean-seeds", "", 0, 200, int),
        default=20,
        help="discrepancy: clean runs for the false-alarm rate (default 20)",
    )
    sub.add_argument("--no-peers", action="store_true", help="estimation: skip filterpy/do-mpc")
    sub.add_argument("--no-speed", action="store_true", help="discrepancy: skip the 60 s speed run")
    sub.add_argument(
        "--resume",
        action="store_true",
        help="discrepancy: continue the run in --out (keep its cases, run the missing ones)",
    )
    sub.add_argument(
        "--cars",
        type=argument_type(parse_counts("cars", 1, 8)),
        help="stack: 1..8 (default 1); link: N[,N...] (default 1,2)",
    )
    sub.add_argument(
        "--presets",
        type=argument_type(parse_presets),
        help=f"link: link presets PRESET[,PRESET...] (default {','.join(PRESET_NAMES)})",
    )
    sub.add_argument(
        "--loads",
        type=argument_type(parse_counts("loads", 0, 16)),
        help="link: busy-looping processes beside each race, N[,N...] (default 0,1,2)",
    )
    sub.add_argument(
        "--estimator", choices=["ekf", "mhe"], default="mhe", help="stack, bridge: (default mhe)"
    )
    sub.add_argument("--seed", type=int, default=0, help="bridge, link: noise seed (default 0)")
    sub.add_argument(
        "--duration",
        type=bounded_number("duration", "s", 0.0, MAX_DURATION_S),
        default=40.0,
        help="stack: wall-clock s per repeat; bridge, link: per run (default 40)",
    )
    sub.add_argument(
        "--repeats",
        type=bounded_number("repeats", "", 0, 20, int),
        default=1,
        help="stack: runs (default 1)",
    )
    sub.add_argument(
        "--load",
        type=bounded_number("load", "", -1, 16, int),
        default=0,
        help="stack: busy-looping processes beside the stack, 0..16 (default 0)",
    )
    sub.set_defaults(handler=bench)
    sub = commands.add_parser(
        "launch",
        help="run the ROS 2 node suite",
        description="sim: per car a simulator, an estimator and a controller node (namespaces "
        "/car1, /car2, ...) and one recorder, as processes on DDS (loopback), for --duration; "
        "then OUT/report.json (laps, estimation RMSE, deadline misses, latencies, CPU), "
        "OUT/path.png, OUT/bag (MCAP) and OUT/logs. car: per car a bridge node (UDP port "
        "20211, 20212, ...), an estimator and a controller, against emulated cars on loopback "
        "(--emulate: one crs car-emulator per car on port 20311, 20312, ...; truth and link "
        "timing in OUT/truth_carN.npz) or real cars (--car-ip IP[,IP...]: the bridge binds "
        "0.0.0.0 and pairs only with that address); the report adds the latency sensor packet "
        "-> estimate -> command packet, the bridge's counts and the emulator's motor cut-offs.",
    )
    sub.add_argument(
        "scenario",
        choices=["sim", "car"],
        help="sim: simulated cars (no car needed); car: cars over UDP (--emulate or --car-ip)",
    )
    sub.add_argument(
        "--emulate",
        action="store_true",
        help="car: emulated cars (crs car-emulator) on loopback UDP, exactly as real ones",
    )
    sub.add_argument(
        "--car-ip",
        help="car: the real car's IPv4 address (several cars: IP,IP,...; one bridge each)",
    )
    sub.add_argument(
        "--link",
        metavar="SPEC",
        help="car --emulate: impair the emulated cars' link both ways like Wi-Fi (default "
        "clean): " + SPEC_HELP,
    )
    sub.add_argument(
        "--link-up", metavar="SPEC", help="car --emulate: car -> host only (overrides --link)"
    )
    sub.add_argument(
        "--link-down", metavar="SPEC", help="car --emulate: host -> car only (overrides --link)"
    )
    sub.add_argument(
        "--link-seed",
        type=bounded_number("link-seed", "", 0, 2**31, int, include_low=True),
        help="car --emulate: seed of the links' draws; car i uses LINK_SEED + i (default: from "
        "each emulator's own seed)",
    )
    sub.add_argument(
        "--cars", type=bounded_number("cars", "", 0, 8, int), default=1, help="1..8 (default 1)"
    )
    sub.add_argument(
        "--estimator", choices=["ekf", "mhe"], default="mhe", help="(default mhe, at 60 Hz)"
    )
    sub.add_argument(
        "--controller",
        choices=["mpcc", "path"],
        default="mpcc",
        help="mpcc: race (MPCC, 30 Hz; default); path: follow the centreline at 1 m/s (50 Hz)",
    )
    sub.add_argument(
        "--output",
        choices=["torque", "velocity"],
        default="torque",
        help="what the controllers command: torque (steering and motor torque; default) or "
        "velocity (steering and a velocity reference for the car's onboard 250 Hz velocity PID, "
        "which the simulators then run; --controller mpcc only)",
    )
    sub.add_argument(
        "--duration",
        type=bounded_number("duration", "s", 0.0, MAX_DURATION_S),
        default=40.0,
        help=f"wall-clock s (default 40, at most {MAX_DURATION_S:g})",
    )
    sub.add_argument("--out", type=Path, required=True, help="output folder")
    sub.add_argument(
        "--domain",
        type=bounded_number("domain", "", -1, 232, int),
        help="ROS_DOMAIN_ID, 0..232 (default: $ROS_DOMAIN_ID, else 42)",
    )
    sub.add_argument(
        "--seed", type=int, default=0, help="noise seed; car i uses SEED + i (default 0)"
    )
    sub.add_argument(
        "--require-laps",
        type=bounded_number("require-laps", "", 0, 1000, int),
        default=0,
        help="exit 1 with a FAILED headline when a car races fewer laps (default 0: none)",
    )
    sub.add_argument(
        "--blind-start",
        action="store_true",
        help="estimators initialise from the Lighthouse instead of the known start pose",
    )
    sub.add_argument(
        "--track", type=Path, help="track YAML (CRS format; default: DEMO_TRACK) for every car"
    )
    sub.add_argument(
        "--params",
        type=Path,
        help="parameter YAML of the cars: the simulated truth and the model of the estimators "
        "and controllers (default: the Chronos parameters)",
    )
    sub.add_argument(
        "--record",
        choices=list(RECORD_SETS),
        default="all",
        help="what the bag (OUT/bag, MCAP) holds: all (default: sensors, inputs, truth, "
        "estimates, odometry, /tf; replays the estimator offline exactly), estimates (no 250 Hz "
        "sensor streams) or sensors (no estimates)",
    )
    sub.add_argument("--overwrite", action="store_true", help=OVERWRITE_HELP)
    sub.set_defaults(handler=launch)
    sub = commands.add_parser(
        "bag",
        help="check a bag, or repair one whose recording was cut off",
        description="check: what a ROS 2 bag folder holds (topics, messages, duration) and, for "
        "an MCAP file cut off by a killed recorder or a full disk, what is still readable and how "
        "much was lost; exit code 0 complete, 1 damaged. repair: write every complete message "
        "of a bag into a new, complete bag at --out (the original is only read).",
    )
    sub.add_argument("tool", choices=["check", "repair"])
    sub.add_argument("bag", type=Path, help="bag folder (holding metadata.yaml and/or *.mcap)")
    sub.add_argument("--out", type=Path, help="repair: the new bag folder (must not exist)")
    sub.set_defaults(handler=bag_tool)
    sub = commands.add_parser(
        "ros",
        help="topics, echo, hz (no ros2 CLI here)",
        description="topics: list the topics and types seen in the ROS domain ($ROS_DOMAIN_ID). "
        "echo: print the next messages of a topic. hz: its receive rate (JSON: rate_hz, "
        "messages, gap_ms_median, gap_ms_max).",
    )
    sub.add_argument("tool", choices=["topics", "echo", "hz"], help="which tool")
    sub.add_argument("topic", nargs="?", help="echo, hz: the topic, e.g. /car1/estimate/state")
    sub.add_argument(
        "--count",
        type=bounded_number("count", "", 0, 1e6, int),
        default=1,
        help="echo: messages to print (default 1)",
    )
    sub.add_argument(
        "--window",
        type=bounded_number("window", "s", 0.0, 3600.0),
        default=2.0,
        help="hz: seconds to listen (default 2)",
    )
    sub.add_argument(
        "--wait",
        type=bounded_number("wait", "s", 0.0, 3600.0),
        default=1.0,
        help="topics: discovery time, s (default 1)",
    )
    sub.add_argument(
        "--timeout",
        type=bounded_number("timeout", "s", 0.0, 3600.0),
        default=5.0,
        help="echo, hz: give up after this many s without a message (default 5)",
    )
    sub.set_defaults(handler=ros_tool)
    add_sysid_commands(commands)
    add_discrepancy_commands(commands)
    add_calibration_commands(commands)
    add_car_emulator_command(commands)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    try:
        args = make_parser().parse_args(argv)
    except SystemExit as exit_:  # --help, or an argument error already printed in one line
        return int(exit_.code or 0)
    try:
        code = args.handler(args)  # an exit code, or what the command made (0)
    except (ValueError, KeyError, FileNotFoundError, FileExistsError) as error:
        print(f"crs {args.command}: error: {error}", file=sys.stderr)
        return 2
    return code if isinstance(code, int) else 0


if __name__ == "__main__":
    sys.exit(main())
