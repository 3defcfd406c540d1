r"""The full-information estimation (FIE) problem of system identification (paper, Sec. IV-B).

Decision variables: the fitted parameters :math:`\theta` (a chosen subset of the model's
parameters; the rest stay fixed) and the state trajectory :math:`x_0 \dots x_{L-1}` on the
dataset's own sample stamps (multiple shooting). The process noise is eliminated:
:math:`w_k = x_{k+1} - F(x_k, u_k, \theta, \Delta t_k)` with ``F`` the model's RK4 step over the
(non-uniform) sample interval, substeps no longer than
:data:`~crs_core.model.car_model.MAX_SUBSTEP`. The cost is the paper's

.. math:: V = \|\theta - \bar\theta_0\|^2_{P_\theta} + \|x_0 - \bar x_0\|^2_{P_x}
          + \sum_k \|w_k\|^2_{Q_k} + \sum_k \|y_k - h(x_k, u_k, \theta)\|^2_{R}

with inverse covariances as weights: :math:`P_\theta^{-1}` from each parameter's
``prior_std`` (a parameter without one gets :data:`DEFAULT_RELATIVE_PRIOR` of its value),
:math:`P_x^{-1}` from :data:`X0_STD`, :math:`Q_k^{-1}` from the estimator's continuous process
noise (``EstimatorNoise.process_std`` times :attr:`FieSettings.process_scale`, variance
``std^2 dt_k``) and :math:`R^{-1}` from the estimator's sensor noise. NaN measurements drop out
(weight 0). Everything is a residual vector ``r(z)``; the NLP minimises ``0.5 r'r`` (half of
``V``) over ``z = [theta_scaled, x_0, ..., x_{L-1}]`` with bounds only:
``theta = theta_bar + prior_std * theta_scaled`` within the parameter bounds, and
:data:`STATE_BOUNDS` on the states (the paper's :math:`\mathbb X_{ID}`).

The model is the one :class:`~crs_core.model.CarModel` definition: its ``step_function`` and
output expressions, mapped over the horizon with ``casadi.Function.map``.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import casadi as ca
import numpy as np

from crs_core.errors import FieldError
from crs_core.estimation.noise import EstimatorNoise, per_plant_state
from crs_core.identification.data import Y_LAYOUT, FieData
from crs_core.identification.jacobian import DefectBlock, MeasurementBlock, residual_jacobian
from crs_core.model import CarModel
from crs_core.model.bicycle import DynamicBicycle
from crs_core.model.car_model import MAX_SUBSTEP
from crs_core.settings import Settings, positive

#: The default ``crs sysid --fit`` of the dynamic bicycle
#: (:attr:`~crs_core.model.bicycle.DynamicBicycle.default_fit`).
DEFAULT_FIT = DynamicBicycle.default_fit
#: The paper's 15 dynamics parameters (the default without the wheel encoders' geometry).
DYNAMICS_FIT = tuple(name for name in DEFAULT_FIT if name not in ("r", "b_car"))
#: Prior standard deviation, relative to the value, of a fitted parameter whose
#: ``prior_std`` is 0 (or of a parameter at 0: a quarter of its bound range).
DEFAULT_RELATIVE_PRIOR = 0.5
#: Standard deviation of the prior on the first state ``[x, y, yaw, vx, vy, omega]`` around the
#: estimator's value at the first sample (m, m, rad, m/s, m/s, rad/s).
X0_STD = (0.05, 0.05, 0.1, 0.5, 0.5, 1.0)
#: :math:`\mathbb X_{ID}`: bounds on the plant's states by the car state they are like (the
#: rest unbounded).
STATE_BOUNDS = {"vx": (-5.0, 5.0), "vy": (-5.0, 5.0), "omega": (-15.0, 15.0)}
#: Substep counts used (the smallest one with substeps <= MAX_SUBSTEP is picked per interval):
#: few distinct counts keep the number of mapped functions small.
SUBSTEP_LADDER = (1, 2, 3, 4, 5, 6, 8, 10, 12, 16, 20, 25, 32, 40, 50, 64, 80, 100, 128)


@dataclass(frozen=True)
class FieSettings(Settings):
    """Tuning of the FIE problem and its solver.

    Attributes
    ----------
    fit : tuple of str
        Parameter names to identify (default :data:`DYNAMICS_FIT`).
    hessian : {"gauss-newton", "exact"}
        IPOPT's Hessian: the Gauss-Newton matrix ``J'J`` of the residuals (custom ``hess_lag``)
        or the exact Hessian of the Lagrangian.
    noise : EstimatorNoise
        Measurement and process noise (the estimators' defaults).
    process_scale : float
        Factor on the estimator's process noise standard deviation for :math:`Q`. 1.0 (the
        EKF's tuning) predicted best on the real runs (2 s open-loop RMSE 0.188 m, against
        0.203 m with 0.3 and 0.259 m with 0.03); on simulated data, whose truth has no process
        noise, 0.1 is used.
    max_iter : int
        IPOPT iteration limit.
    tol : float
        Relative change of the cost below which (three iterations in a row) IPOPT stops
        (``acceptable_obj_change_tol``); also its ``tol``.
    starts : int
        Number of starts: the first from the prior, the others from parameters drawn from the
        prior (seeded), each initialised by an estimator run; the lowest cost wins.
    seed : int
        Seed of the multi-start draws.
    """

    fit: tuple[str, ...] = DYNAMICS_FIT
    hessian: str = "gauss-newton"
    noise: EstimatorNoise = field(default_factory=EstimatorNoise)
    process_scale: float = positive(1.0)
    max_iter: int = 200
    tol: float = 1e-6
    starts: int = 1
    seed: int = 0

    def _check_relations(self) -> None:
        if self.hessian not in ("gauss-newton", "exact"):
            raise FieldError("hessian", f"must be 'exact' or 'gauss-newton', got {self.hessian!r}")
        if not self.fit:
            raise FieldError("fit", "name at least one parameter")
        if len(set(self.fit)) != len(self.fit):
            raise FieldError("fit", f"a parameter is named twice in {', '.join(self.fit)}")
        for name in ("max_iter", "starts"):
            if getattr(self, name) < 1:
                raise FieldError(name, f"must be >= 1, got {getattr(self, name)!r}")


def prior_std(model: CarModel, name: str) -> float:
    """The prior standard deviation of a fitted parameter (see :data:`DEFAULT_RELATIVE_PRIOR`)."""
    parameter = model.parameters[name]
    if parameter.prior_std > 0:
        return parameter.prior_std
    if parameter.value != 0:
        return DEFAULT_RELATIVE_PRIOR * abs(parameter.value)
    return max((parameter.upper - parameter.lower) / 4, 1e-6)


def default_fit(model: CarModel) -> tuple[str, ...]:
    """What ``crs sysid`` fits by default: the plant's
    :attr:`~crs_core.model.plant.Plant.default_fit` (every plant parameter with a prior std > 0
    when it names none), then every effect parameter."""
    plant = model.plant.default_fit or tuple(
        p.name for p in model.plant.parameters().values() if p.prior_std > 0
    )
    return plant + tuple(p.name for e in model.effects for p in e.parameters)


def check_fit(model: CarModel, fit: Sequence[str]) -> None:
    """``ValueError`` for a fitted name the model lacks or whose bounds exclude the prior."""
    for name in fit:
        if name not in model.parameters:
            raise FieldError(
                "fit", f"unknown parameter {name!r} (the model has {', '.join(model.parameters)})"
            )
        if name == "input_delay":
            raise FieldError(
                "fit",
                "'input_delay' is a transport delay without a state-space form in the "
                "model; the FIE cannot fit it (fit steering_lag / motor_lag instead)",
            )
        p = model.parameters[name]
        if not p.lower < p.upper:
            raise FieldError("fit", f"parameter {name!r} has empty bounds [{p.lower}, {p.upper}]")


def substeps_for(dt: float) -> int:
    """Smallest :data:`SUBSTEP_LADDER` entry with ``dt / n <= MAX_SUBSTEP``."""
    need = max(1, math.ceil(dt / MAX_SUBSTEP - 1e-9))
    for n in SUBSTEP_LADDER:
        if n >= need:
            return n
    return need


def _segment_step(model: CarModel, segments: int, substeps: int) -> ca.Function:
    """``(x, u_segments (2 m), p, dt_segments (m)) -> x_next``: the model's RK4 step over
    ``m`` consecutive held commands, ``substeps`` RK4 substeps each."""
    step = model.step_function(substeps, f"rk4_{substeps}")
    u = ca.SX.sym("u", 2 * segments)
    dt = ca.SX.sym("dt", segments)
    x = model.x_sym
    for j in range(segments):
        x = step(x, u[2 * j : 2 * j + 2], model.p_sym, dt[j])
    return ca.Function(
        f"fie_step_{segments}x{substeps}", [model.x_sym, u, model.p_sym, dt], [x], {"cse": True}
    )


class FieProblem:
    """The FIE as a CasADi residual function and an IPOPT solver.

    Parameters
    ----------
    model : CarModel
        The model whose parameter values are the prior :math:`\\bar\\theta_0`.
    data : FieData
    settings : FieSettings
    x0_prior : array
        :math:`\\bar x_0`, the estimator's state at the first sample (model state size).
    """

    def __init__(
        self, model: CarModel, data: FieData, settings: FieSettings, x0_prior: np.ndarray
    ) -> None:
        check_fit(model, settings.fit)
        self.model, self.data, self.settings = model, data, settings
        self.fit = tuple(settings.fit)
        self.n_theta = len(self.fit)
        self.nx = model.nx
        self.n = len(data.t)
        self.theta_prior = np.array([model.parameters.value(n) for n in self.fit])
        self.theta_std = np.array([prior_std(model, n) for n in self.fit])
        self.x0_prior = np.asarray(x0_prior, dtype=float)
        self._build()

    # --- layout ------------------------------------------------------------------------
    @property
    def nz(self) -> int:
        return self.n_theta + self.nx * self.n

    def pack(self, theta: np.ndarray, states: np.ndarray) -> np.ndarray:
        """``z`` from parameter values ``(n_theta,)`` and states ``(N, nx)``."""
        scaled = (np.asarray(theta) - self.theta_prior) / self.theta_std
        return np.concatenate([scaled, np.asarray(states, dtype=float).ravel()])

    def unpack(self, z: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Parameter values and states ``(N, nx)`` from ``z``."""
        z = np.asarray(z, dtype=float).ravel()
        theta = self.theta_prior + self.theta_std * z[: self.n_theta]
        lower, upper = (
            np.array([getattr(self.model.parameters[n], side) for n in self.fit])
            for side in ("lower", "upper")
        )
        theta = np.clip(theta, lower, upper)  # IPOPT may leave a bound by its tolerance
        return theta, z[self.n_theta :].reshape(self.n, self.nx)

    def full_parameters(self, theta: np.ndarray) -> np.ndarray:
        """The model's parameter vector with the fitted entries replaced."""
        p = self.model.parameters.vector().copy()
        for name, value in zip(self.fit, theta, strict=True):
            p[self.model.parameters.index(name)] = value
        return p

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """Lower and upper bounds on ``z``."""
        lo = [(self.model.parameters[n].lower - v) / s for n, v, s in self._theta_rows()]
        hi = [(self.model.parameters[n].upper - v) / s for n, v, s in self._theta_rows()]
        x_lo, x_hi = np.full(self.nx, -np.inf), np.full(self.nx, np.inf)
        for i, name in enumerate(self.model.plant.state_names):
            similar = self.model.plant.car_state_like(name)
            if similar in STATE_BOUNDS:
                x_lo[i], x_hi[i] = STATE_BOUNDS[similar]
        return (
            np.concatenate([lo, np.tile(x_lo, self.n)]),
            np.concatenate([hi, np.tile(x_hi, self.n)]),
        )

    def _theta_rows(self):
        return zip(self.fit, self.theta_prior, self.theta_std, strict=True)

    # --- symbolic ----------------------------------------------------------------------
    def _build(self) -> None:
        model, data, s = self.model, self.data, self.settings
        n, nx = self.n, self.nx
        z = ca.MX.sym("z", self.nz)
        theta = self.theta_prior + self.theta_std * z[: self.n_theta]
        X = ca.reshape(z[self.n_theta :], nx, n)
        fixed = self.model.parameters.vector()
        select = np.zeros((model.np, self.n_theta))
        for j, name in enumerate(self.fit):
            fixed[model.parameters.index(name)] = 0.0
            select[model.parameters.index(name), j] = 1.0
        p = ca.DM(fixed) + ca.mtimes(ca.DM(select), theta)
        U = ca.DM(data.u.T)
        dt = np.diff(data.t)

        # dynamics defects, one mapped RK4 step per substep count, weighted by Q_k^{-1/2}
        q_std = s.noise.process_std_for(model) * s.process_scale
        keys = [
            (int(c), substeps_for(float(np.max(d))))
            for c, d in zip(data.segment_count, data.segment_dt, strict=True)
        ]
        defects, defect_blocks, row = [], [], self.n_theta + nx
        for key in sorted(set(keys)):
            index = [k for k, other in enumerate(keys) if other == key]
            step = _segment_step(model, *key)
            m = key[0]
            u_seg = ca.DM(data.segment_u[index, :m, :].reshape(len(index), 2 * m).T)
            dt_seg = ca.DM(data.segment_dt[index, :m].T)
            x_next = step.map(len(index), "serial")(
                X[:, index], u_seg, ca.repmat(p, 1, len(index)), dt_seg
            )
            after = [k + 1 for k in index]
            weight = 1.0 / (q_std[:, None] * np.sqrt(dt[index])[None, :])
            defects.append(ca.vec((X[:, after] - x_next) * ca.DM(weight)))
            defect_blocks.append(DefectBlock(step, np.array(index), u_seg, dt_seg, weight, row))
            row += weight.size
        # measurements
        outputs = ca.vertcat(*(model.output_expressions[name] for name, _ in Y_LAYOUT))
        h = ca.Function("h_fie", [model.x_sym, model.u_sym, model.p_sym], [outputs])
        Y = h.map(n, "serial")(X, U, ca.repmat(p, 1, n))
        alpha = data.plane1_alpha
        plane1_rows = Y_LAYOUT[0][1].stop
        h1 = None
        if np.any(alpha > 0):  # plane-1 angles at the (interpolated) state of their sweep
            X_prev = ca.horzcat(X[:, 0], X[:, : n - 1])
            a = ca.DM(np.tile(alpha, (nx, 1)))
            X1 = X * (1.0 - a) + X_prev * a
            h1 = ca.Function(
                "h1_fie",
                [model.x_sym, model.u_sym, model.p_sym],
                [model.output_expressions[Y_LAYOUT[0][0]]],
            )
            Y1 = h1.map(n, "serial")(X1, U, ca.repmat(p, 1, n))
            Y = ca.vertcat(Y1, Y[plane1_rows:, :])
        measured = (Y - ca.DM(data.y.T)) * ca.DM(data.weight.T)
        # priors: theta (already scaled by its std) and the first state
        n_plant = len(model.plant.states)
        x0_std = np.concatenate(  # effect states: rad / -
            [per_plant_state(X0_STD, model, "X0_STD"), np.full(nx - n_plant, 0.05)]
        )
        prior_x0 = (X[:, 0] - ca.DM(self.x0_prior)) / ca.DM(x0_std)
        self.blocks = {
            "theta_prior": self.n_theta,
            "x0_prior": nx,
            "process": sum(int(d.numel()) for d in defects),
            "measurement": int(measured.numel()),
        }
        residual = ca.vertcat(z[: self.n_theta], prior_x0, *defects, ca.vec(measured))
        self.z_sym = z
        self.residual = residual
        self.residual_function = ca.Function("fie_residual", [z], [residual])
        self.jacobian = residual_jacobian(
            z,
            X,
            p,
            self.n_theta,
            select * self.theta_std[None, :],
            1.0 / x0_std,
            defect_blocks,
            MeasurementBlock(h, h1, plane1_rows, alpha, U, data.weight, row),
            int(residual.numel()),
        )
        self.output_function = ca.Function("fie_outputs", [z], [Y])

    def jacobian_function(self) -> ca.Function:
        """``z -> dr/dz`` (sparse; :func:`~crs_core.identification.jacobian.residual_jacobian`)."""
        return ca.Function("fie_jacobian", [self.z_sym], [self.jacobian])

    def solver(self, callback: ca.Callback | None = None) -> ca.Function:
        """IPOPT on ``min 0.5 r'r`` with the chosen Hessian."""
        z, r = self.z_sym, self.residual
        f = 0.5 * ca.dot(r, r)
        options: dict[str, Any] = {  # CasADi option values: bool, number, text, Function
            "print_time": False,
            "ipopt.print_level": 0,
            "ipopt.sb": "yes",
            "ipopt.max_iter": self.settings.max_iter,
            "ipopt.tol": self.settings.tol,
            "ipopt.mu_strategy": "adaptive",
            # a large-residual least-squares problem: stop once the cost has settled
            "ipopt.acceptable_tol": 1e3,
            "ipopt.acceptable_obj_change_tol": self.settings.tol,
            "ipopt.acceptable_iter": 3,
        }
        if self.settings.hessian == "gauss-newton":
            jac = self.jacobian
            lam_f = ca.MX.sym("lam_f")
            hess = lam_f * ca.triu(ca.mtimes(jac.T, jac))
            options["hess_lag"] = ca.Function(
                "fie_gn_hessian",
                [z, ca.MX.sym("p", 0), lam_f, ca.MX.sym("lam_g", 0)],
                [hess],
                ["x", "p", "lam_f", "lam_g"],
                ["hess_gamma_x_x"],
            )
        if callback is not None:
            options["iteration_callback"] = callback
        return ca.nlpsol("fie", "ipopt", {"x": z, "f": f}, options)
