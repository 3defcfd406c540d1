r"""acados's MHE beside ours: the same least-squares problem, solved by SQP-RTI with HPIPM.

:class:`AcadosMhe` is the peer ``acados-mhe`` of :func:`benchmarks.estimation.peer_rows`. It
keeps everything of :class:`~crs_core.estimation.mhe.MovingHorizonEstimator` that defines the
problem (the grid, the attachment of measurements to nodes with their means, counts and mean
offsets, the stage inputs, the weights with the discount, the arrival prior, the outlier check,
the read-out) and replaces what solves it: instead of our Gauss-Newton step on the eliminated
nodes (banded Cholesky, backtracking), one real-time iteration of an acados OCP per new node.
Both are :class:`StepTimedMhe`, which times the solver's part of each update (the step and the
marginalization) apart from the bookkeeping they share.

The solver is generated from the model's CasADi expressions and compiled once per problem into
the compile cache (:func:`crs_core.acados_support.build_or_load`, a folder named by the model,
sensors, horizon, rate and a hash of the problem and its C helper); a later construction loads
the library.
"""

from __future__ import annotations

import ctypes
import hashlib
import time
from typing import Any

import casadi as ca
import numpy as np

from crs_core.acados_support import acados_template, build_or_load, solver_dir
from crs_core.estimation.base import sensor_group
from crs_core.estimation.mhe import MheSettings, MovingHorizonEstimator
from crs_core.estimation.mhe_problem import offset_output_functions
from crs_core.model import CarModel

#: Unused stages at start-up: their process noise is pinned to 0 by this many times the
#: nominal process weight (the square root of it; see :class:`AcadosMhe`).
PIN_FACTOR = 1e3


def _hinge(value: ca.SX, lower, upper) -> ca.SX:
    return ca.fmax(value - upper, 0) + ca.fmin(value - lower, 0)


def _symmetric_from_lower(matrix: np.ndarray) -> np.ndarray:
    lower = np.tril(matrix)
    return lower + np.tril(matrix, -1).T


#: A small C helper compiled beside the solver (:func:`~crs_core.acados_support.build_or_load`):
#: an update's data in one call each way instead of about 200 ``ctypes`` calls (acados's
#: ``AcadosOcpSolver.set``/``get`` took 6 ms per update beside a 0.8 ms ``solve()``).
_HELPER_SOURCE = r"""
#include "acados_c/ocp_nlp_interface.h"
#include "acados_solver_{name}.h"

static ocp_nlp_config *config(void *c) { return {name}_acados_get_nlp_config(c); }
static ocp_nlp_dims *dims(void *c) { return {name}_acados_get_nlp_dims(c); }

/* nodes X (N+1 x nx), noise W (N x nu), parameters P (N+1 x np), row-major; the first
   stage's weight matrix W0 (symmetric) and reference y0 */
int {name}_io_load(void *capsule, int N, int nx, int nu, int np,
                   double *X, double *W, double *P, double *W0, double *y0)
{
    ocp_nlp_config *cfg = config(capsule);
    ocp_nlp_dims *dim = dims(capsule);
    ocp_nlp_in *in = {name}_acados_get_nlp_in(capsule);
    ocp_nlp_out *out = {name}_acados_get_nlp_out(capsule);
    for (int k = 0; k <= N; k++) {
        ocp_nlp_out_set(cfg, dim, out, k, "x", X + k * nx);
        {name}_acados_update_params(capsule, k, P + k * np, np);
        if (k < N) ocp_nlp_out_set(cfg, dim, out, k, "u", W + k * nu);
    }
    ocp_nlp_cost_model_set(cfg, dim, in, 0, "W", W0);
    ocp_nlp_cost_model_set(cfg, dim, in, 0, "yref", y0);
    return 0;
}

int {name}_io_read(void *capsule, int N, int nx, int nu, double *X, double *W)
{
    ocp_nlp_config *cfg = config(capsule);
    ocp_nlp_dims *dim = dims(capsule);
    ocp_nlp_out *out = {name}_acados_get_nlp_out(capsule);
    for (int k = 0; k <= N; k++) {
        ocp_nlp_out_get(cfg, dim, out, k, "x", X + k * nx);
        if (k < N) ocp_nlp_out_get(cfg, dim, out, k, "u", W + k * nu);
    }
    return 0;
}

/* stage k's blocks of the last QP, column-major one after the other: A (nx x nx), Q (nx x
   nx, HPIPM fills the lower half), R (nu x nu, likewise), q, r, b; the last stage: Q, q */
int {name}_io_qp_stage(void *capsule, int N, int k, int nx, int nu, double *blocks)
{
    ocp_nlp_config *cfg = config(capsule);
    ocp_nlp_dims *dim = dims(capsule);
    ocp_nlp_solver *solver = {name}_acados_get_nlp_solver(capsule);
    double *A = blocks, *Q = A + nx * nx, *R = Q + nx * nx;
    double *q = R + nu * nu, *r = q + nx, *b = r + nu;
    ocp_nlp_get_at_stage(cfg, dim, solver, k, "Q", Q);
    ocp_nlp_get_at_stage(cfg, dim, solver, k, "q", q);
    if (k < N) {
        ocp_nlp_get_at_stage(cfg, dim, solver, k, "A", A);
        ocp_nlp_get_at_stage(cfg, dim, solver, k, "R", R);
        ocp_nlp_get_at_stage(cfg, dim, solver, k, "r", r);
        ocp_nlp_get_at_stage(cfg, dim, solver, k, "b", b);
    }
    return 0;
}
"""


class _Helper:
    """The C helper's functions and the solver's ``solve()``, bound once; arrays passed in are
    C-contiguous float64."""

    def __init__(self, solver: Any, library: ctypes.CDLL, name: str, nx: int, N: int) -> None:
        pointer, integer = ctypes.c_void_p, ctypes.c_int
        self._capsule, self.nx, self.N = pointer(solver.capsule), nx, N
        self._solve = getattr(solver.shared_lib, f"{name}_acados_solve")
        self._solve.argtypes, self._solve.restype = [pointer], integer
        self._load = getattr(library, f"{name}_io_load")
        self._load.argtypes = [pointer] + [integer] * 4 + [pointer] * 5
        self._read = getattr(library, f"{name}_io_read")
        self._read.argtypes = [pointer] + [integer] * 3 + [pointer] * 2
        self._stage = getattr(library, f"{name}_io_qp_stage")
        self._stage.argtypes = [pointer] + [integer] * 4 + [pointer]
        self._blocks = np.zeros(3 * nx * nx + 3 * nx)

    def solve(self) -> int:
        return self._solve(self._capsule)

    def load(self, X: np.ndarray, W: np.ndarray, P: np.ndarray, W0: np.ndarray, y0: np.ndarray):
        """Nodes (N+1, nx), noise (N, nx), parameters (N+1, np), the first stage's weight
        matrix and reference."""
        self._load(self._capsule, self.N, self.nx, self.nx, P.shape[1], X.ctypes.data,
                   W.ctypes.data, P.ctypes.data, W0.ctypes.data, y0.ctypes.data)  # fmt: skip

    def read(self, X: np.ndarray, W: np.ndarray) -> None:
        self._read(self._capsule, self.N, self.nx, self.nx, X.ctypes.data, W.ctypes.data)

    def qp_stage(self, k: int) -> tuple[np.ndarray, ...]:
        """``A, Q, R, q, r, b`` of stage ``k`` of the last QP (Q and R symmetric; the last
        stage: Q and q, the others zero)."""
        nx, blocks = self.nx, self._blocks
        blocks[:] = 0.0
        self._stage(self._capsule, self.N, k, nx, nx, blocks.ctypes.data)
        n2 = nx * nx
        A = blocks[:n2].reshape((nx, nx), order="F").copy()
        Q = _symmetric_from_lower(blocks[n2 : 2 * n2].reshape((nx, nx), order="F"))
        R = _symmetric_from_lower(blocks[2 * n2 : 3 * n2].reshape((nx, nx), order="F"))
        q, r, b = blocks[3 * n2 :].reshape(3, nx).copy()
        return A, Q, R, q, r, b


class StepTimedMhe(MovingHorizonEstimator):
    """Our MHE, timing per update the solver's part: its steps and marginalizations.

    ``step_times_s`` holds one entry per :meth:`estimate`. Subclasses replace the solver
    through :meth:`_solver_step` and :meth:`_marginalize`.
    """

    def __init__(self, *args, **kwargs) -> None:
        self.step_times_s: list[float] = []
        self._step_time = 0.0
        super().__init__(*args, **kwargs)

    def _estimate(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        self._step_time = 0.0
        result = super()._estimate(t)
        self.step_times_s.append(self._step_time)
        return result

    def _gauss_newton_step(self) -> None:
        begin = time.perf_counter()
        try:
            self._solver_step()
        finally:
            self._step_time += time.perf_counter() - begin

    def _marginalize_first_node(self) -> None:
        begin = time.perf_counter()
        try:
            self._marginalize()
        finally:
            self._step_time += time.perf_counter() - begin

    def _solver_step(self) -> None:
        super()._gauss_newton_step()

    def _marginalize(self) -> None:
        super()._marginalize_first_node()


class AcadosMhe(StepTimedMhe):
    r"""Our MHE's problem as an acados OCP, one SQP-RTI iteration (HPIPM) per new grid node.

    The OCP has ``N = horizon`` stages of the fixed length :math:`\Delta = 1/` ``rate_hz``;
    its states are the nodes :math:`x_0..x_N` and its controls the process noise :math:`w_k`
    (our MHE eliminates them), with the discrete dynamics
    :math:`x_{k+1} = F(x_k, \bar u_k, \Delta_k) + w_k`, :math:`F` the model's RK4 step
    (:meth:`~crs_core.model.CarModel.step_function`, the substeps of ours). Per-stage
    parameters carry the known input :math:`\bar u_k`, the stage length, the process weights,
    the node's mean measurements with their weights :math:`\sqrt{n\,\eta^{N-k}}/\sigma`, mean
    stamp offsets :math:`\tau` and commands, and the weights of the soft bounds; all of them
    come from our MHE's own bookkeeping (:meth:`MovingHorizonEstimator._weights`), so the data
    are ours to the bit. The cost is acados's ``NONLINEAR_LS`` with our residuals (sensor
    models through :func:`~crs_core.estimation.mhe_problem.offset_output_functions`, squared
    hinges for the bounds) and identity weights, except the first stage, whose weight matrix
    carries the arrival information and whose reference the arrival mean. Time steps are 1 in
    acados's eyes (it scales stage costs by them; the stage length is a parameter of the
    discrete step), so the cost is ours exactly (times acados's 1/2).

    Each update shifts the previous solution (ours' prediction for the new node, zero noise on
    the new stage), sets the parameters, runs ``solve()`` once (SQP-RTI: one Gauss-Newton QP
    with HPIPM, full step) and reads the nodes back, the data going through a C helper
    compiled beside the solver, one call each way (``solve_times_s``: ``solve()`` alone;
    ``step_times_s``: the whole step with the marginalization). The node leaving the window
    is marginalized as in ours, from acados's own QP of the last solve (``A``, ``Q``, ``R``,
    ``q``, ``r``, ``b`` of stage 0: the Schur complement onto node 1 with
    :math:`w_0 = \delta x_1 - A\,\delta x_0 - b`), floored, discounted.

    Where acados does not express ours exactly:

    - No step acceptance: RTI takes the full Gauss-Newton step, where ours backtracks until
      the cost falls (:data:`~crs_core.estimation.mhe.STEP_FRACTIONS`).
    - The noise :math:`w_k` is a variable of its own, warm-started from the shifted previous
      solution, so the linearization point can carry defects
      :math:`x_{k+1} - F(x_k) - w_k \ne 0` that ours (with :math:`w` eliminated) never has;
      the QP is the same up to them.
    - Start-up (fewer than ``N + 1`` nodes in use): ours freezes the unused nodes; here the
      unused stages have length 0 and their noise is pinned to 0 by :data:`PIN_FACTOR`
      times the nominal weight, so the unused nodes collapse onto the first one in use, which
      carries the arrival cost (exact to about 1e-7 relative).
    - A non-finite solution or an acados status other than 0 restarts the window (ours'
      ``_restart``); ours first drops the Lighthouse samples whose model output is undefined.
    - acados gives no covariance. The newest node's is computed from acados's QP (a forward
      pass over its stages, in Python) only when the read-out needs it, to carry the node
      over measurements past it; otherwise the covariance returned is the last one computed
      (at first ours' prior at the last restart). On the benchmark's grid queries that is
      when a sample's stamp rounds past the node's (22 of 1199 updates of a 20 s drive: the
      query grid and the node grid differ by a rounding error, and an IMU sample stamped at
      the query falls past the node); with a stale covariance there, those read-outs
      differed from ours by up to 0.09 rad/s.

    Measured on the standard drive (seed 0, 20 s, ``lh+imu+we``, 60 Hz, the standard wrong
    start): after the 2 s settling time its estimates agree with ours to 2e-8 (ours took the
    full step at every update but its first two); they differ in the first second (3 cm at
    the first update), where ours' backtracking and the start-up above act. Warm-starting
    with defect-free noise (:math:`w_k = x_{k+1} - F(x_k)`) changed none of the RMSE digits.

    Parameters
    ----------
    model, sensors
        Estimation model (its parameters fixed) and sensor groups, as for ours.
    settings : MheSettings, optional
        Ours (horizon, rate, discount, noise, bounds, arrival floor; ``iterations`` RTI
        iterations per node).
    hpipm_mode : str
        HPIPM's mode (``"BALANCE"``, acados's default; ``"SPEED"``, ``"ROBUST"``).
    """

    def __init__(
        self,
        model: CarModel,
        sensors: frozenset[str] | str,
        settings: MheSettings | None = None,
        hpipm_mode: str = "BALANCE",
    ) -> None:
        self._qp: tuple | None = None
        self._covariance_due = False  # the newest node's covariance is not computed yet
        self._W = np.zeros(0)
        super().__init__(model, sensors, settings)
        s = self.settings
        self._used = [g for g in self.groups if sensor_group(g) in self.sensors]
        self._rows = np.concatenate([np.r_[self._slot[g]] for g in self._used])
        self._used_index = np.array([self._group_index[g] for g in self._used], dtype=int)
        self._ug_rows = np.concatenate([[2 * g, 2 * g + 1] for g in self._used_index]).astype(int)
        self.hpipm_mode = hpipm_mode
        self._par = self._layout()
        self._W = np.zeros((model.nx, s.horizon))
        self._pin = PIN_FACTOR * np.sqrt(s.rate_hz) / self._q
        #: Per update: seconds in acados's ``solve()`` (``step_times_s`` adds setting the
        #: parameters and the iterate, reading it back, and the marginalization).
        self.solve_times_s: list[float] = []
        self._solve_time = 0.0
        self.solver, library, self.solver_folder, self.built = self._solver()
        self._helper = _Helper(self.solver, library, self.name, model.nx, s.horizon)
        n_first = self.solver.acados_ocp.cost.W_0.shape[0]
        self._weight_first, self._reference_first = np.eye(n_first), np.zeros(n_first)

    # --- the OCP ------------------------------------------------------------------------
    def _layout(self) -> dict[str, slice]:
        """Slices of the per-stage parameter vector."""
        nx, ny, ng = self.model.nx, len(self._rows), len(self._used)
        sizes = {"u": 2, "dt": 1, "wp": nx, "wbound": 1, "y": ny, "wy": ny, "tau": ng,
                 "ug": 2 * ng, "xbound": 1}  # fmt: skip
        offsets = np.cumsum([0, *sizes.values()])
        return {k: slice(int(offsets[i]), int(offsets[i + 1])) for i, k in enumerate(sizes)}

    def _expressions(self) -> tuple[ca.SX, ...]:
        """States, controls, parameters, discrete dynamics and the residuals of the first,
        the middle and the last stage."""
        model = self.model
        nx, layout = model.nx, self._par
        x, w = ca.SX.sym("x", nx), ca.SX.sym("w", nx)
        par = ca.SX.sym("p", layout["xbound"].stop)
        P = ca.DM(self._p)
        step = model.step_function(self._substeps, "acados_mhe_step")
        dynamics = step(x, par[layout["u"]], P, par[layout["dt"]]) + w
        bounds = self._bounds  # ours: |w| bounds, weight, state lower, upper, weight
        nb = nx - 3
        process_bound = ca.DM(bounds[:nx])
        lower = ca.DM(bounds[nx + 1 : nx + 1 + nb])
        upper = ca.DM(bounds[nx + 1 + nb : nx + 1 + 2 * nb])
        outputs = offset_output_functions(model, self._used)
        tau, ug = par[layout["tau"]], par[layout["ug"]]
        predicted = ca.vertcat(
            *[h(x, ug[2 * g : 2 * g + 2], P, tau[g]) for g, h in enumerate(outputs)]
        )
        r_node = ca.vertcat(
            par[layout["wy"]] * (par[layout["y"]] - predicted),
            par[layout["xbound"]] * _hinge(x[3:], lower, upper),
        )
        r_stage = ca.vertcat(
            par[layout["wp"]] * w,
            par[layout["wbound"]] * _hinge(w, -process_bound, process_bound),
            r_node,
        )
        return x, w, par, dynamics, ca.vertcat(x, r_stage), r_stage, r_node

    def _solver(self):
        """The acados solver, generated and compiled once per problem into
        :func:`~crs_core.acados_support.solver_dir` (reused when its library exists)."""
        template = acados_template()
        s, model = self.settings, self.model
        x, w, par, dynamics, r_first, r_stage, r_node = self._expressions()
        N = s.horizon
        options = {
            "qp_solver": "PARTIAL_CONDENSING_HPIPM",
            "hpipm_mode": self.hpipm_mode,
            "nlp_solver_type": "SQP_RTI",
            "hessian_approx": "GAUSS_NEWTON",
            "integrator_type": "DISCRETE",
            "qp_solver_cond_N": N,
            "tf": float(N),  # time steps of 1: acados scales the stage costs by them
            "print_level": 0,
        }
        problem = ca.Function("problem", [x, w, par], [dynamics, r_first, r_stage, r_node])
        digest = hashlib.sha1(
            (problem.serialize() + repr(sorted(options.items())) + _HELPER_SOURCE).encode()
        ).hexdigest()[:10]
        sensors = "_".join(sorted(self.sensors))
        self.name = (
            f"mhe_{model.tag}_{model.n_base_stations}bs_{sensors}_N{N}_"
            f"{s.rate_hz:g}hz_{digest}".replace(".", "p")
        )
        ocp = template.AcadosOcp()
        ocp.model = template.AcadosModel()
        ocp.model.x, ocp.model.u, ocp.model.p = x, w, par
        ocp.model.disc_dyn_expr = dynamics
        ocp.model.cost_y_expr_0 = r_first
        ocp.model.cost_y_expr = r_stage
        ocp.model.cost_y_expr_e = r_node
        ocp.dims.N = N
        for suffix, expression in (("_0", r_first), ("", r_stage), ("_e", r_node)):
            n = expression.numel()
            setattr(ocp.cost, f"cost_type{suffix}", "NONLINEAR_LS")
            setattr(ocp.cost, f"W{suffix}", np.eye(n))
            setattr(ocp.cost, f"yref{suffix}", np.zeros(n))
        ocp.parameter_values = np.zeros(par.numel())
        for key, value in options.items():
            setattr(ocp.solver_options, key, value)
        folder = solver_dir(self.name)
        library = folder / "c_generated_code" / f"libacados_ocp_solver_{self.name}.so"
        built = not library.exists()
        solver, helper = build_or_load(ocp, self.name, helper=_HELPER_SOURCE)
        return solver, helper, folder, built

    # --- our MHE's hooks ----------------------------------------------------------------
    def _restart_window(self, node: int, x: np.ndarray, weight: np.ndarray) -> None:
        super()._restart_window(node, x, weight)
        self._W = np.zeros((self.model.nx, self.settings.horizon))
        self._qp = None
        self._covariance_due = False

    def _shift(self) -> None:
        super()._shift()  # ours: marginalize (below), shift the nodes, predict the new one
        self._W[:, :-1] = self._W[:, 1:]
        self._W[:, -1] = 0.0

    def _estimate(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        self._solve_time = 0.0
        result = super()._estimate(t)
        self.solve_times_s.append(self._solve_time)
        return result

    def _solver_step(self) -> None:
        """One SQP-RTI iteration of acados on the current window (replaces ours)."""
        s, M, nx = self.settings, self.settings.horizon, self.model.nx
        stamp = float(self._times[-1])
        wp, y, wy, tau, ug = self._weights()
        first, information = self._arrival_terms()
        layout = self._par
        P = np.zeros((M + 1, layout["xbound"].stop))  # row k: the parameters of stage k
        P[:M, layout["u"]] = self._U.T
        P[first:M, layout["dt"]] = self._DT[0, first:, None]
        P[:M, layout["wp"]] = wp.T
        P[:first, layout["wp"]] = self._pin
        P[first:M, layout["wbound"]] = s.bound_weight
        P[:, layout["y"]] = y[self._rows].T
        P[:, layout["wy"]] = wy[self._rows].T
        P[:, layout["tau"]] = tau[self._used_index].T
        P[:, layout["ug"]] = ug[self._ug_rows].T
        P[first:, layout["xbound"]] = s.bound_weight
        self._weight_first[:nx, :nx] = information
        self._reference_first[:nx] = self._arrival
        helper = self._helper
        X, W = np.ascontiguousarray(self._X.T), np.ascontiguousarray(self._W.T)
        helper.load(X, W, P, self._weight_first, self._reference_first)
        start = time.perf_counter()
        status = helper.solve()
        self._solve_time += time.perf_counter() - start
        helper.read(X, W)
        if status != 0 or not (np.all(np.isfinite(X)) and np.all(np.isfinite(W))):
            self._qp = None
            self._restart(stamp, f"acados status {status}")
            return
        self._qp = (self._X[:, 1].copy(),)  # the QP of this solve holds stage 0 until the next
        self._X, self._W = X.T.copy(), W.T.copy()
        self._covariance_due = True

    def _read_out(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        """Ours, with the newest node's covariance computed from acados's QP when the read-out
        carries the node forward over measurements (it weighs them with it)."""
        if self._covariance_due and self._pending and self._pending[0][0] <= t:
            self._node_covariance = self._newest_covariance()
            self._covariance_due = False
        return super()._read_out(t)

    def _newest_covariance(self) -> np.ndarray:
        """The newest node's marginal covariance under the last QP: the inverse of its
        Hessian's Schur complement, by a forward (Kalman) pass over the stages, as ours takes
        it from its normal equations."""
        stage = self._helper.qp_stage
        A, Q, R, *_ = stage(0)
        covariance = np.linalg.inv(Q)
        for k in range(1, self.settings.horizon + 1):
            predicted = A @ covariance @ A.T + np.linalg.inv(R)
            A, Q, R, *_ = stage(k)
            covariance = np.linalg.inv(np.linalg.inv(predicted) + Q)
        return 0.5 * (covariance + covariance.T)

    def _marginalize(self) -> None:
        """Fold node 0 into a prior on node 1 from acados's QP of the last solve (see the
        class docstring), as ours does from its Gauss-Newton blocks."""
        if self._qp is None:  # no solve yet or it failed: keep the current prior
            self._arrival = self._X[:, 1].copy()
            return
        (x1_lin,) = self._qp
        self._qp = None
        nx = self.model.nx
        A, Q, R, q, r, b = self._helper.qp_stage(0)
        # the QP's dynamics dx1 = A dx0 + dw0 + b give dw0 = dx1 - A dx0 - b; no residual
        # couples x_0 and w_0 (S = 0). In (dx0, dx1) the Hessian is [[Q + A'RA, -A'R],
        # [-RA, R]] and the gradient [q - A'(r - Rb); r - Rb]; minimising over dx0 leaves
        # 1/2 dx1' L dx1 + beta' dx1 (ours: L = S0 - O0' D0^-1 O0, b = g1 - O0' D0^-1 g0)
        RA = R @ A
        g1 = r - R @ b
        solved = np.linalg.solve(Q + A.T @ RA, np.column_stack([RA.T, q - A.T @ g1]))
        information = R - RA @ solved[:, :-1]
        beta = g1 + RA @ solved[:, -1]
        information = 0.5 * (information + information.T)
        information += np.eye(nx) / self.settings.arrival_floor_std**2
        self._arrival = x1_lin - np.linalg.solve(information, beta)
        self._arrival_information = self.settings.discount * information


__all__ = ["PIN_FACTOR", "AcadosMhe", "StepTimedMhe"]
