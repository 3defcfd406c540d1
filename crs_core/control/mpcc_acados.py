r"""acados's real-time iteration of the MPCC's problem (``MpccSettings(solver="acados")``).

:class:`AcadosRti` states exactly the problem of :class:`~crs_core.control.mpcc_problem.
MpccProblem` as an acados OCP and makes one SQP iteration of it per :meth:`AcadosRti.iterate`
(acados's SQP-RTI, its QP solved by HPIPM), the job of ``Mpcc._solve_qp`` for the CasADi QP:

- stage state :math:`z` and input :math:`v` as in the problem; the dynamics are the problem's
  own CasADi function (the car model's RK4 step), as acados's discrete dynamics;
- the cost is the problem's :attr:`~MpccProblem.least_squares` (weighted squared residuals plus
  the linear progress reward and exact slack penalty) and its terminal one, acados's
  ``EXTERNAL`` cost with the Gauss-Newton Hessian :math:`2 J^\top Q J` as its custom Hessian,
  so the QP is the one our iteration builds;
- the track boundary :math:`|e_c| \le w/2 + \sigma` as two nonlinear (here affine) constraint
  rows on stages 1 to N-1, stage 0 fixed to :math:`z_0`;
- the input bounds set per call; per-stage parameters: the path's linearisation point
  ``[X, Y, heading, theta]``, the weights, the model parameters and the half width.

acados weighs each stage's cost by its time step; that scaling is set to 1 (the MPCC's costs
are per stage), and the QP acados builds is then ours: its Hessian, gradient and dynamics blocks
equal our linearisation's to rounding, and over 149 problems of a race its first command is
4e-6 (median; 1.5e-4 at most) from ours, the two HPIPMs stopping at their own tolerances.

The OCP is generated and compiled once per model structure (tag, base stations), horizon and
rate, and a hash of its expressions and options, into the compile cache
(:func:`~crs_core.acados_support.build_or_load`); a later construction loads the library.
Data go to and from the solver through a small C helper compiled beside it (one call per
iteration instead of a few hundred ``ctypes`` calls of acados's Python wrapper).
"""

from __future__ import annotations

import ctypes
import hashlib
import math
from typing import Any

import casadi as ca
import numpy as np

from crs_core.acados_support import acados_template, build_or_load
from crs_core.control.mpcc_problem import FREE, Iterate, MpccProblem

__all__ = ["QP_SOLVERS", "AcadosRti"]

#: acados QP solvers this module sets up (HPIPM on the stage structure, or condensed).
QP_SOLVERS = ("PARTIAL_CONDENSING_HPIPM", "FULL_CONDENSING_HPIPM")


#: acados's return codes.
STATUS = {
    0: "success",
    1: "nan detected",
    2: "maximum iterations",
    3: "minimum step",
    4: "qp failure",
}


class AcadosRti:
    """acados SQP-RTI (one Gauss-Newton iteration per call, HPIPM) of an :class:`MpccProblem`.

    Parameters
    ----------
    problem : MpccProblem
        The problem (model, horizon, rate, QP iteration limit).
    qp_solver : str
        One of :data:`QP_SOLVERS`.
    condensing_horizon : int, optional
        Partial condensing's horizon (default ``N``: none).
    hpipm_mode : str
        HPIPM's mode (``"SPEED_ABS"``, as our CasADi HPIPM; ``"SPEED"``, ``"BALANCE"``,
        ``"ROBUST"``).
    qp_mu0 : float
        HPIPM's initial barrier parameter. Measured on 149 problems of a race: 10 takes 8 QP
        iterations (median; as our HPIPM), acados's default 11, 0.1 takes 12; the first
        commands agree with ours to 4e-6 (median) either way.
    feasibility_tolerance : float, optional
        Largest violation of the input bounds and boundary rows of an accepted solution
        (default the problem's settings').
    """

    def __init__(
        self,
        problem: MpccProblem,
        qp_solver: str = "PARTIAL_CONDENSING_HPIPM",
        condensing_horizon: int | None = None,
        hpipm_mode: str = "SPEED_ABS",
        qp_mu0: float = 10.0,
        feasibility_tolerance: float | None = None,
    ) -> None:
        if qp_solver not in QP_SOLVERS:
            raise ValueError(f"qp_solver: one of {QP_SOLVERS}, got {qp_solver!r}")
        self.problem = problem
        self.N, self.nz, self.nv = problem.N, problem.nz, problem.nv
        settings = problem.settings
        self.tolerance = (
            settings.feasibility_tolerance
            if feasibility_tolerance is None
            else float(feasibility_tolerance)
        )
        template = acados_template()
        ocp, key = self._ocp(template, qp_solver, condensing_horizon, hpipm_mode)
        model = problem.model
        name = (
            f"mpcc_{_c_name(model.tag)}_{model.n_base_stations}bs_n{self.N}"
            f"_{round(1e6 / settings.rate_hz)}_{key}"
        )
        self.name = name
        self.solver, library = build_or_load(ocp, name, helper=_HELPER_SOURCE)
        assert library is not None
        self.library = library
        self._n_params = ocp.parameter_values.size
        # stage 0's boundary rows are free (z_0 is fixed; the CasADi QP has none there)
        self.solver.constraints_set(0, "lh", np.array([-FREE, -FREE]))
        self.solver.constraints_set(0, "uh", np.array([FREE, FREE]))
        self.solver.options_set("qp_mu0", float(qp_mu0))
        self._helper = _Helper(self.library, name, self.solver.capsule)
        self._helper.unit_scaling(self.N)
        self._bounds: tuple[np.ndarray, np.ndarray] | None = None
        self._params = np.zeros((self.N + 1, self._n_params))
        self._Z = np.zeros((self.N + 1, self.nz))
        self._V = np.zeros((self.N, self.nv))

    # --- the OCP ---------------------------------------------------------------------------
    def _ocp(self, template: Any, qp_solver: str, cond_n: int | None, hpipm_mode: str):
        problem, s = self.problem, self.problem.settings
        z, v, ref, w = problem.z_sym, problem.v_sym, problem.ref_sym, problem.w_sym
        p_model = problem.model.p_sym
        half = ca.SX.sym("half_width")
        params = ca.vertcat(ref, w, p_model, half)
        stage, terminal = problem.least_squares, problem.terminal_least_squares
        contour = problem.contouring_error(z, ref)

        model = template.AcadosModel()
        model.name = "mpcc"  # replaced by the cache name below
        model.x, model.u, model.p = z, v, params
        model.disc_dyn_expr = problem.dynamics(z, v, p_model)
        model.cost_expr_ext_cost = stage.cost
        model.cost_expr_ext_cost_custom_hess = stage.gauss_newton(ca.vertcat(v, z))[0]
        model.cost_expr_ext_cost_e = terminal.cost
        model.cost_expr_ext_cost_custom_hess_e = terminal.gauss_newton(z)[0]
        # e_c - slack <= half, e_c + slack >= -half
        model.con_h_expr = ca.vertcat(contour - v[3] - half, contour + v[3] + half)

        ocp = template.AcadosOcp()
        ocp.model = model
        ocp.dims.N = self.N
        ocp.parameter_values = np.zeros(params.numel())
        ocp.cost.cost_type = ocp.cost.cost_type_e = "EXTERNAL"
        constraints = ocp.constraints
        constraints.x0 = np.zeros(self.nz)
        constraints.idxbu = np.arange(self.nv)
        constraints.lbu = np.full(self.nv, -FREE)
        constraints.ubu = np.full(self.nv, FREE)
        constraints.lh = np.array([-FREE, 0.0])
        constraints.uh = np.array([0.0, FREE])
        options = ocp.solver_options
        options.tf = self.N * s.dt
        options.integrator_type = "DISCRETE"
        options.nlp_solver_type = "SQP_RTI"
        options.hessian_approx = "GAUSS_NEWTON"
        options.qp_solver = qp_solver
        options.qp_solver_iter_max = s.qp_max_iter
        options.hpipm_mode = hpipm_mode
        if cond_n is not None and qp_solver.startswith("PARTIAL"):
            options.qp_solver_cond_N = int(cond_n)
        options.print_level = 0
        # as the suite's own generated code (crs_core.codegen): -O1 built this OCP in 27 s where
        # -O2 took 45 s (a loaded 2-core machine), the solve as fast (1.9-2.6 ms each)
        options.ext_fun_compile_flags = "-O1"
        # the key: what the generated code is made of
        expressions = ca.Function(
            "key",
            [z, v, params],
            [
                model.disc_dyn_expr,
                model.cost_expr_ext_cost,
                model.cost_expr_ext_cost_custom_hess,
                model.cost_expr_ext_cost_e,
                model.cost_expr_ext_cost_custom_hess_e,
                model.con_h_expr,
            ],
        )
        digest = hashlib.sha256(expressions.serialize().encode())
        digest.update(
            repr(
                (
                    qp_solver,
                    cond_n,
                    hpipm_mode,
                    s.qp_max_iter,
                    self.N,
                    s.dt,
                    options.ext_fun_compile_flags,
                    _HELPER_SOURCE,
                )
            ).encode()
        )
        return ocp, digest.hexdigest()[:10]

    # --- one iteration ---------------------------------------------------------------------
    def load(
        self,
        Z: np.ndarray,
        V: np.ndarray,
        refs: np.ndarray,
        weights: np.ndarray,
        p: np.ndarray,
        v_lower: np.ndarray,
        v_upper: np.ndarray,
        half_width: float,
    ) -> None:
        """Give the solver the guess ``Z`` (N+1, nz), ``V`` (N, nv) (stage 0 fixed to
        ``Z[0]``), the path's linearisation points ``refs`` (N+1, 4), the weights, model
        parameters, input bounds and half width."""
        params = self._params
        params[:, :4] = refs
        n_w = weights.size
        params[:, 4 : 4 + n_w] = weights
        params[:, 4 + n_w : -1] = p
        params[:, -1] = half_width
        bounds = self._bounds
        if bounds is None or not (
            np.array_equal(bounds[0], v_lower) and np.array_equal(bounds[1], v_upper)
        ):
            self._bounds = (np.array(v_lower, dtype=float), np.array(v_upper, dtype=float))
            self._helper.set_bounds(self._bounds[0], self._bounds[1], self.N)
        self._helper.load(Z, V, params)

    def solve(self) -> int:
        """One SQP-RTI iteration from what :meth:`load` gave (acados's ``solve()``)."""
        return self.solver.solve()

    def qp_iterations(self) -> int:
        """HPIPM's iterations in the last :meth:`solve`."""
        return self._helper.qp_iterations()

    def plan(self) -> tuple[np.ndarray, np.ndarray]:
        """The last iteration's plan ``(Z, V)`` (copies)."""
        self._helper.read(self._Z, self._V)
        return self._Z.copy(), self._V.copy()

    def iterate(
        self,
        Z: np.ndarray,
        V: np.ndarray,
        refs: np.ndarray,
        weights: np.ndarray,
        p: np.ndarray,
        v_lower: np.ndarray,
        v_upper: np.ndarray,
        half_width: float,
    ) -> Iterate:
        """One SQP iteration from the guess: the new plan and whether it is usable (acados's
        status 0, finite, and within the input bounds and boundary rows to the tolerance)."""
        for name, value in (("Z", Z), ("V", V), ("refs", refs)):
            if not np.all(np.isfinite(value)):
                return Iterate(Z, V, False, math.inf, -1, f"non-finite data in {name}")
        self.load(Z, V, refs, weights, p, v_lower, v_upper, half_width)
        status = self.solve()
        plan_Z, plan_V = self.plan()
        iterations = self.qp_iterations()
        violation = self.violation(plan_Z, plan_V, refs, v_lower, v_upper, half_width)
        success = (
            status == 0
            and bool(np.all(np.isfinite(plan_Z)) and np.all(np.isfinite(plan_V)))
            and violation <= self.tolerance
        )
        return Iterate(
            plan_Z, plan_V, success, violation, iterations, STATUS.get(status, str(status))
        )

    def violation(
        self,
        Z: np.ndarray,
        V: np.ndarray,
        refs: np.ndarray,
        v_lower: np.ndarray,
        v_upper: np.ndarray,
        half_width: float,
    ) -> float:
        """Largest violation of the input bounds, the boundary rows (stages 1..N-1; affine in
        the state, so exact) and stage 0's fixed state of a plan. The dynamics rows HPIPM's
        Riccati recursion satisfies by construction."""
        sin_h, cos_h = np.sin(refs[1:-1, 2]), np.cos(refs[1:-1, 2])
        contour = sin_h * (Z[1:-1, 0] - refs[1:-1, 0]) - cos_h * (Z[1:-1, 1] - refs[1:-1, 1])
        slack = V[1:, 3]
        excess = (
            np.max(V - v_upper, initial=0.0),
            np.max(v_lower - V, initial=0.0),
            np.max(contour - slack - half_width, initial=0.0),
            np.max(-half_width - contour - slack, initial=0.0),
        )
        return float(max(excess))


def _c_name(name: str) -> str:
    return "".join(c if c.isalnum() else "_" for c in name)


# --- the C helper: the data of an iteration in one call each way ---------------------------
_HELPER_SOURCE = r"""
#include "acados_c/ocp_nlp_interface.h"
#include "acados_solver_{name}.h"

static ocp_nlp_config *config(void *c) { return {name}_acados_get_nlp_config(c); }
static ocp_nlp_dims *dims(void *c) { return {name}_acados_get_nlp_dims(c); }

int {name}_io_load(void *capsule, int N, int nx, int nu, int np,
                   double *Z, double *V, double *P)
{
    ocp_nlp_config *cfg = config(capsule);
    ocp_nlp_dims *dim = dims(capsule);
    ocp_nlp_in *in = {name}_acados_get_nlp_in(capsule);
    ocp_nlp_out *out = {name}_acados_get_nlp_out(capsule);
    for (int k = 0; k <= N; k++) {
        ocp_nlp_out_set(cfg, dim, out, k, "x", Z + k * nx);
        {name}_acados_update_params(capsule, k, P + k * np, np);
        if (k < N) ocp_nlp_out_set(cfg, dim, out, k, "u", V + k * nu);
    }
    ocp_nlp_constraints_model_set(cfg, dim, in, 0, "lbx", Z);
    ocp_nlp_constraints_model_set(cfg, dim, in, 0, "ubx", Z);
    return 0;
}

int {name}_io_unit_scaling(void *capsule, int N)
{
    /* acados weighs stage k's cost by its time step; the MPCC's costs are per stage */
    ocp_nlp_config *cfg = config(capsule);
    ocp_nlp_dims *dim = dims(capsule);
    ocp_nlp_in *in = {name}_acados_get_nlp_in(capsule);
    double one = 1.0;
    for (int k = 0; k < N; k++) ocp_nlp_cost_model_set(cfg, dim, in, k, "scaling", &one);
    return 0;
}

int {name}_io_bounds(void *capsule, int N, double *lower, double *upper)
{
    ocp_nlp_config *cfg = config(capsule);
    ocp_nlp_dims *dim = dims(capsule);
    ocp_nlp_in *in = {name}_acados_get_nlp_in(capsule);
    for (int k = 0; k < N; k++) {
        ocp_nlp_constraints_model_set(cfg, dim, in, k, "lbu", lower);
        ocp_nlp_constraints_model_set(cfg, dim, in, k, "ubu", upper);
    }
    return 0;
}

int {name}_io_read(void *capsule, int N, int nx, int nu, double *Z, double *V)
{
    ocp_nlp_config *cfg = config(capsule);
    ocp_nlp_dims *dim = dims(capsule);
    ocp_nlp_out *out = {name}_acados_get_nlp_out(capsule);
    for (int k = 0; k <= N; k++) {
        ocp_nlp_out_get(cfg, dim, out, k, "x", Z + k * nx);
        if (k < N) ocp_nlp_out_get(cfg, dim, out, k, "u", V + k * nu);
    }
    return 0;
}

int {name}_io_qp_iterations(void *capsule)
{
    /* the last row of acados's statistics (iteration, QP status, QP iterations), laid out as
       AcadosOcpSolver.get_stats("statistics") reads it */
    ocp_nlp_config *cfg = config(capsule);
    ocp_nlp_solver *solver = {name}_acados_get_nlp_solver(capsule);
    int sqp_iter = 0, stat_m = 0, stat_n = 0;
    ocp_nlp_get(cfg, solver, "sqp_iter", &sqp_iter);
    ocp_nlp_get(cfg, solver, "stat_m", &stat_m);
    ocp_nlp_get(cfg, solver, "stat_n", &stat_n);
    int columns = stat_m < sqp_iter + 1 ? stat_m : sqp_iter + 1;
    if (columns < 1 || stat_n < 2 || stat_n > 16 || stat_m > 64) return -1;
    double stat[17 * 64];
    ocp_nlp_get(cfg, solver, "statistics", stat);
    return (int) stat[2 * columns + columns - 1];
}
"""


class _Helper:
    """The C helper's functions, bound once."""

    def __init__(self, library: ctypes.CDLL, name: str, capsule: int) -> None:
        pointer, integer = ctypes.c_void_p, ctypes.c_int
        self._capsule = pointer(capsule)
        self._load = getattr(library, f"{name}_io_load")
        self._load.argtypes = [pointer, integer, integer, integer, integer] + [pointer] * 3
        self._bounds = getattr(library, f"{name}_io_bounds")
        self._bounds.argtypes = [pointer, integer, pointer, pointer]
        self._read = getattr(library, f"{name}_io_read")
        self._read.argtypes = [pointer, integer, integer, integer, pointer, pointer]
        scaling = getattr(library, f"{name}_io_unit_scaling")
        scaling.argtypes = [pointer, integer]
        self.unit_scaling = lambda N: scaling(self._capsule, N)
        self._iterations = getattr(library, f"{name}_io_qp_iterations")
        self._iterations.argtypes = [pointer]
        self._iterations.restype = integer

    def load(self, Z: np.ndarray, V: np.ndarray, P: np.ndarray) -> None:
        Z, V = np.ascontiguousarray(Z, dtype=float), np.ascontiguousarray(V, dtype=float)
        N, nz = Z.shape[0] - 1, Z.shape[1]
        self._load(
            self._capsule,
            N,
            nz,
            V.shape[1],
            P.shape[1],
            Z.ctypes.data,
            V.ctypes.data,
            P.ctypes.data,
        )

    def set_bounds(self, lower: np.ndarray, upper: np.ndarray, N: int) -> None:
        self._bounds(self._capsule, N, lower.ctypes.data, upper.ctypes.data)

    def read(self, Z: np.ndarray, V: np.ndarray) -> None:
        N, nz = Z.shape[0] - 1, Z.shape[1]
        self._read(self._capsule, N, nz, V.shape[1], Z.ctypes.data, V.ctypes.data)

    def qp_iterations(self) -> int:
        return int(self._iterations(self._capsule))
