"""Tests of crs_core.estimation.mhe_problem: the block-tridiagonal Hessian in LAPACK banded
storage."""

from __future__ import annotations

import numpy as np
from scipy.linalg import solveh_banded

from crs_core.estimation.mhe_problem import Band


def test_banded_storage_holds_the_block_tridiagonal_matrix_and_solves_like_it():
    """Blocks D_j on the diagonal and O_j above it (column-major, side by side): every entry of
    the upper band is the dense matrix's, and the banded Cholesky solve equals numpy's."""
    nx, nodes = 3, 4
    rng = np.random.default_rng(2)
    diag = [(lambda a: a @ a.T + 4 * np.eye(nx))(rng.normal(size=(nx, nx))) for _ in range(nodes)]
    off = [rng.normal(size=(nx, nx)) for _ in range(nodes - 1)]
    dense = np.zeros((nx * nodes, nx * nodes))
    for j, block in enumerate(diag):
        dense[j * nx : (j + 1) * nx, j * nx : (j + 1) * nx] = block
    for j, block in enumerate(off):
        dense[j * nx : (j + 1) * nx, (j + 1) * nx : (j + 2) * nx] = block
        dense[(j + 1) * nx : (j + 2) * nx, j * nx : (j + 1) * nx] = block.T
    band = Band(nx, nodes)
    ab = band.matrix(np.hstack(diag), np.hstack(off))
    for i in range(nx * nodes):
        for k in range(i, min(i + band.u + 1, nx * nodes)):
            assert ab[band.u + i - k, k] == dense[i, k]
    b = rng.normal(size=nx * nodes)
    np.testing.assert_allclose(solveh_banded(ab, b), np.linalg.solve(dense, b), rtol=1e-10)
