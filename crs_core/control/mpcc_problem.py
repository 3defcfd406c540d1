r"""The MPCC's optimal control problem, from the one car model, and its sparse QP.

Model predictive contouring control (Liniger et al., the CRS paper's racing controller). The
stage variables are the state :math:`z = [x, \theta, \delta^-, T^-, v_\theta^-]` (the car's state
with any effect states, the progress :math:`\theta` along the reference path in m, and the
previous stage's inputs for the rate penalties) and the input
:math:`v = [\delta, T, v_\theta, \sigma]` (steering angle rad, normalised torque, progress speed
m/s, and the track-boundary slack m). The dynamics are the car model's RK4 step over
:math:`\Delta = 1/f` (substeps no longer than :data:`~crs_core.model.MAX_SUBSTEP`),
:math:`\theta^+ = \theta + \Delta v_\theta` and the input memory.

With the reference path linearised at the stage's progress guess :math:`\bar\theta_k`
(point :math:`\bar p_k`, tangent angle :math:`\bar\varphi_k`), the contouring and lag errors

.. math::

    e_c = \sin\bar\varphi\,(X - \bar X) - \cos\bar\varphi\,(Y - \bar Y), \qquad
    e_l = -\cos\bar\varphi\,(X - \bar X) - \sin\bar\varphi\,(Y - \bar Y) + (\theta - \bar\theta)

are affine in :math:`z` (:math:`e_c` is the signed distance to the right of the tangent line,
:math:`e_l` the progress estimate's error along it), and the stage cost

.. math::

    \ell = q_c e_c^2 + q_l e_l^2 - q_v \Delta v_\theta
        + \sum_i r_{\Delta,i} (v_i - v_i^-)^2 + r_\delta \delta^2 + r_T T^2
        + \rho_1 \sigma + \rho_2 \sigma^2

is quadratic. The track boundary :math:`|e_c| \le w/2 - m - \sigma`, :math:`\sigma \ge 0`, is
softened by an exact penalty (:math:`\rho_1` above the constraint's multipliers, so the soft
problem has the hard one's solution whenever that is feasible). One Gauss-Newton SQP iteration
(real-time iteration) linearises only the dynamics; the QP is in the variables
``[z_0, v_0, z_1, v_1, ..., z_N]`` in the block structure a Riccati-based solver exploits (HPIPM).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import casadi as ca
import numpy as np

from crs_core.codegen import SX_OPTIONS, external_functions
from crs_core.control.ocp_qp import QP_SOLVERS, SparseAssembly, qp_solver
from crs_core.errors import FieldError
from crs_core.model import MAX_SUBSTEP, CarModel
from crs_core.settings import Settings, finite, non_negative, positive

__all__ = [
    "EXTRA_STATES",
    "INPUTS",
    "QP_ARGUMENTS",
    "SOLVERS",
    "Iterate",
    "LeastSquares",
    "MpccProblem",
    "MpccSettings",
    "RtiFunctions",
    "SqpStep",
    "gauss_newton",
]

#: Stage states after the car's: progress and the previous stage's inputs.
EXTRA_STATES = ("theta", "steer_previous", "torque_previous", "progress_speed_previous")
#: Stage inputs.
INPUTS = ("steer", "torque", "progress_speed", "slack")
#: Bound standing for "free" (HPIPM takes finite bounds on every variable).
FREE = 1e4
#: Values of :attr:`MpccSettings.solver`: a CasADi QP plugin behind our own real-time
#: iteration, ``"acados"`` (its SQP-RTI with HPIPM, :mod:`~crs_core.control.mpcc_acados`), or
#: ``"native"`` (the iteration in one compiled call, :mod:`~crs_core.control.mpcc_native`).
SOLVERS = (*QP_SOLVERS, "acados", "native")


#: The integer fields of :class:`MpccSettings` (each >= 1).
_COUNTS = ("horizon", "max_failures", "qp_max_iter", "cold_start_iterations")


@dataclass
class MpccSettings(Settings):
    r"""Tuning of the MPCC; defaults race a Chronos car on the DEMO_TRACK.

    Attributes
    ----------
    horizon : int
        Number of stages ``N`` (the paper's 40).
    rate_hz : float
        Control rate, Hz; the stage length is ``1 / rate_hz`` s (the paper's 30 Hz).
    q_contour : float
        Weight of the squared contouring error, 1/m^2.
    q_lag : float
        Weight of the squared lag error, 1/m^2.
    q_progress : float
        Reward per m of progress.
    r_steer_rate, r_torque_rate, r_progress_rate : float
        Weights of the squared input changes from stage to stage (1/rad^2, -, s^2/m^2).
    r_steer, r_torque : float
        Weights of the squared inputs (regularisation), 1/rad^2 and -.
    slack_linear : float
        Exact-penalty weight of the boundary slack, 1/m.
    slack_quadratic : float
        Quadratic weight of the boundary slack, 1/m^2.
    terminal_scale : float
        The terminal stage's contouring and lag weights are this times the stage ones.
    q_sideslip : float
        Weight of the squared lateral velocity beyond the kinematic bicycle's,
        :math:`(v_y - v_x l_r \tan\delta / (l_f + l_r))^2`, s^2/m^2: keeps the plan out of a
        slide, where the linearised tires mislead the real-time iteration.
    track_margin : float
        Car-size margin kept from each track edge, m: the car's centre stays within
        ``width / 2 - track_margin`` of the centreline.
    steer_max : float
        Steering limit, rad.
    torque_min, torque_max : float
        Limits of the normalised torque (negative brakes).
    progress_speed_max : float
        Upper bound of the progress speed, m/s.
    max_failures : int
        Failed solves in a row served from the shifted plan before a safe stop.
    brake_gain : float
        Safe stop: torque ``-brake_gain * v_x`` (within the limits) until the car stands.
    solver : str
        ``"native"`` (default): the whole real-time iteration as one compiled C call, HPIPM's
        Riccati interior point on the stages (:mod:`~crs_core.control.mpcc_native`; needs
        ``./run.sh setup``'s acados for its HPIPM build, else it warns and runs as
        ``"hpipm"``). A CasADi QP plugin behind the iteration in CasADi (the reference):
        ``"hpipm"``, or for comparison ``"qrqp"``, ``"osqp"``, ``"qpoases"``. ``"acados"``:
        the same problem's real-time iteration by acados (SQP-RTI, HPIPM;
        :mod:`~crs_core.control.mpcc_acados`). Each compiled once into the compile cache.
    qp_max_iter : int
        Iteration limit of the QP solver.
    cold_start_iterations : int
        SQP iterations of a call without a plan to start from (first call, after a stop);
        every later call makes one (real-time iteration).
    feasibility_tolerance : float
        Largest constraint violation of a QP solution that is used (a solver stopped at its
        iteration limit with a feasible point counts: the next iteration continues from it).
    velocity_lead_s : float
        Velocity output: the reference is the plan's speed this far ahead, s (rounded to a
        stage, at least one), ahead of the car's velocity loop's lag.
    velocity_max : float
        Velocity output: the reference is clipped to ``[0, velocity_max]``, m/s.
    kinematic_speed : float
        Below this longitudinal speed (m/s) the plan starts from the kinematic bicycle's
        lateral velocity and yaw rate instead of the estimate's (0: never).
    solve_time_budget : float
        Wall time of a call, s, within which its SQP iterations must end: one that would end
        past it (judged by the previous one's time) is not started; the first always is.
        0: no limit (offline studies stay deterministic). A real-time loop sets one: ten
        cold-start iterations took 292 ms on a loaded machine, past the car's 200 ms cut-off.
    parameter_rate : float
        Online parameters (:meth:`~crs_core.control.mpcc.Mpcc.use_parameters`) move the
        prediction model's parameters by at most this share of their own model value per
        second, 1/s: an estimate that jumps does not jerk the plan.
    """

    horizon: int = 40
    rate_hz: float = positive(30.0)
    q_contour: float = non_negative(5.0)
    q_lag: float = positive(1000.0)
    q_progress: float = non_negative(10.0)
    r_steer_rate: float = non_negative(2.0)
    r_torque_rate: float = non_negative(0.5)
    r_progress_rate: float = non_negative(0.05)
    r_steer: float = non_negative(0.01)
    r_torque: float = non_negative(0.01)
    slack_linear: float = non_negative(500.0)
    slack_quadratic: float = positive(5000.0)
    terminal_scale: float = non_negative(2.0)
    q_sideslip: float = non_negative(10.0)
    track_margin: float = non_negative(0.06)
    steer_max: float = positive(0.34)
    torque_min: float = finite(-1.0)
    torque_max: float = non_negative(1.0)
    progress_speed_max: float = positive(4.0)
    max_failures: int = 5
    brake_gain: float = non_negative(1.0)
    solver: str = "native"
    qp_max_iter: int = 50
    cold_start_iterations: int = 10
    feasibility_tolerance: float = non_negative(1e-6)
    velocity_lead_s: float = non_negative(0.15)
    velocity_max: float = non_negative(5.0)
    kinematic_speed: float = non_negative(0.3)
    solve_time_budget: float = non_negative(0.0)
    parameter_rate: float = non_negative(0.05)

    def _check_relations(self) -> None:
        for name in _COUNTS:
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < 1:
                raise FieldError(name, f"must be a positive integer, got {value!r}")
        if self.steer_max >= 0.5 * math.pi:
            raise FieldError("steer_max", f"must be below pi/2 rad, got {self.steer_max!r}")
        if self.torque_min > 0 or not self.torque_min < self.torque_max:
            raise FieldError(
                "torque_max",
                f"must exceed torque_min ({self.torque_min!r}, itself <= 0), "
                f"got {self.torque_max!r}",
            )
        if self.solver not in SOLVERS:
            raise FieldError("solver", f"one of {', '.join(SOLVERS)}, got {self.solver!r}")

    @property
    def dt(self) -> float:
        """Stage length, s."""
        return 1.0 / self.rate_hz

    def weights(self) -> np.ndarray:
        """The weight vector the generated cost functions take (order of :data:`_WEIGHTS`)."""
        return np.array([getattr(self, name) for name in _WEIGHTS])


_WEIGHTS = (
    "q_contour",
    "q_lag",
    "q_progress",
    "r_steer_rate",
    "r_torque_rate",
    "r_progress_rate",
    "r_steer",
    "r_torque",
    "slack_linear",
    "slack_quadratic",
    "terminal_scale",
    "q_sideslip",
)


def gauss_newton(
    residuals: ca.SX, weights: ca.SX, linear: ca.SX | float, w: ca.SX
) -> tuple[ca.SX, ca.SX]:
    r"""Gauss-Newton model of :math:`\sum_i q_i r_i(w)^2 + l(w)` at :math:`\bar w`, as the
    Hessian and the gradient at zero of the quadratic in absolute variables:
    :math:`H = 2 J^\top Q J`, :math:`g = 2 J^\top Q (r - J \bar w) + \nabla l` (exact for
    affine residuals and linear :math:`l`)."""
    J = ca.jacobian(residuals, w)
    QJ = J * ca.repmat(weights, 1, w.numel())
    H = 2 * J.T @ QJ
    g = 2 * QJ.T @ (residuals - J @ w) + ca.gradient(linear, w)
    return H, g


#: Arguments of a CasADi QP solver, in the order :meth:`MpccProblem.real_time_iteration`'s
#: data function returns them.
QP_ARGUMENTS = ("h", "g", "a", "lba", "uba", "lbx", "ubx", "x0")


@dataclass(frozen=True)
class LeastSquares:
    r"""A cost :math:`\sum_i q_i r_i^2 + l` as weighted squared residuals plus linear terms,
    symbolic over :class:`MpccProblem`'s ``z_sym``, ``v_sym``, ``ref_sym``, ``w_sym`` and the
    model's ``p_sym`` (the form a Gauss-Newton Hessian :math:`2 J^\top Q J` comes from).

    Attributes
    ----------
    residuals : casadi.SX
        The residuals :math:`r`.
    weights : casadi.SX
        Their weights :math:`q` (functions of ``w_sym``).
    linear : casadi.SX
        The linear terms :math:`l` (0 for the terminal cost).
    """

    residuals: ca.SX
    weights: ca.SX
    linear: ca.SX

    @property
    def cost(self) -> ca.SX:
        """The cost expression."""
        return ca.sum1(self.weights * self.residuals**2) + self.linear

    def gauss_newton(self, w: ca.SX) -> tuple[ca.SX, ca.SX]:
        """Its Gauss-Newton Hessian and gradient at zero over the variables ``w``
        (:func:`gauss_newton`)."""
        return gauss_newton(self.residuals, self.weights, self.linear, w)


@dataclass(frozen=True)
class Iterate:
    """One SQP iteration's plan and how it went (every backend's answer).

    Attributes
    ----------
    Z, V : numpy.ndarray
        The plan: stage states (N+1, nz) and inputs (N, nv).
    success : bool
        Finite and within the feasibility tolerance of every constraint.
    violation : float
        Largest constraint violation of the QP's solution.
    iterations : int
        The QP solver's iterations (-1 unknown).
    status : str
        The solver's own word on the solve.
    """

    Z: np.ndarray
    V: np.ndarray
    success: bool
    violation: float
    iterations: int
    status: str


@dataclass(frozen=True)
class SqpStep:
    """One SQP iteration of a call: its guess, and the QP with the step check after it.

    Attributes
    ----------
    guess : tuple of numpy.ndarray
        The guess: stage states (N+1, nz), its inputs (N, nv) rolled out from the car's stage
        state.
    refs : numpy.ndarray
        The path at the guess's progress states (N+1, 4: X, Y, heading, theta).
    qp : Iterate
        How the QP went; its ``Z``, ``V`` the plan after the step check (the guess's when the
        QP is not usable).
    contour : float
        The contouring error of the car's stage state, m.
    """

    guess: tuple[np.ndarray, np.ndarray]
    refs: np.ndarray
    qp: Iterate
    contour: float


@dataclass(frozen=True)
class RtiFunctions:
    """The CasADi functions of one real-time iteration.

    Attributes
    ----------
    data : casadi.Function
        Guess, path linearisation, initial state, weights, parameters, input bounds, half
        width -> the QP's data (:data:`QP_ARGUMENTS`).
    solver : casadi.Function
        The QP solver (its ``stats()`` tell the iterations of the last solve).
    violation : casadi.Function
        ``(w, a, lba, uba, lbx, ubx) -> largest constraint violation`` of a QP solution.
    """

    data: ca.Function
    solver: ca.Function
    violation: ca.Function


class MpccProblem:
    """The MPCC's symbolic stage functions and their compiled, horizon-wide linearisation.

    Parameters
    ----------
    model : CarModel
        The car model (effects included) the controller predicts with.
    settings : MpccSettings
        Horizon, rate and limits (weights are inputs of the generated code, so they may change
        without recompiling).

    Attributes
    ----------
    nz, nv, N : int
        Stage state size, stage input size, horizon.
    """

    def __init__(self, model: CarModel, settings: MpccSettings) -> None:
        plant = model.plant
        like = [plant.car_state_like(n) for n in plant.state_names]
        if "vx" not in like:
            raise FieldError("model", f"the MPCC needs a state like vx in {plant.name}")
        #: Where the state like ``vx`` (the speed the MPCC bounds and brakes by) sits.
        self.speed_index = like.index("vx")
        #: Where the state like ``vy`` sits (None: the model cannot slide sideways).
        self.lateral_index = like.index("vy") if "vy" in like else None
        self.model = model
        self.settings = settings
        self.nx_car = model.nx
        self.nz = model.nx + len(EXTRA_STATES)
        self.nv = len(INPUTS)
        self.N = settings.horizon
        self._build_symbolic()

    # --- symbolic definition (used by the RTI and by the IPOPT peer alike) -----------------
    def _build_symbolic(self) -> None:
        nxc, s = self.nx_car, self.settings
        z = ca.SX.sym("z", self.nz)
        v = ca.SX.sym("v", self.nv)
        ref = ca.SX.sym("ref", 4)  # X, Y, heading, theta of the linearisation point
        w = ca.SX.sym("w", len(_WEIGHTS))
        p = self.model.p_sym
        W = dict(zip(_WEIGHTS, ca.vertsplit(w), strict=True))
        substeps = max(1, math.ceil(s.dt / MAX_SUBSTEP - 1e-9))
        car_step = self.model.step_function(substeps, "mpcc_rk4")
        z_next = ca.vertcat(
            car_step(z[:nxc], v[:2], p, s.dt), z[nxc] + s.dt * v[2], v[0], v[1], v[2]
        )
        sin_h, cos_h = ca.sin(ref[2]), ca.cos(ref[2])
        dx, dy = z[0] - ref[0], z[1] - ref[1]
        contour = sin_h * dx - cos_h * dy
        lag = -cos_h * dx - sin_h * dy + (z[nxc] - ref[3])
        previous = z[nxc + 1 : nxc + 4]
        # lateral velocity beyond the kinematic bicycle's: the car sliding (tires saturated);
        # a model without a lateral velocity cannot slide
        sideslip = ca.SX(0)
        if self.lateral_index is not None:
            names = list(self.model.parameters.names)
            lf, lr = p[names.index("lf")], p[names.index("lr")]
            vx, vy = z[self.speed_index], z[self.lateral_index]
            sideslip = vy - vx * lr * ca.tan(v[0]) / (lf + lr)
        # weighted squared residuals plus linear terms (progress reward, exact slack penalty)
        residuals = ca.vertcat(contour, lag, v[:3] - previous, v[0], v[1], v[3], sideslip)
        residual_weights = ca.vertcat(
            W["q_contour"],
            W["q_lag"],
            W["r_steer_rate"],
            W["r_torque_rate"],
            W["r_progress_rate"],
            W["r_steer"],
            W["r_torque"],
            W["slack_quadratic"],
            W["q_sideslip"],
        )
        linear = -W["q_progress"] * s.dt * v[2] + W["slack_linear"] * v[3]
        terminal_residuals = ca.vertcat(contour, lag)
        terminal_weights = W["terminal_scale"] * ca.vertcat(W["q_contour"], W["q_lag"])
        #: The stage cost as weighted squared residuals plus linear terms (the one definition
        #: the RTI's QP, the IPOPT peer and acados's OCP all take their cost from).
        self.least_squares = LeastSquares(residuals, residual_weights, linear)
        #: The terminal cost, likewise (no linear terms).
        self.terminal_least_squares = LeastSquares(terminal_residuals, terminal_weights, ca.SX(0))
        stage_cost = self.least_squares.cost
        terminal_cost = self.terminal_least_squares.cost
        self.z_sym, self.v_sym, self.ref_sym, self.w_sym = z, v, ref, w
        self.dynamics = ca.Function("mpcc_dynamics", [z, v, p], [z_next], SX_OPTIONS)
        self.contouring_error = ca.Function("mpcc_contour", [z, ref], [contour], SX_OPTIONS)
        self.stage_cost = ca.Function(
            "mpcc_stage_cost", [z, v, ref, w, p], [stage_cost], SX_OPTIONS
        )
        self.terminal_cost = ca.Function(
            "mpcc_terminal_cost", [z, ref, w], [terminal_cost], SX_OPTIONS
        )

    def stage_linearization(self) -> ca.Function:
        """Per stage at the guess ``(z, v)``: dynamics ``z+ = A z + B v + c``, the cost's
        Gauss-Newton Hessian and its gradient at zero over ``[z; v]``, and the contouring
        error's row ``e_c = C z + e0``."""
        z, v, ref, w, p = self.z_sym, self.v_sym, self.ref_sym, self.w_sym, self.model.p_sym
        zv = ca.vertcat(z, v)
        z_next = self.dynamics(z, v, p)
        A, B = ca.jacobian(z_next, z), ca.jacobian(z_next, v)
        H, g = self.least_squares.gauss_newton(zv)
        contour = self.contouring_error(z, ref)
        C = ca.jacobian(contour, z)
        # dense blocks: HPIPM's interface reads the stage structure from dense blocks
        outputs = [A, B, z_next - A @ z - B @ v, H, g, C, contour - C @ z]
        outputs = [ca.densify(o) for o in outputs]
        return ca.Function(
            "mpcc_stage",
            [z, v, ref, w, p],
            outputs,
            ["z", "v", "ref", "w", "p"],
            ["A", "B", "c", "H", "g", "C", "e0"],
            SX_OPTIONS,
        )

    def horizon_linearization(self) -> tuple[ca.Function, ca.Function]:
        """The linearisation of a whole horizon: ``mpcc_horizon(Z, V, REF, w, p)`` (the
        stage linearisation over the first N columns of the guess and path points, its
        outputs side by side per stage) and ``mpcc_terminal(z_N, ref_N, w)`` (the terminal
        cost's Hessian and gradient)."""
        stage = self.stage_linearization()
        return (
            stage.map("mpcc_horizon", "serial", self.N, [3, 4], []),
            self.terminal_linearization(),
        )

    def terminal_linearization(self) -> ca.Function:
        z, ref, w = self.z_sym, self.ref_sym, self.w_sym
        H, g = self.terminal_least_squares.gauss_newton(z)
        return ca.Function(
            "mpcc_terminal",
            [z, ref, w],
            [ca.densify(H), ca.densify(g)],
            ["z", "ref", "w"],
            ["H", "g"],
            SX_OPTIONS,
        )

    def merit(self) -> ca.Function:
        """The horizon's nonlinear cost ``merit(Z, V, REF, w, p, half_width)``: the stage costs
        (slack input ignored) and the terminal cost with the path at ``REF`` (4, N+1), plus the
        boundary's exact penalty ``slack_linear e + slack_quadratic e^2`` on each stage's
        excess ``e = max(|e_c| - half_width, 0)`` from stage 1 on (what the QP's slack
        measures, on the states themselves)."""
        N, nz, nv = self.N, self.nz, self.nv
        Z, V = ca.SX.sym("Z", nz, N + 1), ca.SX.sym("V", nv, N)
        REF, w = ca.SX.sym("REF", 4, N + 1), ca.SX.sym("w", len(_WEIGHTS))
        p, half = self.model.p_sym, ca.SX.sym("half_width")
        W = dict(zip(_WEIGHTS, ca.vertsplit(w), strict=True))
        no_slack = ca.vertcat(V[:3, :], ca.SX.zeros(1, N))
        stages = self.stage_cost.map(N)(Z[:, :N], no_slack, REF[:, :N], w, p)
        contours = self.contouring_error.map(N)(Z[:, 1:], REF[:, 1:])
        excess = ca.fmax(ca.fabs(contours) - half, 0)
        cost = (
            ca.sum2(stages)
            + self.terminal_cost(Z[:, N], REF[:, N], w)
            + W["slack_linear"] * ca.sum2(excess)
            + W["slack_quadratic"] * ca.sumsqr(excess)
        )
        return ca.Function(
            "mpcc_merit",
            [Z, V, REF, w, p, half],
            [cost],
            ["Z", "V", "REF", "w", "p", "half_width"],
            ["cost"],
            SX_OPTIONS,
        )

    # --- the real-time iteration's QP ------------------------------------------------------
    def real_time_iteration(self, solver: str | None = None) -> RtiFunctions:
        """The QP of one SQP iteration as CasADi functions (see :class:`RtiFunctions`).

        ``data(Z, V, REF, z0, w, p, lbv, ubv, half_width)`` linearises at the guess ``Z``
        (nz, N+1), ``V`` (nv, N) with the path linearised at ``REF`` (4, N+1: X, Y, heading,
        theta), stage 0 fixed to ``z0``, inputs within ``[lbv, ubv]`` and the boundary
        ``|e_c| <= half_width + slack``, and returns the QP's ``h, g, a, lba, uba, lbx, ubx,
        x0`` (the arguments of ``solver``, in that order) over ``[z_0, v_0, ..., z_N]``. The
        linearisation runs as compiled code inside the graph, and the data stay CasADi
        matrices between the calls (no conversion to numpy and back).
        """
        N, nz, nv = self.N, self.nz, self.nv
        nw = nz + nv
        compiled = external_functions(
            self.horizon_linearization(),
            f"mpcc_{self.model.tag}_{self.model.n_base_stations}bs_n{N}"
            f"_{round(1e6 / self.settings.rate_hz)}",
        )
        Z, V = ca.MX.sym("Z", nz, N + 1), ca.MX.sym("V", nv, N)
        REF, z0 = ca.MX.sym("REF", 4, N + 1), ca.MX.sym("z0", nz)
        w, p = ca.MX.sym("w", len(_WEIGHTS)), ca.MX.sym("p", self.model.np)
        lbv, ubv, half = ca.MX.sym("lbv", nv), ca.MX.sym("ubv", nv), ca.MX.sym("half_width")
        A, B, c, H, g, C, e0 = compiled["mpcc_horizon"](Z[:, :N], V, REF[:, :N], w, p)
        H_N, g_N = compiled["mpcc_terminal"](Z[:, N], REF[:, N], w)
        size = N * nw + nz

        hessian = SparseAssembly((size, size))
        hessian.add_matrix(H, lambda r, c: (c // nw) * nw + r, lambda r, c: c)
        hessian.add_matrix(H_N, lambda r, c: N * nw + r, lambda r, c: N * nw + c)

        # rows: stage k's dynamics gap (nz rows), then for k >= 1 its two boundary rows
        ng = [0] + [2] * (N - 1)
        gap_row = np.cumsum([0] + [nz + n for n in ng[:-1]])
        con_row = gap_row + nz
        n_rows = int(gap_row[-1] + nz + ng[-1])
        jac = SparseAssembly((n_rows, size))
        jac.add_matrix(A, lambda r, c: gap_row[c // nz] + r, lambda r, c: (c // nz) * nw + c % nz)
        jac.add_matrix(
            B, lambda r, c: gap_row[c // nv] + r, lambda r, c: (c // nv) * nw + nz + c % nv
        )
        stages, states = np.repeat(np.arange(N), nz), np.tile(np.arange(nz), N)
        jac.add(ca.DM(-np.ones(N * nz)), gap_row[stages] + states, (stages + 1) * nw + states)
        cc = np.asarray(C.sparsity().get_triplet()[1], dtype=int)
        later = np.flatnonzero(cc // nz >= 1)  # stage 0 has no boundary rows (z0 is fixed)
        k = cc[later] // nz
        for side in (0, 1):  # e_c - slack <= half, e_c + slack >= -half
            jac.add(C.nz[later.tolist()], con_row[k] + side, k * nw + cc[later] % nz)
        k = np.repeat(np.arange(1, N), nv)
        inputs = np.tile(np.arange(nv), N - 1)
        slack = np.tile([0.0, 0.0, 0.0, 1.0], N - 1)  # the input columns, dense (HPIPM)
        jac.add(ca.DM(-slack), con_row[k], k * nw + nz + inputs)
        jac.add(ca.DM(slack), con_row[k] + 1, k * nw + nz + inputs)
        a_matrix = jac.build()

        gap_rows = (gap_row[:, None] + np.arange(nz)).ravel()
        order = np.concatenate((gap_rows, con_row[1:], con_row[1:] + 1))
        inverse = np.empty(n_rows, dtype=int)
        inverse[order] = np.arange(n_rows)
        free = FREE * ca.DM.ones(N - 1)
        boundary_lower = -half - e0[1:].T
        boundary_upper = half - e0[1:].T
        lba = ca.vertcat(-ca.vec(c), -free, boundary_lower)[inverse.tolist()]
        uba = ca.vertcat(-ca.vec(c), boundary_upper, free)[inverse.tolist()]

        free_z = FREE * ca.DM.ones(nz)
        lbw = ca.vertcat(z0, ca.repmat(ca.vertcat(lbv, -free_z), N - 1, 1), lbv, -free_z)
        ubw = ca.vertcat(z0, ca.repmat(ca.vertcat(ubv, free_z), N - 1, 1), ubv, free_z)
        guess = ca.vertcat(ca.vec(ca.vertcat(Z[:, :N], V)), Z[:, N])
        gradient = ca.vertcat(ca.vec(g), g_N)

        h_matrix = hessian.build()
        qp = qp_solver(
            "mpcc_qp",
            solver or self.settings.solver,
            h_matrix.sparsity(),
            a_matrix.sparsity(),
            N,
            nz,
            nv,
            ng,
            self.settings.qp_max_iter,
        )
        w_opt = ca.MX.sym("w_opt", size)
        a_sym = ca.MX.sym("a", a_matrix.sparsity())
        lower_a, upper_a = ca.MX.sym("lba", n_rows), ca.MX.sym("uba", n_rows)
        lower_w, upper_w = ca.MX.sym("lbx", size), ca.MX.sym("ubx", size)
        rows = a_sym @ w_opt
        excess = ca.vertcat(rows - upper_a, lower_a - rows, w_opt - upper_w, lower_w - w_opt, 0)
        violation = ca.Function(
            "mpcc_violation", [w_opt, a_sym, lower_a, upper_a, lower_w, upper_w], [ca.mmax(excess)]
        )
        data = ca.Function(
            "mpcc_qp_data",
            [Z, V, REF, z0, w, p, lbv, ubv, half],
            [h_matrix, gradient, a_matrix, lba, uba, lbw, ubw, guess],
            ["Z", "V", "REF", "z0", "w", "p", "lbv", "ubv", "half_width"],
            list(QP_ARGUMENTS),
        )
        return RtiFunctions(data, qp, violation)
