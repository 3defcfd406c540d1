"""The minimum-curvature line of a track: how tightly a car within the borders must turn.

A car that uses the track's width turns much less tightly than its centreline: the demo
track's hairpins have a centreline radius of 0.3 m, while a line that swings out and cuts in
turns at 0.35-0.45 m, and its chicanes need almost no turning at all. Corner speeds drawn from
the centreline are therefore far below what a racing controller drives.

:func:`minimum_curvature_line` places a closed line at lateral offsets ``n_i`` from the
centreline, within ``±max_offset``, minimising the sum of its squared curvatures (second
differences of the points at the centreline's spacing): a convex QP in the offsets, solved by
OSQP through CasADi in a few milliseconds. At a fixed spacing a shorter line counts as less
curved, so the line leans inwards where that shortens it (on a circle it is the inner border,
1.18 1/m on a 1 m circle with 0.15 m either side, against 0.87 outside): its corners are a
little tighter than a racing line's, which makes corner speeds drawn from it err on the slow
side. Through the demo track's hairpins it turns at 0.36-0.45 m against the centreline's 0.3.

Conventions: arc length ``s`` along the centreline (m, from the track's first point), offsets
positive to the left of the direction of travel (m), curvature positive turning left (1/m).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import casadi as ca
import numpy as np
from numpy.typing import NDArray
from scipy import sparse

from crs_core.errors import FieldError
from crs_core.track.geometry import Track

__all__ = ["RacingLine", "minimum_curvature_line"]


@dataclass(frozen=True)
class RacingLine:
    """A closed line along a track, sampled at centreline arc lengths.

    Attributes
    ----------
    s : numpy.ndarray
        (n,) centreline arc lengths of the samples, m (evenly spaced, ``[0, length)``).
    offset : numpy.ndarray
        (n,) lateral offsets from the centreline, m (positive left).
    curvature : numpy.ndarray
        (n,) curvature of the line, 1/m (positive turning left).
    """

    s: NDArray[np.float64]
    offset: NDArray[np.float64]
    curvature: NDArray[np.float64]


def minimum_curvature_line(track: Track, max_offset: float, step: float = 0.05) -> RacingLine:
    """The closed line of least squared curvature within ``±max_offset`` (m) of the centreline.

    Parameters
    ----------
    track : Track
    max_offset : float
        Largest lateral offset, m: half the track's width less the car's half width and a
        margin; within ``[0, width / 2)``.
    step : float, optional
        Sample spacing along the centreline, m (> 0, default 0.05).

    Returns
    -------
    RacingLine
    """
    if not (math.isfinite(max_offset) and 0 <= max_offset < track.width / 2):
        raise FieldError(
            "max_offset", f"must be within [0, {track.width / 2:g}) m, got {max_offset!r}"
        )
    if not (math.isfinite(step) and 0 < step < track.length / 4):
        raise FieldError("step", f"must be a number within (0, length / 4) m, got {step!r}")
    n = math.ceil(track.length / step)
    step = track.length / n
    s = np.arange(n, dtype=np.float64) * step
    x, y, heading, _ = track.interpolate(s)
    normal_x, normal_y = -np.sin(heading), np.cos(heading)
    second = _second_difference(n, step)
    # the line's second differences: second @ (centre + offset * normal), per coordinate
    A = sparse.vstack([second @ sparse.diags(normal_x), second @ sparse.diags(normal_y)]).tocsc()
    b = -np.concatenate((second @ x, second @ y))
    hessian = (A.T @ A).tocsc()
    hessian.sort_indices()
    pattern = ca.Sparsity(n, n, hessian.indptr.tolist(), hessian.indices.tolist())
    solver = ca.conic(
        "racing_line",
        "osqp",
        {"h": pattern, "a": ca.Sparsity(0, n)},
        {"osqp": {"verbose": False, "eps_abs": 1e-9, "eps_rel": 1e-9, "max_iter": 100000}},
    )
    result = solver(h=ca.DM(pattern, hessian.data), g=-(A.T @ b), lbx=-max_offset, ubx=max_offset)
    offset = np.clip(np.asarray(result["x"], dtype=float).ravel(), -max_offset, max_offset)
    line_x, line_y = x + offset * normal_x, y + offset * normal_y
    return RacingLine(s, offset, _closed_curvature(line_x, line_y))


def _second_difference(n: int, step: float) -> sparse.csr_matrix:
    """The cyclic second-difference operator over ``step`` squared, (n, n)."""
    rows = np.repeat(np.arange(n), 3)
    cols = (rows + np.tile([-1, 0, 1], n)) % n
    values = np.tile([1.0, -2.0, 1.0], n) / step**2
    return sparse.csr_matrix((values, (rows, cols)), shape=(n, n))


def _closed_curvature(x: NDArray[np.float64], y: NDArray[np.float64]) -> NDArray[np.float64]:
    """Curvature of a closed polyline from central differences (wrapping at the ends)."""
    dx = (np.roll(x, -1) - np.roll(x, 1)) / 2
    dy = (np.roll(y, -1) - np.roll(y, 1)) / 2
    ddx = np.roll(x, -1) - 2 * x + np.roll(x, 1)
    ddy = np.roll(y, -1) - 2 * y + np.roll(y, 1)
    return (dx * ddy - dy * ddx) / np.maximum(dx * dx + dy * dy, 1e-12) ** 1.5
