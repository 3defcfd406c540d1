"""A recording on the command line: a dataset folder, or a bag recorded by ``crs launch``.

Every offline command (``estimate``, ``sysid``, ``validate``, ``discrepancy``, ``consistency``,
``calibrate-lighthouse moving``, ``dataset``) takes either where it takes a recording
(:func:`ros4crs.bag_dataset.load_recording`), with the bag options of :func:`add_bag_options`:
``--car NAME`` (needed only when the bag holds several cars) and ``--geometry FILE`` (the
Lighthouse geometry of a bag's recording: a calibration's ``geometry.yaml`` or a
``dataset.yaml``; default the real recordings', which the simulator and the emulator use too).
What a bag's conversion leaves out or assumes is one ``warning:`` line each on stderr.
"""

from __future__ import annotations

import argparse
import sys
import warnings
from pathlib import Path

from crs_core.dataset import Dataset, Geometry
from crs_core.errors import FieldError

#: The help of a recording argument.
RECORDING_HELP = (
    "dataset folder (crs_core.dataset format), or a bag (folder or .mcap file) recorded by "
    "crs launch"
)


def add_bag_options(parser: argparse.ArgumentParser) -> None:
    """``--car`` and ``--geometry``: which car of a bag, and its Lighthouse geometry."""
    parser.add_argument(
        "--car", help="a bag's car (its namespace, e.g. car2); needed when it holds several"
    )
    parser.add_argument(
        "--geometry",
        type=Path,
        help="a bag's Lighthouse geometry: a geometry.yaml of crs calibrate-lighthouse or a "
        "dataset.yaml (default: the real recordings', as the simulator and emulator use)",
    )


def load_recording(
    path: Path, args: argparse.Namespace, option: str = "DATASET", **bag_options: str
) -> Dataset:
    """The recording at ``path`` (``args``: its ``--car`` and ``--geometry``, where the command
    has them; ``bag_options``: ``inputs`` and ``reference`` of
    :func:`~ros4crs.bag_dataset.dataset_from_bag`); errors name the option (``DATASET: ...``,
    ``--car: ...``), and what a bag's conversion left out is printed as warnings."""
    from ros4crs.bag_dataset import load_recording as load

    car, geometry_file = getattr(args, "car", None), getattr(args, "geometry", None)
    try:
        geometry = Geometry.from_file(geometry_file) if geometry_file is not None else None
    except FieldError as error:
        raise FieldError("--geometry", str(error)) from None
    try:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            dataset = load(path, car, geometry, **bag_options)
    except FileNotFoundError as error:
        raise FieldError(option, str(error)) from None
    except FieldError as error:
        names = {
            "car": "--car",
            "geometry": "--geometry",
            "bag": option,
            "inputs": "--inputs",
            "reference": "--reference",
        }
        raise error.renamed(names.get(error.field, error.field)) from None
    notes = [str(w.message) for w in caught]
    if geometry is None and "bag" in dataset.meta:  # a bag's conversion records the bag
        notes.insert(0, "a bag without --geometry: the real recordings' Lighthouse geometry")
    for note in notes:
        print(f"warning: {option}: {note}", file=sys.stderr)
    return dataset
