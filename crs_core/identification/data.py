"""The data of the FIE: a dataset's samples, measurement weights and held-command segments.

:class:`FieData` turns a :class:`~crs_core.dataset.Dataset` into the arrays the FIE problem uses
(model order, NaN masked out with weight 0), and validates it with one-line ``ValueError``
messages naming the field.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np

from crs_core.dataset import Dataset
from crs_core.errors import FieldError, parse_finite
from crs_core.estimation.base import sensor_group
from crs_core.estimation.noise import EstimatorNoise
from crs_core.measurements import lighthouse_sensor

#: Dataset columns per model sensor: (sensor name in the model, columns of ``y``).
Y_LAYOUT = (
    (lighthouse_sensor(0, 1), slice(0, 4)),
    (lighthouse_sensor(0, 2), slice(4, 8)),
    ("wheel_encoders", slice(8, 12)),
    ("gyro", slice(12, 13)),
)
#: Fewest samples the FIE accepts.
MIN_SAMPLES = 20
#: :attr:`Dataset.meta` key (a ``dataset.yaml`` key) of the first-plane sweep lag, s, of a
#: dataset without a stream (see :func:`plane1_lag`).
PLANE1_LAG_KEY = "lighthouse_plane1_lag_s"


@dataclass(frozen=True)
class FieData:
    """The arrays of a dataset the FIE uses (model order, masks for missing values).

    ``y`` has NaN replaced by 0 and ``weight`` is ``1 / sigma`` where measured, 0 where not.
    """

    t: np.ndarray
    u: np.ndarray
    y: np.ndarray
    weight: np.ndarray
    plane1_lag: np.ndarray
    segment_u: np.ndarray
    segment_dt: np.ndarray
    segment_count: np.ndarray

    @classmethod
    def from_dataset(cls, dataset: Dataset, noise: EstimatorNoise) -> FieData:
        """Validate ``dataset`` for identification; ``ValueError`` naming the field."""
        n = len(dataset.t)
        if n < MIN_SAMPLES:
            raise FieldError(
                "dataset", f"{n} samples are too few for identification (>= {MIN_SAMPLES})"
            )
        if dataset.u is None:
            raise FieldError("dataset", "has no inputs (u.npy); identification needs the commands")
        measured = np.isfinite(dataset.y)
        empty = [sensor for sensor, columns in Y_LAYOUT if not measured[:, columns].any()]
        if len(empty) == len(Y_LAYOUT):
            raise FieldError("dataset", "y.npy is NaN everywhere (no measurement at all)")
        sigma = np.concatenate([noise.measurement_std(sensor) for sensor, _ in Y_LAYOUT])
        weight = np.where(measured, 1.0 / sigma, 0.0)
        segment_u, segment_dt, segment_count = input_segments(dataset)
        return cls(
            plane1_lag=plane1_lag(dataset),
            segment_u=segment_u,
            segment_dt=segment_dt,
            segment_count=segment_count,
            t=np.asarray(dataset.t, dtype=float),
            u=np.asarray(dataset.u, dtype=float),
            y=np.where(measured, dataset.y, 0.0),
            weight=weight,
        )

    def explained_by(self, explains: Sequence[str]) -> FieData:
        """These data with the channels of sensor groups outside ``explains`` (a plant's
        :attr:`~crs_core.model.plant.Plant.explains`) weighted 0: a model is fitted to what it
        can explain (the kinematic bicycle not to the gyro of an understeering car)."""
        weight = self.weight.copy()
        for sensor, columns in Y_LAYOUT:
            if sensor_group(sensor) not in explains:
                weight[:, columns] = 0.0
        if not weight.any():
            raise FieldError("dataset", "has no measurement the model explains")
        return replace(self, weight=weight)

    @property
    def plane1_alpha(self) -> np.ndarray:
        """Weight of the previous sample in the state of the plane-1 sweep (linear
        interpolation back by :attr:`plane1_lag`), ``(N,)`` in [0, 1]."""
        alpha = np.zeros(len(self.t))
        alpha[1:] = np.clip(self.plane1_lag[1:] / np.diff(self.t), 0.0, 1.0)
        return alpha

    @property
    def channels_present(self) -> list[str]:
        """Model sensors with at least one measured value."""
        return [s for s, cols in Y_LAYOUT if (self.weight[:, cols] > 0).any()]


def input_segments(dataset: Dataset) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The commands held over each sample interval, split where the command changes.

    With the full-rate input stream (``stream.npz``: the simulator's commands at the controller
    rate) an interval ``[t_k, t_{k+1}]`` is split at every command stamp inside it. Without one,
    ``u`` holds samples of the command signal at the sample stamps (the real recordings
    interpolate it onto them), not commands held from them: the interval holds the signal's
    value at its middle, :math:`(u_k + u_{k+1}) / 2`. Holding :math:`u_k` instead would act
    half a sample interval (about 10 ms) late on average, and a fitted input delay or actuator
    lag would come out short by as much. Returns ``u`` ``(K, M, 2)``,
    segment lengths ``(K, M)`` (0 beyond the interval's count) and counts ``(K,)``, with
    ``K = N - 1`` intervals and ``M`` the most segments of any interval.
    """
    t, u = dataset.t, np.asarray(dataset.u, dtype=float)
    k_count = len(t) - 1
    if not dataset.inputs:
        middle = 0.5 * (u[:-1] + u[1:])
        return middle[:, None, :], np.diff(t)[:, None], np.ones(k_count, dtype=int)
    stamps = np.array([s.stamp for s in dataset.inputs])
    order = np.argsort(stamps, kind="stable")
    stamps = stamps[order]
    values = np.stack([dataset.inputs[i].u for i in order])
    segments: list[list[tuple[np.ndarray, float]]] = []
    for k in range(k_count):
        start, end = t[k], t[k + 1]
        i = np.searchsorted(stamps, start, side="right") - 1
        current = values[i] if i >= 0 else u[k]
        inside = np.flatnonzero((stamps > start) & (stamps < end))
        pieces, edge = [], start
        for j in inside:
            if stamps[j] > edge:
                pieces.append((current, stamps[j] - edge))
                edge = stamps[j]
            current = values[j]
        pieces.append((current, end - edge))
        segments.append(pieces)
    m = max(len(p) for p in segments)
    seg_u, seg_dt = np.zeros((k_count, m, 2)), np.zeros((k_count, m))
    for k, pieces in enumerate(segments):
        for piece, (value, length) in enumerate(pieces):
            seg_u[k, piece], seg_dt[k, piece] = value, length
    return seg_u, seg_dt, np.array([len(p) for p in segments])


def plane1_lag(dataset: Dataset) -> np.ndarray:
    """How long before each sample stamp its first-plane sweep was taken, s ``(N,)``.

    A sample pairs the second-plane sweep at its stamp with the latest first-plane sweep
    before it (about half a sweep period earlier). With the full-rate stream the lag is known
    (simulated datasets); without one (the real recordings) it is the metadata's
    :data:`PLANE1_LAG_KEY` when stated (the same for every sample but the first; ``crs
    discrepancy`` estimates it), else taken as 0.
    """
    lag = np.zeros(len(dataset.t))
    if not dataset.measurements:
        stated = dataset.meta.get(PLANE1_LAG_KEY)
        if stated is not None:
            value = parse_finite(stated)
            if value is None or value < 0.0:
                raise FieldError(PLANE1_LAG_KEY, f"expected a finite lag >= 0 s, got {stated!r}")
            lag[1:] = value
        return lag
    first = lighthouse_sensor(0, 1)
    stamps = np.sort([m.stamp for m in dataset.measurements if m.sensor == first])
    if not stamps.size:
        return lag
    index = np.searchsorted(stamps, dataset.t + 1e-12, side="right") - 1
    found = index >= 0
    lag[found] = dataset.t[found] - stamps[index[found]]
    return np.clip(lag, 0.0, None)
