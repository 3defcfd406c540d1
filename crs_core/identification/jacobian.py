r"""The FIE residual's sparse Jacobian, assembled from per-sample model Jacobians.

The FIE residual (:mod:`~crs_core.identification.problem`) is block structured: a dynamics
defect :math:`W_k (x_{k+1} - F(x_k, u_k, p, \Delta t_k))` depends on two neighbouring states
and the fitted parameters, a measurement residual :math:`W_k (h(x_k, u_k, p) - y_k)` on one
state (two for a plane-1 sweep read between samples) and the parameters. CasADi's automatic
Jacobian of the whole mapped graph colours its columns and sweeps the graph once per colour
(about :math:`2 n_x + n_\theta` forward sweeps over every sample); here the per-sample blocks
:math:`\partial F / \partial x`, :math:`\partial F / \partial p\, S` and their measurement
counterparts come from small SX functions of the model (one reverse sweep per output row),
mapped over the samples, and their nonzeros are placed into the sparse matrix by one index
operation. Same values as the automatic Jacobian to rounding
(``tests/crs_core/identification/test_jacobian.py``), four times faster (real run 1, 15
parameters: 0.34 s against 1.38 s per evaluation); IPOPT evaluates it for the Gauss-Newton
Hessian :math:`J^\top J` in every iteration, which was 86 % of the solve.

``S`` maps the prior-scaled fitted parameters :math:`\theta_s` to the model's parameter
vector: :math:`p = p_\text{fixed} + S\,\theta_s` up to a constant, so
:math:`\partial r / \partial \theta_s = \partial r / \partial p\, S`.
"""

from __future__ import annotations

from dataclasses import dataclass

import casadi as ca
import numpy as np


@dataclass(frozen=True)
class DefectBlock:
    """Dynamics defects of the samples ``index`` (interval ``[k, k+1]`` each), one mapped step.

    Attributes
    ----------
    step : ``(x, u, p, dt) -> x_next`` (SX)
    index : (L,) first sample of each interval
    u, dt : the step's command and interval inputs, one column per interval
    weight : (nx, L) :math:`Q_k^{-1/2}` per state and interval
    row : first residual row of the block
    """

    step: ca.Function
    index: np.ndarray
    u: ca.DM
    dt: ca.DM
    weight: np.ndarray
    row: int


@dataclass(frozen=True)
class MeasurementBlock:
    """Measurement residuals ``vec((Y - y) * weight)``, one column of ``Y`` per sample.

    Attributes
    ----------
    output : ``(x, u, p) -> y`` (SX), every output row
    plane1_output : ``(x, u, p) -> y[:plane1_rows]`` read at the interpolated state
        ``(1 - alpha_k) x_k + alpha_k x_{k-1}``, or ``None`` when every ``alpha`` is 0
    plane1_rows : rows of ``Y`` from ``plane1_output``
    alpha : (N,) weight of the previous sample in that state
    u : command input, one column per sample
    weight : (N, ny) ``1 / sigma`` (0 where not measured)
    row : first residual row of the block
    """

    output: ca.Function
    plane1_output: ca.Function | None
    plane1_rows: int
    alpha: np.ndarray
    u: ca.DM
    weight: np.ndarray
    row: int


def block_jacobian(f: ca.Function) -> ca.Function:
    """``f(x, u, p, ...) -> (df/dx, df/dp)``, dense, one SX function (CasADi's VM: gcc took
    minutes on the Jacobian of a step over several commands, and common-subexpression
    elimination seconds per function, for a few percent of evaluation time)."""
    args = [ca.SX.sym(f.name_in(i), f.sparsity_in(i)) for i in range(f.n_in())]
    x, p = args[0], args[2]
    jac = ca.jacobian(f(*args), ca.vertcat(x, p))
    nx = x.numel()
    return ca.Function(f"{f.name()}_jac", args, [ca.densify(jac[:, :nx]), ca.densify(jac[:, nx:])])


def _theta_entries(
    d_p: ca.MX, instances: int, rows: np.ndarray, n_out: int, theta_columns: np.ndarray
) -> tuple[np.ndarray, np.ndarray, ca.MX]:
    """Rows, columns (fitted-parameter indices) and values of ``df/dp @ theta_columns`` from a
    mapped ``n_out x (np * instances)`` output, for the output rows ``rows`` of each instance.

    ``theta_columns`` has one nonzero per column (a fitted parameter's prior std at its
    index), so the product is a selection of ``df/dp``'s columns, scaled."""
    n_p = theta_columns.shape[0]
    index, column = np.nonzero(theta_columns)
    scale = theta_columns[index, column]
    grid = np.arange(instances * n_p * n_out).reshape(instances, n_p, n_out)[:, index][:, :, rows]
    values = ca.vec(d_p)[grid.ravel().tolist()] * ca.DM(
        np.broadcast_to(scale[None, :, None], grid.shape).ravel()
    )
    return grid, np.broadcast_to(column[None, :, None], grid.shape), values


class _Triplets:
    """Rows, columns and values (MX or constant pieces) of a sparse matrix, in one order."""

    def __init__(self) -> None:
        self.rows: list[np.ndarray] = []
        self.cols: list[np.ndarray] = []
        self.values: list[ca.MX] = []

    def add(self, rows: np.ndarray, cols: np.ndarray, values) -> None:
        rows, cols = np.broadcast_arrays(np.ravel(rows), np.ravel(cols))
        self.rows.append(rows.astype(np.int64))
        self.cols.append(cols.astype(np.int64))
        self.values.append(ca.MX(values) if not isinstance(values, ca.MX) else values)

    def matrix(self, shape: tuple[int, int]) -> ca.MX:
        rows, cols = np.concatenate(self.rows), np.concatenate(self.cols)
        order = np.lexsort((rows, cols))
        rows, cols = rows[order], cols[order]
        repeated = (np.diff(rows) == 0) & (np.diff(cols) == 0)
        if repeated.any():
            raise AssertionError("FIE Jacobian: an entry is assembled twice")
        colind = np.searchsorted(cols, np.arange(shape[1] + 1))
        sparsity = ca.Sparsity(shape[0], shape[1], colind.tolist(), rows.tolist())
        values = ca.vertcat(*self.values)
        return ca.MX(sparsity, values[order.tolist()])


def residual_jacobian(
    z: ca.MX,
    states: ca.MX,
    p: ca.MX,
    n_theta: int,
    theta_columns: np.ndarray,
    x0_weight: np.ndarray,
    defects: list[DefectBlock],
    measurements: MeasurementBlock,
    n_rows: int,
) -> ca.MX:
    """``dr/dz`` of the FIE residual ``r = [theta_s, W0 (x_0 - x0_bar), defects, measurements]``
    as a sparse MX expression of ``z = [theta_s, vec(states)]``.

    ``states`` is ``nx x N`` (``reshape`` of ``z``), ``p`` the model's parameter vector as an
    expression of ``z``, ``theta_columns`` the ``np x n_theta`` matrix ``dp/dtheta_s``,
    ``x0_weight`` ``(nx,)`` the initial-state prior's ``1 / std``.
    """
    nx, n = states.shape
    entries = _Triplets()
    state_col = n_theta + np.arange(n * nx).reshape(n, nx)  # [k, c] -> column of x_k[c]
    theta_col = np.arange(n_theta)
    entries.add(theta_col, theta_col, ca.DM.ones(n_theta))
    entries.add(n_theta + np.arange(nx), state_col[0], ca.DM(x0_weight))

    for block in defects:
        size = len(block.index)
        jac = block_jacobian(block.step).map(size, "serial")
        d_x, d_p = jac(states[:, block.index.tolist()], block.u, ca.repmat(p, 1, size), block.dt)
        row = block.row + np.arange(size * nx).reshape(size, nx)  # [i, r]
        w = block.weight.T  # [i, r]
        # + W x_{k+1}
        entries.add(row, state_col[block.index + 1], ca.DM(w.ravel()))
        # - W dF/dx: nonzero [i, c, r] of d_x
        entries.add(
            np.broadcast_to(row[:, None, :], (size, nx, nx)),
            np.broadcast_to(state_col[block.index][:, :, None], (size, nx, nx)),
            -ca.vec(d_x) * ca.DM(np.broadcast_to(w[:, None, :], (size, nx, nx)).ravel()),
        )
        # - W dF/dp S
        grid, columns, values = _theta_entries(d_p, size, np.arange(nx), nx, theta_columns)
        weight = np.broadcast_to(w[:, None, :], grid.shape)
        entries.add(
            np.broadcast_to(row[:, None, :], grid.shape),
            columns,
            -values * ca.DM(weight.ravel()),
        )

    m = measurements
    ny = m.weight.shape[1]
    rows = m.row + np.arange(n * ny).reshape(n, ny)  # [k, o]
    first = np.arange(n) == 0
    if m.plane1_output is None:
        reads = [(m.output, states, slice(0, ny), [(state_col, np.ones(n))])]
    else:
        # plane 1 at (1 - alpha_k) x_k + alpha_k x_{k-1}; x_0's "previous" is itself
        alpha = np.where(first, 0.0, m.alpha)
        previous = ca.horzcat(states[:, 0], states[:, : n - 1])
        a = ca.DM(np.tile(alpha, (nx, 1)))
        reads = [
            (m.output, states, slice(m.plane1_rows, ny), [(state_col, np.ones(n))]),
            (
                m.plane1_output,
                states * (1.0 - a) + previous * a,
                slice(0, m.plane1_rows),
                [(state_col, 1.0 - alpha), (state_col[np.maximum(np.arange(n) - 1, 0)], alpha)],
            ),
        ]
    for output, at, keep, coefficients in reads:
        n_out = output.size1_out(0)
        d_x, d_p = block_jacobian(output).map(n, "serial")(at, m.u, ca.repmat(p, 1, n))
        kept = np.arange(n_out)[keep]
        w = m.weight[:, keep]  # [k, o]
        # nonzero [k, c, o] of d_x, [k, j, o] of d_theta
        grid_x = np.arange(n * nx * n_out).reshape(n, nx, n_out)[:, :, kept]
        rows_x = np.broadcast_to(rows[:, None, keep], grid_x.shape)
        for columns, factor in coefficients:
            used = factor != 0  # samples whose residual depends on these states
            if not used.any():
                continue
            scale = w[used][:, None, :] * factor[used][:, None, None]
            entries.add(
                rows_x[used],
                np.broadcast_to(columns[used][:, :, None], scale.shape[:1] + grid_x.shape[1:]),
                ca.vec(d_x)[grid_x[used].ravel().tolist()]
                * ca.DM(np.broadcast_to(scale, grid_x[used].shape).ravel()),
            )
        grid, columns, values = _theta_entries(d_p, n, kept, n_out, theta_columns)
        weight = np.broadcast_to(w[:, None, :], grid.shape)
        entries.add(
            np.broadcast_to(rows[:, None, keep], grid.shape),
            columns,
            values * ca.DM(weight.ravel()),
        )
    return entries.matrix((n_rows, z.numel()))
