"""``crs consistency``: the sensor models against the real recordings."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from benchmarks.machine import REAL_DATA
from launch_scripts.arguments import Command, add_out, command_line
from launch_scripts.output_folder import prepare_output_file
from launch_scripts.recording import add_bag_options, load_recording


def consistency(args: argparse.Namespace) -> None:
    """Real-data consistency of the sensor models (median / p95 error per channel)."""
    from crs_core.analysis.consistency import channel_errors

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
        rows[Path(folder).name] = channel_errors(load_recording(Path(folder), args, "--data"))
    text = json.dumps({"command": command_line(), "runs": rows}, indent=2)
    if args.out:
        Path(args.out).write_text(text)
    print(f"{'channel':18s}" + "".join(f"{name[-12:]:>26s}" for name in rows))
    for channel in next(iter(rows.values())):
        cells = "".join(
            f"{r[channel]['median']:12.4g} /{r[channel]['p95']:11.4g}" for r in rows.values()
        )
        print(f"{channel:18s}{cells}")
    print("(median / p95 of |recorded - model(recorded state)|; rad for Lighthouse, rad/s else)")


def add_arguments(sub: argparse.ArgumentParser) -> None:
    """``crs consistency``'s arguments."""
    sub.add_argument(
        "--data",
        type=Path,
        action="append",
        help=f"a recording with reference states: dataset folder or bag (repeatable; default: "
        f"the real recordings in {REAL_DATA})",
    )
    add_bag_options(sub)
    add_out(sub, "also write the table as JSON to this file")


COMMAND = Command(
    "consistency",
    help="sensor models vs. the real recordings",
    description="Replay recorded states through the sensor models and print the error per "
    "channel (median / p95).",
    arguments=add_arguments,
    handler=consistency,
)
