"""Solve the FIE: initial guess from an estimator run, IPOPT, multi-start, the result.

:func:`identify` is the entry point (``crs sysid``): it runs the EKF over the dataset with the
prior parameters (the paper's advice for initialising the state trajectory), solves the FIE
(:mod:`~crs_core.identification.problem`) with IPOPT, and adds the parameter covariance
(:mod:`~crs_core.identification.uncertainty`).
"""

from __future__ import annotations

import sys
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import casadi as ca
import numpy as np

from crs_core.dataset import Dataset
from crs_core.errors import FieldError
from crs_core.estimation.offline import estimate_dataset
from crs_core.identification.data import FieData, input_segments
from crs_core.identification.problem import FieProblem, FieSettings, check_fit
from crs_core.identification.uncertainty import ParameterUncertainty, parameter_uncertainty
from crs_core.model import CarModel
from crs_core.model.plants import DEFAULT_MODEL, plant_spec
from crs_core.model.terms import CLOCK_STATE
from crs_core.parameters import ParameterSet


class _IterationProgress(ca.Callback):
    """IPOPT iteration callback: calls ``report(iteration, cost)`` once per iteration."""

    def __init__(self, nz: int, report: Callable[[int, float], None]) -> None:
        ca.Callback.__init__(self)
        self.nz, self.report, self.iteration = nz, report, 0
        self.construct("fie_progress", {})

    def get_n_in(self) -> int:
        return ca.nlpsol_n_out()

    def get_n_out(self) -> int:
        return 1

    def get_name_in(self, i: int) -> str:
        return ca.nlpsol_out(i)

    def get_name_out(self, i: int) -> str:
        return "ret"

    def get_sparsity_in(self, i: int) -> ca.Sparsity:
        name = ca.nlpsol_out(i)
        if name == "f":
            return ca.Sparsity.scalar()
        if name in ("x", "lam_x"):
            return ca.Sparsity.dense(self.nz)
        return ca.Sparsity(0, 0)

    def eval(self, arg):
        self.report(self.iteration, 2.0 * float(arg[ca.nlpsol_out().index("f")]))
        self.iteration += 1
        return [0]


def stderr_progress(iteration: int, cost: float) -> None:
    """One line per IPOPT iteration on stderr."""
    print(f"sysid: iteration {iteration:3d}  cost {cost:.6g}", file=sys.stderr, flush=True)


@dataclass
class FieResult:
    """What identification found.

    Attributes
    ----------
    parameters : ParameterSet
        The model's parameters with the identified values.
    prior : ParameterSet
        The prior (the model's parameters before identification).
    fit : tuple of str
    theta, theta_prior, theta_prior_std : arrays (n_theta,)
    uncertainty : ParameterUncertainty
    states : (N, nx) identified state trajectory on ``t``
    t : (N,) stamps
    outputs : (N, 13) model outputs of the identified trajectory (dataset columns)
    data : FieData
    cost : float, the paper's ``V`` (sum of squared weighted residuals) at the optimum
    cost_initial : float, ``V`` at the initial guess
    cost_terms : dict, ``V`` split into prior, initial state, process and measurement terms
    iterations : int, IPOPT iterations (all starts)
    time_s : float, wall time of :func:`identify` (estimator runs, building, solving, covariance)
    build_s : float, building the problem and the solver (CasADi graphs and derivatives)
    solver_status : str, IPOPT's return status of the best start
    settings : FieSettings
    starts : list of per-start summaries (cost, iterations, status, time_s)
    model : str, the spec of the model's plant (:func:`~crs_core.model.plants.plant_spec`)
    car_states : (N, 6) the car state of ``states`` (:data:`~crs_core.model.plant.CAR_STATE_NAMES`)
    """

    parameters: ParameterSet
    prior: ParameterSet
    fit: tuple[str, ...]
    theta: np.ndarray
    theta_prior: np.ndarray
    theta_prior_std: np.ndarray
    uncertainty: ParameterUncertainty
    states: np.ndarray
    t: np.ndarray
    outputs: np.ndarray
    data: FieData
    cost: float
    cost_initial: float
    cost_terms: dict[str, float]
    iterations: int
    time_s: float
    build_s: float
    solver_status: str
    settings: FieSettings
    starts: list[dict[str, Any]] = field(default_factory=list)
    model: str = DEFAULT_MODEL
    car_states: np.ndarray = field(default_factory=lambda: np.zeros((0, 6)))

    @property
    def time_per_iteration_s(self) -> float:
        return self.solve_s / max(self.iterations, 1)

    @property
    def solve_s(self) -> float:
        return sum(s["time_s"] for s in self.starts)


def initial_trajectory(
    dataset: Dataset, model: CarModel, parameters: ParameterSet | None = None
) -> np.ndarray:
    """States ``(N, nx)`` from an EKF run with ``model`` (its effects included) and
    ``parameters`` (default the model's): yaw unwrapped; the samples before the first fix take
    the first fix; effect states (an actuator lag's output) at rest under the first command and
    then run through the commands (:func:`effect_state_trajectory`)."""
    if parameters is not None:
        model = model.with_parameters(parameters)
    estimates = estimate_dataset(dataset, "ekf", model=model)
    x = estimates.x.T.copy()
    found = np.flatnonzero(estimates.status != "lost")
    if not found.size:
        raise FieldError("dataset", "the estimator never found the car (no Lighthouse fix)")
    first = found[0]
    x[:first] = x[first]
    lost = estimates.status == "lost"
    for k in np.flatnonzero(lost)[np.flatnonzero(lost) > first]:
        x[k] = x[k - 1]  # hold through a later loss
    x[:, 2] = np.unwrap(x[:, 2])
    u = dataset.u if dataset.u is not None else np.zeros((len(x), 2))
    P = model.parameters.value
    plant = np.stack(
        [model.plant.state_from_car(row, cmd, P) for row, cmd in zip(x, u, strict=True)]
    )
    return _with_effect_states(dataset, model, plant, model.parameters.vector())


def effect_state_trajectory(
    dataset: Dataset,
    model: CarModel,
    states: np.ndarray,
    p: np.ndarray | None = None,
) -> np.ndarray:
    """``states`` ``(N, nx)`` with the effect states (after the plant's states) integrated
    through ``dataset``'s commands (the FIE's held-command segments,
    :func:`~crs_core.identification.data.input_segments`) from their value at the first sample
    with parameter vector ``p`` (default the model's), the base states kept. At rest under the
    command is wrong where commands change faster than an actuator follows: a lag's output
    trails its command by up to the time constant, and a prediction started from the command
    would carry that error."""
    n_effect = sum(len(e.initial_states([0.0, 0.0])) for e in model.effects)
    if n_effect == 0:
        return states
    base = len(model.plant.states)  # the effects' states come first after the plant's
    effect = slice(base, base + n_effect)
    numeric = model.numeric
    p = model.parameters.vector() if p is None else p
    seg_u, seg_dt, seg_count = input_segments(dataset)
    out = states.copy()
    for k in range(len(dataset.t) - 1):
        x = np.concatenate([states[k, :base], out[k, effect], states[k, effect.stop :]])
        for j in range(seg_count[k]):
            x = np.asarray(numeric.step(x, seg_u[k, j], p, seg_dt[k, j])).ravel()
        out[k + 1, effect] = x[effect]
    return out


@dataclass(frozen=True)
class WarmStart:
    """An initial guess for the first start instead of the prior and an estimator run.

    Attributes
    ----------
    values : mapping of parameter name to value; fitted parameters named here start there (the
        prior stays the model's)
    states : (N, >= n) state trajectory on the dataset's stamps of a model of the same plant;
        its plant's n states are used, effect states are run through the commands
        (:func:`effect_state_trajectory`)
    """

    values: dict[str, float]
    states: np.ndarray


def _warm_states(
    dataset: Dataset, model: CarModel, states: np.ndarray, p: np.ndarray
) -> np.ndarray:
    """``states``' plant columns, effect states run through the commands with parameter
    vector ``p``."""
    n = len(model.plant.states)
    if states.shape[0] != len(dataset.t) or states.shape[1] < n:
        raise FieldError(
            "warm_start.states", f"expected ({len(dataset.t)}, >= {n}), got {states.shape}"
        )
    return _with_effect_states(dataset, model, states[:, :n], p)


def _with_effect_states(
    dataset: Dataset, model: CarModel, base: np.ndarray, p: np.ndarray
) -> np.ndarray:
    """Model states ``(N, nx)`` from plant states ``(N, n)``: effect states at rest under the
    first command, then run through the commands with parameter vector ``p``; a term's clock
    the time since the recording's start (:attr:`~crs_core.dataset.Dataset.recording_start`)."""
    u = dataset.u if dataset.u is not None else np.zeros((len(base), 2))
    at_rest = np.stack([model.augmented_state(row, cmd) for row, cmd in zip(base, u, strict=True)])
    if model.has_clock:
        at_rest[:, model.state_names.index(CLOCK_STATE[0])] = dataset.t - dataset.recording_start
    return effect_state_trajectory(dataset, model, at_rest, p)


def _warm_vector(model: CarModel, values: dict[str, float]) -> np.ndarray:
    """The model's parameter vector with the warm start's values."""
    return model.parameters.updated(
        {n: v for n, v in values.items() if n in model.parameters.names}
    ).vector()


def identify(
    dataset: Dataset,
    model: CarModel,
    settings: FieSettings | None = None,
    progress: Callable[[int, float], None] | None = None,
    warm_start: WarmStart | None = None,
) -> FieResult:
    """Identify ``settings.fit`` from ``dataset``; ``model.parameters`` is the prior.

    ``warm_start`` (for example an earlier result of a nested model) replaces the estimator run
    and the prior as the first start's guess. Raises ``ValueError`` (naming the field) for a
    dataset too short, without inputs or measurements, and for unknown parameter names or
    bounds that exclude the prior.
    """
    settings = settings or FieSettings()
    check_fit(model, settings.fit)
    data = FieData.from_dataset(dataset, settings.noise).explained_by(model.plant.explains)
    started = time.perf_counter()
    rng = np.random.default_rng(settings.seed)
    problem: FieProblem | None = None
    best: tuple[float, np.ndarray, dict[str, Any]] | None = None
    starts: list[dict[str, Any]] = []
    solver: ca.Function | None = None
    callback: _IterationProgress | None = None
    build_s = 0.0
    for start in range(settings.starts):
        theta0: np.ndarray | None = None
        if start > 0 and problem is not None:
            lo, hi = problem.bounds()
            draw = rng.standard_normal(problem.n_theta)
            draw = np.clip(draw, lo[: problem.n_theta] + 1e-3, hi[: problem.n_theta] - 1e-3)
            theta0 = problem.theta_prior + problem.theta_std * draw
        start_params = (
            model.parameters
            if theta0 is None
            else model.parameters.updated(dict(zip(settings.fit, theta0, strict=True)))
        )
        if start == 0 and warm_start is not None:
            states0 = _warm_states(
                dataset, model, warm_start.states, _warm_vector(model, warm_start.values)
            )
        else:
            states0 = initial_trajectory(dataset, model, start_params)
        if start == 0:
            prior_states = states0
        if problem is None:
            t_build = time.perf_counter()
            problem = FieProblem(model, data, settings, states0[0])
            callback = _IterationProgress(problem.nz, progress) if progress else None
            solver = problem.solver(callback)  # keep ``callback`` alive while solving
            build_s = time.perf_counter() - t_build
            theta0 = problem.theta_prior.copy()
            if warm_start is not None:
                for j, name in enumerate(problem.fit):
                    if name in warm_start.values:
                        theta0[j] = warm_start.values[name]
        assert solver is not None and theta0 is not None  # (set by the first start)
        lo, hi = problem.bounds()
        z0 = np.clip(problem.pack(theta0, states0), lo, hi)
        t_solve = time.perf_counter()
        solution = solver(x0=z0, lbx=lo, ubx=hi)
        stats = solver.stats()
        z = np.asarray(solution["x"]).ravel()
        cost = 2.0 * float(solution["f"])
        summary: dict[str, Any] = {
            "start": start,
            "cost": cost,
            "iterations": int(stats.get("iter_count", 0)),
            "status": str(stats.get("return_status", "unknown")),
            "time_s": time.perf_counter() - t_solve,
        }
        starts.append(summary)
        if best is None or cost < best[0]:
            best = (cost, z, summary)
    assert problem is not None and best is not None
    cost, z, summary = best
    theta, states = problem.unpack(z)
    z_init = problem.pack(problem.theta_prior, prior_states)
    r0 = np.asarray(problem.residual_function(z_init)).ravel()
    r = np.asarray(problem.residual_function(z)).ravel()
    terms, offset = {}, 0
    for name, size in problem.blocks.items():
        terms[name] = float(np.sum(r[offset : offset + size] ** 2))
        offset += size
    jacobian = problem.jacobian_function()(z)
    lo, hi = problem.bounds()
    uncertainty = parameter_uncertainty(
        jacobian.sparse(),
        problem.fit,
        theta,
        problem.theta_std,
        at_bound=(z[: problem.n_theta] <= lo[: problem.n_theta] + 1e-6)
        | (z[: problem.n_theta] >= hi[: problem.n_theta] - 1e-6),
    )
    outputs = np.asarray(problem.output_function(z)).T
    return FieResult(
        parameters=model.parameters.updated(dict(zip(problem.fit, theta, strict=True))),
        prior=model.parameters,
        fit=problem.fit,
        theta=theta,
        theta_prior=problem.theta_prior,
        theta_prior_std=problem.theta_std,
        uncertainty=uncertainty,
        states=states,
        t=data.t,
        outputs=outputs,
        data=data,
        cost=cost,
        cost_initial=float(np.sum(r0**2)),
        cost_terms=terms,
        iterations=sum(s["iterations"] for s in starts),
        time_s=time.perf_counter() - started,
        build_s=build_s,
        solver_status=summary["status"],
        settings=settings,
        starts=starts,
        model=plant_spec(model.plant),
        car_states=model.numeric.car_states(states, data.u),
    )
