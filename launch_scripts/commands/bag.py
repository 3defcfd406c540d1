"""``crs bag check|repair``: what a (cut-off) bag holds; a complete copy of it."""

from __future__ import annotations

import argparse
from pathlib import Path

from launch_scripts.arguments import Command


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


def add_arguments(sub: argparse.ArgumentParser) -> None:
    """``crs bag``'s arguments."""
    sub.add_argument("tool", choices=["check", "repair"])
    sub.add_argument(
        "bag", type=Path, help="bag folder (holding metadata.yaml and/or *.mcap), or an .mcap file"
    )
    sub.add_argument("--out", type=Path, help="repair: the new bag folder (must not exist)")


COMMAND = Command(
    "bag",
    help="check a bag, or repair one whose recording was cut off",
    description="check: what a ROS 2 bag (folder or .mcap file) holds (topics, messages, "
    "duration) and, for "
    "an MCAP file cut off by a killed recorder or a full disk, what is still readable and how "
    "much was lost; exit code 0 complete, 1 damaged. repair: write every complete message "
    "of a bag into a new, complete bag at --out (the original is only read).",
    arguments=add_arguments,
    handler=bag_tool,
)
