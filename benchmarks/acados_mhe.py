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
the compile cache (:func:`crs_core.acados_support.solver_dir`, a folder named by the model,
sensors, horizon, rate and a hash of the problem); a later construction loads the library.
"""

from __future__ import annotations

import contextlib
import ctypes
import fcntl
import hashlib
import io
import time

import casadi as ca
import numpy as np

from crs_core.acados_support import acados_template, solver_dir
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


class CInterface:
    """acados's C interface to one solver, its argument types declared once.

    ``AcadosOcpSolver.set``/``get``/``cost_set``/``get_from_qp_in`` declare the argument
    types, check dimensions and copy on every call (about 30 us each here); an MHE update makes
    about 200 such calls, which took 6 ms beside a 0.8 ms ``solve()``. These are the same C
    functions called directly (1-2 us each), the way acados's Cython wrapper does in C.
    Arrays passed in must be C-contiguous float64.
    """

    def __init__(self, solver) -> None:
        lib, name = solver.shared_lib, solver.model_name
        pointer, integer = ctypes.c_void_p, ctypes.c_int
        self._handles = (solver.nlp_config, solver.nlp_dims)
        self._out, self._in, self._solver = solver.nlp_out, solver.nlp_in, solver.nlp_solver
        self._capsule = solver.capsule
        self._solve = getattr(lib, f"{name}_acados_solve")
        self._solve.argtypes, self._solve.restype = [pointer], integer
        self._params = getattr(lib, f"{name}_acados_update_params")
        self._params.argtypes = [pointer, integer, pointer, integer]
        self._params.restype = integer
        self._out_set, self._out_get = lib.ocp_nlp_out_set, lib.ocp_nlp_out_get
        self._cost_set, self._qp_get = lib.ocp_nlp_cost_model_set, lib.ocp_nlp_get_at_stage
        for function in (self._out_set, self._out_get, self._cost_set, self._qp_get):
            function.argtypes = [pointer, pointer, pointer, integer, ctypes.c_char_p, pointer]
            function.restype = None

    def solve(self) -> int:
        return self._solve(self._capsule)

    def set_parameters(self, values: np.ndarray) -> None:
        """Row ``k`` of ``values`` (C-contiguous float64) to stage ``k``, every stage."""
        address, size = values.ctypes.data, values.shape[1]
        for stage in range(values.shape[0]):
            if self._params(self._capsule, stage, address + 8 * size * stage, size) != 0:
                raise RuntimeError(f"acados refused the parameters of stage {stage}")

    def set_iterate(self, field: bytes, values: np.ndarray) -> None:
        """``field`` (``b"x"``, ``b"u"``) of the iterate at stage ``k`` from row ``k``."""
        address, size = values.ctypes.data, values.shape[1]
        for stage in range(values.shape[0]):
            self._out_set(*self._handles, self._out, stage, field, address + 8 * size * stage)

    def get_iterate(self, field: bytes, out: np.ndarray) -> None:
        """``field`` of the iterate at stage ``k`` into row ``k`` of ``out``."""
        address, size = out.ctypes.data, out.shape[1]
        for stage in range(out.shape[0]):
            self._out_get(*self._handles, self._out, stage, field, address + 8 * size * stage)

    def set_cost(self, field: bytes, stage: int, values: np.ndarray) -> None:
        """``W`` (symmetric, so its order does not matter) or ``yref`` of a stage."""
        self._cost_set(*self._handles, self._in, stage, field, values.ctypes.data)

    def get_qp(self, field: bytes, stage: int, shape: tuple[int, int]) -> np.ndarray:
        """A matrix of the last QP (``A``, ``Q``, ``q``, ...), column-major in acados."""
        out = np.zeros(shape[0] * shape[1])
        self._qp_get(*self._handles, self._solver, stage, field, out.ctypes.data)
        return out.reshape(shape, order="F")


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
    with HPIPM, full step) and reads the nodes back, all through :class:`CInterface`
    (``solve_times_s``: ``solve()`` alone; ``step_times_s``: the whole step with the
    marginalization). The node leaving the window is
    marginalized as in ours, from acados's own QP of the last solve (``A``, ``Q``, ``R``,
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
        self.solver, self.solver_folder, self.built = self._solver()
        self.interface = CInterface(self.solver)
        n_first = self.solver.acados_ocp.cost.W_0.shape[0]
        self._weight_first, self._reference_first = np.eye(n_first), np.zeros(n_first)
        nx = model.nx  # the controls are the process noise: nu = nx
        self._qp_shapes = tuple(
            (field.encode(), shape)
            for field, shape in (("A", (nx, nx)), ("Q", (nx, nx)), ("R", (nx, nx)),
                                 ("q", (nx, 1)), ("r", (nx, 1)), ("b", (nx, 1)))
        )  # fmt: skip

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
            (problem.serialize() + repr(sorted(options.items())) + str(N)).encode()
        ).hexdigest()[:10]
        sensors = "_".join(sorted(self.sensors))
        folder = solver_dir(
            f"mhe_{model.tag}_{model.n_base_stations}bs_{sensors}_N{N}_"
            f"{s.rate_hz:g}hz_{digest}".replace(".", "p")
        )
        name = f"crs_mhe_{digest}"

        ocp = template.AcadosOcp()
        ocp.model = template.AcadosModel()
        ocp.model.name = name
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
        ocp.code_export_directory = str(folder / "c_generated_code")
        json_file = str(folder / f"{name}.json")
        library = folder / "c_generated_code" / f"libacados_ocp_solver_{name}.so"
        quiet = io.StringIO()  # acados prints its build steps and notes
        with open(folder / "build.lock", "w") as lock, contextlib.redirect_stdout(quiet):
            fcntl.flock(lock, fcntl.LOCK_EX)  # one process generates, the others wait and reuse
            built = not library.exists()
            solver = template.AcadosOcpSolver(
                ocp, json_file=json_file, build=built, generate=built, verbose=False
            )
        if built and not library.exists():
            raise RuntimeError(f"acados did not build {library}:\n{quiet.getvalue()}")
        return solver, folder, built

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
        c = self.interface
        c.set_cost(b"W", 0, self._weight_first)
        c.set_cost(b"yref", 0, self._reference_first)
        X, W = np.ascontiguousarray(self._X.T), np.ascontiguousarray(self._W.T)
        c.set_parameters(P)
        c.set_iterate(b"x", X)
        c.set_iterate(b"u", W)
        start = time.perf_counter()
        status = c.solve()
        self._solve_time += time.perf_counter() - start
        c.get_iterate(b"x", X)
        c.get_iterate(b"u", W)
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
        nx, M = self.model.nx, self.settings.horizon
        get, shape = self.interface.get_qp, (nx, nx)
        covariance = np.linalg.inv(_symmetric_from_lower(get(b"Q", 0, shape)))
        for k in range(M):
            A = get(b"A", k, shape)
            noise = np.linalg.inv(_symmetric_from_lower(get(b"R", k, shape)))
            predicted = A @ covariance @ A.T + noise
            information = np.linalg.inv(predicted) + _symmetric_from_lower(get(b"Q", k + 1, shape))
            covariance = np.linalg.inv(information)
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
        A, Q, R, q, r, b = (
            self.interface.get_qp(field, 0, shape) for field, shape in self._qp_shapes
        )
        Q, R = _symmetric_from_lower(Q), _symmetric_from_lower(R)  # HPIPM keeps the lower half
        q, r, b = q.ravel(), r.ravel(), b.ravel()
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


__all__ = ["PIN_FACTOR", "AcadosMhe", "CInterface", "StepTimedMhe"]
