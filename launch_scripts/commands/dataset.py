"""``crs dataset``: a bag as a dataset folder (argument handling only; the conversion is
:mod:`ros4crs.bag_dataset`)."""

from __future__ import annotations

import argparse
from collections import Counter
from pathlib import Path

from crs_core.errors import FieldError
from launch_scripts.arguments import Command, add_out
from launch_scripts.output_folder import prepare_output
from launch_scripts.recording import add_bag_options, load_recording
from ros4crs.bag_dataset import INPUT_CHOICES, REFERENCE_CHOICES, is_bag


def run(args: argparse.Namespace) -> int:
    """Convert, write the folder, print what it holds."""
    if not is_bag(args.bag):
        raise FieldError(
            "BAG",
            f"{args.bag} is not a bag (a folder with metadata.yaml or .mcap files, or an "
            ".mcap file)",
        )
    dataset = load_recording(args.bag, args, "BAG", inputs=args.inputs, reference=args.reference)
    out = prepare_output(args.out, "dataset", args.overwrite)
    dataset.save(out)
    sensors = Counter(m.sensor for m in dataset.measurements or ())
    meta = dataset.meta
    print(
        f"dataset: {dataset.t.size} samples over {dataset.t[-1] - dataset.t[0]:.1f} s of "
        f"{meta['car'] or 'the car'}; inputs {meta['inputs'] or 'none'}; reference "
        f"{meta['reference'] or 'none'}"
    )
    print("stream: " + ", ".join(f"{name} {count}" for name, count in sorted(sensors.items())))
    print(f"wrote {Path(out)}/ (its dataset.yaml says where each part came from)")
    return 0


def add_arguments(sub: argparse.ArgumentParser) -> None:
    """``crs dataset``'s arguments."""
    sub.add_argument("bag", type=Path, metavar="BAG", help="bag folder or .mcap file")
    add_bag_options(sub)
    sub.add_argument(
        "--inputs",
        default="auto",
        choices=INPUT_CHOICES,
        help="u from the inputs the car applied (input/applied) or the commands sent (input); "
        "default auto: applied where the bag has them",
    )
    sub.add_argument(
        "--reference",
        default="auto",
        choices=REFERENCE_CHOICES,
        help="x from the simulation truth (ground_truth) or the car's on-line estimates "
        "(estimate/state); default auto: the truth, else the estimates",
    )
    add_out(sub, "the dataset folder to write", required=True)


COMMAND = Command(
    "dataset",
    help="turn a recorded bag into a dataset folder",
    description="Write one car's recording in a bag (crs launch sim|car, or any bag with "
    "this suite's topics) as a dataset folder (crs_core.dataset format) every offline command "
    "reads: stream.npz (every sensor reading, inputs, truth), the 13-channel samples at the "
    "Lighthouse sweeps (t.npy, y.npy), u.npy from the recorded inputs and x.npy from the "
    "recorded truth or estimates, labelled in dataset.yaml. The offline commands also take the "
    "bag itself.",
    arguments=add_arguments,
    handler=run,
)
