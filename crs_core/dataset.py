"""Datasets on disk: the layout of the real Chronos recordings, plus what simulation adds.

A dataset folder holds

* ``t.npy`` (N,) stamps, s; ``u.npy`` (2, N) **torque first, steering second** (as recorded);
  ``y.npy`` (13, N) per :data:`Y_CHANNELS`; ``x.npy`` (6, N) a state trajectory (truth when
  simulated, the car's on-line estimate in the real runs);
* ``dataset.yaml`` (optional): source, Lighthouse geometry, sensor rates, and for simulated data
  the truth parameters, effects and noise settings. Without it the real recordings' geometry is
  assumed;
* ``stream.npz`` (optional): the full-rate measurement stream, commanded inputs and truth.

In memory, inputs are in model order ``[steer, torque]``; the swap happens here, by name.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from crs_core.measurements import InputSample, Measurement, lighthouse_sensor
from crs_core.model.chronos import (
    base_station_from_parameters,
    base_station_parameters,
    photodiode_parameters,
)
from crs_core.model.lighthouse import RECORDED_BASE_STATION, RECORDED_PHOTODIODES, BaseStation
from crs_core.parameters import ParameterSet

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


@dataclass(frozen=True)
class Geometry:
    """Lighthouse geometry of a dataset: base stations and photodiode positions (body, m)."""

    base_stations: tuple[BaseStation, ...] = (RECORDED_BASE_STATION,)
    photodiodes: tuple[tuple[float, float], ...] = RECORDED_PHOTODIODES

    def parameters(self) -> ParameterSet:
        """The geometry as model parameters (``bs{i}_*``, ``lh_d{k}_*``)."""
        return photodiode_parameters(self.photodiodes).merged(
            base_station_parameters(self.base_stations)
        )

    @classmethod
    def from_parameters(cls, params: ParameterSet, n_stations: int) -> Geometry:
        diodes = tuple((params.value(f"lh_d{k}_x"), params.value(f"lh_d{k}_y")) for k in range(4))
        stations = tuple(base_station_from_parameters(params, i) for i in range(n_stations))
        return cls(stations, diodes)

    def to_dict(self) -> dict[str, Any]:
        return {
            "base_stations": [
                {
                    "rotation": station.rotation.tolist(),
                    "position": list(station.position),
                    "dt1": station.dt1,
                    "dt2": station.dt2,
                }
                for station in self.base_stations
            ],
            "photodiodes": [list(d) for d in self.photodiodes],
        }

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> Geometry:
        try:
            stations = tuple(
                BaseStation.from_rotation(
                    np.array(s["rotation"], dtype=float), tuple(s["position"]), s["dt1"], s["dt2"]
                )
                for s in data["base_stations"]
            )
            diodes = tuple((float(x), float(y)) for x, y in data["photodiodes"])
        except (KeyError, TypeError, ValueError) as error:
            raise ValueError(f"geometry: malformed ({error!r})") from None
        if len(diodes) != 4:
            raise ValueError("geometry.photodiodes: need exactly 4 (x, y) pairs")
        return cls(stations, diodes)


@dataclass
class Dataset:
    """Samples at Lighthouse stamps, optional full-rate stream, and metadata.

    Attributes
    ----------
    t : (N,) stamps, s.
    u : (N, 2) inputs ``[steer (rad), torque (-)]`` (model order).
    y : (N, 13) measurements per :data:`Y_CHANNELS`.
    x : (N, 6) or None: state trajectory (truth if simulated).
    geometry : Lighthouse geometry.
    meta : free-form metadata saved in ``dataset.yaml`` (source, rates, truth, noise).
    measurements, inputs : the full-rate stream, if kept.
    truth_t, truth_x : full-rate truth (simulated only).
    """

    t: np.ndarray
    u: np.ndarray
    y: np.ndarray
    x: np.ndarray | None = None
    geometry: Geometry = field(default_factory=Geometry)
    meta: dict[str, Any] = field(default_factory=dict)
    measurements: list[Measurement] | None = None
    inputs: list[InputSample] | None = None
    truth_t: np.ndarray | None = None
    truth_x: np.ndarray | None = None

    def __post_init__(self) -> None:
        n = len(self.t)
        _check_array("t", self.t, (n,))
        _check_array("u", self.u, (n, 2))
        _check_array("y", self.y, (n, len(Y_CHANNELS)), allow_nan=True)
        if self.x is not None:
            _check_array("x", self.x, (n, self.x.shape[1] if self.x.ndim == 2 else -1))
        if n > 1 and np.any(np.diff(self.t) <= 0):
            raise ValueError("t: stamps must be strictly increasing")

    # --- disk ---------------------------------------------------------------------------
    @classmethod
    def load(cls, folder: str | Path) -> Dataset:
        """Read a dataset folder (real recording or simulated)."""
        folder = Path(folder)
        if not folder.is_dir():
            raise FileNotFoundError(f"dataset folder {folder} does not exist")
        t = np.load(folder / "t.npy")
        u_recorded = np.load(folder / "u.npy")
        y = np.load(folder / "y.npy")
        if u_recorded.ndim != 2 or u_recorded.shape[0] != 2:
            raise ValueError(f"u.npy: expected shape (2, N), got {u_recorded.shape}")
        if y.ndim != 2 or y.shape[0] != len(Y_CHANNELS):
            raise ValueError(f"y.npy: expected shape ({len(Y_CHANNELS)}, N), got {y.shape}")
        x = np.load(folder / "x.npy").T if (folder / "x.npy").exists() else None
        meta: dict[str, Any] = {"source": "real"}
        geometry = Geometry()
        if (folder / "dataset.yaml").exists():
            meta = yaml.safe_load((folder / "dataset.yaml").read_text()) or {}
            if not isinstance(meta, dict):
                raise ValueError("dataset.yaml: expected a mapping")
            if meta.get("format", FORMAT) != FORMAT:
                raise ValueError(f"dataset.yaml: format {meta['format']!r}, expected {FORMAT!r}")
            if "geometry" in meta:
                geometry = Geometry.from_dict(meta.pop("geometry"))
        dataset = cls(
            t=t, u=u_recorded[::-1].T.copy(), y=y.T.copy(), x=x, geometry=geometry, meta=meta
        )
        if (folder / "stream.npz").exists():
            _read_stream(dataset, folder / "stream.npz")
        return dataset

    def save(self, folder: str | Path) -> Path:
        """Write the dataset folder; returns its path."""
        folder = Path(folder)
        folder.mkdir(parents=True, exist_ok=True)
        np.save(folder / "t.npy", self.t)
        np.save(folder / "u.npy", self.u[:, ::-1].T.copy())  # torque first on disk
        np.save(folder / "y.npy", self.y.T.copy())
        optional = {"x.npy": self.x is not None, "stream.npz": bool(self.measurements)}
        for name, present in optional.items():
            if not present:
                (folder / name).unlink(missing_ok=True)  # no stale file from an earlier save
        if self.x is not None:
            np.save(folder / "x.npy", self.x.T.copy())
        meta = {"format": FORMAT, **self.meta, "geometry": self.geometry.to_dict()}
        meta["y_channels"] = list(Y_CHANNELS)
        (folder / "dataset.yaml").write_text(yaml.safe_dump(_plain(meta), sort_keys=False))
        if self.measurements:
            _write_stream(self, folder / "stream.npz")
        return folder

    # --- views --------------------------------------------------------------------------
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
        raise ValueError(f"{name}: expected an array of shape {shape}")
    if any(want not in (-1, got) for want, got in zip(shape, array.shape, strict=True)):
        raise ValueError(f"{name}: expected shape {shape}, got {array.shape}")
    finite = np.isfinite(array) | (np.isnan(array) if allow_nan else False)
    if not np.all(finite):
        raise ValueError(f"{name}: contains non-finite values")


def _plain(value: Any) -> Any:
    """Convert numpy scalars/arrays and tuples to YAML-safe builtins."""
    if isinstance(value, Mapping):
        return {str(k): _plain(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_plain(v) for v in value]
    if isinstance(value, np.ndarray):
        return _plain(value.tolist())
    if isinstance(value, np.generic):
        return value.item()
    return value


def _write_stream(dataset: Dataset, path: Path) -> None:
    arrays: dict[str, np.ndarray] = {}
    by_sensor: dict[str, list[Measurement]] = {}
    for m in dataset.measurements or []:
        by_sensor.setdefault(m.sensor, []).append(m)
    for sensor, items in by_sensor.items():
        key = sensor.replace("/", "__")
        arrays[f"meas:{key}:t"] = np.array([m.stamp for m in items])
        arrays[f"meas:{key}:v"] = np.stack([m.values for m in items])
    if dataset.inputs:
        arrays["inputs:t"] = np.array([s.stamp for s in dataset.inputs])
        arrays["inputs:u"] = np.stack([s.u for s in dataset.inputs])
    if dataset.truth_t is not None and dataset.truth_x is not None:
        arrays["truth:t"] = dataset.truth_t
        arrays["truth:x"] = dataset.truth_x
    np.savez_compressed(path, **arrays)


def _read_stream(dataset: Dataset, path: Path) -> None:
    with np.load(path) as data:
        measurements = []
        for key in data.files:
            kind, *rest = key.split(":")
            if kind == "meas" and rest[1] == "t":
                sensor = rest[0].replace("__", "/")
                values = data[f"meas:{rest[0]}:v"]
                measurements.extend(
                    Measurement(float(s), sensor, v) for s, v in zip(data[key], values, strict=True)
                )
        measurements.sort(key=lambda m: (m.stamp, m.sensor))
        dataset.measurements = measurements
        if "inputs:t" in data.files:
            dataset.inputs = [
                InputSample(float(s), u)
                for s, u in zip(data["inputs:t"], data["inputs:u"], strict=True)
            ]
        if "truth:t" in data.files:
            dataset.truth_t, dataset.truth_x = data["truth:t"], data["truth:x"]
