"""Metrics shared by benchmarks, offline estimation, reports and tests: estimation errors, laps.

SI units throughout (m, rad, m/s, rad/s) unless an argument says otherwise; yaw errors are
wrapped to [-pi, pi). The figures that show these numbers draw them with
:mod:`crs_core.analysis.figures`.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from crs_core.analysis.angles import wrap_angle
from crs_core.analysis.laps import LapCounter
from crs_core.model.car_state import CAR_STATE_NAMES
from crs_core.track import Track

#: Names of the car states ``[x, y, yaw, vx, vy, omega]``, in order.
STATE_NAMES = CAR_STATE_NAMES


def state_errors(estimate: ArrayLike, reference: ArrayLike) -> np.ndarray:
    """``estimate - reference`` per sample; the yaw error (column 2) wrapped to [-pi, pi).

    Parameters
    ----------
    estimate, reference : array_like
        (n, k) states ``[x, y, yaw, vx, vy, omega, ...]`` (m, m, rad, m/s, m/s, rad/s), both with
        the same k >= 3; columns past the 6 base states are ignored. Yaw may be wrapped or
        unwrapped in either.

    Returns
    -------
    numpy.ndarray
        (n, min(k, 6)) errors in the units of the states.
    """
    error = np.asarray(estimate, dtype=float)[:, :6] - np.asarray(reference, dtype=float)[:, :6]
    error[:, 2] = wrap_angle(error[:, 2])
    return error


def pose_errors(estimate: ArrayLike, reference: ArrayLike) -> np.ndarray:
    """:func:`state_errors` of the pose ``x, y, yaw`` only.

    Parameters
    ----------
    estimate, reference : array_like
        (n, >= 3) states ``[x, y, yaw, ...]`` (m, m, rad; yaw wrapped or unwrapped); they may
        have different numbers of columns.

    Returns
    -------
    numpy.ndarray
        (n, 3) errors: m, m, rad (the yaw error wrapped to [-pi, pi)).
    """
    estimate, reference = np.asarray(estimate, dtype=float), np.asarray(reference, dtype=float)
    return state_errors(estimate[:, :3], reference[:, :3])


def interpolate_states(t: ArrayLike, stamps: ArrayLike, states: ArrayLike) -> np.ndarray:
    """A trajectory's states ``[x, y, yaw, ...]`` at other times, by linear interpolation.

    The yaw is unwrapped before interpolating, so that a wrap by 2 pi between two samples is
    not smeared into a half turn back.

    Parameters
    ----------
    t : array_like
        (m,) times to interpolate at, s. Outside ``stamps`` the end values are held.
    stamps : array_like
        (n,) increasing times of ``states``, s.
    states : array_like
        (n, k >= 3) states ``[x, y, yaw, ...]`` (m, m, rad, ...).

    Returns
    -------
    numpy.ndarray
        (m, k) states; the yaw continuous (not wrapped).
    """
    t, stamps = np.asarray(t, dtype=float), np.asarray(stamps, dtype=float)
    states = np.array(states, dtype=float)
    states[:, 2] = np.unwrap(states[:, 2])
    return np.stack([np.interp(t, stamps, c) for c in states.T], axis=1)


def interpolate_pose(t: ArrayLike, stamps: ArrayLike, states: ArrayLike) -> np.ndarray:
    """The pose ``x, y, yaw`` (m, m, rad) of a trajectory at other times:
    :func:`interpolate_states` of its first three states."""
    return interpolate_states(t, stamps, np.asarray(states, dtype=float)[:, :3])


def pose_error_bands(
    estimate: ArrayLike,
    variance: ArrayLike,
    reference: ArrayLike,
    valid: ArrayLike | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Pose errors against a reference, and the standard deviations the estimator claims.

    Parameters
    ----------
    estimate : array_like
        (n, >= 3) estimated states ``[x, y, yaw, ...]`` (m, m, rad).
    variance : array_like
        (n, >= 3) the diagonal of the estimator's covariance, ``x, y, yaw`` first (m², m²,
        rad²); slightly negative values (rounding) count as 0.
    reference : array_like
        (n, >= 3) reference states at the same stamps (m, m, rad).
    valid : array_like of bool, optional
        (n,) false where the estimate does not count (e.g. status ``lost``).

    Returns
    -------
    errors : numpy.ndarray
        (n, 3) :func:`pose_errors` (m, m, rad; yaw wrapped), NaN where not ``valid``.
    sigmas : numpy.ndarray
        (n, 3) standard deviations of ``x, y, yaw`` (m, m, rad).
    """
    errors = pose_errors(estimate, reference)
    if valid is not None:
        errors[~np.asarray(valid, dtype=bool)] = np.nan
    sigmas = np.sqrt(np.clip(np.asarray(variance, dtype=float)[:, :3], 0.0, None))
    return errors, sigmas


def band_statistics(error: ArrayLike, sigma: ArrayLike) -> dict[str, float | int | None]:
    """RMSE of ``error`` and the fraction of samples with ``|error| <= 2 sigma``.

    A consistent estimator has about 95 % of its samples inside its own ±2σ band.

    Parameters
    ----------
    error : array_like
        (n,) errors of one component, in any unit (mm, mrad, ...); NaN marks a sample without
        estimate or reference.
    sigma : array_like
        (n,) the standard deviation the estimator claims, in the unit of ``error``; NaN marks
        a sample without a known covariance.

    Returns
    -------
    dict
        ``rmse`` (unit of ``error``) over the finite errors, ``samples`` of them;
        ``inside_2sigma`` (0..1) over the samples where both are finite,
        ``samples_with_sigma`` of them. ``rmse`` / ``inside_2sigma`` are None where there is
        no sample to count.
    """
    error, sigma = np.asarray(error, dtype=float), np.asarray(sigma, dtype=float)
    finite = np.isfinite(error)
    both = finite & np.isfinite(sigma)
    return {
        "rmse": float(np.sqrt(np.mean(error[finite] ** 2))) if finite.any() else None,
        "inside_2sigma": float(np.mean(np.abs(error[both]) <= 2.0 * sigma[both]))
        if both.any()
        else None,
        "samples": int(finite.sum()),
        "samples_with_sigma": int(both.sum()),
    }


def state_rmse(
    estimate: ArrayLike, reference: ArrayLike, mask: ArrayLike | None = None
) -> dict[str, float] | None:
    """Root-mean-square error per base state and of the position.

    Parameters
    ----------
    estimate, reference : array_like
        (n, >= 6) states ``[x, y, yaw, vx, vy, omega, ...]`` (m, m, rad, m/s, m/s, rad/s).
    mask : array_like of bool, optional
        (n,) only the samples where it is true count.

    Returns
    -------
    dict or None
        RMSE per name of :data:`STATE_NAMES` (unit of that state; the yaw error wrapped) and
        ``position``: sqrt(rmse_x² + rmse_y²), m. None when no sample counts.
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


def lap_statistics(
    t: ArrayLike, states: ArrayLike, track: Track, line_tolerance: float = 1e-3
) -> dict[str, Any]:
    """Laps completed, lap times and path-following errors of a trajectory on a track.

    Parameters
    ----------
    t : array_like
        (n,) increasing stamps, s.
    states : array_like
        (n, >= 2) states ``[x, y, ...]``, m (world frame).
    track : Track
        The track; laps are counted at its start/finish line
        (:class:`~crs_core.analysis.laps.LapCounter`).
    line_tolerance : float, optional
        A first sample within this distance past the line (m) counts as starting on it.

    Returns
    -------
    dict
        JSON-ready: ``laps_completed``; ``lap_times_s`` (s, rounded to ms); ``crossings_s``,
        the stamps of the start/finish line crossings (s, each lap runs from one to the next);
        ``distance_m``,
        the progress along the centreline since the first sample (m, rounded to mm);
        ``max_lateral_error_m`` and ``rms_lateral_error_m``, the distance from the centreline
        (m, rounded to 0.1 mm).
    """
    counter = LapCounter(track.length, line_tolerance)
    lateral = []
    s_hint = None
    s_start = None
    for stamp, state in zip(
        np.asarray(t, dtype=float), np.asarray(states, dtype=float), strict=True
    ):
        projection = track.project(state[0], state[1], s_hint)
        s_hint = projection.s
        s_start = projection.s if s_start is None else s_start
        lateral.append(projection.lateral_error)
        counter.update(stamp, projection.s)
    lateral_arr = np.abs(np.array(lateral))
    return {
        "laps_completed": counter.laps_completed,
        "lap_times_s": [round(v, 3) for v in counter.lap_times],
        "crossings_s": counter.crossing_stamps,
        "distance_m": round(counter.progress - (s_start or 0.0), 3),
        "max_lateral_error_m": round(float(lateral_arr.max()), 4),
        "rms_lateral_error_m": round(float(np.sqrt(np.mean(lateral_arr**2))), 4),
    }
