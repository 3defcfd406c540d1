"""Tests of crs_core.integrators: the classical RK4 step with substeps."""

from __future__ import annotations

import math

import casadi as ca
import numpy as np
import pytest

from crs_core.integrators import rk4


def _step(rhs, x0: np.ndarray, u: float, dt: float, substeps: int) -> np.ndarray:
    x, uu = ca.SX.sym("x", len(x0)), ca.SX.sym("u")
    f = ca.Function("step", [x, uu], [rk4(rhs, x, uu, dt, substeps)])
    return np.array(f(x0, u)).ravel()


@pytest.mark.parametrize("substeps", [1, 3])
def test_a_linear_decay_is_advanced_by_the_rk4_polynomial(substeps: int):
    """For ``x' = -a x + u`` one RK4 step of ``h`` multiplies ``x - u/a`` by the degree-4 Taylor
    polynomial of ``exp(-a h)``; ``substeps`` steps of ``dt / substeps`` apply it that often."""
    a, u, dt, x0 = 3.0, 0.6, 0.2, 1.5
    z = -a * dt / substeps
    growth = (1 + z + z**2 / 2 + z**3 / 6 + z**4 / 24) ** substeps
    expected = u / a + (x0 - u / a) * growth
    got = _step(lambda x, u: -a * x + u, np.array([x0]), u, dt, substeps)
    assert got[0] == pytest.approx(expected, rel=1e-14)


def test_the_error_falls_with_the_fourth_power_of_the_substep():
    """A harmonic oscillator over one period: doubling the substeps cuts the error 16 times."""

    def rhs(x, u):
        return ca.vertcat(x[1], -x[0])

    errors = [
        np.linalg.norm(_step(rhs, np.array([1.0, 0.0]), 0.0, 2 * math.pi, n) - [1.0, 0.0])
        for n in (20, 40)
    ]
    assert errors[0] / errors[1] == pytest.approx(16.0, rel=0.05)


def test_fewer_than_one_substep_is_refused():
    with pytest.raises(ValueError, match="substeps must be >= 1"):
        rk4(lambda x, u: -x, ca.SX.sym("x"), ca.SX.sym("u"), 0.1, 0)
