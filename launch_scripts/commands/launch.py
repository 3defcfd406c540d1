"""``crs launch sim|car``: the ROS 2 node suite against simulated cars, or against cars over
UDP (emulated or real), then its report."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from chronos_bridge.impairment import SPEC_HELP
from crs_core.control.supervisor import HOLD_SAFE_MODES
from crs_core.errors import FieldError
from crs_core.model.online import DEFAULT_REVERSION_S, parse_online_names
from launch_scripts.arguments import (
    ZENOH_OPEN,
    Command,
    add_cars,
    add_domain,
    add_duration,
    add_effect,
    add_estimator,
    add_model,
    add_out,
    add_track,
    add_zenoh_open,
    argument_type,
    bounded_number,
    endpoints,
)
from launch_scripts.commands.simulate import build_model
from launch_scripts.output_folder import prepare_output
from launch_scripts.sim_stack import RECORD_SETS, CarTruth, StackOptions
from launch_scripts.stack_models import car_model_and_parameters
from launch_scripts.stack_part import (
    STACK_NODES,
    ZENOH_FLAGS,
    StackPart,
    parse_nodes,
    zenoh_settings,
)
from launch_scripts.visualizer import VizSettings, add_serving_options
from ros4crs.zenoh.admission import check_listening
from ros4crs.zenoh.session import MODES
from sim.drift import load_drift


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

    if args.track is not None:
        read_track(args.track)
    options = _stack_options(args)
    _check_and_prepare(args)
    report = run_stack(args.cars, options, args.duration, args.out, args.domain)
    print(summary(report, Path(args.out)))
    return verdict(report, args.require_laps)


def _stack_options(args: argparse.Namespace) -> StackOptions:
    """What ``run_stack`` and ``run_car_stack`` both take, from their options (no
    ``--hold-safe``: the stack's default; ``crs launch car`` refuses ``--track``)."""
    same_name = (
        "estimator",
        "controller",
        "output",
        "record",
        "blind_start",
        "hold_safe",
        "seed",
        "process_per_node",
        "after_start_up",
    )
    values = {field: getattr(args, field) for field in same_name}
    if args.drive is not None:  # the path follower drives a drive
        values["controller"] = "path"
    return StackOptions(
        **values,
        drive_file=args.drive,
        drive_after=args.drive_after,
        params_file=args.params,
        model=args.model,
        track_file=args.track,
        car=CarTruth(args.car_params, tuple(args.car_effect or ()), args.car_drift, args.car_model),
        part=_stack_part(args),
        online_parameters=_online_names(args.online_params),
        viz=_viz_settings(args),
    )


def _online_names(text: str | None) -> tuple[str, ...]:
    """``--online-params``: the names (checked against the model before the launch)."""
    if text is None:
        return ()
    try:
        return parse_online_names(text)
    except FieldError as error:
        raise error.renamed("--online-params") from None


#: ``crs launch``'s visualizer options, by the :class:`VizSettings` field they set.
VIZ_FLAGS = {"host": "--viz-host", "port": "--viz-port", "page_port": "--viz-page-port"}


def _viz_settings(args: argparse.Namespace) -> VizSettings | None:
    """The visualizer's settings with ``--viz`` (None without; its options refused then);
    errors name the option."""
    given = {field: getattr(args, f"viz_{field}") for field in VIZ_FLAGS}
    if not args.viz:
        for field, value in given.items():
            if value is not None:
                raise ValueError(f"{VIZ_FLAGS[field]}: only with --viz")
        return None
    try:
        return VizSettings(**{field: value for field, value in given.items() if value is not None})
    except FieldError as error:
        raise error.renamed(VIZ_FLAGS[error.field]) from None


def _stack_part(args: argparse.Namespace) -> StackPart:
    """This machine's part of the stack: ``--nodes`` (of the scenario's stack) and the Zenoh
    options (listening beyond loopback authenticated, or ``--zenoh-open`` with one warning
    line: :func:`~ros4crs.zenoh.admission.check_listening`); errors name the option."""
    zenoh = zenoh_settings(
        args.zenoh_mode, args.zenoh_listen, args.zenoh_connect, args.zenoh_config
    )
    if args.zenoh_open and not args.zenoh_listen:
        raise ValueError(f"{ZENOH_OPEN}: only with --zenoh-listen (it opens a listener)")
    if zenoh is not None:
        warning = check_listening(zenoh, args.zenoh_open, ZENOH_FLAGS, ZENOH_OPEN)
        if warning is not None:
            print(f"crs launch: warning: {warning}", file=sys.stderr, flush=True)
    part = StackPart(args.nodes, zenoh)
    part.check(args.scenario, "--nodes")
    if not args.viz and part.nodes is not None and "visualizer" in part.nodes:
        raise ValueError("--nodes: the visualizer runs with --viz")
    if args.require_laps and not part.runs("recorder"):
        raise ValueError(
            "--require-laps: laps are counted from the bag, and --nodes runs no recorder here"
        )
    return part


def _check_and_prepare(args: argparse.Namespace) -> None:
    """What both scenarios check before anything starts (the nodes check these too, but a
    mistake is cheaper to hear before the processes start), then the output folder."""
    if args.output == "velocity" and args.controller != "mpcc":
        raise ValueError(
            f"--output: velocity needs --controller mpcc (the {args.controller} controller "
            "commands torque)"
        )
    if args.drive is None and args.drive_after:
        raise ValueError("--drive-after: needs --drive")
    if args.drive is not None:
        from crs_core.discrepancy.drive_file import load_drive

        if args.output == "velocity":
            raise ValueError("--drive: a drive commands torque, not --output velocity")
        try:
            load_drive(args.drive)
        except ValueError as error:
            raise ValueError(f"--drive: {error}") from None
    if args.params is not None:
        build_model([], 1, args.params, model=args.model)  # a contradicting --model: refused
    car_options = (
        ("--car-params", args.car_params is not None),
        ("--car-model", args.car_model is not None),
        ("--car-effect", bool(args.car_effect)),
        ("--car-drift", args.car_drift is not None),
    )
    given = [option for option, present in car_options if present]
    if given and args.scenario == "car" and not args.emulate:
        raise ValueError(
            f"{given[0]}: only for simulated or emulated cars (a real car is what it is)"
        )
    if args.scenario == "sim" or args.emulate:
        # the cars' model (--car-model, else --car-params', else dynamic) and its parameters
        car_model, car_params = car_model_and_parameters(
            args.car_model, args.car_params, args.params
        )
        model = build_model(args.car_effect or [], 1, car_params, "--car-params", car_model)
        if args.car_drift is not None:
            try:
                load_drift(args.car_drift).model_for(model)
            except FieldError as error:
                raise error.within("--car-drift") from None
    if args.online_params is not None:
        online = _online_names(args.online_params)
        try:
            model = build_model([], 1, args.params, model=args.model)
            model.with_online(online, DEFAULT_REVERSION_S)
        except FieldError as error:
            raise error.renamed("--online-params") from None
    prepare_output(Path(args.out), "launch", args.overwrite)


def verdict(report: dict, require_laps: int) -> int:
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
    options = _stack_options(args)
    _check_and_prepare(args)
    report = run_car_stack(
        args.cars,
        options,
        args.duration,
        Path(args.out),
        args.emulate,
        car_ips,
        args.domain,
        link=link,
    )
    print(summary(report, Path(args.out)))
    return verdict(report, args.require_laps)


def add_arguments(sub: argparse.ArgumentParser) -> None:
    """``crs launch``'s arguments."""
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
    add_cars(sub)
    add_part(sub)
    add_estimator(sub)
    add_viz(sub)
    sub.add_argument(
        "--controller",
        choices=["mpcc", "path"],
        default="mpcc",
        help="mpcc: race (MPCC, 30 Hz; default); path: follow the centreline at 1 m/s (50 Hz)",
    )
    sub.add_argument(
        "--drive",
        type=Path,
        help="a drive.yaml of crs plan-drive: every car's path follower drives it (its speed "
        "and command offsets, begun when the car passes the drive's start at speed; replaces "
        "--controller)",
    )
    sub.add_argument(
        "--drive-after",
        type=bounded_number("drive-after", "s", 0.0, include_low=True),
        default=0.0,
        help="with --drive: the path follower alone races this long first, s (a race and the "
        "drive in one recording, for crs sysid; default 0)",
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
        "--hold-safe",
        choices=HOLD_SAFE_MODES,
        help="MPCC commands safe to hold through a link outage (the car holds the last one "
        "200 ms, then coasts): always (car's default; about 4 %% slower laps), after_outage "
        "(sim's default: from the first outage on), never (racing commands)",
    )
    add_duration(sub, 40.0, "wall-clock time from the launch")
    sub.add_argument(
        "--after-start-up",
        action="store_true",
        help="count --duration from the moment every process has started (at most 60 s after "
        "the launch): a loaded machine's start-up does not shorten the run",
    )
    add_out(sub, "output folder", required=True)
    add_domain(sub, "", "$ROS_DOMAIN_ID, else 42")
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
        "--process-per-node",
        action="store_true",
        help="every node in a process of its own, for debugging (default: a car's simulator or "
        "bridge, estimator and controller share one; the topics are the same)",
    )
    add_track(sub, " of every car")
    sub.add_argument(
        "--params",
        type=Path,
        help="parameter YAML of the cars: the model of the estimators and controllers, and the "
        "simulated truth when it is of the cars' model (--car-model) (default: the model's "
        "defaults, for the dynamic model the Chronos parameters)",
    )
    add_model(
        sub,
        "the estimators' and controllers' model: dynamic (default), kinematic, or FILE.py:CLASS "
        "/ MODULE:CLASS, a model of your own (docs/own-model.md); by default the one --params "
        "names",
    )
    sub.add_argument(
        "--car-params",
        type=Path,
        help="sim, car --emulate: the simulated or emulated cars' own parameter YAML, their "
        "truth apart from the stack's model (--params): a car to identify (default: --params "
        "when it is of the cars' model, else the model's defaults)",
    )
    add_model(
        sub,
        "sim, car --emulate: the simulated or emulated cars' model, their truth: dynamic, "
        "kinematic or FILE.py:CLASS; by default the one --car-params names, else dynamic (not "
        "--model: the stack's model meets the dynamic car)",
        flag="--car-model",
        dest="car_model",
    )
    add_effect(
        sub,
        "sim, car --emulate: a hidden effect of the simulated or emulated cars (repeatable), "
        "e.g. steering_lag=0.05; the stack's model does not have it",
        dest="car_effect",
        flag="--car-effect",
    )
    sub.add_argument(
        "--car-drift",
        type=Path,
        metavar="FILE.yaml",
        help="sim, car --emulate: the simulated or emulated cars change while they race, as this "
        "schedule says (drift: a list of {parameter or effect, at_s or from_s/to_s, factor or "
        "value}, seconds since the car applied its first command; docs/online.md)",
    )
    sub.add_argument(
        "--online-params",
        metavar="NAMES",
        help="parameters every estimator estimates online, comma-separated (e.g. "
        "Cm1,gyro_bias,grip): published on estimate/parameters and written to "
        "OUT/online_parameters_carN.csv (docs/online.md)",
    )
    sub.add_argument(
        "--record",
        choices=list(RECORD_SETS),
        default="all",
        help="what the bag (OUT/bag, MCAP) holds: all (default: sensors, inputs, truth, "
        "estimates, odometry, /tf; replays the estimator offline exactly), estimates (no 250 Hz "
        "sensor streams) or sensors (no estimates)",
    )


def add_viz(sub: argparse.ArgumentParser) -> None:
    """``--viz`` and where the visualizer serves."""
    sub.add_argument(
        "--viz",
        action="store_true",
        help="watch the race live: add the visualizer node (a Foxglove WebSocket and the "
        "built-in page; docs/live-view.md)",
    )
    add_serving_options(sub, "viz-", "--viz: ")


def add_part(sub: argparse.ArgumentParser) -> None:
    """``--nodes`` and the Zenoh link's options (a stack split across machines)."""
    sub.add_argument(
        "--nodes",
        type=argument_type(parse_nodes),
        metavar="NAME[,NAME...]",
        help="run only these nodes of the stack here, for every car (sim: "
        f"{', '.join(STACK_NODES['sim'])}; car: {', '.join(STACK_NODES['car'])}, the emulated "
        "car going with its bridge; default: all); the others run on other machines, joined "
        "by the Zenoh link (docs/several-machines.md)",
    )
    sub.add_argument(
        "--zenoh-listen",
        action="extend",
        type=endpoints,
        metavar="ENDPOINT",
        help="join the other machines through a zenoh_link node that listens on ENDPOINT, "
        "e.g. tcp/0.0.0.0:7447 (repeatable or comma-separated); beyond loopback it needs a "
        "--zenoh-config that authenticates who joins (docs/zenoh/) or --zenoh-open",
    )
    sub.add_argument(
        "--zenoh-connect",
        action="extend",
        type=endpoints,
        metavar="ENDPOINT",
        help="... that connects to ENDPOINT, e.g. tcp/10.0.0.1:7447 (a peer or a router; "
        "repeatable or comma-separated)",
    )
    sub.add_argument(
        "--zenoh-mode",
        choices=MODES,
        help="the link's Zenoh role (default peer; client to join a router only, as a stock "
        "rmw_zenohd needs)",
    )
    sub.add_argument(
        "--zenoh-config",
        type=Path,
        metavar="FILE",
        help="a Zenoh JSON5 configuration the link reads first: TLS, user / password, access "
        "control (the options above are set over it; examples: docs/zenoh/)",
    )
    add_zenoh_open(sub, "--zenoh-listen", "--zenoh-config")


COMMAND = Command(
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
    "-> estimate -> command packet, the bridge's counts and the emulator's motor cut-offs. "
    "Several machines: each runs its --nodes, joined by --zenoh-listen / --zenoh-connect; a "
    "part without the recorder reports its processes only.",
    arguments=add_arguments,
    handler=launch,
)
