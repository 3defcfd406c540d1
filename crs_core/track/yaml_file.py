"""The CRS track file: a race track in YAML, and the packaged demo track.

A file holds a top-level key ``track`` with ``xCoords``, ``yCoords`` (m), ``tangentAngle`` (rad),
``arcLength`` (m), ``curvature`` (1/m), ``trackLength`` (m), ``width_of_track`` (m), ``x_init``,
``y_init`` (m) and ``yaw_init`` (rad), in the units and frames of :mod:`crs_core.track.geometry`.

The CRS files may hold more than one lap (``DEMO_TRACK.yaml`` holds two laps, 6932 samples with
``arcLength`` running to ``2 * trackLength``) or repeat the first sample at the end. On loading,
only the samples with ``arcLength < trackLength`` are kept; ``trackLength`` is authoritative for
the loop length.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import yaml
from numpy.typing import NDArray

from crs_core.errors import FieldError

# the validators Track itself uses, so a file and a direct construction fail alike
from crs_core.track.geometry import (
    _MIN_POINTS,
    Track,
    _as_finite_float,
    _as_float_array,
    _check_arc_length,
)
from crs_core.yaml_io import load_yaml

__all__ = ["DEMO_TRACK_PATH", "load_demo_track", "read_track"]

#: Packaged compact copy of the CRS demo race track (every 10th sample of ``DEMO_TRACK.yaml``).
DEMO_TRACK_PATH: Path = Path(__file__).resolve().parents[1] / "data" / "tracks" / "demo_track.yaml"

_ARRAY_KEYS: tuple[str, ...] = ("xCoords", "yCoords", "tangentAngle", "arcLength", "curvature")
_SCALAR_KEYS: tuple[str, ...] = ("trackLength", "width_of_track", "x_init", "y_init", "yaw_init")
_FIELD_TO_KEY: dict[str, str] = {
    "x": "xCoords",
    "y": "yCoords",
    "x, y": "xCoords, yCoords",
    "heading": "tangentAngle",
    "arc_length": "arcLength",
    "length": "trackLength",
    "width": "width_of_track",
    "start_x": "x_init",
    "start_y": "y_init",
    "start_yaw": "yaw_init",
}


def read_track(path: str | Path) -> Track:
    """Load a track from a CRS track YAML file.

    Parameters
    ----------
    path : str or pathlib.Path
        YAML file with a top-level key ``track`` holding ``xCoords``, ``yCoords`` (m),
        ``tangentAngle`` (rad), ``arcLength`` (m), ``curvature`` (1/m), ``trackLength`` (m),
        ``width_of_track`` (m), ``x_init``, ``y_init`` (m) and ``yaw_init`` (rad). Other keys
        (``xRate``, ``yRate``, ``trackWidth``, ``density``) are ignored.

    Returns
    -------
    Track
        One lap: samples with ``arcLength < trackLength`` (files holding several laps or a
        repeated end point are cut to one lap).

    Raises
    ------
    ValueError
        If the file is not a mapping with ``track``, a required key is missing, a list is
        not numeric or has non-finite values, the lists differ in length, there are fewer
        than 10 samples, ``arcLength`` does not start at 0 or does not increase, or the
        centerline does not close. The message names the offending field.
    OSError
        If the file cannot be read.
    """
    path = Path(path)
    with path.open("r", encoding="utf-8") as stream:
        try:
            document = load_yaml(stream)
        except yaml.YAMLError as exc:
            raise FieldError(str(path), f"not valid YAML ({exc})") from None
    if not isinstance(document, dict) or not isinstance(document.get("track"), dict):
        raise FieldError(f"{path}: track", "missing top-level mapping 'track'")
    data = document["track"]
    missing = [k for k in (*_ARRAY_KEYS, *_SCALAR_KEYS) if k not in data]
    if missing:
        raise FieldError(f"{path}: track.{missing[0]}", "required key missing")
    arrays: dict[str, NDArray[np.float64]] = {}
    for key in _ARRAY_KEYS:
        value = data[key]
        if not isinstance(value, list) or not all(
            isinstance(v, int | float) and not isinstance(v, bool) for v in value
        ):
            raise FieldError(f"{path}: track.{key}", "must be a list of numbers")
        try:
            arrays[key] = _as_float_array(f"track.{key}", value)
        except FieldError as exc:
            raise exc.renamed(f"{path}: {exc.field}") from None
    n = arrays["xCoords"].size
    for key in _ARRAY_KEYS:
        if arrays[key].size != n:
            size = arrays[key].size
            raise FieldError(f"{path}: track.{key}", f"has {size} values, xCoords has {n}")
    scalars: dict[str, float] = {}
    for key in _SCALAR_KEYS:
        try:
            scalars[key] = _as_finite_float(f"track.{key}", data[key])
        except FieldError as exc:
            raise exc.renamed(f"{path}: {exc.field}") from None
    length = scalars["trackLength"]
    if not length > 0.0:
        raise FieldError(f"{path}: track.trackLength", f"must be positive, got {length!r}")
    s = arrays["arcLength"]
    try:
        _check_arc_length("track.arcLength", s)
    except FieldError as exc:
        raise exc.renamed(f"{path}: {exc.field}") from None
    # One lap; a tolerance of a micrometre drops an end point repeated at s == trackLength.
    keep = s < length - 1e-6
    if np.count_nonzero(keep) < _MIN_POINTS:
        raise FieldError(
            f"{path}: track.xCoords",
            f"need at least {_MIN_POINTS} samples in one lap, got {np.count_nonzero(keep)}",
        )
    try:
        return Track(
            x=arrays["xCoords"][keep],
            y=arrays["yCoords"][keep],
            heading=arrays["tangentAngle"][keep],
            arc_length=s[keep],
            curvature=arrays["curvature"][keep],
            length=length,
            width=scalars["width_of_track"],
            start_x=scalars["x_init"],
            start_y=scalars["y_init"],
            start_yaw=scalars["yaw_init"],
        )
    except FieldError as exc:  # named by the YAML key rather than the dataclass field
        raise exc.renamed(f"{path}: track.{_FIELD_TO_KEY.get(exc.field, exc.field)}") from None
    except ValueError as exc:
        raise FieldError(f"{path}: track", str(exc)) from None


def load_demo_track() -> Track:
    """Load the packaged CRS demo race track.

    The packaged file is a compact copy (every 10th sample, 30 samples per metre, values rounded
    to 1e-6) of ``DEMO_TRACK.yaml``, the track the real Chronos cars race on in the published
    CRS experiments (BSD 2-Clause data, see ``data/tracks/LICENSE-data.txt``). Lap length
    11.568 m, drivable width 0.46 m, driven counter-clockwise.

    Returns
    -------
    Track
        The demo track.
    """
    return read_track(DEMO_TRACK_PATH)
