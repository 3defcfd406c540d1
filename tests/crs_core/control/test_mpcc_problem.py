"""The MPCC problem: its settings name a bad field; its stage linearisation and its contouring
and lag errors."""

from __future__ import annotations

import math

import casadi as ca
import numpy as np
import pytest

from crs_core.control.mpcc_problem import MpccProblem, MpccSettings
from crs_core.errors import FieldError
from crs_core.model import CarModel


# --- settings ---------------------------------------------------------------------------------
@pytest.mark.parametrize(
    ("field", "value"),
    [
        ("horizon", 0),
        ("rate_hz", 0.0),
        ("q_lag", math.nan),
        ("steer_max", 2.0),
        ("torque_max", -2.0),
        ("solver", "gurobi"),
        ("max_failures", 1.5),
    ],
)
def test_bad_settings_name_the_field(field: str, value: object) -> None:
    with pytest.raises(ValueError, match=field):
        MpccSettings(**{field: value})


@pytest.mark.parametrize(
    ("values", "message"),
    [
        ({"q_contour": -1}, "q_contour: must be a finite number >= 0, got -1"),
        ({"rate_hz": 0.0}, "rate_hz: must be a finite number > 0, got 0.0"),
        ({"torque_min": math.inf}, "torque_min: must be a finite number, got inf"),
        ({"q_lag": True}, "q_lag: must be a finite number > 0, got True"),
        ({"horizon": True}, "horizon: must be a positive integer, got True"),
        ({"horizon": 40.0}, "horizon: must be a positive integer, got 40.0"),
    ],
)
def test_settings_errors_are_field_errors_in_the_shared_wording(
    values: dict[str, object], message: str
) -> None:
    with pytest.raises(FieldError) as error:
        MpccSettings(**values)  # type: ignore[arg-type]
    assert str(error.value) == message


# --- the problem ------------------------------------------------------------------------------
def test_stage_dynamics_linearisation_matches_finite_differences() -> None:
    problem = MpccProblem(CarModel(["steering_lag"]), MpccSettings(horizon=3))
    p = problem.model.parameters.vector()
    rng = np.random.default_rng(0)
    z = np.concatenate(([0.3, -0.2, 0.4, 1.2, 0.05, 0.8, 0.1], rng.normal(0, 0.1, 4)))
    v = np.array([0.15, 0.4, 1.1, 0.0])
    stage = problem.stage_linearization()
    A, B, c = (np.asarray(o) for o in stage(z, v, np.zeros(4), MpccSettings().weights(), p)[:3])
    f = problem.dynamics

    def step(zz, vv):
        return np.asarray(f(zz, vv, p)).ravel()

    eps = 1e-6
    A_fd = np.column_stack(
        [(step(z + eps * e, v) - step(z - eps * e, v)) / (2 * eps) for e in np.eye(z.size)]
    )
    B_fd = np.column_stack(
        [(step(z, v + eps * e) - step(z, v - eps * e)) / (2 * eps) for e in np.eye(v.size)]
    )
    assert np.max(np.abs(A - A_fd)) < 1e-6
    assert np.max(np.abs(B - B_fd)) < 1e-6
    assert np.max(np.abs(A @ z + B @ v + c.ravel() - step(z, v))) < 1e-12
    # the progress integrates the progress speed; the input memory holds the inputs
    nxc = problem.nx_car
    assert step(z, v)[nxc] == pytest.approx(z[nxc] + v[2] / 30.0)
    assert step(z, v)[nxc + 1 :] == pytest.approx(v[:3])


def test_contouring_and_lag_errors_are_distances_along_the_path_normal_and_tangent() -> None:
    problem = MpccProblem(CarModel(), MpccSettings(horizon=2))
    heading = 0.7
    ref = np.array([1.0, 2.0, heading, 5.0])
    tangent = np.array([math.cos(heading), math.sin(heading)])
    left = np.array([-math.sin(heading), math.cos(heading)])
    z = np.zeros(problem.nz)
    z[:2] = ref[:2] + 0.03 * left + 0.2 * tangent
    z[problem.nx_car] = 5.2
    # e_c: distance to the right of the path
    assert float(problem.contouring_error(z, ref)) == pytest.approx(-0.03)
    cost_terms = problem.least_squares.residuals
    lag = ca.Function("lag", [problem.z_sym, problem.v_sym, problem.ref_sym], [cost_terms[1]])
    assert float(lag(z, np.zeros(problem.nv), ref)) == pytest.approx(0.0, abs=1e-12)
