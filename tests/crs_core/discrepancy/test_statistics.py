"""Tests of crs_core.discrepancy.statistics: whiteness, regime regression, mean offset."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import stats

from crs_core.discrepancy.statistics import autocorrelation, ljung_box, mean_z, regime_regression
from tests.crs_core.discrepancy.conftest import N


def test_coloured_noise_is_not_white():
    rng = np.random.default_rng(1)
    e = np.convolve(rng.normal(0.0, 1.0, N + 9), np.ones(10) / 10, mode="valid")
    assert ljung_box(e) < 1e-10


def test_regression_with_constant_and_collinear_regressors():
    rng = np.random.default_rng(5)
    x = rng.normal(size=500)
    design = np.column_stack([x, 2.0 * x, np.ones(500)])
    r2, p = regime_regression(x + rng.normal(0.0, 0.1, 500), design)
    assert r2 > 0.95 and p < 1e-100
    assert regime_regression(np.zeros(500), design) == (0.0, 1.0)


def test_ljung_box_is_the_chi_squared_tail_of_q():
    """Against the textbook statistic computed here: ``Q = n (n + 2) sum r_k^2 / (n - k)``."""
    x = np.random.default_rng(6).normal(size=300) + 0.3 * np.sin(np.arange(300))
    d = x - x.mean()
    r = np.array([np.sum(d[:-k] * d[k:]) for k in range(1, 9)]) / np.sum(d**2)
    np.testing.assert_allclose(autocorrelation(x, 8), r, rtol=1e-12)
    q = 300 * 302 * np.sum(r**2 / (300 - np.arange(1, 9)))
    assert ljung_box(x, lags=8) == pytest.approx(stats.chi2.sf(q, 8), rel=1e-9)
    assert ljung_box(x[:5], lags=8) == 1.0  # too short to tell


def test_regime_regression_is_r2_and_f_test_of_least_squares_with_an_intercept():
    rng = np.random.default_rng(7)
    design = np.column_stack([rng.uniform(0, 2, 400), rng.normal(size=400)])
    e = 0.2 * design[:, 0] - 0.1 * design[:, 1] + rng.normal(0.0, 0.3, 400)
    a = np.column_stack([np.ones(400), design])
    fitted = a @ np.linalg.lstsq(a, e, rcond=None)[0]
    r2 = 1 - np.sum((e - fitted) ** 2) / np.sum((e - e.mean()) ** 2)
    f = (r2 / 2) / ((1 - r2) / (400 - 3))
    got_r2, got_p = regime_regression(e, design)
    assert got_r2 == pytest.approx(r2, rel=1e-9)
    assert got_p == pytest.approx(stats.f.sf(f, 2, 397), rel=1e-6)


def test_mean_z_counts_standard_errors_of_independent_samples():
    """For a series without lag-1 correlation, ``|mean| / (std / sqrt(n))``."""
    x = np.tile([1.0, 3.0, 2.0, 2.0], 50)  # r_1 < 0: no reduction of the sample count
    assert autocorrelation(x, 1)[0] < 0
    assert mean_z(x) == pytest.approx(2.0 / (np.std(x, ddof=1) / np.sqrt(200)), rel=1e-12)
    assert mean_z(np.full(10, 0.5)) == float("inf") and mean_z(np.zeros(10)) == 0.0
