"""State-error metrics shared by offline estimation, reports and tests (SI units, yaw wrapped)."""

from __future__ import annotations

import numpy as np

#: Names of the base states ``[x, y, yaw, vx, vy, omega]``, in order.
STATE_NAMES = ("x", "y", "yaw", "vx", "vy", "omega")


def state_errors(estimate: np.ndarray, reference: np.ndarray) -> np.ndarray:
    """``estimate - reference`` per sample, shape (n, 6); the yaw error wrapped to (-pi, pi].

    Parameters
    ----------
    estimate, reference : np.ndarray
        (n, 6) base states ``[x, y, yaw, vx, vy, omega]`` (m, m, rad, m/s, m/s, rad/s); extra
        columns are ignored. Yaw may be wrapped or unwrapped in either.
    """
    error = np.asarray(estimate, dtype=float)[:, :6] - np.asarray(reference, dtype=float)[:, :6]
    error[:, 2] = np.arctan2(np.sin(error[:, 2]), np.cos(error[:, 2]))
    return error


def state_rmse(
    estimate: np.ndarray, reference: np.ndarray, mask: np.ndarray | None = None
) -> dict[str, float] | None:
    """Root-mean-square error per state and of the position (``position``: sqrt(x² + y²)).

    Only the samples where ``mask`` is true count; ``None`` when none does.
    """
    error = state_errors(estimate, reference)
    if mask is not None:
        error = error[np.asarray(mask, dtype=bool)]
    if not len(error):
        return None
    values = np.sqrt(np.mean(error**2, axis=0))
    out = {name: float(v) for name, v in zip(STATE_NAMES, values, strict=True)}
    out["position"] = float(np.hypot(values[0], values[1]))
    return out
