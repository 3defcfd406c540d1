"""Tests of crs_core.analysis.metrics: pose errors, ±2σ band statistics, lap statistics."""

from __future__ import annotations

import numpy as np
import pytest

from crs_core.analysis.metrics import (
    band_statistics,
    interpolate_pose,
    lap_statistics,
    pose_error_bands,
    pose_errors,
    state_errors,
    state_rmse,
)
from crs_core.track import load_demo_track


def test_state_errors_and_rmse_wrap_the_yaw():
    """Six states: only the yaw is wrapped; the RMSE per state and of the position."""
    estimate = np.array([[1.0, 0.0, 3.1, 1.0, 0.0, 0.1], [0.0, 1.0, -3.1, 1.0, 0.0, 0.1]])
    reference = np.array([[0.0, 0.0, -3.1, 0.5, 0.0, 0.1], [0.0, 0.0, 3.1, 0.5, 0.0, 0.1]])
    error = state_errors(estimate, reference)
    assert error[:, 2] == pytest.approx([6.2 - 2 * np.pi, 2 * np.pi - 6.2])
    assert error[:, 3] == pytest.approx([0.5, 0.5])
    rmse = state_rmse(estimate, reference)
    assert rmse["x"] == pytest.approx(np.sqrt(0.5)) and rmse["yaw"] == pytest.approx(
        2 * np.pi - 6.2
    )
    assert rmse["position"] == pytest.approx(1.0)
    assert state_rmse(estimate, reference, mask=[False, False]) is None
    np.testing.assert_array_equal(pose_errors(estimate, reference), error[:, :3])


def test_band_statistics_on_known_numbers():
    """The RMSE counts the finite errors, the fraction inside ±2σ the samples where the sigma is
    known too."""
    error = np.array([1.0, -1.0, 3.0, -2.0, np.nan, 5.0])
    sigma = np.array([1.0, 1.0, 1.0, 1.0, 1.0, np.nan])
    stats = band_statistics(error, sigma)
    assert stats["samples"] == 5 and stats["samples_with_sigma"] == 4
    assert stats["rmse"] == pytest.approx(np.sqrt((1 + 1 + 9 + 4 + 25) / 5))
    assert stats["inside_2sigma"] == pytest.approx(3 / 4)  # |-2| <= 2 counts, |3| does not
    empty = {"rmse": None, "inside_2sigma": None, "samples": 0, "samples_with_sigma": 0}
    assert band_statistics([], []) == empty
    assert band_statistics([np.nan], [1.0])["rmse"] is None
    no_sigma = band_statistics([3.0, 4.0], [np.nan, np.nan])
    assert no_sigma["rmse"] == pytest.approx(np.sqrt(12.5)) and no_sigma["inside_2sigma"] is None


def test_band_statistics_of_gaussian_errors_is_about_95_percent():
    """Errors drawn with the claimed sigma land inside ±2σ about 95.4 % of the time."""
    rng = np.random.default_rng(0)
    sigma = rng.uniform(0.5, 2.0, 20_000)
    stats = band_statistics(rng.normal(0.0, sigma), sigma)
    assert stats["inside_2sigma"] == pytest.approx(0.954, abs=0.01)
    assert stats["rmse"] == pytest.approx(np.sqrt(np.mean(sigma**2)), rel=0.02)


def test_pose_errors_wrap_the_yaw():
    """A yaw of 3.1 rad against -3.1 rad (or against it plus whole turns) is -0.083 rad off."""
    estimate = np.array([[1.0, 2.0, 3.1], [0.0, 0.0, 3.1], [0.0, 0.0, 0.2]])
    reference = np.array([[0.9, 2.5, -3.1], [0.0, 0.0, -3.1 + 4 * np.pi], [0.0, 0.0, -0.1]])
    error = pose_errors(estimate, reference)
    assert error[0, :2] == pytest.approx([0.1, -0.5])
    assert error[:, 2] == pytest.approx([6.2 - 2 * np.pi, 6.2 - 2 * np.pi, 0.3])


def test_interpolate_pose_does_not_smear_a_wrapped_yaw():
    """Half-way between yaw 3.1 and -3.1 (a wrap, not a half turn back) the yaw is ±pi."""
    stamps = np.array([0.0, 1.0, 2.0])
    states = np.array([[0.0, 0.0, 3.1], [1.0, 2.0, -3.1], [2.0, 4.0, -3.0]])
    pose = interpolate_pose(np.array([0.5, 1.5]), stamps, states)
    assert pose[:, :2] == pytest.approx(np.array([[0.5, 1.0], [1.5, 3.0]]))
    assert abs(np.cos(pose[0, 2]) + 1.0) < 1e-6  # pi, not 0
    assert pose[1, 2] == pytest.approx(-3.05 + 2 * np.pi)


def test_pose_error_bands_mark_invalid_samples_and_clip_the_variance():
    """Errors NaN where not valid; sigma the square root of the variance, a tiny negative
    variance (rounding) counting as 0."""
    estimate = np.array([[1.0, 2.0, 0.1, 9.0], [1.0, 2.0, 0.1, 9.0]])
    reference = np.array([[0.9, 2.0, 0.0], [0.9, 2.0, 0.0]])
    variance = np.array([[4.0, 1.0, -1e-18, 7.0], [1.0, 1.0, 0.25, 7.0]])
    errors, sigmas = pose_error_bands(estimate, variance, reference, [True, False])
    assert errors[0] == pytest.approx([0.1, 0.0, 0.1]) and np.all(np.isnan(errors[1]))
    np.testing.assert_array_equal(sigmas, [[2.0, 1.0, 0.0], [1.0, 1.0, 0.5]])
    errors, _ = pose_error_bands(estimate, variance, reference)
    assert np.all(np.isfinite(errors))


def test_lap_statistics_along_the_centreline():
    """Driving the centreline for 1.25 laps: one lap timed, the distance 1.25 lengths, no
    lateral error."""
    track = load_demo_track()
    s = np.linspace(0.0, 1.25 * track.length, 2000)
    closed = np.r_[track.arc_length, track.length]
    x = np.interp(s % track.length, closed, np.r_[track.x, track.x[0]])
    y = np.interp(s % track.length, closed, np.r_[track.y, track.y[0]])
    t = s / 2.0  # 2 m/s
    laps = lap_statistics(t, np.stack([x, y], axis=1), track)
    assert laps["laps_completed"] == 1
    assert laps["lap_times_s"] == [pytest.approx(track.length / 2.0, abs=0.01)]
    assert laps["distance_m"] == pytest.approx(1.25 * track.length, rel=1e-3)
    assert laps["max_lateral_error_m"] < 1e-3


def test_states_interpolate_with_the_yaw_unwrapped():
    """Every column linearly; the yaw across a wrap goes the short way; the pose is its first
    three columns."""
    from crs_core.analysis.metrics import interpolate_pose, interpolate_states

    stamps = np.array([0.0, 1.0])
    states = np.array([[0.0, 0.0, 3.1, 1.0, 0.0, 0.0], [1.0, 2.0, -3.1, 3.0, 1.0, 2.0]])
    out = interpolate_states([0.5, 2.0], stamps, states)
    np.testing.assert_allclose(out[0], [0.5, 1.0, np.pi, 2.0, 0.5, 1.0])
    np.testing.assert_allclose(out[1], [1.0, 2.0, 2 * np.pi - 3.1, 3.0, 1.0, 2.0])  # held
    np.testing.assert_array_equal(interpolate_pose([0.5], stamps, states), out[:1, :3])
