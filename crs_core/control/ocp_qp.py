r"""Sparse matrices scattered from stage blocks, and the QP solvers for optimal-control QPs.

An optimal-control QP

.. math::

    \min_w \tfrac12 w^\top H w + g^\top w \quad \text{s.t.} \quad
    \underline a \le A w \le \overline a,\; \underline w \le w \le \overline w

over ``w = [z_0, v_0, z_1, v_1, ..., z_N]`` has a block-diagonal ``H`` and, in the row order
``[gap_0, con_0, gap_1, con_1, ...]`` (the dynamics :math:`A_k z_k + B_k v_k - z_{k+1}`, then the
stage's constraint rows), the banded ``A`` whose structure HPIPM's Riccati recursion exploits.
:class:`SparseAssembly` builds such a matrix inside a CasADi graph from the nonzeros of the
stage blocks (one reindexing of the nonzeros, no dense intermediate), so the whole real-time
iteration (linearisation, assembly, QP) is one compiled CasADi call.
"""

from __future__ import annotations

import casadi as ca
import numpy as np

from crs_core.errors import FieldError

__all__ = ["QP_SOLVERS", "SparseAssembly", "qp_solver"]

#: CasADi QP plugins that :func:`qp_solver` sets up.
QP_SOLVERS = ("hpipm", "qrqp", "osqp", "qpoases")


class SparseAssembly:
    """A sparse ``(rows, cols)`` matrix whose nonzeros come from pieces placed at known
    positions: each piece is a CasADi column of values with the row and column of each value.
    Duplicate positions are not allowed."""

    def __init__(self, shape: tuple[int, int]) -> None:
        self.shape = shape
        self._values: list[ca.MX] = []
        self._rows: list[np.ndarray] = []
        self._cols: list[np.ndarray] = []

    def add(self, values: ca.MX | ca.DM, rows: np.ndarray, cols: np.ndarray) -> None:
        """Place ``values`` (a column of ``len(rows)`` entries) at ``(rows[i], cols[i])``."""
        rows, cols = np.asarray(rows, dtype=int), np.asarray(cols, dtype=int)
        if values.numel() != rows.size or rows.size != cols.size:
            raise ValueError(f"piece of {values.numel()} values for {rows.size} positions")
        self._values.append(ca.vec(ca.MX(values) if isinstance(values, ca.DM) else values))
        self._rows.append(rows)
        self._cols.append(cols)

    def add_matrix(self, matrix: ca.MX, row_of, col_of) -> None:
        """Place every structural nonzero ``(r, c)`` of ``matrix`` at
        ``(row_of(r, c), col_of(r, c))`` (vectorised functions of numpy index arrays)."""
        triplet_rows, triplet_cols = matrix.sparsity().get_triplet()
        r, c = np.asarray(triplet_rows, dtype=int), np.asarray(triplet_cols, dtype=int)
        self.add(matrix.nz[:], row_of(r, c), col_of(r, c))

    def build(self) -> ca.MX:
        """The sparse matrix (its sparsity is fixed; only the values are symbolic)."""
        rows, cols = np.concatenate(self._rows), np.concatenate(self._cols)
        keys = rows.astype(np.int64) * self.shape[1] + cols
        if np.unique(keys).size != keys.size:
            raise ValueError("two values placed at the same position")
        order = np.lexsort((rows, cols))
        colind = np.concatenate(([0], np.cumsum(np.bincount(cols, minlength=self.shape[1]))))
        sparsity = ca.Sparsity(self.shape[0], self.shape[1], colind.tolist(), rows[order].tolist())
        values = ca.vertcat(*self._values)
        return ca.MX(sparsity, values[order.tolist()])


def qp_solver(
    name: str,
    solver: str,
    h: ca.Sparsity,
    a: ca.Sparsity,
    N: int,
    nz: int,
    nv: int,
    ng: list[int],
    max_iter: int,
) -> ca.Function:
    """A CasADi QP solver for the optimal-control QP above.

    ``"hpipm"`` is told the stage structure (``N``, state size ``nz``, input size ``nv``,
    ``ng[k]`` constraint rows per stage, the terminal stage none) and runs its Riccati-based
    interior point method in its fastest mode; the others see a general sparse QP. A failed
    solve does not raise: the caller checks the solution.
    """
    if solver not in QP_SOLVERS:
        raise FieldError("solver", f"one of {', '.join(QP_SOLVERS)}, got {solver!r}")
    options: dict = {"error_on_fail": False}
    if solver == "hpipm":
        options.update(
            N=N,
            nx=[nz] * (N + 1),
            nu=[nv] * N + [0],
            ng=[*ng, 0],
            hpipm={"iter_max": max_iter, "mode": "speed_abs", "warm_start": 1},
        )
    elif solver == "qrqp":
        options.update(max_iter=max_iter, print_iter=False, print_header=False, print_info=False)
    elif solver == "osqp":
        options.update(
            osqp={
                "max_iter": 100 * max_iter,
                "verbose": False,
                "eps_abs": 1e-8,
                "eps_rel": 1e-8,
                "polish": True,
            }
        )
    else:
        options.update(printLevel="none", nWSR=100 * max_iter)
    return ca.conic(name, solver, {"h": h, "a": a}, options)
