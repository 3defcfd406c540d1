"""The ``stream.npz`` file of a dataset: the full-rate measurement stream, inputs and truth.

The format is documented in :mod:`crs_core.dataset`. Reading validates every array and names
it: a :class:`~crs_core.errors.FieldError` with the field ``stream.npz`` and a reason that starts
with the array (``stream.npz: meas:imu:v expected shape (n, 3), got ...``); a row of values with
NaN is a missing sample and is skipped.
"""

from __future__ import annotations

import zipfile
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from crs_core.errors import FieldError
from crs_core.measurements import InputSample, Measurement, parse_lighthouse, sensor_size

#: The field of every error in reading the stream (its reason names the array).
STREAM = "stream.npz"


@dataclass
class StreamContents:
    """What ``stream.npz`` holds: measurements (sorted by stamp, sensor), inputs and truth."""

    measurements: list[Measurement]
    inputs: list[InputSample] | None = None
    truth_t: np.ndarray | None = None
    truth_x: np.ndarray | None = None


def write_stream(
    path: Path,
    measurements: Sequence[Measurement] | None,
    inputs: Sequence[InputSample] | None,
    truth_t: np.ndarray | None = None,
    truth_x: np.ndarray | None = None,
) -> None:
    """Write ``stream.npz`` (compressed)."""
    arrays: dict[str, np.ndarray] = {}
    by_sensor: dict[str, list[Measurement]] = {}
    for m in measurements or []:
        by_sensor.setdefault(m.sensor, []).append(m)
    for sensor, items in by_sensor.items():
        key = sensor.replace("/", "__")
        arrays[f"meas:{key}:t"] = np.array([m.stamp for m in items])
        arrays[f"meas:{key}:v"] = np.stack([m.values for m in items])
    if inputs:
        arrays["inputs:t"] = np.array([s.stamp for s in inputs])
        arrays["inputs:u"] = np.stack([s.u for s in inputs])
    if truth_t is not None and truth_x is not None:
        arrays["truth:t"] = truth_t
        arrays["truth:x"] = truth_x
    # numpy's stub lets any keyword be allow_pickle (a bool); these keys are "meas:...",
    # "inputs:..." and "truth:..." only
    np.savez_compressed(path, **arrays)  # type: ignore[arg-type]


def read_stream(path: Path, stations: int | None) -> StreamContents:
    """Read ``stream.npz``; ``stations`` is the number of base stations of the geometry (None:
    the geometry gives none yet, so sweeps of any station are kept)."""
    try:
        archive = np.load(path, allow_pickle=False)
    except (OSError, ValueError, EOFError, zipfile.BadZipFile) as error:
        problem = str(error).splitlines()[0] if str(error) else type(error).__name__
        raise FieldError(STREAM, f"not a readable .npz archive ({problem})") from None
    if not isinstance(archive, np.lib.npyio.NpzFile):
        raise FieldError(STREAM, "not an .npz archive")
    with archive as data:
        arrays = {}
        for key in data.files:
            try:
                arrays[key] = np.asarray(data[key])
            except (OSError, ValueError, EOFError, zipfile.BadZipFile) as error:
                raise FieldError(STREAM, f"{key} cannot be read ({error})") from None
    measurements = []
    for key in arrays:
        kind, *rest = key.split(":")
        if kind == "meas" and len(rest) == 2 and rest[1] in ("t", "v"):
            if rest[1] == "t":
                measurements += _stream_sensor(arrays, rest[0], stations)
            elif f"meas:{rest[0]}:t" not in arrays:
                raise FieldError(STREAM, f"{key} has no stamps meas:{rest[0]}:t")
        elif key not in ("inputs:t", "inputs:u", "truth:t", "truth:x"):
            raise FieldError(
                STREAM, f"unknown array {key!r} (expected meas:<sensor>:t|v, inputs:t|u, truth:t|x)"
            )
    measurements.sort(key=lambda m: (m.stamp, m.sensor))
    contents = StreamContents(measurements)
    for group, width in (("inputs", "u"), ("truth", "x")):
        stamps, values = arrays.get(f"{group}:t"), arrays.get(f"{group}:{width}")
        if (stamps is None) != (values is None):
            raise FieldError(STREAM, f"{group}:t and {group}:{width} must come together")
        if stamps is None or values is None:  # (both, by the check above)
            continue
        columns = 2 if group == "inputs" else -1
        stamps, values = _stream_arrays(f"{group}:t", stamps, f"{group}:{width}", values, columns)
        if not np.all(np.isfinite(values)):
            raise FieldError(STREAM, f"{group}:{width} contains non-finite values")
        if group == "inputs":
            order = np.argsort(stamps, kind="stable")
            contents.inputs = [InputSample(float(stamps[i]), values[i]) for i in order]
        else:
            contents.truth_t, contents.truth_x = stamps, values
    return contents


def _stream_arrays(
    t_name: str, stamps: np.ndarray, v_name: str, values: np.ndarray, columns: int
) -> tuple[np.ndarray, np.ndarray]:
    """Stamps (n,) and values (n, columns) of one stream entry, validated by name."""
    if stamps.dtype.kind not in "fiu" or stamps.ndim != 1:
        raise FieldError(STREAM, f"{t_name} must be a 1-D numeric array of stamps")
    if not np.all(np.isfinite(stamps)):
        raise FieldError(STREAM, f"{t_name} contains non-finite stamps")
    want = f"({stamps.size}, {columns if columns > 0 else 'k'})"
    if values.dtype.kind not in "fiu" or values.ndim != 2 or values.shape[0] != stamps.size:
        raise FieldError(STREAM, f"{v_name} expected shape {want}, got {values.shape}")
    if columns > 0 and values.shape[1] != columns:
        raise FieldError(STREAM, f"{v_name} expected shape {want}, got {values.shape}")
    return stamps.astype(float), values.astype(float)


def _stream_sensor(
    arrays: Mapping[str, np.ndarray], key: str, stations: int | None
) -> list[Measurement]:
    """The measurements of one sensor of ``stream.npz``; NaN rows (missing samples) skipped."""
    sensor = key.replace("__", "/")
    try:
        size = sensor_size(sensor)
    except FieldError:
        raise FieldError(
            STREAM,
            f"meas:{key}:t names an unknown sensor {sensor!r} (imu, gyro, "
            "wheel_encoders, pose, lighthouse__<station>__<plane>)",
        ) from None
    lighthouse = parse_lighthouse(sensor)
    if lighthouse is not None and stations is not None and lighthouse[0] >= stations:
        raise FieldError(
            STREAM,
            f"meas:{key} is base station {lighthouse[0]}, but the geometry has "
            f"{stations} (dataset.yaml geometry.base_stations)",
        )
    if f"meas:{key}:v" not in arrays:
        raise FieldError(STREAM, f"meas:{key}:t has no values meas:{key}:v")
    stamps, values = _stream_arrays(
        f"meas:{key}:t", arrays[f"meas:{key}:t"], f"meas:{key}:v", arrays[f"meas:{key}:v"], size
    )
    if np.any(np.isinf(values)):
        raise FieldError(STREAM, f"meas:{key}:v contains inf")
    present = np.all(np.isfinite(values), axis=1)
    return [
        Measurement(float(stamp), sensor, row)
        for stamp, row in zip(stamps[present], values[present], strict=True)
    ]
