"""The sparse QP assembly: values land where they are placed; a position placed twice is refused."""

from __future__ import annotations

import casadi as ca
import numpy as np
import pytest

from crs_core.control.ocp_qp import SparseAssembly


def test_sparse_assembly_places_values_and_refuses_duplicates() -> None:
    assembly = SparseAssembly((3, 4))
    assembly.add(ca.DM([1.0, 2.0]), np.array([0, 2]), np.array([3, 0]))
    assembly.add(ca.DM([5.0]), np.array([1]), np.array([1]))
    dense = np.array(ca.DM(ca.evalf(assembly.build())))
    expected = np.zeros((3, 4))
    expected[0, 3], expected[2, 0], expected[1, 1] = 1.0, 2.0, 5.0
    assert dense == pytest.approx(expected)
    assembly.add(ca.DM([7.0]), np.array([0]), np.array([3]))
    with pytest.raises(ValueError, match="same position"):
        assembly.build()
