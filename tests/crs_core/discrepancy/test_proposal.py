"""Tests of crs_core.discrepancy.proposal: the sparse regression, and a term outside the registry
proposed, tested and stored by the workflow (a simulated car whose tyres scrub speed when
steered)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from crs_core.discrepancy.proposal import MAX_DEGREE, library, propose, sparse_fit
from crs_core.discrepancy.report import write_final_params
from crs_core.discrepancy.workflow import DiscrepancySettings, find_discrepancy
from crs_core.identification.problem import FieSettings
from crs_core.identification.solve import identify
from crs_core.model import CarModel
from crs_core.model.terms import TERM_VARIABLES, Term
from sim.scenarios import SIM_PROCESS_SCALE, simulate_dataset

#: The fit of the workflow tests.
FIT = FieSettings(fit=("Cm1", "Df", "Dr", "Iz"), process_scale=SIM_PROCESS_SCALE)
#: The hidden truth: speed lost in proportion to the steering angle squared (m/s^2 per rad^2
#: per m/s), a term no registry effect has.
SCRUB = Term("scrub", "vx", (("steer", "steer", "vx"),), coefficients=(-2.0,))


def _variables(n: int, seed: int) -> dict[str, np.ndarray]:
    rng = np.random.default_rng(seed)
    return {
        name: rng.uniform(-1.0, 1.0, n) + (1.5 if name == "vx" else 0.0) for name in TERM_VARIABLES
    }


def test_the_library_holds_every_monomial_up_to_its_degree_with_time_at_most_once():
    monomials, theta = library(_variables(50, 0))
    n = len(TERM_VARIABLES) - 1  # without t
    without_t = sum(math.comb(n + d - 1, d) for d in range(MAX_DEGREE + 1))  # multisets
    with_t = sum(math.comb(n + d - 1, d) for d in range(MAX_DEGREE))  # t times one of those
    assert len(monomials) == len(set(monomials)) == without_t + with_t == theta.shape[1]
    assert all(m.count("t") <= 1 for m in monomials)
    assert () in monomials and ("steer", "steer", "vx") not in monomials  # canonical order
    assert ("vx", "steer", "steer") in monomials and ("torque", "t") in monomials
    np.testing.assert_array_equal(theta[:, monomials.index(())], 1.0)


def test_the_sparse_fit_finds_the_terms_of_a_sparse_function_and_none_in_noise():
    variables = _variables(3000, 1)
    monomials, theta = library(variables)
    rng = np.random.default_rng(2)
    truth = 3.0 * variables["vx"] * variables["torque"] - 2.0 * variables["steer"] ** 2
    found = sparse_fit(truth + rng.normal(0, 0.2, 3000), monomials, theta, "vx")
    assert set(found.monomials) == {("vx", "torque"), ("steer", "steer")}
    coefficients = dict(zip(found.monomials, found.coefficients, strict=True))
    assert coefficients[("vx", "torque")] == pytest.approx(3.0, rel=0.05)
    assert coefficients[("steer", "steer")] == pytest.approx(-2.0, rel=0.1)
    assert found.r2 > 0.9 and list(found.r2_path) == sorted(found.r2_path)
    nothing = sparse_fit(rng.normal(0, 1.0, 3000), monomials, theta, "vx")
    assert nothing.monomials == () and nothing.r2 == 0.0


@pytest.mark.slow
def test_a_right_model_leaves_nothing_to_propose():
    data = simulate_dataset(15.0, 4, driver="joystick")
    result = identify(data, CarModel(), FIT)
    assert propose(data, CarModel(parameters=result.parameters), result) == []


def test_wheels_reading_apart_by_side_are_proposed_on_the_sides_target():
    """A car whose right wheels read faster and left ones slower under drive torque: the
    four-wheel mean hides it (it cancels), the sides target proposes it with the torque."""
    truth = CarModel(terms=[Term("sides", "wheel_speed_sides", (("torque",),), (6.0,))])
    data = simulate_dataset(15.0, 4, truth, driver="joystick")
    result = identify(data, CarModel(), FIT)
    proposals = propose(data, CarModel(parameters=result.parameters), result)
    targets = [p.target for p in proposals]
    assert targets and targets[0] == "wheel_speed_sides", targets
    assert "wheel_speeds" not in targets
    assert any("torque" in monomial for monomial in proposals[0].monomials)


@pytest.mark.slow
def test_a_term_outside_the_registry_is_proposed_tested_and_stored(tmp_path):
    """The workflow proposes a term in vx's derivative with the steering in it, it predicts the
    held-out run better than the current model, and the final model's file reloads it."""
    truth = CarModel(terms=[SCRUB])
    train = simulate_dataset(20.0, 100, truth, "path")
    held_out = simulate_dataset(15.0, 1100, truth, "path")
    settings = DiscrepancySettings(identification=FIT, candidates=("gyro_bias",))
    result = find_discrepancy(train, CarModel(), held_out, settings)
    summary = result.summary()
    assert result.verdict == "proposed" and result.effects == ()
    accepted = [entry for entry in summary["proposed_terms"] if entry["accepted"]]
    assert len(accepted) == 1 and accepted[0]["target"] == "vx"
    assert {"steer", "vx"} <= set(accepted[0]["variables"])
    assert accepted[0]["held_out"]["improvement"] > 0.05
    assert summary["gap_after"] < 0.8 * summary["gap_before"]
    path = write_final_params(result, tmp_path / "params.yaml")
    reloaded = CarModel.from_file(path)
    assert reloaded.terms == result.terms
    for name in result.terms[0].coefficient_names():
        assert reloaded.parameters.value(name) == pytest.approx(
            result.final_model.parameters.value(name)
        )
