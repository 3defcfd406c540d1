"""Tests of crs_core.analysis.statistics: the one summary of a sample."""

from __future__ import annotations

import math

import numpy as np
import pytest

from crs_core.analysis.statistics import covariance_ellipse, summary


def test_default_keys_are_median_p95_max_and_equal_numpy():
    values = np.random.default_rng(0).exponential(2.0, 1001)
    result = summary(values)
    assert list(result) == ["median", "p95", "max"]
    assert result["median"] == np.median(values)
    assert result["p95"] == np.percentile(values, 95)
    assert result["max"] == np.max(values)
    assert all(type(v) is float for v in result.values())


def test_chosen_keys_in_the_given_order_with_a_hand_computed_example():
    """1..10: mean 5.5, median 5.5, p95 = 9.55 (linear interpolation at index 8.55), p99.9."""
    values = list(range(1, 11))
    result = summary(values, ("n", "mean", "p95", "median", "min", "p99.9", "max"))
    assert list(result) == ["n", "mean", "p95", "median", "min", "p99.9", "max"]
    assert result["n"] == 10 and type(result["n"]) is int
    assert result["mean"] == 5.5 and result["median"] == 5.5
    assert result["p95"] == pytest.approx(9.55)
    assert result["p99.9"] == pytest.approx(np.percentile(values, 99.9))
    assert result["min"] == 1.0 and result["max"] == 10.0


def test_digits_round_every_statistic_but_the_count():
    values = np.array([0.123456, 0.987654, 0.5])
    result = summary(values, ("median", "max", "n"), digits=2)
    assert result == {"median": 0.5, "max": 0.99, "n": 3}
    assert summary(values, ("p95",), digits=4)["p95"] == round(float(np.percentile(values, 95)), 4)


def test_any_shape_is_flattened():
    values = np.arange(12.0).reshape(3, 4)
    assert summary(values, ("median", "n")) == {"median": 5.5, "n": 12}


def test_an_empty_sample_gives_nan_and_zero_count():
    result = summary([], ("mean", "median", "p95", "max", "n"))
    assert result["n"] == 0
    assert all(math.isnan(result[k]) for k in ("mean", "median", "p95", "max"))


@pytest.mark.parametrize("key", ["average", "p", "pxx", "q95", "P95"])
def test_an_unknown_key_is_refused_even_for_an_empty_sample(key):
    with pytest.raises(ValueError, match="unknown statistic"):
        summary([1.0, 2.0], (key,))
    with pytest.raises(ValueError, match="unknown statistic"):
        summary([], (key,))


def test_the_ellipse_has_sigma_times_the_deviation_along_the_principal_axes():
    P = np.array([[0.04, 0.0], [0.0, 0.01]])  # sigma 0.2 m along x, 0.1 m along y
    points = covariance_ellipse(np.array([1.0, 2.0]), P, 2.0, 4)
    np.testing.assert_allclose(np.abs(points - [1.0, 2.0]).max(axis=0), [0.4, 0.2], atol=1e-12)
