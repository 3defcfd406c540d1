"""The drift schedule: its YAML read strictly (the entry and key named), steps and ramps from
the car's first command, effects switched on from 0, and the simulated car changing with it."""

from __future__ import annotations

import numpy as np
import pytest

from crs_core.errors import FieldError
from crs_core.model import CarModel
from sim.drift import load_drift, parse_drift
from sim.sensors import SensorSuite
from sim.simulator import Simulator

ISSUE_SCHEDULE = """
drift:
  - {parameter: Cm1, from_s: 10, to_s: 100, factor: 0.8}
  - {parameter: Df, at_s: 60, factor: 0.85}
  - {parameter: Dr, at_s: 60, factor: 0.85}
  - {effect: gyro_bias, at_s: 30, value: 0.05}
"""


def test_steps_and_ramps_from_the_start_values(tmp_path):
    path = tmp_path / "drift.yaml"
    path.write_text(ISSUE_SCHEDULE)
    schedule = load_drift(path)
    start = {"Cm1": 1.0, "Df": 0.6, "Dr": 1.0, "gyro_bias": 0.0}
    assert schedule.values_at(5.0, start) == start
    at_55 = schedule.values_at(55.0, start)
    assert at_55["Cm1"] == pytest.approx(1.0 - 0.2 * 45 / 90) and at_55["gyro_bias"] == 0.05
    assert at_55["Df"] == 0.6
    late = schedule.values_at(200.0, start)
    assert late == pytest.approx({"Cm1": 0.8, "Df": 0.51, "Dr": 0.85, "gyro_bias": 0.05})


def test_changes_of_one_parameter_chain():
    schedule = parse_drift(
        {
            "drift": [
                {"parameter": "Cm1", "at_s": 1, "factor": 0.5},
                {"parameter": "Cm1", "from_s": 2, "to_s": 4, "value": 2.0},
            ]
        }
    )
    assert schedule.values_at(1.5, {"Cm1": 1.0})["Cm1"] == 0.5
    assert schedule.values_at(3.0, {"Cm1": 1.0})["Cm1"] == pytest.approx(1.25)  # halfway 0.5 -> 2


@pytest.mark.parametrize(
    ("document", "field", "message"),
    [
        ({"drift": []}, "drift", "non-empty list"),
        ({"changes": []}, "drift", "one key, drift"),
        ({"drift": [{"parameter": "Cm1", "at_s": 1}]}, "drift[0].factor", "exactly one of"),
        (
            {"drift": [{"parameter": "Cm1", "at_s": 1, "factor": 1, "value": 2}]},
            "drift[0].factor",
            "exactly one",
        ),
        ({"drift": [{"parameter": "Cm1", "factor": 0.9}]}, "drift[0].at_s", "give at_s"),
        (
            {"drift": [{"parameter": "Cm1", "from_s": 5, "to_s": 5, "factor": 0.9}]},
            "drift[0].to_s",
            "after from_s",
        ),
        ({"drift": [{"parameter": "Cm1", "at_s": -1, "factor": 0.9}]}, "drift[0].at_s", ">= 0"),
        (
            {"drift": [{"parameter": "Cm1", "at_s": "soon", "factor": 0.9}]},
            "drift[0].at_s",
            "finite number",
        ),
        (
            {"drift": [{"parameter": "Cm1", "at_s": 1, "factor": 0.9, "when": 3}]},
            "drift[0].when",
            "unknown key",
        ),
        (
            {"drift": [{"effect": "gyro_drift", "at_s": 1, "value": 0.1}]},
            "drift[0].effect",
            "unknown effect",
        ),
        (
            {"drift": [{"effect": "lighthouse_offset", "at_s": 1, "value": 0.1}]},
            "drift[0].parameter",
            "name one",
        ),
        ({"drift": [{"at_s": 1, "value": 0.1}]}, "drift[0].parameter", "name a parameter"),
    ],
)
def test_a_bad_schedule_names_the_entry_and_key(document, field, message):
    with pytest.raises(FieldError, match=message) as error:
        parse_drift(document)
    assert error.value.field == field


def test_a_parameter_the_car_lacks_is_refused_and_an_effect_is_switched_on_from_zero():
    schedule = parse_drift({"drift": [{"parameter": "Cm9", "at_s": 1, "factor": 0.9}]})
    with pytest.raises(FieldError, match="no parameter 'Cm9'") as error:
        Simulator(CarModel(), drift=schedule)
    assert error.value.field == "drift[0].parameter"
    bias = parse_drift({"drift": [{"effect": "gyro_bias", "at_s": 1, "value": 0.05}]})
    simulator = Simulator(CarModel(), drift=bias)
    assert [e.name for e in simulator.model.effects] == ["gyro_bias"]
    assert simulator.model.parameters.value("gyro_bias") == 0.0


def test_the_simulated_car_changes_from_its_first_command():
    """The gyro reads a bias once it has drifted in, counted from the first command (issued
    2 s into the session), not from the session's start."""
    bias = parse_drift({"drift": [{"effect": "gyro_bias", "at_s": 1.0, "value": 0.2}]})
    session = Simulator(CarModel(), SensorSuite().ideal(), drift=bias).session(np.zeros(6))
    session.advance(2.0)
    assert session.drifted == {"gyro_bias": 0.0}
    session.command(np.zeros(2))
    early = session.advance(2.9)
    late = session.advance(4.0)
    gyro = [m.values[2] for m in early if m.sensor == "imu"]
    assert np.allclose(gyro, 0.0)
    assert np.allclose([m.values[2] for m in late if m.sensor == "imu" and m.stamp > 3.05], 0.2)
    assert session.drifted == {"gyro_bias": 0.2} and session.first_command_time == 2.0
