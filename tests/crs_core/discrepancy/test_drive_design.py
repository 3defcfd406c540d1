"""Tests of the design of drives that decide (crs_core.discrepancy.drive_design)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from crs_core.discrepancy.drive_design import (
    SEARCHES,
    DesignSettings,
    base_drive,
    design_drive,
    evaluate_drive,
    planned_fit,
    prior_covariance,
    prior_from,
    rollout,
    slalom_drive,
    with_open_effects,
)
from crs_core.discrepancy.drive_reach import drive_summary
from crs_core.errors import FieldError
from crs_core.model import CarModel
from crs_core.track import load_demo_track

OPEN = ("Dr", "Br", "tau_motor")
#: A short drive and a small search: seconds.
SETTINGS = DesignSettings(
    duration_s=2.0, segment_s=1.0, process_scale=0.1, evaluations=25, starts=1
)


@pytest.fixture(scope="module")
def setup():
    model = with_open_effects(CarModel(), OPEN)
    fit = planned_fit(model, OPEN)
    return model, fit, prior_covariance(model, fit), load_demo_track()


@pytest.fixture(scope="module")
def designed(setup):
    model, fit, prior, track = setup
    return design_drive(model, fit, OPEN, prior, track, SETTINGS)


def test_an_open_effect_parameter_switches_its_effect_on_at_the_prior() -> None:
    model = with_open_effects(CarModel(), ("Dr", "tau_motor"))
    assert [e.name for e in model.effects] == ["motor_lag"]
    assert model.parameters.value("tau_motor") == CarModel(["motor_lag"]).parameters.value(
        "tau_motor"
    )
    assert with_open_effects(model, ("tau_motor",)) is model
    with pytest.raises(FieldError) as caught:
        with_open_effects(CarModel(), ("Dr", "grip_of_the_moon"))
    assert caught.value.field == "open" and "grip_of_the_moon" in caught.value.reason


def test_the_fit_holds_every_open_parameter(setup) -> None:
    _, fit, _, _ = setup
    assert set(OPEN) <= set(fit) and len(set(fit)) == len(fit)


def test_a_designed_drive_beats_its_start_and_the_slalom_on_the_criterion(setup, designed):
    model, fit, prior, track = setup
    slalom = evaluate_drive(
        model, slalom_drive(SETTINGS, OPEN, track, 0.1, 1.5), fit, OPEN, prior, track, SETTINGS
    )
    assert slalom.penalty == 0.0  # a fair peer: on the track
    assert designed.criterion + designed.penalty <= slalom.criterion + slalom.penalty
    sigma = designed.sigma()
    before = designed.sigma(after=False)
    assert all(sigma[n] < before[n] for n in OPEN)


def test_the_designed_drive_stays_on_the_track_and_in_view(setup, designed) -> None:
    model, _, _, track = setup
    summary = drive_summary(designed, model, track, SETTINGS.track_margin)
    assert summary["max_lateral_error_m"] <= summary["lateral_limit_m"]  # the best feasible one
    assert summary["in_view_fraction"] == 1.0
    assert 0 < summary["grip_used_max"]["rear"] <= 1.0 + 1e-9
    assert set(summary["sigma"]) == set(OPEN)


def test_leaving_the_track_is_penalised(setup) -> None:
    model, fit, prior, track = setup
    wild = base_drive(SETTINGS, OPEN, track).with_offsets((0.34, 0.34), (0.5, 0.5))
    result = evaluate_drive(model, wild, fit, OPEN, prior, track, SETTINGS)
    _, lateral = rollout(model, wild, track, SETTINGS.sample_period, SETTINGS.view_limit)
    assert np.max(np.abs(lateral)) > 0.18 and result.penalty > 0


def test_a_prior_from_an_identification_keeps_its_correlations(setup) -> None:
    model, fit, _, _ = setup
    rho = np.array([[1.0, -0.9], [-0.9, 1.0]])
    cov = prior_from(model, fit, ["Dr", "Br"], [0.01, 0.1], rho)
    i, j, k = fit.index("Dr"), fit.index("Br"), fit.index("tau_motor")
    assert cov[i, j] == pytest.approx(-0.9 * 0.01 * 0.1)
    assert cov[k, k] == pytest.approx(prior_covariance(model, fit)[k, k])
    with pytest.raises(FieldError, match="correlation"):
        prior_from(model, fit, ["Dr", "Br"], [0.01, 0.1], np.eye(3))


def test_the_design_refuses_an_open_parameter_the_model_lacks(setup) -> None:
    _, fit, prior, track = setup
    with pytest.raises(FieldError, match="lacks"):
        design_drive(CarModel(), fit, OPEN, prior, track, SETTINGS)


class _Bests(list):
    """The best objective after each drive of a search (its progress callback)."""

    def add(self, count: int, best: float) -> None:
        self.append(best)


def test_both_searches_improve_on_their_start_within_the_budget(setup) -> None:
    model, fit, prior, track = setup
    for search in SEARCHES:
        settings = replace(SETTINGS, search=search, starts=2, evaluations=30)
        counted = _Bests()
        design = design_drive(model, fit, OPEN, prior, track, settings, counted.add)
        assert 0 < design.evaluations <= 30 and len(counted) == design.evaluations
        assert counted[-1] == design.criterion + design.penalty <= counted[0]
    with pytest.raises(FieldError, match="search"):
        DesignSettings(search="random")
