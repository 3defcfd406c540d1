"""``crs viz``: the visualizer node alone, against a stack that runs already (this machine's
DDS, or a far one through a ``crs launch --nodes ... --zenoh-*`` part): it joins and leaves
without disturbing it (its subscriptions are best effort, and it publishes nothing to ROS)."""

from __future__ import annotations

import argparse
import os
from pathlib import Path

from crs_core.errors import FieldError
from launch_scripts.arguments import Command, add_domain, add_track
from launch_scripts.visualizer import VIZ_NODE, VizSettings, add_serving_options

#: ``crs viz``'s options, by the :class:`VizSettings` field they set.
FLAGS = {"host": "--host", "port": "--port", "page_port": "--page-port"}


def node_arguments(args: argparse.Namespace) -> list[str]:
    """The visualizer node's command line (``--ros-args``) for ``crs viz``'s options; errors
    name the option."""
    from ros4crs.visualizer_node import parse_cars

    try:
        given = {field: getattr(args, field) for field in FLAGS}
        settings = VizSettings(**{k: v for k, v in given.items() if v is not None})
    except FieldError as error:
        raise error.renamed(FLAGS[error.field]) from None
    parameters = settings.parameters()
    if args.cars is not None:
        try:
            parameters["cars"] = ",".join(parse_cars(args.cars))
        except ValueError as error:
            raise FieldError("--cars", str(error)) from None
    if args.track is not None:
        if not args.track.is_file():
            raise FieldError("--track", f"{args.track}: no such file")
        parameters["track_file"] = str(args.track.resolve())
    command = ["crs-viz", "--ros-args", "-r", f"__node:={VIZ_NODE[0]}"]
    for name, value in parameters.items():
        command += ["-p", f"{name}:={value}"]
    return command


#: The cars of a written layout unless ``--cars`` names them.
LAYOUT_CARS = ("car1", "car2")


def write_layout(args: argparse.Namespace) -> Path:
    """``--layout FILE``: the Foxglove layout of ``--cars`` (default car1, car2) on ``--track``
    written to FILE (which must not exist); errors name the option."""
    from crs_core.track import load_demo_track, read_track
    from ros4crs.visualizer_node import parse_cars
    from ros4crs.viz_layout import layout_json, live_layout

    path: Path = args.layout
    if path.exists():
        raise FieldError("--layout", f"{path} exists (remove it, or give another file)")
    try:
        cars = parse_cars(args.cars) if args.cars is not None else LAYOUT_CARS
    except ValueError as error:
        raise FieldError("--cars", str(error)) from None
    if not cars:
        raise FieldError("--cars", "names no car")
    if args.track is not None and not args.track.is_file():
        raise FieldError("--track", f"{args.track}: no such file")
    track = read_track(args.track) if args.track is not None else load_demo_track()
    path.write_text(layout_json(live_layout(cars, track)))
    print(f"wrote {path}: the live view of {', '.join(cars)} (Foxglove: Layout -> Import)")
    return path


def viz(args: argparse.Namespace) -> int:
    """Run the visualizer until Ctrl-C or SIGTERM (exit code 0; 2 when it cannot start); with
    ``--layout`` write the Foxglove layout and exit."""
    if args.layout is not None:
        write_layout(args)
        return 0
    command = node_arguments(args)
    if args.domain is not None:
        os.environ["ROS_DOMAIN_ID"] = str(args.domain)
    from ros4crs.visualizer_node import main

    return main(command)


def add_arguments(sub: argparse.ArgumentParser) -> None:
    """``crs viz``'s arguments."""
    add_serving_options(sub, "")
    sub.add_argument(
        "--cars",
        metavar="NS[,NS...]",
        help="the cars' namespaces, e.g. car1,car2 (default: every /carN in the graph)",
    )
    add_track(sub, " the cars race")
    sub.add_argument(
        "--layout",
        type=Path,
        metavar="FILE",
        help="write the Foxglove layout of --cars (default car1,car2) on --track to FILE and "
        "exit (docs/foxglove/chronos-layout.json is the default one)",
    )
    add_domain(sub, " of the running stack", "$ROS_DOMAIN_ID")


COMMAND = Command(
    "viz",
    help="watch a running stack live (Foxglove WebSocket and the built-in page)",
    description="The visualizer node alone, against a running stack: a Foxglove WebSocket "
    "(ws://HOST:PORT, subprotocol foxglove.sdk.v1; open it in the Foxglove app with "
    "docs/foxglove/chronos-layout.json) and the built-in page (http://HOST:PAGE_PORT/). Viewers "
    "can only watch: nothing they do reaches a car. Runs until Ctrl-C (docs/live-view.md).",
    arguments=add_arguments,
    handler=viz,
)
