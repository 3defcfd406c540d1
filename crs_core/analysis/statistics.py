"""Summary statistics of a sample: the one place a median, a 95th percentile and friends are
computed for benchmarks, reports and logs; and the ellipse of a 2-D covariance.

Call sites choose which statistics they report (``keys``) and how many decimals they keep
(``digits``); the numbers are numpy's (``np.median``, ``np.percentile`` with its default linear
interpolation).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from crs_core.errors import FieldError

__all__ = ["covariance_ellipse", "summary"]


_FUNCTIONS: dict[str, Callable[[np.ndarray], Any]] = {
    "mean": np.mean,
    "median": np.median,
    "min": np.min,
    "max": np.max,
}


def _statistic(values: np.ndarray, key: str) -> float:
    percentile = key.startswith("p") and key[1:].replace(".", "", 1).isdigit()
    if key not in _FUNCTIONS and not percentile:
        raise FieldError("keys", f"unknown statistic {key!r} (mean, median, min, max, pNN or n)")
    if values.size == 0:
        return math.nan
    if percentile:
        return float(np.percentile(values, float(key[1:])))
    return float(_FUNCTIONS[key](values))


def summary(
    values: ArrayLike,
    keys: Sequence[str] = ("median", "p95", "max"),
    digits: int | None = None,
) -> dict[str, float]:
    """Summary statistics of ``values``, keyed by name, in the order of ``keys``.

    Parameters
    ----------
    values : array_like
        The sample, any shape (flattened), in the unit the caller reports. NaN is not skipped:
        filter it out first if it means "missing".
    keys : sequence of str, optional
        Which statistics: ``"mean"``, ``"median"``, ``"min"``, ``"max"``, ``"pNN"`` (the NN-th
        percentile, e.g. ``"p95"``, ``"p99"``, ``"p99.9"``) and ``"n"`` (the sample size, an
        int). Default median, p95, max.
    digits : int, optional
        Round every statistic (not ``n``) to this many decimals (Python's ``round``). Default:
        no rounding.

    Returns
    -------
    dict
        ``{key: value}``; every statistic is NaN for an empty sample.

    Raises
    ------
    ValueError
        If a key is not one of the above.
    """
    values = np.asarray(values, dtype=float).ravel()
    out: dict[str, float] = {}
    for key in keys:
        if key == "n":
            out[key] = int(values.size)
            continue
        value = _statistic(values, key)
        out[key] = round(value, digits) if digits is not None else value
    return out


def covariance_ellipse(
    centre: ArrayLike, covariance: ArrayLike, sigma: float, n: int
) -> np.ndarray:
    """The ``sigma``-sigma ellipse of a 2 x 2 covariance (symmetric, positive semi-definite)
    around ``centre`` (its first two values): ``(n, 2)`` points, in the units of ``centre``."""
    values, vectors = np.linalg.eigh(np.asarray(covariance, dtype=float))
    angle = np.linspace(0.0, 2.0 * math.pi, n, endpoint=False)
    unit = np.stack([np.cos(angle), np.sin(angle)], axis=1)
    axes = sigma * (unit * np.sqrt(np.maximum(values, 0.0))) @ vectors.T
    return np.asarray(centre, dtype=float)[:2] + axes
