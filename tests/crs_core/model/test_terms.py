"""Tests of crs_core.model.terms: a proposed term in the model, nested, stored and reloaded."""

from __future__ import annotations

import pickle

import numpy as np
import pytest

from crs_core.errors import FieldError
from crs_core.model import CarModel
from crs_core.model.terms import Term, parse_terms

#: A state and an input where every term variable is non-zero.
X = np.array([0.3, -0.2, 0.4, 1.5, 0.1, 0.8])
U = np.array([0.2, 0.35])

SLIP = Term("slip", "wheel_speeds", (("torque", "vx"),), coefficients=(11.4,))
SCRUB = Term("scrub", "vx", (("steer", "steer", "vx"), ()), coefficients=(-2.0, 0.05))


def test_a_term_at_zero_is_the_model_without_it():
    plain, nested = CarModel(), CarModel(terms=[Term("scrub", "vx", SCRUB.monomials)])
    p_plain, p_nested = plain.parameters.vector(), nested.parameters.vector()
    np.testing.assert_array_equal(nested.numeric.f(X, U, p_nested), plain.numeric.f(X, U, p_plain))
    for name, y in plain.numeric.outputs(X, U, p_plain).items():
        np.testing.assert_array_equal(nested.numeric.outputs(X, U, p_nested)[name], y)


def test_a_state_term_adds_to_that_derivative_only():
    plain, scrub = CarModel(), CarModel(terms=[SCRUB])
    difference = scrub.numeric.f(X, U, scrub.parameters.vector()) - plain.numeric.f(
        X, U, plain.parameters.vector()
    )
    expected = np.zeros(6)
    expected[3] = -2.0 * U[0] ** 2 * X[3] + 0.05
    np.testing.assert_allclose(difference, expected, atol=1e-12)


def test_an_output_term_adds_to_every_wheel():
    plain, slip = CarModel(), CarModel(terms=[SLIP])
    before = plain.numeric.outputs(X, U, plain.parameters.vector())
    after = slip.numeric.outputs(X, U, slip.parameters.vector())
    np.testing.assert_allclose(
        after["wheel_encoders"] - before["wheel_encoders"], 11.4 * U[1] * X[3]
    )
    np.testing.assert_array_equal(after["imu"], before["imu"])


def test_a_sides_term_moves_the_right_wheels_up_and_the_left_ones_down():
    sides = Term("sides", "wheel_speed_sides", (("torque",),), coefficients=(4.0,))
    plain, model = CarModel(), CarModel(terms=[sides])
    before = plain.numeric.outputs(X, U, plain.parameters.vector())
    after = model.numeric.outputs(X, U, model.parameters.vector())
    change = after["wheel_encoders"] - before["wheel_encoders"]  # fl, fr, rl, rr
    np.testing.assert_allclose(change, 4.0 * U[1] * np.array([-1.0, 1.0, -1.0, 1.0]))
    assert sides.unit == "rad/s"


def test_the_coefficients_are_parameters_with_units_and_an_equation():
    model = CarModel(terms=[SCRUB])
    first = model.parameters["scrub_c1"]
    assert first.group == "term:scrub" and first.unit == "m/s^2/(rad*rad*m/s)"
    assert model.parameters["scrub_c2"].unit == "m/s^2"
    assert SCRUB.equation() == "d vx/dt += c1 * steer*steer*vx + c2 * 1"
    assert SCRUB.equation([-2.0, 0.05]) == "d vx/dt += -2 * steer*steer*vx + 0.05 * 1"
    assert SCRUB.variables() == ["vx", "steer"]
    assert model.tag != CarModel().tag and model.tag != CarModel(terms=[SLIP]).tag


def test_a_model_with_terms_crosses_processes_and_keeps_them():
    model = CarModel({"gyro_bias": 0.02}, terms=[SLIP])
    copy = pickle.loads(pickle.dumps(model))
    assert copy.terms == model.terms and copy.tag == model.tag
    assert copy.parameters.value("slip_c1") == 11.4
    same = model.with_parameters(model.parameters.updated({"slip_c1": 3.0}))
    assert same.terms == model.terms and same.parameters.value("slip_c1") == 3.0


def test_a_parameter_file_carries_the_terms(tmp_path):
    path = tmp_path / "params.yaml"
    path.write_text(
        "terms:\n  - {name: scrub, target: vx, monomials: ['steer*steer*vx', '1'],\n"
        "     prior_stds: [20, 0.01]}\nparameters:\n  scrub_c1: -1.5\n  scrub_c2: 0.02\n"
    )
    model = CarModel.from_file(path)
    assert [t.monomials for t in model.terms] == [SCRUB.monomials]
    assert model.parameters.value("scrub_c1") == -1.5
    assert model.parameters["scrub_c2"].prior_std == 0.01
    assert model.parameters["scrub_c1"].lower == -2000.0  # 100 prior stds
    assert parse_terms([model.terms[0].to_dict()]) == model.terms


@pytest.mark.parametrize(
    ("entries", "field", "message"),
    [
        ({"name": "t"}, "terms[0]", "must have the keys"),
        ({"name": "t", "target": "vx", "monomials": ["vx"], "std": 1}, "terms[0]", "the keys"),
        ({"name": "t", "target": "x", "monomials": ["vx"]}, "terms.t.target", "one of vx"),
        ({"name": "t", "target": "vx", "monomials": ["speed"]}, "terms.t.monomials", "'speed'"),
        ({"name": "t", "target": "vx", "monomials": "vx"}, "terms[0].monomials", "a list"),
        ({"name": "1t", "target": "vx", "monomials": ["vx"]}, "terms.name", "identifier"),
    ],
)
def test_a_bad_term_is_refused_naming_the_field(entries, field, message):
    with pytest.raises(FieldError, match=message) as error:
        parse_terms([entries])
    assert error.value.field == field


def test_a_term_in_time_gives_the_model_a_clock():
    """``t`` is a state, ``clock``: derivative 1, 0 at rest, read by the term."""
    term = Term("battery", "vx", (("torque", "t"),), coefficients=(-0.02,))
    model = CarModel(terms=[term])
    assert model.state_names[-1] == "clock" and model.has_clock and not CarModel().has_clock
    x = model.initial_state(X, U)
    assert x[-1] == 0.0
    x[-1] = 30.0
    p = model.parameters.vector()
    xdot = model.numeric.f(x, U, p)
    plain = CarModel().numeric.f(X, U, CarModel().parameters.vector())
    assert xdot[-1] == 1.0
    np.testing.assert_allclose(xdot[3] - plain[3], -0.02 * U[1] * 30.0, atol=1e-12)
    with pytest.raises(ValueError, match="clock"):
        term.value(X, U, lambda name: 1.0)
