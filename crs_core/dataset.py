"""Datasets on disk: the layout of the real Chronos recordings, plus what simulation adds.

In memory, inputs are in model order ``[steer, torque]``; the swap happens here, by name. Every
file is validated when it is read: a malformed one raises :class:`~crs_core.errors.FieldError`
(a ``ValueError``; a missing required one ``FileNotFoundError``) whose field names the file or
the key (``x.npy``, ``stream.npz``, ``geometry.base_stations[0].position``), with a one-line
message ``"<field>: <reason>"``.

Dataset folder format (``chronos-dataset/1``): write your own recordings into it
------------------------------------------------------------------------------------
All arrays are float ``.npy`` / ``.npz`` written with plain numpy (``np.save``,
``np.savez``); every stamp is in seconds on one clock, any origin (the real recordings use
Unix time). SI units, rad; REP 103 frames (world x-y plane, z up; body x forward, y left).

=================  =========  ===================================================================
file               shape      content
=================  =========  ===================================================================
``t.npy``          (N,)       sample stamps, s, strictly increasing. The time base of ``y``,
                              ``u``, ``x`` and of offline estimates (``crs estimate``).
``y.npy``          (13, N)    samples per :data:`Y_CHANNELS`: Lighthouse station 0 plane 1
                              and plane 2 sweep angles of photodiodes 0..3 (rad), wheel speeds
                              fl, fr, rl, rr (rad/s), yaw rate (rad/s). **NaN = channel not
                              available** at that sample (a sensor you do not have: all NaN).
``u.npy``          (2, N)     optional commanded inputs, **torque first** (normalised, -1..1),
                              steering second (rad), as in the real recordings. Without it the
                              dataset has no inputs (``Dataset.u is None``): estimators then
                              estimate them (``inputs="estimated"``).
``x.npy``          (6, N)     optional reference states ``[x, y, yaw, vx, vy, omega]`` (m, m,
                              rad, m/s, m/s, rad/s; world pose, body velocities): simulation
                              truth, or a recording's own on-line estimate (not ground truth).
``dataset.yaml``   mapping    optional metadata and the Lighthouse geometry (below). Without
                              it, or without its ``geometry`` block, the geometry of the real
                              recordings is assumed; a block with the photodiodes alone means
                              the stations are not known yet.
``stream.npz``     archive    optional full-rate measurement stream (below); when present,
                              estimators use it instead of the samples in ``y.npy``.
=================  =========  ===================================================================

``stream.npz`` holds, per sensor, two arrays named after the stream sensor name
(:mod:`crs_core.measurements`) with ``/`` replaced by ``__``; any sensor may be absent:

* ``meas:<key>:t`` (n,) stamps, s, and ``meas:<key>:v`` (n, k) values, with ``<key>`` one of
  ``imu`` (k = 3: a_x, a_y in m/s^2, body; yaw rate in rad/s), ``gyro`` (k = 1, rad/s),
  ``wheel_encoders`` (k = 4: fl, fr, rl, rr in rad/s), ``pose`` (k = 3: x, y in m, yaw in rad;
  motion capture) and ``lighthouse__<station>__<plane>`` (k = 4: sweep angles of photodiodes
  0..3 in rad, plane 1 or 2, station < the number of stations in the geometry, any station
  when the geometry gives none). A row with NaN
  is a missing sample and is skipped; inf is an error. Rows need not be sorted.
* ``inputs:t`` (n,) and ``inputs:u`` (n, 2): commanded inputs in **model order, steering
  first** (rad, then normalised torque), each held from its stamp on. Optional.
* ``truth:t`` (n,) and ``truth:x`` (n, 6): dense simulation truth. Optional.

Any other array name is an error (it catches a misspelt key). Reading and writing:
:mod:`crs_core.stream_file`.

``dataset.yaml`` (all keys optional)::

    format: chronos-dataset/1
    source: my-lab-recording   # "simulated" marks x.npy as simulation truth
    geometry:
      base_stations:           # one entry per Lighthouse base station, index = list position
        - rotation: [[-0.0017, 0.9995, 0.0319],    # world-from-station rotation, rows
                     [-0.3676, 0.0290, -0.9295],
                     [-0.9300, -0.0133, 0.3674]]
          position: [0.189, 0.138, 1.743]          # station position, world, m
          dt1: -0.0509                              # factory light-plane tilt offsets, rad
          dt2: 0.0464
      photodiodes: [[-0.045, 0.015], [-0.06, 0.015], [-0.045, -0.015], [-0.06, -0.015]]
                               # photodiodes 0..3 in the car body frame (x, y), m; z = 0

``photodiodes`` is required in a ``geometry`` block; ``base_stations`` is optional. A new
set-up knows only its deck layout, ``geometry: {photodiodes: [[x, y], ...]}``: such a dataset
loads (:attr:`Geometry.base_stations` is None) and is what ``crs calibrate-lighthouse`` fits the
stations from (moving calibration: sweeps plus motion-capture poses); everything that needs the
stations (estimators, identification, validation, pose fixes) refuses it with
``geometry.base_stations: the dataset's geometry gives no base stations: calibrate them first
(crs calibrate-lighthouse)``. Paste the ``geometry.yaml`` the calibration writes over the block.

Any other keys (rates, noise settings, notes) are kept in :attr:`Dataset.meta`.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal, overload

import numpy as np
import yaml

from crs_core.errors import FieldError
from crs_core.measurements import InputSample, Measurement, lighthouse_sensor
from crs_core.model.chronos import (
    base_station_from_parameters,
    base_station_parameters,
    photodiode_parameters,
)
from crs_core.model.lighthouse import RECORDED_BASE_STATION, RECORDED_PHOTODIODES, BaseStation
from crs_core.parameters import ParameterSet
from crs_core.stream_file import read_stream, write_stream
from crs_core.yaml_io import load_yaml

#: Row names of ``y.npy``.
Y_CHANNELS = (
    *(f"lh_plane1_diode{k}" for k in range(4)),
    *(f"lh_plane2_diode{k}" for k in range(4)),
    "wheel_fl",
    "wheel_fr",
    "wheel_rl",
    "wheel_rr",
    "yaw_rate",
)
FORMAT = "chronos-dataset/1"
#: ``meta`` key of a time split's recording start (:meth:`Dataset.samples`), s.
RECORDING_START_KEY = "recording_start_s"


#: The error of a reader that needs base stations when the geometry gives none.
NO_STATIONS = (
    "the dataset's geometry gives no base stations: calibrate them first (crs calibrate-lighthouse)"
)


@dataclass(frozen=True)
class Geometry:
    """Lighthouse geometry of a dataset: base stations and photodiode positions (body, m).

    Attributes
    ----------
    base_stations : the base stations (world frame), or None when they are not known yet: a
        geometry of the deck layout alone, as a new set-up has before its first calibration
        (``crs calibrate-lighthouse`` fits them from the sweeps). Whatever needs the stations
        (a model, an estimator, a pose fix) reads them through :meth:`known_stations`.
    photodiodes : photodiodes 0..3 of the Lighthouse deck (x, y) in the body frame, m; z = 0.
    """

    base_stations: tuple[BaseStation, ...] | None = (RECORDED_BASE_STATION,)
    photodiodes: tuple[tuple[float, float], ...] = RECORDED_PHOTODIODES

    def known_stations(self) -> tuple[BaseStation, ...]:
        """The base stations; a :class:`~crs_core.errors.FieldError` naming
        ``geometry.base_stations`` when the geometry gives none."""
        if self.base_stations is None:
            raise FieldError("geometry.base_stations", NO_STATIONS)
        return self.base_stations

    def parameters(self) -> ParameterSet:
        """The geometry as model parameters (``bs{i}_*``, ``lh_d{k}_*``); needs the stations
        (:meth:`known_stations`)."""
        return photodiode_parameters(self.photodiodes).merged(
            base_station_parameters(self.known_stations())
        )

    @classmethod
    def from_parameters(cls, params: ParameterSet, n_stations: int) -> Geometry:
        diodes = tuple((params.value(f"lh_d{k}_x"), params.value(f"lh_d{k}_y")) for k in range(4))
        stations = tuple(base_station_from_parameters(params, i) for i in range(n_stations))
        return cls(stations, diodes)

    def to_dict(self) -> dict[str, Any]:
        """The ``geometry`` block of ``dataset.yaml`` (no ``base_stations`` when unknown)."""
        out: dict[str, Any] = {}
        if self.base_stations is not None:
            out["base_stations"] = [
                {
                    "rotation": station.rotation.tolist(),
                    "position": list(station.position),
                    "dt1": station.dt1,
                    "dt2": station.dt2,
                }
                for station in self.base_stations
            ]
        out["photodiodes"] = [list(d) for d in self.photodiodes]
        return out

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> Geometry:
        """The ``geometry`` block of ``dataset.yaml`` (module docstring); ``ValueError`` naming
        the field when it is malformed. ``base_stations`` may be left out (or null): the
        stations are then unknown (``base_stations`` None)."""
        given = [k for k in ("base_stations", "photodiodes") if data.get(k) is not None]
        if not given:
            raise FieldError(
                "geometry",
                "gives neither base_stations nor photodiodes; give at least the photodiodes "
                "of the Lighthouse deck (body frame, m)",
            )
        try:
            stations = None
            if "base_stations" in given:
                stations = tuple(_base_stations(data["base_stations"]))
            if "photodiodes" not in given:
                raise FieldError(
                    "geometry.photodiodes",
                    "missing: photodiodes 0..3 of the Lighthouse deck, [[x, y] x 4] in the body "
                    "frame, m",
                )
            diodes = _finite_array("geometry.photodiodes", data["photodiodes"], (4, 2))
        except FieldError:
            raise
        except (TypeError, ValueError) as error:
            raise FieldError("geometry", f"malformed ({error})") from None
        return cls(stations, tuple((float(x), float(y)) for x, y in diodes))

    @classmethod
    def from_file(cls, path: str | Path) -> Geometry:
        """The ``geometry`` block of a YAML file: the ``geometry.yaml`` of ``crs
        calibrate-lighthouse``, or a dataset's ``dataset.yaml``. Errors name the file (it cannot
        be read, is not YAML, has no ``geometry``) or the block's field."""
        path = Path(path)
        try:
            document = load_yaml(path.read_text())
        except OSError as error:
            raise FieldError(str(path), f"cannot read it ({error.strerror or error})") from None
        except yaml.YAMLError as error:
            problem = str(error).splitlines()[0]
            raise FieldError(str(path), f"not valid YAML ({problem})") from None
        if not isinstance(document, Mapping) or not isinstance(document.get("geometry"), Mapping):
            raise FieldError(str(path), "expected a mapping with a 'geometry' block")
        return cls.from_dict(document["geometry"])


def _base_stations(entries: Any) -> list[BaseStation]:
    """The ``base_stations`` list of a geometry block (at least one entry)."""
    if not isinstance(entries, list):
        raise FieldError("geometry.base_stations", f"expected a list, got {entries!r}")
    if not entries:
        raise FieldError(
            "geometry.base_stations",
            "needs at least one base station (leave the key out while they are unknown)",
        )
    stations = []
    for i, entry in enumerate(entries):
        name = f"geometry.base_stations[{i}]"
        if not isinstance(entry, Mapping):
            raise FieldError(name, f"expected a mapping, got {entry!r}")
        missing = [k for k in ("rotation", "position", "dt1", "dt2") if k not in entry]
        if missing:
            lacks = f"malformed ({name[9:]} lacks {', '.join(missing)})"
            raise FieldError("geometry", lacks)
        rotation = _finite_array(f"{name}.rotation", entry["rotation"], (3, 3))
        position = _finite_array(f"{name}.position", entry["position"], (3,))
        dt = [_finite_array(f"{name}.{k}", entry[k], ()) for k in ("dt1", "dt2")]
        try:
            station = BaseStation.from_rotation(
                rotation, tuple(position), float(dt[0]), float(dt[1])
            )
        except FieldError as error:  # the rotation's own check names the rotation
            raise error.renamed(f"{name}.rotation") from None
        except ValueError as error:
            raise FieldError(f"{name}.rotation", str(error)) from None
        stations.append(station)
    return stations


def _finite_array(name: str, value: Any, shape: tuple[int, ...]) -> np.ndarray:
    try:
        array = np.array(value, dtype=float)
    except (TypeError, ValueError):
        raise FieldError(name, f"expected numbers, got {value!r}") from None
    if array.shape != shape:
        what = "a number" if not shape else f"shape {shape}"
        raise FieldError(name, f"expected {what}, got {value!r}")
    if not np.all(np.isfinite(array)):
        raise FieldError(name, "contains non-finite values")
    return array


@dataclass
class Dataset:
    """Samples at Lighthouse stamps, optional full-rate stream, and metadata.

    Attributes
    ----------
    t : (N,) stamps, s.
    u : (N, 2) or None: commanded inputs ``[steer (rad), torque (-)]`` (model order); None when
        the recording has none (no ``u.npy``).
    y : (N, 13) measurements per :data:`Y_CHANNELS`.
    x : (N, 6) or None: state trajectory (truth if simulated).
    geometry : Lighthouse geometry.
    meta : free-form metadata saved in ``dataset.yaml`` (source, rates, truth, noise).
    measurements, inputs : the full-rate stream, if kept.
    truth_t, truth_x : full-rate truth (simulated only).
    """

    t: np.ndarray
    u: np.ndarray | None
    y: np.ndarray
    x: np.ndarray | None = None
    geometry: Geometry = field(default_factory=Geometry)
    meta: dict[str, Any] = field(default_factory=dict)
    measurements: list[Measurement] | None = None
    inputs: list[InputSample] | None = None
    truth_t: np.ndarray | None = None
    truth_x: np.ndarray | None = None

    def __post_init__(self) -> None:
        if not isinstance(self.t, np.ndarray) or self.t.ndim != 1:
            raise FieldError("t", "expected a 1-D array of stamps")
        n = len(self.t)
        _check_array("t", self.t, (n,))
        if self.u is not None:
            _check_array("u", self.u, (n, 2))
        _check_array("y", self.y, (n, len(Y_CHANNELS)), allow_nan=True)
        if self.x is not None:
            _check_array("x", self.x, (n, self.x.shape[1] if self.x.ndim == 2 else -1))
        if n > 1 and np.any(np.diff(self.t) <= 0):
            raise FieldError("t", "stamps must be strictly increasing")

    # --- disk ---------------------------------------------------------------------------
    @classmethod
    def load(cls, folder: str | Path) -> Dataset:
        """Read a dataset folder (real recording or simulated)."""
        folder = Path(folder)
        if not folder.is_dir():
            problem = "is not a folder" if folder.exists() else "does not exist"
            raise FileNotFoundError(f"dataset folder {folder} {problem}")
        t = _load_npy(folder, "t.npy", required=True)
        y = _load_npy(folder, "y.npy", required=True)
        u_recorded = _load_npy(folder, "u.npy")
        u_recorded = None if u_recorded is not None and np.isnan(u_recorded).all() else u_recorded
        x_recorded = _load_npy(folder, "x.npy")
        if t.ndim != 1:
            raise FieldError("t.npy", f"expected shape (N,), got {t.shape}")
        if u_recorded is not None and (u_recorded.ndim != 2 or u_recorded.shape[0] != 2):
            raise FieldError("u.npy", f"expected shape (2, N), got {u_recorded.shape}")
        if y.ndim != 2 or y.shape[0] != len(Y_CHANNELS):
            raise FieldError("y.npy", f"expected shape ({len(Y_CHANNELS)}, N), got {y.shape}")
        if x_recorded is not None and (x_recorded.ndim != 2 or x_recorded.shape[0] != 6):
            raise FieldError("x.npy", f"expected shape (6, N), got {x_recorded.shape}")
        for name, array in (("y.npy", y), ("u.npy", u_recorded), ("x.npy", x_recorded)):
            if array is not None and array.shape[1] != t.size:
                raise FieldError(
                    name,
                    f"has {array.shape[1]} samples but t.npy has {t.size} (one column per stamp)",
                )
        x = x_recorded.T.copy() if x_recorded is not None else None
        u = u_recorded[::-1].T.copy() if u_recorded is not None else None
        meta: dict[str, Any] = {"source": "real"}
        geometry = Geometry()
        if (folder / "dataset.yaml").exists():
            try:
                meta = load_yaml((folder / "dataset.yaml").read_text()) or {}
            except yaml.YAMLError as error:
                problem = str(error).splitlines()[0]
                raise FieldError("dataset.yaml", f"not valid YAML ({problem})") from None
            if not isinstance(meta, dict):
                raise FieldError("dataset.yaml", "expected a mapping")
            if meta.get("format", FORMAT) != FORMAT:
                raise FieldError("dataset.yaml", f"format {meta['format']!r}, expected {FORMAT!r}")
            if "geometry" in meta:
                if not isinstance(meta["geometry"], Mapping):
                    raise FieldError("dataset.yaml", "geometry must be a mapping")
                geometry = Geometry.from_dict(meta.pop("geometry"))
        dataset = cls(t=t, u=u, y=y.T.copy(), x=x, geometry=geometry, meta=meta)
        if (folder / "stream.npz").exists():
            stations = None if geometry.base_stations is None else len(geometry.base_stations)
            stream = read_stream(folder / "stream.npz", stations)
            dataset.measurements, dataset.inputs = stream.measurements, stream.inputs
            dataset.truth_t, dataset.truth_x = stream.truth_t, stream.truth_x
        return dataset

    def save(self, folder: str | Path, metadata: bool = True) -> Path:
        """Write the dataset folder; returns its path. ``metadata=False`` writes the layout of
        the real recordings: the ``.npy`` files only (no ``dataset.yaml``, no stream), read back
        with the recordings' geometry."""
        folder = Path(folder)
        folder.mkdir(parents=True, exist_ok=True)
        np.save(folder / "t.npy", self.t)
        if self.u is not None:
            np.save(folder / "u.npy", self.u[:, ::-1].T.copy())  # torque first on disk
        np.save(folder / "y.npy", self.y.T.copy())
        optional = {
            "u.npy": self.u is not None,
            "x.npy": self.x is not None,
            "stream.npz": metadata and bool(self.measurements or self.inputs),
            "dataset.yaml": metadata,
        }
        for name, present in optional.items():
            if not present:
                (folder / name).unlink(missing_ok=True)  # no stale file from an earlier save
        if self.x is not None:
            np.save(folder / "x.npy", self.x.T.copy())
        if not metadata:
            return folder
        meta = {"format": FORMAT, **self.meta, "geometry": self.geometry.to_dict()}
        meta["y_channels"] = list(Y_CHANNELS)
        (folder / "dataset.yaml").write_text(yaml.safe_dump(plain(meta), sort_keys=False))
        if optional["stream.npz"]:
            write_stream(
                folder / "stream.npz", self.measurements, self.inputs, self.truth_t, self.truth_x
            )
        return folder

    # --- views --------------------------------------------------------------------------
    @property
    def recording_start(self) -> float:
        """Stamp of the recording's first sample, s: this dataset's own, or for a time split
        (:meth:`samples`) the first of the recording it was cut from (a model term's time ``t``
        counts from it)."""
        return float(self.meta.get(RECORDING_START_KEY, self.t[0]))

    def samples(self, start: int, stop: int) -> Dataset:
        """Samples ``start:stop`` as a dataset of their own (a time split for training and
        held-out data). The full-rate stream keeps what falls within the kept stamps, and the
        command in force at the first kept stamp."""
        n = len(self.t)
        start, stop, _ = slice(start, stop).indices(n)
        if stop - start < 2:
            raise FieldError("samples", f"{start}:{stop} keeps fewer than 2 of {n} samples")
        first, last = self.t[start], self.t[stop - 1]
        measurements = inputs = truth_t = truth_x = None
        if self.measurements is not None:
            measurements = [m for m in self.measurements if first <= m.stamp <= last]
        if self.inputs is not None:
            before = [s for s in self.inputs if s.stamp <= first]
            inputs = before[-1:] + [s for s in self.inputs if first < s.stamp <= last]
        if self.truth_t is not None and self.truth_x is not None:
            keep = (self.truth_t >= first) & (self.truth_t <= last)
            truth_t, truth_x = self.truth_t[keep], self.truth_x[keep]
        return Dataset(
            t=self.t[start:stop],
            u=None if self.u is None else self.u[start:stop],
            y=self.y[start:stop],
            x=None if self.x is None else self.x[start:stop],
            geometry=self.geometry,
            meta={**self.meta, RECORDING_START_KEY: self.recording_start},
            measurements=measurements,
            inputs=inputs,
            truth_t=truth_t,
            truth_x=truth_x,
        )

    def sample_stream(self) -> list[Measurement]:
        """The 13-channel samples as a measurement stream (for datasets without ``stream.npz``).

        Each stamp yields both Lighthouse planes of station 0, the wheel speeds and the yaw rate
        (``gyro``); NaN entries (missing channels) are skipped.
        """
        out = []
        groups = (
            (lighthouse_sensor(0, 1), slice(0, 4)),
            (lighthouse_sensor(0, 2), slice(4, 8)),
            ("wheel_encoders", slice(8, 12)),
            ("gyro", slice(12, 13)),
        )
        for stamp, row in zip(self.t, self.y, strict=True):
            for sensor, rows in groups:
                if np.all(np.isfinite(row[rows])):
                    out.append(Measurement(float(stamp), sensor, row[rows]))
        return out


def _check_array(name: str, array: np.ndarray, shape: tuple[int, ...], allow_nan=False) -> None:
    if not isinstance(array, np.ndarray) or array.ndim != len(shape):
        raise FieldError(name, f"expected an array of shape {shape}")
    if any(want not in (-1, got) for want, got in zip(shape, array.shape, strict=True)):
        raise FieldError(name, f"expected shape {shape}, got {array.shape}")
    finite = np.isfinite(array) | (np.isnan(array) if allow_nan else False)
    if not np.all(finite):
        raise FieldError(name, "contains non-finite values")


def plain(value: Any, nonfinite_as_none: bool = False) -> Any:
    """Numpy scalars and arrays, tuples and mappings as YAML / JSON builtins (a non-finite float
    as ``None`` with ``nonfinite_as_none``, for strict JSON)."""
    if isinstance(value, Mapping):
        return {str(k): plain(v, nonfinite_as_none) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [plain(v, nonfinite_as_none) for v in value]
    if isinstance(value, np.ndarray):
        return plain(value.tolist(), nonfinite_as_none)
    if isinstance(value, np.generic):
        value = value.item()
    if nonfinite_as_none and isinstance(value, float) and not math.isfinite(value):
        return None
    return value


@overload
def _load_npy(folder: Path, name: str, required: Literal[True]) -> np.ndarray: ...
@overload
def _load_npy(folder: Path, name: str, required: bool = False) -> np.ndarray | None: ...
def _load_npy(folder: Path, name: str, required: bool = False) -> np.ndarray | None:
    """A numeric array from ``folder/name`` as float; None if absent and not required."""
    path = folder / name
    if not path.exists():
        if required:
            raise FileNotFoundError(f"{name}: missing in dataset folder {folder}")
        return None
    try:
        array = np.load(path, allow_pickle=False)
    except (OSError, ValueError, EOFError) as error:
        problem = str(error).splitlines()[0] if str(error) else type(error).__name__
        raise FieldError(name, f"not a readable .npy array ({problem})") from None
    if not isinstance(array, np.ndarray) or array.dtype.kind not in "fiu":
        raise FieldError(name, "expected a numeric array")
    return array.astype(float, copy=False)
