"""Tests of the residual diagnosis: the statistics on synthetic series, and clean vs hidden-effect
identification runs (the calibration of the ``structured`` rule)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from crs_core.discrepancy.residuals import (
    CHANNEL_GROUPS,
    MEAN_Z_MIN,
    REGIME_R2_MIN,
    ChannelDiagnosis,
    diagnose,
    diagnose_residual,
    fie_residuals,
    regime_regressors,
    where_misfit,
)
from crs_core.identification import FieSettings, identify
from crs_core.model import CarModel
from sim.scenarios import SIM_PROCESS_SCALE, simulate_dataset
from tests.crs_core.discrepancy.conftest import N

DURATION = 20.0
FIT = ("Cm1", "Df", "Dr", "Iz")


def _regressors(rng: np.random.Generator, n: int = N) -> dict[str, np.ndarray]:
    """Independent synthetic regime variables."""
    t = np.arange(n) * 0.02
    states = np.zeros((n, 6))
    states[:, 3] = rng.uniform(0.0, 2.0, n)
    states[:, 5] = rng.normal(0.0, 1.0, n)
    u = np.column_stack([rng.uniform(-0.3, 0.3, n), rng.uniform(0.0, 1.0, n)])
    return regime_regressors(t, states, u)


def _identify(seed: int, truth: CarModel | None = None):
    dataset = simulate_dataset(DURATION, seed, model=truth)
    settings = FieSettings(fit=FIT, process_scale=SIM_PROCESS_SCALE)
    return identify(dataset, CarModel(), settings)


@pytest.fixture(scope="module")
def clean_results():
    return [_identify(seed) for seed in (1, 2)]


@pytest.fixture(scope="module")
def gyro_bias_result():
    return _identify(1, CarModel({"gyro_bias": {"gyro_bias": 0.1}}))


# --- statistics on synthetic series -------------------------------------------------------


def test_regime_regressors_names_units_and_acceleration():
    t = np.linspace(0.0, 4.0, 201)
    states = np.zeros((201, 6))
    states[:, 3] = 0.5 * t  # vx grows at 0.5 m/s^2
    states[:, 5] = -0.2
    u = np.column_stack([np.full(201, -0.1), np.full(201, 0.3)])
    r = regime_regressors(t + 10.0, states, u)
    assert set(r) == {
        "vx",
        "steering",
        "abs_steering",
        "yaw_rate",
        "abs_yaw_rate",
        "torque",
        "acceleration",
        "time",
    }
    assert np.allclose(r["acceleration"], 0.5)
    assert r["time"][0] == 0.0 and r["time"][-1] == pytest.approx(4.0)
    assert np.allclose(r["abs_steering"], 0.1) and np.allclose(r["abs_yaw_rate"], 0.2)
    assert np.allclose(r["torque"], 0.3)


def test_white_noise_is_white_and_regime_free():
    rng = np.random.default_rng(0)
    e = rng.normal(0.0, 1.0, N)
    d = diagnose_residual("x", e, 1.0, _regressors(rng))
    assert d.whiteness_p > 0.01
    assert abs(d.lag1_autocorrelation) < 0.1
    assert d.regime_r2 < 0.02 and d.regime_p > 1e-3
    assert d.normalized_rms == pytest.approx(1.0, abs=0.05)
    assert not d.structured


def test_residual_following_speed_is_found_at_high_speed():
    rng = np.random.default_rng(2)
    regressors = _regressors(rng)
    vx = regressors["vx"]
    e = 0.5 * vx + rng.normal(0.0, 0.2, N)
    d = diagnose_residual("x", e, 0.2, regressors)
    assert d.strongest_regressor == "vx"
    assert d.regime_r2 > 0.6 and d.regime_p < 1e-12  # expected 0.68
    worst = d.worst_regime
    assert worst["regressor"] == "vx"
    assert worst["low"] == pytest.approx(np.quantile(vx, 0.75))
    assert worst["high"] == pytest.approx(vx.max())
    assert worst["share"] == pytest.approx(0.25, abs=0.01)
    assert d.structured


def test_regime_dominated_residual_is_structured_under_a_too_large_sigma():
    """A residual that mostly follows the regime counts even when the assumed sigma (here 10x
    the residual) would call it negligible: a recording's noise need not be the tuning's."""
    rng = np.random.default_rng(5)
    regressors = _regressors(rng)
    e = 0.05 * regressors["vx"] + rng.normal(0.0, 0.02, N)
    d = diagnose_residual("x", e, 1.0, regressors)
    assert d.normalized_rms < 0.2 and d.regime_r2 > 0.2
    assert d.structured
    white = diagnose_residual("x", rng.normal(0.0, 0.02, N), 1.0, regressors)
    assert not white.structured


def test_constant_offset_is_structured_through_the_mean():
    """An intercept-only regression sees no offset; the mean test does."""
    rng = np.random.default_rng(3)
    e = 0.3 + rng.normal(0.0, 1.0, N)
    d = diagnose_residual("x", e, 1.0, _regressors(rng))
    assert d.regime_r2 < 0.02
    assert d.mean == pytest.approx(0.3, abs=0.05) and d.mean_z > 8.0
    assert d.structured
    tiny = diagnose_residual("x", 0.05 + rng.normal(0.0, 0.01, N), 1.0, _regressors(rng))
    assert tiny.mean_z > 8.0 and not tiny.structured  # significant but negligible


def test_missing_samples_are_skipped():
    rng = np.random.default_rng(4)
    regressors = _regressors(rng)
    e = np.column_stack([0.5 * regressors["vx"] + rng.normal(0.0, 0.1, N) for _ in range(2)])
    e[::3, 0] = np.nan
    e[1::3, 1] = np.nan
    e[:100] = np.nan  # not measured at all at the start
    d = diagnose_residual("x", e, 0.1, regressors)
    assert d.samples == N - 100
    assert np.isfinite([d.rms, d.lag1_autocorrelation, d.whiteness_p, d.regime_r2]).all()
    assert d.strongest_regressor == "vx" and d.regime_r2 > 0.8
    empty = diagnose_residual("x", np.full(N, np.nan), 0.1, regressors)
    assert empty.samples == 0 and empty.regime_p == 1.0 and not empty.structured
    json.dumps(d.to_dict())


def test_where_misfit_picks_the_largest_structure():
    def diagnosis(name: str, mean: float, r2: float, structured: bool) -> ChannelDiagnosis:
        regime = {"regressor": "vx", "low": 1.0, "high": 2.0, "rms": 0.5, "share": 0.25}
        return ChannelDiagnosis(
            name, 100, 1.0, 1.0, 1.0, 0.0, 1.0, r2, 1e-9, "vx", regime, structured, mean, 0.0
        )

    assert where_misfit([diagnosis("a", 0.0, 0.5, False)]) is None
    found = where_misfit(
        [
            diagnosis("a", 0.0, 0.1, True),
            diagnosis("b", 0.0, 0.5, True),
            diagnosis("c", 0, 1, False),
        ]
    )
    assert found is not None and found["channel"] == "b"
    assert found["regressor"] == "vx" and found["low"] == 1.0 and found["high"] == 2.0


# --- identification runs -------------------------------------------------------------------


@pytest.mark.slow
def test_fie_residuals_shapes(clean_results):
    result = clean_results[0]
    residuals, floors = fie_residuals(result)
    assert set(residuals) == set(CHANNEL_GROUPS) == set(floors)
    for name, columns in CHANNEL_GROUPS.items():
        assert residuals[name].shape == (len(result.t), len(columns))
    assert floors["lighthouse_plane1"] == pytest.approx(2e-3)
    assert floors["yaw_rate"] == pytest.approx(0.06)


@pytest.mark.slow
def test_clean_data_is_not_structured(clean_results):
    """The model is the simulated truth: no channel carries structure."""
    for result in clean_results:
        diagnoses = diagnose(result)
        assert [d.channel for d in diagnoses] == list(CHANNEL_GROUPS)
        assert not [d.to_dict() for d in diagnoses if d.structured]
        assert where_misfit(diagnoses) is None
        for d in diagnoses:
            assert d.regime_r2 < REGIME_R2_MIN and d.mean_z < MEAN_Z_MIN
            json.dumps(d.to_dict())


@pytest.mark.slow
def test_hidden_gyro_bias_shows_in_the_yaw_rate(gyro_bias_result):
    diagnoses = {d.channel: d for d in diagnose(gyro_bias_result)}
    yaw = diagnoses["yaw_rate"]
    assert yaw.structured
    assert yaw.mean > 0.0 and yaw.mean_z > 30.0
    assert not diagnoses["lighthouse_plane1"].structured
    found = where_misfit(list(diagnoses.values()))
    assert found is not None and found["channel"] == "yaw_rate"
