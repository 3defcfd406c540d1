r"""The MHE's least-squares problem as generated code, and its banded linear algebra.

:func:`build_mhe_function` generates, from the one car model, a function returning the
Gauss-Newton blocks of the whole horizon (block-tridiagonal Hessian, gradient, cost) and a
cheaper function returning the cost alone (for the step acceptance test);
:class:`Band` maps the blocks into LAPACK's banded storage for ``dpbtrf``/``dpbtrs``.
Residuals (all in units of their standard deviation):

* stage :math:`j`: :math:`\sqrt{w_j}\,(x_{j+1} - f(x_j, \bar u_j, \Delta))` with the RK4 step
  of the fixed stage length :math:`\Delta` (substeps no longer than
  :data:`~crs_core.model.MAX_SUBSTEP`), plus a squared hinge on :math:`|w_j|` beyond
  ``process_bound``;
* node :math:`j`: the weighted residuals of the mean measurement per sensor, the output taken
  :math:`\tau` s after the node (one Euler step of the model), plus squared hinges on the state
  bounds of every state but the pose.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import casadi as ca
import numpy as np
from scipy.linalg.lapack import dpbtrf, dpbtrs

from crs_core.codegen import SX_OPTIONS
from crs_core.integrators import rk4
from crs_core.measurements import lighthouse_sensor
from crs_core.model import CarModel


def measurement_groups(model: CarModel) -> list[str]:
    """Sensors an MHE node can hold, in slot order."""
    groups = ["imu", "gyro", "wheel_encoders", "pose"]
    for station in range(model.n_base_stations):
        groups += [lighthouse_sensor(station, 1), lighthouse_sensor(station, 2)]
    return groups


def offset_output_functions(model: CarModel, groups: list[str]) -> list[ca.Function]:
    """Per sensor ``y(x, u, p, tau) = h(x + tau f(x, u), u, p)``: the output ``tau`` s after
    the node, the state moved by one Euler step (exact to first order in ``tau``)."""
    x, u, p, tau = model.x_sym, model.u_sym, model.p_sym, ca.SX.sym("tau")
    moved = x + tau * model.dynamics_function(x, u, p)
    return [
        ca.Function(
            "offset_" + group.replace("/", "_"),
            [x, u, p, tau],
            [model.output_function(group)(moved, u, p)],
            SX_OPTIONS,
        )
        for group in groups
    ]


def _hinge(value: ca.SX, lower: ca.SX, upper: ca.SX) -> ca.SX:
    return ca.fmax(value - upper, 0) + ca.fmin(value - lower, 0)


def bound_data_size(nx: int) -> int:
    """Length of the ``BND`` input: process bounds and weight, state bounds and weight."""
    return nx + 1 + 2 * (nx - 3) + 1


def build_mhe_function(
    model: CarModel, horizon: int, substeps: int, groups: list[str]
) -> tuple[ca.Function, ca.Function, ca.Function, list[int]]:
    """The Gauss-Newton blocks and the cost of the whole horizon, one node's terms, and the
    sensor sizes.

    Inputs of both functions: ``X`` (nx, M+1), ``U`` (2, M), ``DT`` (1, M), ``WP`` (nx, M)
    process weights, ``Y`` (ny, M+1), ``WY`` (ny, M+1) measurement weights, ``TAU`` (ng, M+1)
    offsets, ``UG`` (2 ng, M+1) node inputs, ``p``, ``BND`` bound data
    (:func:`bound_data_size`). Outputs of ``mhe_gn``: diagonal blocks ``D`` (nx, nx (M+1)),
    upper blocks ``O`` (nx, nx M), gradient ``G`` (nx, M+1), cost, the weighted measurement
    residuals ``RY`` (ny, M+1), and stage 0's contributions to node 1 (``S0`` block and ``g0b``
    gradient) for the marginalization of node 0. ``mhe_cost`` returns the cost alone.
    ``mhe_node`` is one node's measurement and bound terms, the Gauss-Newton block ``H`` (nx, nx)
    and gradient ``g`` (nx), from ``x`` (nx), ``ug`` (2 ng), ``y`` (ny), ``wy`` (ny), ``tau``
    (ng), the state bounds (``BND`` after the process bounds) and ``p``.
    """
    nx, p = model.nx, model.p_sym
    nb = nx - 3  # every state but the pose is bounded
    xa, xb = ca.SX.sym("xa", nx), ca.SX.sym("xb", nx)
    u, dt = ca.SX.sym("u", 2), ca.SX.sym("dt")
    wp = ca.SX.sym("wp", nx)
    wbound = ca.SX.sym("wbound", nx + 1)  # per-state |w| bound, then weight
    predicted = rk4(lambda xx, uu: model.dynamics_function(xx, uu, p), xa, u, dt, substeps)
    w = xb - predicted
    r_stage = ca.vertcat(wp * w, wbound[nx] * _hinge(w, -wbound[:nx], wbound[:nx]))
    Ja, Jb = ca.jacobian(r_stage, xa), ca.jacobian(r_stage, xb)
    stage_args = [xa, xb, u, dt, wp, wbound, p]
    stage = ca.Function(
        "stage",
        stage_args,
        [Ja.T @ Ja, Ja.T @ Jb, Jb.T @ Jb, Ja.T @ r_stage, Jb.T @ r_stage, ca.sumsqr(r_stage)],
        SX_OPTIONS,
    )
    stage_cost = ca.Function("stage_cost", stage_args, [ca.sumsqr(r_stage)], SX_OPTIONS)
    sizes = [model.output_expressions[g].numel() for g in groups]
    ny = sum(sizes)
    y, wy = ca.SX.sym("y", ny), ca.SX.sym("wy", ny)
    ng = len(groups)
    tau, ug = ca.SX.sym("tau", ng), ca.SX.sym("ug", 2 * ng)
    xstate_bounds = ca.SX.sym("xbnd", 2 * nb + 1)  # lower; upper; weight
    predicted_y = [
        h(xa, ug[2 * g : 2 * g + 2], p, tau[g])
        for g, h in enumerate(offset_output_functions(model, groups))
    ]
    r_y = wy * (y - ca.vertcat(*predicted_y))
    r_bounds = xstate_bounds[2 * nb] * _hinge(
        xa[3:], xstate_bounds[:nb], xstate_bounds[nb : 2 * nb]
    )
    r_node = ca.vertcat(r_y, r_bounds)
    Jn = ca.jacobian(r_node, xa)
    node_args = [xa, ug, y, wy, tau, xstate_bounds, p]
    node = ca.Function(
        "node", node_args, [Jn.T @ Jn, Jn.T @ r_node, ca.sumsqr(r_node), r_y], SX_OPTIONS
    )
    node_cost = ca.Function("node_cost", node_args, [ca.sumsqr(r_node)], SX_OPTIONS)
    node_terms = ca.Function(
        "mhe_node", node_args, [ca.densify(v) for v in node(*node_args)[:2]], SX_OPTIONS
    )
    # the horizon is assembled in MX so the generated code loops over the (SX) stage and node
    # functions instead of inlining M copies of them
    M = horizon
    X, P = ca.MX.sym("X", nx, M + 1), ca.MX.sym("p", p.numel())
    U, DT, WP = ca.MX.sym("U", 2, M), ca.MX.sym("DT", 1, M), ca.MX.sym("WP", nx, M)
    Y, WY = ca.MX.sym("Y", ny, M + 1), ca.MX.sym("WY", ny, M + 1)
    TAU, UG = ca.MX.sym("TAU", ng, M + 1), ca.MX.sym("UG", 2 * ng, M + 1)
    BND = ca.MX.sym("BND", bound_data_size(nx))
    inputs = [X, U, DT, WP, Y, WY, TAU, UG, P, BND]
    names = ["X", "U", "DT", "WP", "Y", "WY", "TAU", "UG", "p", "BND"]
    stage_inputs = [
        X[:, :M],
        X[:, 1:],
        U,
        DT,
        WP,
        ca.repmat(BND[: nx + 1], 1, M),
        ca.repmat(P, 1, M),
    ]
    node_inputs = [X, UG, Y, WY, TAU, ca.repmat(BND[nx + 1 :], 1, M + 1), ca.repmat(P, 1, M + 1)]
    # serial on purpose: OpenMP gained ~10 % alone but stalled to >10 ms per call when other
    # processes (simulator, controller) shared the two cores
    s_aa, s_ab, s_bb, s_ga, s_gb, s_cost = stage.map(M, "serial")(*stage_inputs)
    n_h, n_g, n_cost, n_ry = node.map(M + 1, "serial")(*node_inputs)
    zero_block = ca.MX.zeros(nx, nx)
    zero_col = ca.MX.zeros(nx, 1)
    D = n_h + ca.horzcat(s_aa, zero_block) + ca.horzcat(zero_block, s_bb)
    G = n_g + ca.horzcat(s_ga, zero_col) + ca.horzcat(zero_col, s_gb)
    cost = ca.sum2(s_cost) + ca.sum2(n_cost)
    blocks = ca.Function(
        "mhe_gn",
        inputs,
        [ca.densify(v) for v in (D, s_ab, G, cost, n_ry, s_bb[:, :nx], s_gb[:, 0])],
        names,
        ["D", "O", "G", "cost", "RY", "S0", "g0b"],
    )
    only_cost = ca.sum2(stage_cost.map(M, "serial")(*stage_inputs)) + ca.sum2(
        node_cost.map(M + 1, "serial")(*node_inputs)
    )
    only_cost_function = ca.Function("mhe_cost", inputs, [only_cost], names, ["cost"])
    return blocks, only_cost_function, node_terms, sizes


class Band:
    """Index maps from block-tridiagonal blocks into LAPACK upper banded storage."""

    def __init__(self, nx: int, nodes: int) -> None:
        self.nx, self.n = nx, nx * nodes
        self.u = 2 * nx - 1
        a, b = np.meshgrid(np.arange(nx), np.arange(nx), indexing="ij")
        upper = a <= b
        rows_d, cols_d, src_d = [], [], []
        for j in range(nodes):
            i, k = j * nx + a[upper], j * nx + b[upper]
            rows_d.append(self.u + i - k)
            cols_d.append(k)
            src_d.append(j * nx * nx + (b[upper] * nx + a[upper]))  # column-major block entry
        self.diag_rows, self.diag_cols = np.concatenate(rows_d), np.concatenate(cols_d)
        self.diag_src = np.concatenate(src_d)
        rows_o, cols_o, src_o = [], [], []
        for j in range(nodes - 1):
            i, k = j * nx + a.ravel(), (j + 1) * nx + b.ravel()
            rows_o.append(self.u + i - k)
            cols_o.append(k)
            src_o.append(j * nx * nx + (b.ravel() * nx + a.ravel()))
        self.off_rows, self.off_cols = np.concatenate(rows_o), np.concatenate(cols_o)
        self.off_src = np.concatenate(src_o)

    def matrix(self, diag_blocks: np.ndarray, off_blocks: np.ndarray) -> np.ndarray:
        """Banded storage from ``D`` (nx, nx*nodes) and ``O`` (nx, nx*(nodes-1)), column-major."""
        ab = np.zeros((self.u + 1, self.n))
        ab[self.diag_rows, self.diag_cols] = diag_blocks.ravel(order="F")[self.diag_src]
        ab[self.off_rows, self.off_cols] = off_blocks.ravel(order="F")[self.off_src]
        return ab


class StepOutcome:
    """What a Gauss-Newton step of the window did (the codes both step solvers return)."""

    TAKEN = 0
    NON_FINITE_COST = 1
    NOT_POSITIVE_DEFINITE = 2
    NON_FINITE_STEP = 3
    COST_RAISED = 4


class BandedGaussNewton:
    """One Gauss-Newton step of the MHE's window in numpy, its normal equations in LAPACK's
    banded Cholesky (``dpbtrf``/``dpbtrs``): the reference of the compiled step
    (:class:`~crs_core.estimation.mhe_native.NativeGaussNewton`, the same interface), used
    where the functions run in CasADi's VM.

    Parameters
    ----------
    blocks, cost : NumericFunction
        The window's ``mhe_gn`` and ``mhe_cost`` (:func:`build_mhe_function`), callable.
    step_fractions : sequence of float
        The step lengths tried, in order, until the cost does not rise.
    """

    def __init__(self, blocks, cost, step_fractions: Sequence[float]) -> None:
        self._blocks, self._cost = blocks, cost
        self._fractions = tuple(step_fractions)
        self.nx, self.nodes = blocks.function.size1_in(0), blocks.function.size2_in(0)
        self._band = Band(self.nx, self.nodes)
        #: the accepted window, the newest node's covariance (after a taken step), the
        #: weighted measurement residuals (after a non-finite cost)
        self.X = np.zeros((self.nx, self.nodes))
        self.covariance = np.zeros((self.nx, self.nx))
        self.residuals = np.zeros((0, self.nodes))
        self._last: tuple[np.ndarray, ...] = ()

    def step(
        self,
        inputs: Sequence[np.ndarray],
        first: int,
        information: np.ndarray,
        mean: np.ndarray,
    ) -> int:
        """One step from the window ``inputs[0]`` (the ten inputs of ``mhe_gn``), the prior
        ``information`` / ``mean`` on node ``first``; returns a :class:`StepOutcome` code."""
        nx, M = self.nx, self.nodes - 1
        X = np.asarray(inputs[0], dtype=float)
        D, upper, G, cost, residuals, stage0_block, stage0_gradient = self._blocks(*inputs)
        if not np.isfinite(cost[0]):
            self.residuals = residuals
            return StepOutcome.NON_FINITE_COST
        D[:, first * nx : (first + 1) * nx] += information
        G[:, first] += information @ (X[:, first] - mean)
        for j in range(first):  # unused nodes: keep them where they are
            D[:, j * nx : (j + 1) * nx] = np.eye(nx)
            G[:, j] = 0.0
            if j < M:
                upper[:, j * nx : (j + 1) * nx] = 0.0
        ab = self._band.matrix(D, upper)
        ab[-1] += 1e-9  # Levenberg-Marquardt floor against rank deficiency
        factor, info = dpbtrf(ab)
        if info != 0:
            return StepOutcome.NOT_POSITIVE_DEFINITE
        rhs = np.zeros((ab.shape[1], 1 + nx))
        rhs[:, 0] = -G.ravel(order="F")
        rhs[M * nx + np.arange(nx), 1 + np.arange(nx)] = 1.0  # unit vectors of the newest node
        solution, info = dpbtrs(factor, rhs)
        step = solution[:, 0].reshape((nx, M + 1), order="F")
        if not np.all(np.isfinite(step)):
            return StepOutcome.NON_FINITE_STEP
        self._last = (
            D[:, :nx].copy(),
            upper[:, :nx].copy(),
            stage0_block,
            G[:, 0].copy(),
            stage0_gradient,
            X[:, 1].copy(),
        )

        def total(candidate: np.ndarray) -> float:
            d = candidate[:, first] - mean
            cost = self._cost(candidate, *inputs[1:])[0]
            return float(np.asarray(cost).ravel()[0]) + float(d @ information @ d)

        before = total(X)
        for fraction in self._fractions:
            candidate = X + fraction * step
            after = total(candidate)
            if math.isfinite(after) and after <= before * (1 + 1e-9) + 1e-12:
                self.X = candidate
                self.covariance = solution[M * nx :, 1:]
                return StepOutcome.TAKEN
        return StepOutcome.COST_RAISED

    def marginalization_blocks(self) -> tuple[np.ndarray, ...]:
        """``(D0, O0, S0, g0, g0b, x1)`` of the last step (after the prior and the unused
        nodes were folded in), as the marginalisation of node 0 takes them."""
        return self._last
