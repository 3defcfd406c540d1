"""The positions an open-loop prediction is compared with (the paper's validation metric).

A dataset with reference states (``x.npy``) gives their positions: simulation truth, or a
recording's own on-line estimate. A recording without them (a user's bag or dataset holds
Lighthouse sweeps, not states) gives each sample's **Lighthouse fix**: the least-squares planar
pose explaining the sample's eight sweep angles of station 0 in the dataset's geometry
(:class:`~crs_core.estimation.lighthouse_pose.LighthousePoseSolver`: no dynamics, no model of
the car beyond its photodiode layout), NaN where a sample has no credible fix. On the two real
recordings these fixes lie within 4 mm (median; 1 cm at the 95th percentile) of the car's own
on-line estimate.

The fixes of a dataset are computed once (about 0.3 ms a sample) and kept for the datasets seen
last, so that the many predictors of an identification or a discrepancy search share them.
"""

from __future__ import annotations

import hashlib
from collections import OrderedDict
from dataclasses import dataclass

import numpy as np

from crs_core.dataset import Dataset
from crs_core.estimation.lighthouse_pose import LighthousePoseSolver
from crs_core.estimation.offline import dataset_model, reference_label
from crs_core.measurements import lighthouse_sensor

__all__ = ["LIGHTHOUSE_REFERENCE", "PositionReference", "position_reference"]

#: How the Lighthouse reference is named in reports.
LIGHTHOUSE_REFERENCE = (
    "each sample's Lighthouse fix (least-squares pose from its 8 sweep angles, no dynamics; "
    "the dataset has no reference states x.npy; not motion capture)"
)
#: Datasets whose Lighthouse fixes are kept.
_KEPT = 8
_fixes: OrderedDict[str, np.ndarray] = OrderedDict()


@dataclass(frozen=True)
class PositionReference:
    """Reference positions of a dataset's samples.

    Attributes
    ----------
    xy : np.ndarray
        ``(N, 2)`` world x, y per sample, m (NaN: no reference at that sample).
    description : str
        What they are, for reports.
    """

    xy: np.ndarray
    description: str


def position_reference(dataset: Dataset) -> PositionReference:
    """The reference positions of ``dataset``'s samples: its ``x`` where it has one, else the
    Lighthouse fixes of its samples."""
    if dataset.x is not None:
        return PositionReference(dataset.x[:, :2], reference_label(dataset))
    return PositionReference(_lighthouse_fixes(dataset), LIGHTHOUSE_REFERENCE)


def _lighthouse_fixes(dataset: Dataset) -> np.ndarray:
    """``(N, 2)`` positions of the samples' Lighthouse fixes (station 0), NaN where none."""
    key = hashlib.sha256()
    for array in (dataset.t, dataset.y[:, :8], dataset.geometry.parameters().vector()):
        key.update(np.ascontiguousarray(array, dtype=float).tobytes())
    digest = key.hexdigest()
    if digest in _fixes:
        _fixes.move_to_end(digest)
        return _fixes[digest]
    solver = LighthousePoseSolver(dataset_model(dataset))
    xy = np.full((len(dataset.t), 2), np.nan)
    for k, (stamp, row) in enumerate(zip(dataset.t, dataset.y, strict=True)):
        if np.all(np.isfinite(row[:8])):
            sweeps = {lighthouse_sensor(0, 1): row[:4], lighthouse_sensor(0, 2): row[4:8]}
            fix = solver.solve(sweeps, float(stamp))
            if fix is not None:
                xy[k] = fix.pose[:2]
    xy.setflags(write=False)
    _fixes[digest] = xy
    while len(_fixes) > _KEPT:
        _fixes.popitem(last=False)
    return xy
