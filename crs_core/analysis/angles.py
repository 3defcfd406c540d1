"""Angles: the suite's one wrap to ``[-pi, pi)``.

Every numeric (numpy / float) angle wrap in the suite is :func:`wrap_angle`: yaw errors,
innovations, track headings, Lighthouse sweep residuals. The CasADi expressions of the EKF wrap
symbolically with ``atan2(sin, cos)`` (:mod:`crs_core.estimation.ekf`); the two agree everywhere
except exactly at ``±pi``.

This module imports numpy only, so any low-level module (track, estimation, calibration,
control) may import it.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = ["wrap_angle"]

_TURN = 2.0 * np.pi


def wrap_angle(angle: ArrayLike) -> NDArray[np.float64] | float:
    """Wrap angles to ``[-pi, pi)``.

    An angle already in ``[-pi, pi)`` comes back unchanged (bit for bit, so a small error of
    1e-9 rad keeps its full precision); otherwise whole turns are subtracted. ``pi`` and ``-pi``
    both become ``-pi``. NaN stays NaN; infinities become NaN.

    Parameters
    ----------
    angle : array_like
        Angle(s) or angle differences, rad.

    Returns
    -------
    float or numpy.ndarray
        The wrapped angle(s), rad; a float for a scalar input, an array of the input's shape
        otherwise.
    """
    a = np.asarray(angle, dtype=float)
    wrapped = a - _TURN * np.floor((a + np.pi) / _TURN)
    # rounding can leave a result one ulp outside [-pi, pi)
    wrapped = np.where(wrapped >= np.pi, wrapped - _TURN, wrapped)
    wrapped = np.where(wrapped < -np.pi, wrapped + _TURN, wrapped)
    return float(wrapped) if wrapped.ndim == 0 else wrapped
