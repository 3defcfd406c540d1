"""Tests of crs_core.discrepancy.prediction: a drift the smoothed fit absorbs shows in open-loop
prediction (simulated runs with a battery losing torque, and without)."""

from __future__ import annotations

import numpy as np
import pytest

from crs_core.dataset import Dataset
from crs_core.discrepancy.prediction import (
    COHERENCE_MAX,
    PREDICTION_CHANNEL,
    PredictionDiagnosis,
    diagnose_prediction,
)
from crs_core.discrepancy.residuals import diagnose
from crs_core.discrepancy.workflow import DiscrepancySettings, find_discrepancy
from crs_core.identification.problem import FieSettings
from crs_core.identification.solve import FieResult, identify
from crs_core.model import CarModel
from sim.drift import parse_drift
from sim.scenarios import SIM_PROCESS_SCALE, simulate_dataset

pytestmark = pytest.mark.slow

#: Length of the simulated runs, s.
DURATION = 40.0
#: The battery: the motor constant falls by 30 % over the run.
BATTERY = parse_drift(
    {"drift": [{"parameter": "Cm1", "from_s": 0, "to_s": DURATION, "factor": 0.7}]}
)
#: The fit: the parameters the battery's drift could hide in.
FIT = FieSettings(fit=("Cm1", "Df", "Dr", "Iz"), process_scale=SIM_PROCESS_SCALE)


def _fitted(battery: bool) -> tuple[Dataset, FieResult, PredictionDiagnosis]:
    data = simulate_dataset(DURATION, 3, driver="joystick", drift=BATTERY if battery else None)
    result = identify(data, CarModel(), FIT)
    model = CarModel(parameters=result.parameters)
    return data, result, diagnose_prediction(data, model, result.states, 2.0)


@pytest.fixture(scope="module")
def clean() -> tuple[Dataset, FieResult, PredictionDiagnosis]:
    return _fitted(battery=False)


@pytest.fixture(scope="module")
def sagging() -> tuple[Dataset, FieResult, PredictionDiagnosis]:
    return _fitted(battery=True)


def test_a_right_model_misses_less_than_its_shuffled_residuals(clean):
    """On a clean run the fit's process residuals are its wiggles around the truth: in order
    they cancel over the horizon, shuffled they add up."""
    _, _, diagnosis = clean
    assert not diagnosis.structured
    assert diagnosis.coherence < 1.0
    assert diagnosis.gap < 0.01
    low, high = diagnosis.shuffled_range
    assert low <= diagnosis.shuffled_gap <= high


def test_a_sagging_battery_hides_from_the_residuals_but_not_from_prediction(sagging, clean):
    """The fit's state absorbs the lost torque (no channel's residual is structured), its
    open-loop predictions miss coherently: well above the clean run's gap and above every
    shuffled order's; the per-start gap follows how hard the motor is driven or the time."""
    _, result, diagnosis = sagging
    assert not any(d.structured for d in diagnose(result))
    assert diagnosis.structured
    assert diagnosis.coherence > COHERENCE_MAX
    assert diagnosis.gap > 3 * clean[2].gap
    assert diagnosis.gap > diagnosis.shuffled_range[1]
    strongest = diagnosis.strongest
    assert (strongest["series"], strongest["regressor"]) == ("along", "time")
    assert strongest["correlation"] < -0.5  # further than predicted early, less far late
    where = diagnosis.where()
    assert where["channel"] == PREDICTION_CHANNEL
    assert where["low"] <= where["high"] and where["rms"] > 0
    assert np.isfinite(list(diagnosis.to_dict()["shuffled_range"])).all()


def test_the_workflow_does_not_call_a_sagging_battery_none(sagging):
    """Without terms beyond the registry (and no candidate effect for it), the verdict is
    ``unexplained`` in the open-loop prediction, not ``none``; the report carries both
    diagnoses."""
    data = sagging[0]
    settings = DiscrepancySettings(identification=FIT, candidates=("gyro_bias",), propose=False)
    result = find_discrepancy(data, CarModel(), settings=settings)
    assert result.verdict == "unexplained"
    assert result.where is not None and result.where["channel"] == PREDICTION_CHANNEL
    summary = result.summary()
    assert summary["prediction_before"]["structured"]
    assert summary["prediction_after"] == summary["prediction_before"]
    assert summary["proposed_terms"] == []


def test_a_sagging_battery_is_proposed_as_a_term_in_time_and_torque(sagging):
    """With terms proposed, the lost torque is a term in ``t * torque`` on vx's derivative (the
    last 30 % of the run held out: the time goes on there), and its coefficient is the truth's:
    Cm1 falling by 30 % in 40 s takes ``0.3 / 40 * Cm1 / m`` m/s^2 per s and unit torque."""
    data = sagging[0]
    settings = DiscrepancySettings(identification=FIT, candidates=("gyro_bias",))
    result = find_discrepancy(data, CarModel(), settings=settings)
    assert result.verdict == "proposed"
    (term,) = result.terms
    assert term.target == "vx" and ("t", "torque") in {tuple(sorted(m)) for m in term.monomials}
    k = [tuple(sorted(m)) for m in term.monomials].index(("t", "torque"))
    fitted = result.final_model.parameters.value(term.coefficient_names()[k])
    base = CarModel().parameters
    assert fitted == pytest.approx(-0.3 / DURATION * base.value("Cm1") / base.value("m"), rel=0.2)
    assert result.gap["after"] < 0.5 * result.gap["before"]
