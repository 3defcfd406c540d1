"""``crs bench NAME``: the benchmarks, each a sub-command with its own options, each printing
its figures and writing them as JSON to ``--out``."""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Callable
from functools import partial
from pathlib import Path
from typing import Any

from benchmarks.machine import REAL_DATA
from launch_scripts.arguments import (
    Command,
    add_duration,
    add_estimator,
    add_evaluations,
    add_out,
    add_seed,
    argument_type,
    bounded_number,
    command_line,
)
from launch_scripts.output_folder import prepare_output, prepare_output_file

#: What a benchmark gives: the JSON-ready result and the text to print.
Outcome = tuple[dict[str, Any], str]


def _runs(args: argparse.Namespace, name: str) -> Path:
    """The folder of a benchmark's launched runs: ``<--out without .json>_runs`` (or
    ``out/bench/<name>_runs``), new or written by an earlier ``crs bench``."""
    runs = Path(args.out).with_suffix("") if args.out else Path("out/bench") / name
    return prepare_output(runs.with_name(runs.name + "_runs"), "bench", args.overwrite)


def _with_machine(result: dict[str, Any]) -> dict[str, Any]:
    from benchmarks.machine import machine

    return {"machine": machine(), "command": command_line(), **result}


def model(args: argparse.Namespace) -> Outcome:
    from benchmarks.model import format_markdown, model_benchmark

    result = _with_machine(model_benchmark())
    return result, format_markdown(result)


def estimation(args: argparse.Namespace) -> Outcome:
    from benchmarks.estimation import format_table, run_all

    folders = sorted(p for p in REAL_DATA.iterdir() if p.is_dir()) if REAL_DATA.is_dir() else []
    plots = Path(args.out).parent / "estimation_plots" if args.out else None
    rows = run_all(tuple(range(args.seeds)), folders, plots, peers=not args.no_peers)
    return _with_machine({"rows": rows}), format_table(rows)


def stack(args: argparse.Namespace) -> Outcome:
    work = _runs(args, "stack")
    if len(args.cars) > 1:  # how the cost grows with the cars
        from benchmarks.stack_scale import format_markdown, plot, scale_benchmark

        if args.repeats != 1 or args.viz:
            raise ValueError("--cars: a list of counts runs each once, without --viz")
        result = scale_benchmark(list(args.cars), args.estimator, args.duration, args.load, work)
        figure = work / "stack_scale.png"
        plot(result, figure)
        text = f"{format_markdown(result)}\nplot: {figure}\nruns (reports, figures, bags): {work}"
        return _with_machine(result), text
    from benchmarks.stack import format_table, stack_benchmark

    result = stack_benchmark(
        args.cars[0], args.estimator, args.duration, args.repeats, args.load, work, viz=args.viz
    )
    return _with_machine(result), f"{format_table(result)}\nruns (reports, figures, bags): {work}"


def adaptation(args: argparse.Namespace) -> Outcome:
    from benchmarks.adaptation import adaptation_benchmark, format_markdown, plot

    work = _runs(args, "adaptation")
    schedules = tuple(args.schedules.split(","))
    result = adaptation_benchmark(
        work, args.duration, args.repeats, schedules, args.seed, not args.default_noise
    )
    figure = work / "adaptation.png"
    plot(result, figure)
    return _with_machine(result), f"{format_markdown(result)}\nplot: {figure}\nruns: {work}"


def _adaptation_options(parser: argparse.ArgumentParser) -> None:
    from benchmarks.adaptation import SCHEDULES

    add_duration(parser, 120.0, "wall-clock time of each race")
    _repeats(parser, 3, "races per schedule and mode")
    parser.add_argument(
        "--schedules",
        type=argument_type(lambda text: _known_names("schedules", tuple(SCHEDULES), text)),
        default=",".join(SCHEDULES),
        help=f"comma-separated, of {', '.join(SCHEDULES)} (default all)",
    )
    add_seed(parser, "noise and link seed of the first repeat")
    parser.add_argument(
        "--default-noise",
        action="store_true",
        help="race with the estimators' default noise instead of the one fitted to a steady "
        "60 s race first (crs tune-noise)",
    )


def _known_names(option: str, known: tuple[str, ...], text: str) -> str:
    """``text``, a comma-separated list of names out of ``known``."""
    names = [name.strip() for name in text.split(",")]
    unknown = [name for name in names if name not in known]
    if unknown or not text.strip():
        raise ValueError(f"--{option}: one or more of {', '.join(known)}, got {text!r}")
    return ",".join(names)


def online_real(args: argparse.Namespace) -> Outcome:
    from benchmarks.online_real import format_markdown, online_real_benchmark

    plots = Path(args.out).parent / "online_real_plots" if args.out else None
    result = _with_machine(online_real_benchmark(plots))
    return result, format_markdown(result) + (f"\nfigures: {plots}" if plots else "")


def online_tuning(args: argparse.Namespace) -> Outcome:
    from benchmarks.online_tuning import format_markdown, online_tuning_benchmark

    work = _runs(args, "online_tuning")
    result = _with_machine(online_tuning_benchmark(work, args.duration, args.seed))
    return result, f"{format_markdown(result)}\nthe race: {work}"


def floor(args: argparse.Namespace) -> Outcome:
    from benchmarks.middleware_floor import floor_benchmark, format_markdown

    work = _runs(args, "floor")
    result = _with_machine(floor_benchmark(args.duration, args.repeats, work))
    return result, f"{format_markdown(result)}\nruns of the real stack: {work}"


def machines(args: argparse.Namespace) -> Outcome:
    from benchmarks.several_machines import format_table, machines_benchmark

    work = _runs(args, "machines")
    result = machines_benchmark(args.duration, work)
    return _with_machine(result), f"{format_table(result)}\nruns (reports, logs, bags): {work}"


def bridge(args: argparse.Namespace) -> Outcome:
    from benchmarks.bridge import bridge_benchmark, format_table

    work = _runs(args, "bridge")
    result = _with_machine(bridge_benchmark(args.duration, work, args.estimator, args.seed))
    return result, f"{format_table(result)}\nruns (reports, figures, bags, emulator logs): {work}"


def link(args: argparse.Namespace) -> Outcome:
    from benchmarks.link import format_table, link_benchmark

    work = _runs(args, "link")
    result = link_benchmark(
        work,
        presets=args.presets,
        loads=args.loads,
        car_counts=args.cars,
        duration=args.duration,
        seed=args.seed,
    )
    result = _with_machine(result)
    return result, f"{format_table(result)}\nruns (reports, figures, bags, emulator logs): {work}"


def workflow(args: argparse.Namespace) -> Outcome:
    from benchmarks.workflow import format_table, workflow_benchmark

    work = _runs(args, "workflow")
    result = _with_machine(workflow_benchmark(work, args.duration, args.seed))
    return result, f"{format_table(result)}\nruns (races, bags, sysid, discrepancy): {work}"


def plan_drive(args: argparse.Namespace) -> Outcome:
    from benchmarks.plan_drive import format_table, plan_drive_benchmark

    result = plan_drive_benchmark(args.race, args.duration, args.seed, args.evaluations)
    result = _with_machine(result)
    return result, format_table(result)


def plan_drive_stack(args: argparse.Namespace) -> Outcome:
    from benchmarks.plan_drive_stack import format_table, plan_drive_stack_benchmark

    work = _runs(args, "plan_drive_stack")
    result = _with_machine(plan_drive_stack_benchmark(work, args.race, args.after, args.seed))
    return result, f"{format_table(result)}\nruns (races, bags, sysid, plan): {work}"


def models(args: argparse.Namespace) -> Outcome:
    from benchmarks.models import format_markdown, models_benchmark, plot

    work = _runs(args, "models")
    result = _with_machine(models_benchmark(work, lambda line: print(line, file=sys.stderr)))
    figure = work / "models.png"
    plot(result, figure)
    return result, f"{format_markdown(result)}\nplot: {figure}\nruns: {work}"


def _add_seconds(parser: argparse.ArgumentParser, flag: str, default: float, what: str) -> None:
    """``--FLAG``: ``what`` in s, ``(5, 600]``."""
    name = flag.removeprefix("--")
    parser.add_argument(
        flag,
        type=bounded_number(name, "s", 5.0, 600.0),
        default=default,
        help=f"{what}, s (default {default:g})",
    )


def _plan_drive_stack_options(parser: argparse.ArgumentParser) -> None:
    add_seed(parser, "seed of the emulated car's noise and of the design's starts")
    _add_seconds(parser, "--race", 40.0, "the first race, whose bag the drive is designed from")
    _add_seconds(parser, "--after", 30.0, "racing before each drive (--drive-after)")


def _plan_drive_options(parser: argparse.ArgumentParser) -> None:
    add_duration(parser, 8.0, "the drive (designed and slalom)")
    add_seed(parser, "seed of the simulated car's noise and of the design's starts")
    _add_seconds(parser, "--race", 30.0, "the race before the drive")
    add_evaluations(parser, "the design")


def _duration_and_seed(
    default: float, duration: str, seed: str
) -> Callable[[argparse.ArgumentParser], None]:
    """The options ``--duration`` (``default`` s, what it is ``duration``) and ``--seed``."""

    def options(parser: argparse.ArgumentParser) -> None:
        add_duration(parser, default, duration)
        add_seed(parser, seed)

    return options


def sysid(args: argparse.Namespace) -> Outcome:
    from benchmarks.sysid import sysid_benchmark

    result = {"command": command_line(), **sysid_benchmark(None, args.seeds)}
    return result, json.dumps(result, indent=2)


def discrepancy(args: argparse.Namespace) -> Outcome:
    from benchmarks.discrepancy import discrepancy_benchmark, format_markdown

    result = {
        "command": command_line(),
        **discrepancy_benchmark(
            args.out,
            seeds=args.seeds,
            clean_seeds=args.clean_seeds,
            progress=lambda line: print(f"discrepancy bench: {line}", file=sys.stderr),
            speed_run=not args.no_speed,
            resume=args.resume,
        ),
    }
    return result, format_markdown(result)


def control(args: argparse.Namespace) -> Outcome:
    from benchmarks.control import control_benchmark, format_table

    def progress(line: str) -> None:
        print(f"control bench: {line}", file=sys.stderr)

    result = {
        "command": command_line(),
        **control_benchmark(laps=args.laps, progress=progress),
    }
    return result, format_table(result)


def contingency(args: argparse.Namespace) -> Outcome:
    from benchmarks.contingency import contingency_benchmark, format_table

    def progress(line: str) -> None:
        print(f"contingency bench: {line}", file=sys.stderr)

    result = _with_machine(
        contingency_benchmark(args.seeds, args.duration, args.outage, args.seed, progress)
    )
    return result, format_table(result)


def calibration(args: argparse.Namespace) -> Outcome:
    import time

    from benchmarks.calibration import format_markdown, moving_study, static_study

    started = time.perf_counter()
    result = _with_machine(
        {
            "static": static_study(seeds=args.seeds),
            "moving": moving_study(seeds=min(args.seeds, 3)),
        }
    )
    result["elapsed_s"] = round(time.perf_counter() - started, 1)
    return result, format_markdown(result)


def run(benchmark: Callable[[argparse.Namespace], Outcome], args: argparse.Namespace) -> None:
    """Run ``benchmark``; print its figures; write ``--out``."""
    resume = getattr(args, "resume", False)
    if resume and not args.out:
        raise ValueError("--resume: needs --out FILE (the run to continue)")
    if args.out:
        prepare_output_file(args.out, args.overwrite or resume)
    result, text = benchmark(args)
    print(text)
    if args.out:
        Path(args.out).write_text(json.dumps(result, indent=2))
        print(f"JSON: {args.out}")


def _seeds(parser: argparse.ArgumentParser, what: str, default: int = 5, high: int = 50) -> None:
    """``--seeds``: an integer in ``[1, high]``."""
    parser.add_argument(
        "--seeds",
        type=bounded_number("seeds", "", 0, high, int),
        default=default,
        help=f"{what} (default {default})",
    )


def _repeats(parser: argparse.ArgumentParser, default: int, what: str) -> None:
    """``--repeats``: an integer in ``[1, 20]``."""
    parser.add_argument(
        "--repeats",
        type=bounded_number("repeats", "", 0, 20, int),
        default=default,
        help=f"{what} (default {default})",
    )


def _stack_options(parser: argparse.ArgumentParser) -> None:
    from benchmarks.link import parse_counts

    parser.add_argument(
        "--cars",
        type=argument_type(parse_counts("cars", 1, 8)),
        default=(1,),
        help="cars, 1..8 (default 1); a list such as 1,2,4,6 runs the stack once with each and "
        "reports how its cost grows (JSON, Markdown table and a plot)",
    )
    add_estimator(parser)
    add_duration(parser, 40.0, "wall-clock time per repeat")
    _repeats(parser, 1, "runs")
    parser.add_argument(
        "--load",
        type=bounded_number("load", "", -1, 16, int),
        default=0,
        help="busy-looping processes beside the stack, 0..16 (default 0)",
    )
    parser.add_argument(
        "--viz",
        action="store_true",
        help="each repeat again with the visualizer (crs launch sim --viz) and a Foxglove "
        "viewer subscribed to every channel: its CPU, and the stack's figures beside it",
    )


def _floor_options(parser: argparse.ArgumentParser) -> None:
    add_duration(parser, 20.0, "wall-clock time of each run")
    _repeats(parser, 3, "repeats")


def _bridge_options(parser: argparse.ArgumentParser) -> None:
    add_estimator(parser)
    add_seed(parser, "noise seed")
    add_duration(parser, 40.0, "wall-clock time of each run")


def _link_options(parser: argparse.ArgumentParser) -> None:
    from benchmarks.link import PRESET_NAMES, parse_counts, parse_presets

    parser.add_argument(
        "--presets",
        type=argument_type(parse_presets),
        default=PRESET_NAMES,
        help=f"link presets PRESET[,PRESET...] (default {','.join(PRESET_NAMES)})",
    )
    parser.add_argument(
        "--loads",
        type=argument_type(parse_counts("loads", 0, 16)),
        default=(0, 1, 2),
        help="busy-looping processes beside each race, N[,N...] (default 0,1,2)",
    )
    parser.add_argument(
        "--cars",
        type=argument_type(parse_counts("cars", 1, 8)),
        default=(1, 2),
        help="emulated cars racing at once, N[,N...] (default 1,2)",
    )
    add_duration(parser, 40.0, "wall-clock time of each race")
    add_seed(parser, "noise seed")


def _sysid_options(parser: argparse.ArgumentParser) -> None:
    _seeds(parser, "seeds of the simulated coverage study")


def _contingency_options(parser: argparse.ArgumentParser) -> None:
    _seeds(parser, "outage draws, each raced with racing and with hold-safe commands", 8, 200)
    add_duration(parser, 60.0, "simulated time of each race")
    parser.add_argument(
        "--outage",
        type=bounded_number("outage", "s", 0.0, 2.0, float),
        default=0.3,
        help="length of each outage, s (default 0.3, the outages preset's)",
    )
    add_seed(
        parser, "first seed of the outage draws (the filter's settings were chosen on 0..15)", 100
    )


def _control_options(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--laps",
        type=bounded_number("laps", "", 1, 20, int, include_low=True),
        default=5,
        help="laps of each race (default 5; the QP solvers' races: at most 2)",
    )


def _calibration_options(parser: argparse.ArgumentParser) -> None:
    _seeds(parser, "static seeds per setting; moving uses min(seeds, 3)")


def _estimation_options(parser: argparse.ArgumentParser) -> None:
    _seeds(parser, "seeds per row")
    parser.add_argument("--no-peers", action="store_true", help="skip filterpy, do-mpc and acados")


def _discrepancy_options(parser: argparse.ArgumentParser) -> None:
    _seeds(parser, "runs per hidden effect and magnitude")
    parser.add_argument(
        "--clean-seeds",
        type=bounded_number("clean-seeds", "", 0, 200, int),
        default=20,
        help="clean runs for the false-alarm rate (default 20)",
    )
    parser.add_argument("--no-speed", action="store_true", help="skip the 60 s speed run")
    parser.add_argument(
        "--resume",
        action="store_true",
        help="continue the run in --out (keep its cases, run the missing ones)",
    )


#: name: (function, options, description).
BENCHMARKS: dict[str, tuple[Callable[[argparse.Namespace], Outcome], Any, str]] = {
    "model": (model, None, "model evaluation speed and the simulator's real-time factor (s)"),
    "estimation": (
        estimation,
        _estimation_options,
        "EKF / MHE accuracy and speed on simulated runs (and on the real recordings in "
        f"{REAL_DATA} when present), with peers (filterpy, do-mpc, acados); ~11 min",
    ),
    "stack": (
        stack,
        _stack_options,
        "the launched ROS 2 stack (crs launch sim) per car: laps, estimation RMSE, deadline "
        "misses, re-initialisations, latencies, and CPU and peak memory per node; --load K busy "
        "processes beside it; the runs go to <out without .json>_runs/",
    ),
    "adaptation": (
        adaptation,
        _adaptation_options,
        "a car that changes while it races (sim.drift: the issue's schedule, one of ours, and "
        "a car that does not change), "
        "emulated behind a typical Wi-Fi link, raced with and without Cm1, gyro_bias and grip "
        "estimated online: laps, flying laps before and after the grip change, contouring "
        "error, time off the track, cut-offs, RMSE, and each online parameter against the "
        "truth (within tolerance, inside ±2σ, final value from the prior) with a plot of each "
        "against the truth; ~repeats x 6 x (duration + 25 s)",
    ),
    "online-real": (
        online_real,
        None,
        f"Cm1 and gyro_bias estimated online (MHE) on the two real recordings in {REAL_DATA}: "
        "their course over each run (figures beside --out), and each run's end values tried "
        "on the other run's held-out 2 s prediction; ~1.5 min",
    ),
    "online-tuning": (
        online_tuning,
        _duration_and_seed(120.0, "wall-clock time of the race", "noise and link seed of the race"),
        "how sharply the online gyro bias can be known against what the same tuning does to "
        "the real recordings: one race of the adaptation bench's issue schedule recorded with "
        "every sensor, estimated again offline with tighter process noise of x, y and yaw, "
        "the wheel speeds trusted less and a slower walk of the online parameters, each "
        "judged against the truth, "
        f"and the real recordings in {REAL_DATA} with the same settings (Lighthouse residual, "
        "distance from the on-board estimate); ~duration + 2.5 min",
    ),
    "floor": (
        floor,
        _floor_options,
        "what rclpy itself costs one car's pipeline: stand-in processes with the stack's "
        "topics, message types, QoS and rates that compute nothing (with the pipeline's own "
        "subscriptions, and publishing only) beside a raw stand-in recorder, and the real "
        "one-car stack in the same run; CPU per process and the host's yardstick; "
        "~repeats x (3 x duration + 30 s)",
    ),
    "machines": (
        machines,
        partial(add_duration, default=40.0, what="each run"),
        "the stack split across two machines (network namespaces joined by a veth pair; needs "
        "root) over the Zenoh link next to the same stack on one machine: laps, RMSE, sensor -> "
        "input latency, CPU per node, the link's bytes per second and CPU; ~2 x duration + 40 s",
    ),
    "bridge": (
        bridge,
        _bridge_options,
        "crs launch sim (direct simulator) and crs launch car --emulate (the emulated car over "
        "loopback UDP through the bridge) for the same --duration and --seed, side by side: "
        "laps, RMSE, deadline misses, latencies (sensor packet -> estimate -> command packet), "
        "bridge counts, CPU per process; ~2 x duration + 30 s",
    ),
    "link": (
        link,
        _link_options,
        "crs launch car --emulate over a Wi-Fi-like link, every --presets x --loads (busy loops "
        "beside the race) x --cars, one --duration race each: laps, mean flying lap (and its "
        "ratio to the clean run), seconds off the track (the emulator's truth and the car's "
        "footprint), motor cut-offs, estimation RMSE, QP failures, re-initialisations, sensor "
        "-> command latency, per outage the cut-off and the time to race again, CPU per "
        "process, and the issue's targets per run; a Markdown table; ~24 x (duration + 30 s) "
        "for the full matrix",
    ),
    "workflow": (
        workflow,
        _duration_and_seed(40.0, "each race", "seed of the emulated car's noise"),
        "a researcher's day on an emulated car that is not the model (tyres and motor off by "
        "10-20 %%, a hidden gyro bias): race it with the default model and record, crs sysid "
        "and crs discrepancy on the bag, race again with the result; laps, flying lap, "
        "contouring error, estimation RMSE and the held-out 2 s prediction error before and "
        "after, the parameters and the effect against the truth, each step's time; ~5 min with "
        "40 s races",
    ),
    "plan-drive": (
        plan_drive,
        _plan_drive_options,
        "does a designed drive decide what a race leaves open: issue 27's truth car with a "
        "hidden motor lag raced by the path follower, identified (FIE) from the race alone, "
        "from the race plus a designed drive (crs plan-drive's design from the race's "
        "covariance) and from the race plus a slalom of the same length; the sigma predicted "
        "and reported by the FIE and the error against the truth of Dr, Br, tau_motor (and "
        "Df, Bf), the grip and peak slip the drives reached; ~3 min",
    ),
    "plan-drive-stack": (
        plan_drive_stack,
        _plan_drive_stack_options,
        "crs bench plan-drive the way a user goes, every step a crs command: the same truth on "
        "the emulated car raced (crs launch car --emulate), crs sysid on its bag, crs "
        "plan-drive, then the designed drive and the slalom each driven after a race (--drive "
        "--drive-after); crs sysid on each bag cut at the drive's start and end: the sigma of "
        "Dr, Br, tau_motor from the race alone and with the drive; ~9 min",
    ),
    "models": (
        models,
        None,
        "the dynamic and kinematic bicycles and docs/own-model.md's model from a file, side by "
        "side: where the kinematic one departs (a ramp drive on both), estimation and "
        "identification on simulated drives (validated 2 s open-loop), an MPCC race on the "
        "simulated dynamic car, identification and estimation on the two real recordings; "
        "a plot of the departure beside --out; ~10 min",
    ),
    "sysid": (
        sysid,
        _sysid_options,
        "identification speed (a real run, 3000 simulated samples), real-data "
        "cross-validation (run 1 <-> run 2) and the simulated coverage study; ~10 min",
    ),
    "discrepancy": (
        discrepancy,
        _discrepancy_options,
        "every registry effect hidden at two magnitudes, the steering gain at three (--seeds "
        "runs each) and --clean-seeds clean runs (every third with mismatched sensor noise): "
        "the confusion table, false-alarm rate, parameter accuracy, gap before / after, and "
        "the time of one run on 60 s of data; ~40 s a case on two cores (--seeds 1: 41 "
        "cases, ~30 min)",
    ),
    "contingency": (
        contingency,
        _contingency_options,
        "the MPCC through link outages (the car holds the last command 200 ms, then coasts), "
        "its commands racing and hold-safe, offline on the model: time off the track, flying "
        "lap, commands replaced, over --seeds outage draws; ~4 min",
    ),
    "calibration": (
        calibration,
        _calibration_options,
        "Lighthouse calibration accuracy on simulated data: static, 24 simulated points (1 mrad "
        "per sweep) for 1 or 20 sweeps per point and 0 or 2 mm error of the known positions, "
        "the mean/max reprojected error and the true station error vs n = 4..24, mean over "
        "--seeds; moving, 20 s recordings with a 20 ms clock offset, the offset and station "
        "errors; ~1 min",
    ),
    "control": (
        control,
        _control_options,
        "the MPCC's solve time (N = 40, 30 Hz) against an IPOPT peer on the same problem and "
        "against acados (SQP-RTI + HPIPM of the same problem, in its own race and as the MPCC's "
        "iteration), the QP solvers (HPIPM, qpOASES, OSQP, qrqp), and --laps-lap races on the "
        "true state and with the MHE, with and without a 1.127 s Lighthouse blackout per lap, on "
        "a mismatched car and with velocity references; ~6 min",
    ),
}


def _benchmark_command(
    name: str, function: Callable[[argparse.Namespace], Outcome], add_options: Any, description: str
) -> Command:
    """``crs bench NAME``: ``--out`` and ``--overwrite``, then the benchmark's own options."""

    def add_arguments(sub: argparse.ArgumentParser) -> None:
        add_out(sub, "also write the JSON to this file")
        if add_options is not None:
            add_options(sub)

    return Command(
        name,
        help=description.split(": ")[0].split("; ")[0],
        description=f"{description}.",
        arguments=add_arguments,
        handler=partial(run, function),
    )


COMMAND = Command(
    "bench",
    help="benchmarks that print and save JSON",
    description="Benchmarks: each prints its figures and, with --out FILE, saves them as "
    "JSON. crs bench NAME --help for one.",
    subcommands=tuple(_benchmark_command(name, *spec) for name, spec in BENCHMARKS.items()),
    dest="what",
    metavar="NAME",
)
