"""Tests of crs_core.analysis.angles: the one angle wrap, to [-pi, pi)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from crs_core.analysis.angles import wrap_angle


def test_the_boundary_pi_and_minus_pi_both_become_minus_pi():
    assert wrap_angle(np.pi) == -np.pi
    assert wrap_angle(-np.pi) == -np.pi
    # just inside the interval: unchanged
    below_pi = np.nextafter(np.pi, 0.0)
    assert wrap_angle(below_pi) == below_pi


def test_whole_turns_are_removed():
    """3 pi and -3 pi lie on the boundary up to rounding; 7 rad is 7 - 2 pi."""
    assert abs(wrap_angle(3 * np.pi)) == pytest.approx(np.pi, abs=1e-12)
    assert abs(wrap_angle(-3 * np.pi)) == pytest.approx(np.pi, abs=1e-12)
    assert wrap_angle(7.0) == pytest.approx(7.0 - 2 * np.pi, abs=1e-15)
    assert wrap_angle(-0.5 + 2 * np.pi) == pytest.approx(-0.5, abs=1e-15)
    assert wrap_angle(0.5 + 10 * 2 * np.pi) == pytest.approx(0.5, abs=1e-13)


def test_angles_inside_the_interval_come_back_bit_for_bit():
    """A small error keeps its full precision (no round trip through pi or sin / cos)."""
    assert wrap_angle(1e-9) == 1e-9
    assert wrap_angle(-1e-300) == -1e-300
    inside = np.random.default_rng(0).uniform(-np.pi, np.pi, 10_000)
    assert np.array_equal(wrap_angle(inside), inside)


def test_scalars_give_floats_and_arrays_give_arrays_of_the_same_shape():
    assert isinstance(wrap_angle(1), float)
    assert isinstance(wrap_angle(np.float64(4.0)), float)
    wrapped = wrap_angle([[0.5, 4.0], [-4.0, 3 * np.pi]])
    assert isinstance(wrapped, np.ndarray) and wrapped.shape == (2, 2)
    assert wrapped[0] == pytest.approx([0.5, 4.0 - 2 * np.pi])
    assert wrapped[1, 0] == pytest.approx(2 * np.pi - 4.0)


def test_every_result_lies_in_minus_pi_to_pi_and_agrees_with_atan2_away_from_the_boundary():
    angles = np.concatenate(
        [np.linspace(-20.0, 20.0, 401), np.random.default_rng(1).uniform(-1e3, 1e3, 10_000)]
    )
    wrapped = wrap_angle(angles)
    assert np.all(wrapped >= -np.pi) and np.all(wrapped < np.pi)
    reference = np.arctan2(np.sin(angles), np.cos(angles))
    away = np.abs(np.abs(reference) - np.pi) > 1e-9
    assert wrapped[away] == pytest.approx(reference[away], abs=1e-12)
    # the same angle up to whole turns
    assert np.cos(wrapped) == pytest.approx(np.cos(angles), abs=1e-12)
    assert np.sin(wrapped) == pytest.approx(np.sin(angles), abs=1e-12)


def test_nan_stays_nan():
    assert math.isnan(wrap_angle(float("nan")))
    assert np.isnan(wrap_angle([0.0, np.nan])[1])
