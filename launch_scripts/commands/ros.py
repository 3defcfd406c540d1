"""``crs ros topics|echo|hz``: small stand-ins for the ``ros2`` command line."""

from __future__ import annotations

import argparse
import json

from launch_scripts.arguments import Command, bounded_number


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


def add_arguments(sub: argparse.ArgumentParser) -> None:
    """``crs ros``'s arguments."""
    sub.add_argument("tool", choices=["topics", "echo", "hz"], help="which tool")
    sub.add_argument("topic", nargs="?", help="echo, hz: the topic, e.g. /car1/estimate/state")
    sub.add_argument(
        "--count",
        type=bounded_number("count", "", 0, 1e6, int),
        default=1,
        help="echo: messages to print (default 1)",
    )
    for option, default, help_text in (
        ("--window", 2.0, "hz: seconds to listen (default 2)"),
        ("--wait", 1.0, "topics: discovery time, s (default 1)"),
        ("--timeout", 5.0, "echo, hz: give up after this many s without a message (default 5)"),
    ):
        seconds = bounded_number(option.removeprefix("--"), "s", 0.0, 3600.0)
        sub.add_argument(option, type=seconds, default=default, help=help_text)


COMMAND = Command(
    "ros",
    help="topics, echo, hz (no ros2 CLI here)",
    description="topics: list the topics and types seen in the ROS domain ($ROS_DOMAIN_ID). "
    "echo: print the next messages of a topic. hz: its receive rate (JSON: rate_hz, "
    "messages, gap_ms_median, gap_ms_max).",
    arguments=add_arguments,
    handler=ros_tool,
)
