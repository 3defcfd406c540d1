"""Tests of crs_core.identification.uncertainty: the parameter covariance and what makes a
parameter unidentifiable."""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from crs_core.identification.uncertainty import MAX_CORRELATION, parameter_uncertainty


def test_linear_covariance_matches_the_closed_form():
    """Parameters only: covariance = (I + A'A)^-1 scaled by the prior std."""
    rng = np.random.default_rng(0)
    a = rng.standard_normal((30, 3))
    jac = sp.csc_matrix(np.vstack([np.eye(3), a]))
    std = np.array([2.0, 0.5, 1.0])
    u = parameter_uncertainty(jac, ("a", "b", "c"), np.ones(3), std)
    expected = np.linalg.inv(np.eye(3) + a.T @ a) * np.outer(std, std)
    np.testing.assert_allclose(u.covariance, expected, rtol=1e-9)
    assert np.all(u.identifiable)


def test_states_are_eliminated_by_the_schur_complement():
    """With a state in the problem, the parameter block equals that of the full inverse."""
    rng = np.random.default_rng(1)
    jac = rng.standard_normal((20, 4))
    jac[:2, :2] = np.eye(2)
    u = parameter_uncertainty(sp.csc_matrix(jac), ("a", "b"), np.ones(2), np.ones(2))
    full = np.linalg.inv(jac.T @ jac)[:2, :2]
    np.testing.assert_allclose(u.covariance, full, rtol=1e-9)


def test_unidentifiable_parameters_are_named_with_the_reason():
    """A parameter the data do not see is flat; two the data see only as a sum correlate; a
    parameter on its bound is flagged."""
    data = np.zeros((40, 4))
    data[:20, 0] = 10.0  # a: well determined
    data[20:, 1] = data[20:, 2] = 10.0  # b, c: only b + c is seen
    jac = sp.csc_matrix(np.vstack([np.eye(4), data]))  # d: column of zeros (flat)
    u = parameter_uncertainty(
        jac, ("a", "b", "c", "d"), np.ones(4), np.ones(4), at_bound=np.array([1, 0, 0, 0], bool)
    )
    assert list(u.identifiable) == [False, False, False, False]
    assert u.reasons[0] == "bound active"
    assert u.std[0] < 0.1
    assert (
        "strongly correlated with c" in u.reasons[1] and abs(u.correlation[1, 2]) > MAX_CORRELATION
    )
    assert "flat direction" in u.reasons[3]
    assert any("'d'" in w and "flat" in w for w in u.warnings())
