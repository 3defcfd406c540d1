"""The first-plane sweep lag of a recording without a stream: a nuisance fitted before the
hypotheses.

A sample pairs the second-plane sweep at its stamp with the latest first-plane sweep before it,
about half a sweep period earlier (:func:`~crs_core.identification.data.plane1_lag`). With the
full-rate stream (simulated datasets) that lag is known; in the real recordings' layout (no
stream) it is not, and the FIE took it as 0. Every plane-1 angle is then read at the wrong
instant: a misfit of about ``lag * d(angle)/dt`` on every sample, shared by every hypothesis,
that the hypotheses then compete to absorb. It does not absorb evenly: on the benchmark's
independent case with hidden Lighthouse plane offsets (0.006 / -0.004 rad, seed 101, 20 s of
joystick data) the FIE cost of the current model is 3117.8 with the lag taken as 0 and 2948.8
at the true 10 ms; ``lighthouse_offset`` lowers it by 54 at 0 and by 74 at 10 ms (its plane-2
offset fits to -0.0026 rad at 0 and -0.0043 at 10 ms), ``wheel_radius_error`` by 72 at 0 and by
64 at 10 ms. With the lag at 0 the training likelihood named the wheel radius; at 10 ms the
plane offsets.

:func:`estimate_plane1_lag` fits the lag as a profile of the current model's FIE cost (the
other parameters and the states refitted), once, before the hypotheses: the lag is a property
of the recording's sensor timing, not of an effect, so every hypothesis is fitted and compared
with the same one. The lag is carried in the dataset's metadata
(:data:`~crs_core.identification.data.PLANE1_LAG_KEY`; a recording can state it there too).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, replace

import numpy as np

from crs_core.dataset import Dataset
from crs_core.identification.data import PLANE1_LAG_KEY
from crs_core.identification.problem import FieSettings
from crs_core.identification.solve import FieResult, WarmStart, identify
from crs_core.measurements import lighthouse_sensor
from crs_core.model import CarModel

#: Spacing of the lags the profile tries, in sample intervals (the median one).
LAG_STEP = 0.25


@dataclass(frozen=True)
class SweepLag:
    """The first-plane sweep lag the workflow used.

    ``source``: ``"stream"`` (known from the full-rate stream), ``"dataset"`` (stated in the
    dataset's metadata), ``"estimated"`` (:func:`estimate_plane1_lag`; ``std`` from the
    profile's curvature) or ``"none"`` (no first-plane data, or not estimated: taken as 0).
    """

    value_s: float | None
    std_s: float | None
    source: str

    def to_dict(self) -> dict[str, float | str | None]:
        return {"value_s": self.value_s, "std_s": self.std_s, "source": self.source}


def with_plane1_lag(dataset: Dataset, lag_s: float) -> Dataset:
    """``dataset`` with its first-plane sweep lag stated as ``lag_s`` (a copy of the metadata;
    ignored by the FIE when the dataset has a stream, which knows the lag)."""
    return replace(dataset, meta={**dataset.meta, PLANE1_LAG_KEY: float(lag_s)})


def plane1_lag_source(dataset: Dataset) -> str:
    """Where the FIE takes ``dataset``'s first-plane lag from: ``"stream"``, ``"dataset"``,
    ``"unknown"`` (taken as 0) or ``"none"`` (no first-plane angle measured)."""
    if not np.isfinite(dataset.y[:, 0:4]).any():
        return "none"
    first = lighthouse_sensor(0, 1)
    if dataset.measurements and any(m.sensor == first for m in dataset.measurements):
        return "stream"
    if dataset.meta.get(PLANE1_LAG_KEY) is not None:
        return "dataset"
    return "unknown"


def estimate_plane1_lag(
    dataset: Dataset,
    model: CarModel,
    current: FieResult,
    settings: FieSettings,
    progress: Callable[[int, float], None] | None = None,
) -> tuple[float, float, FieResult]:
    """The first-plane sweep lag by the FIE's profile cost of ``model`` on ``dataset``:
    ``current`` is its fit with the lag at 0; fits at lags :data:`LAG_STEP` sample intervals
    apart (warm started at ``current``) walk up while the cost falls, at most one sample
    interval (the lag interpolates between neighbouring samples); a parabola through the lowest
    and its neighbours gives the lag and, from the curvature, its std. Returns the lag (s), its
    std (s) and the fit at that lag."""
    interval = float(np.median(np.diff(dataset.t)))
    step = LAG_STEP * interval
    warm = WarmStart({n: current.parameters.value(n) for n in current.fit}, current.states)
    results: dict[float, FieResult] = {0.0: current}

    def cost(lag: float) -> float:
        if lag not in results:
            data = with_plane1_lag(dataset, lag)
            results[lag] = identify(data, model, settings, progress, warm_start=warm)
        return results[lag].cost

    k = 1
    while cost(k * step) < cost((k - 1) * step) and (k + 1) * step <= interval + 1e-12:
        k += 1
    lags = sorted(results)
    i = min(range(len(lags)), key=lambda j: results[lags[j]].cost)
    if i == 0:
        return 0.0, math.inf, current
    i = min(i, len(lags) - 2)
    x = np.array(lags[i - 1 : i + 2])
    a, b, _ = np.polyfit(x, [results[lag].cost for lag in x], 2)
    if a <= 0:
        best = lags[i]
        return best, math.inf, results[best]
    best = float(np.clip(-b / (2 * a), 0.0, interval))
    std = math.sqrt(1.0 / a)  # V = -2 log L + c: var = 2 / V'' = 1 / a
    cost(best)
    return best, std, results[best]
