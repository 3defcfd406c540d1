"""Model predictive contouring control in real-time iterations (the CRS racing controller).

:class:`Mpcc` turns a state estimate into the car input: per call one Gauss-Newton SQP iteration
(real-time iteration) of the problem in :mod:`~crs_core.control.mpcc_problem`, warm-started from
the previous plan shifted by one stage, its QP solved by HPIPM (:mod:`~crs_core.control.ocp_qp`);
with ``MpccSettings(solver="acados")`` the iteration is acados's SQP-RTI of the same problem
(:mod:`~crs_core.control.mpcc_acados`), everything around it (guess, step check, fallbacks)
unchanged.

Fallback: a failed or non-finite solve serves the shifted previous plan's next input; after
``max_failures`` of them in a row, or on an estimate that is stale or unusable, the car is
stopped (straight wheels, braking torque until it stands). A command is never NaN.

Hold-safe commands (``hold_safe=True``, what the supervisor asks for once the link has shown an
outage): the command is checked by the :class:`~crs_core.control.contingency.HoldSafetyFilter`
and replaced by the nearest one the car can hold through an outage and still be on the track
and able to brake for what comes; the plan's first input is set to it.

A model with the ``input_delay`` effect is compensated: the state is carried over the delay
under the commands still in flight (issued at the control rate) before the plan starts.

Conventions: state ``[x_p, y_p, psi, v_x, v_y, omega]`` (+ the model's effect states), input
``[delta, T]`` (rad, normalised torque); with ``output="velocity"`` the command is
``[delta, v_x]`` (rad, m/s) for cars that track speed on board.
"""

from __future__ import annotations

import math
import time
import warnings
from collections import deque
from collections.abc import Mapping
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import ArrayLike

from crs_core.analysis.angles import wrap_angle
from crs_core.codegen import compile_functions
from crs_core.control.contingency import ContingencySettings, HoldSafetyFilter, lag_decay
from crs_core.control.mpcc_problem import (
    FREE,
    QP_ARGUMENTS,
    Iterate,
    MpccProblem,
    MpccSettings,
    SqpStep,
)
from crs_core.control.path_following import PathFollower, PathFollowerSettings
from crs_core.control.reference_path import ReferencePath
from crs_core.model import CarModel
from crs_core.model.online import model_values
from crs_core.parameters import ParameterSet
from crs_core.track import Track

if TYPE_CHECKING:
    from crs_core.control.mpcc_acados import AcadosRti
    from crs_core.control.mpcc_native import NativeRti

__all__ = ["Mpcc", "MpccStatus"]

#: Outputs of the controller.
OUTPUTS = ("torque", "velocity")
#: How far the car may be from its plan (position m, yaw rad, speed m/s) for one real-time
#: iteration to start from that plan (:meth:`Mpcc._off_plan`).
OFF_PLAN = (0.1, 0.25, 0.4)
#: SQP iterations of a call whose car is off its plan: each costs a QP (14 ms median on this
#: machine), and ten of them under a busy loop took 230 ms, past the car's 200 ms cut-off.
OFF_PLAN_ITERATIONS = 3
#: Fractions of the QP's step tried after the full one (:meth:`Mpcc._step`).
STEP_FRACTIONS = (1.0, 0.5, 0.25, 0.125)
_FRACTIONS = np.array(STEP_FRACTIONS)


@dataclass(frozen=True)
class MpccStatus:
    """What :class:`Mpcc` did at its last call.

    Attributes
    ----------
    mode : str
        ``"solved"`` (the plan's first input), ``"fallback"`` (the shifted previous plan after a
        failed solve) or ``"stop"`` (safe stop).
    solve_time_s : float
        Wall time of the whole call, s (linearisation, QP, bookkeeping).
    qp_iterations : int
        Iterations of the QP solver (-1 when not solved).
    progress : float
        Arc length of the car's projection (laps unwrapped), m.
    contouring_error : float
        Signed distance of the car to the right of the reference path, m.
    max_slack : float
        Largest track-boundary slack of the plan, m (0: the plan keeps the margin).
    failures : int
        Failed solves in a row.
    reason : str
        Why the mode is not ``solved``.
    """

    mode: str
    solve_time_s: float
    qp_iterations: int
    progress: float
    contouring_error: float
    max_slack: float
    failures: int
    reason: str = ""


class Mpcc:
    """MPCC on a track with the one car model.

    Parameters
    ----------
    track : Track
        The track to race on, in the direction of increasing arc length.
    model : CarModel, optional
        Prediction model (effects included); default the Chronos model.
    settings : MpccSettings, optional
        Horizon, rate, weights, limits.
    parameters : ParameterSet, optional
        Model parameter values; default the model's.
    output : {"torque", "velocity"}
        Command ``[delta, T]`` or ``[delta, v_x]``.
    contingency : ContingencySettings, optional
        What an outage is assumed to do, for hold-safe commands (default
        :class:`~crs_core.control.contingency.ContingencySettings`).
    """

    def __init__(
        self,
        track: Track,
        model: CarModel | None = None,
        settings: MpccSettings | None = None,
        parameters: ParameterSet | None = None,
        output: str = "torque",
        contingency: ContingencySettings | None = None,
    ) -> None:
        if output not in OUTPUTS:
            raise ValueError(f"output: one of {OUTPUTS}, got {output!r}")
        self.model = model or CarModel()
        self.settings = settings or MpccSettings()
        racing_speed = self.model.plant.racing_speed
        if racing_speed is not None and self.settings.progress_speed_max > racing_speed:
            # a simple model plans only as fast as it holds (Plant.racing_speed)
            self.settings = replace(self.settings, progress_speed_max=racing_speed)
        self.settings.validate()
        self.output = output
        self.path = ReferencePath(track)
        self._track = track
        self.contingency = contingency or ContingencySettings()
        self._safety: HoldSafetyFilter | None = None  # built at the first hold-safe call
        self.problem = MpccProblem(self.model, self.settings)
        self.p = (parameters or self.model.parameters).vector()
        s = self.settings
        #: acados's iteration of the problem (``solver="acados"``), else None
        self._acados = _acados_rti(self.problem) if s.solver == "acados" else None
        self._native = _native_rti(self.problem, self.path) if s.solver == "native" else None
        in_casadi = self._acados is None and self._native is None
        qp = "hpipm" if s.solver == "native" else None  # native's fallback: CasADi's HPIPM
        self._rti = self.problem.real_time_iteration(qp) if in_casadi else None
        # the step check's rollouts and costs, compiled (in CasADi's VM they were a quarter of
        # a call: 0.38 ms per cost); the native iteration's library holds them already
        checks = (
            self._native.checks
            if self._native is not None
            else compile_functions(
                [
                    self.problem.dynamics.mapaccum("mpcc_rollout", self.problem.N),
                    self.problem.merit(),
                ],
                "mpcc_checks",
            )
        )
        self._rollout, self._merit_function = checks["mpcc_rollout"], checks["mpcc_merit"]
        self._parameter_columns = np.tile(self.p[:, None], (1, self.problem.N))
        self._nxc = self.model.nx
        self._vx = self.problem.speed_index
        values = parameters or self.model.parameters
        self._wheelbase_parts = (values.value("lf"), values.value("lr"))
        self._drive_off = PathFollower(
            track,
            sum(self._wheelbase_parts),
            PathFollowerSettings(
                steer_max=s.steer_max, torque_min=s.torque_min, torque_max=s.torque_max
            ),
        )
        self._v_lower = np.array([-s.steer_max, s.torque_min, 0.0, 0.0])
        self._v_upper = np.array([s.steer_max, s.torque_max, s.progress_speed_max, FREE])
        self._values = values
        self._half_width = self.path.half_width - s.track_margin
        self._weights = s.weights()
        #: the model's input delay (s), compensated by predicting over it
        self._delay = self.model.input_delay(parameters)
        self._in_flight: deque[np.ndarray] = deque(
            maxlen=max(1, math.ceil(self._delay * s.rate_hz))
        )
        self._velocity_stage = min(max(1, round(s.velocity_lead_s * s.rate_hz)), s.horizon)
        self.reset()

    # --- public --------------------------------------------------------------------------
    def use_parameters(self, online: Mapping[str, float], elapsed: float) -> dict[str, float]:
        """Move the prediction model toward the online parameter estimates ``online`` (by name,
        :func:`~crs_core.model.online.model_values`), each by at most ``parameter_rate`` of its
        model value per second over ``elapsed`` s (no recompilation: the parameters are an
        argument of the generated functions). Returns the values now in use, by name."""
        names = self._values.names
        used = {}
        for name, target in model_values(self._values, online).items():
            k = names.index(name)
            step = self.settings.parameter_rate * abs(self._values.value(name)) * max(elapsed, 0.0)
            self.p[k] = float(np.clip(target, self.p[k] - step, self.p[k] + step))
            used[name] = float(self.p[k])
        self._parameter_columns[:] = self.p[:, None]
        return used

    def reset(self) -> None:
        """Forget the plan and the commands in flight (the next call starts cold)."""
        self._Z: np.ndarray | None = None
        self._V: np.ndarray | None = None
        self._failures = 0
        self._hold_safe = False  # this call's commands must be safe to hold
        self._held = 0  # stops in a row with the plan kept
        self._command = np.zeros(2)
        self._steering = 0.0  # the angle the car steers at: the commands through its lag
        self._in_flight.clear()
        self._progress_speed = 0.0
        self.status: MpccStatus | None = None
        #: The guess ``(Z, V, refs)`` the last call started from (for comparisons).
        self.last_guess: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None

    def warm_up(self) -> None:
        """One call from the track's start pose, then :meth:`reset`: the first call's one-off
        costs (the model's numeric functions built, the compiled code's pages first touched;
        85 ms against 68 for a later cold call on an idle machine) are paid before a car waits
        for a command. With torque output the hold-safety filter is built and run once too (a
        hold-safe call from the start pose, one moving along the track): its first call took
        another 130 ms on an idle machine, and beside two busy loops that paused the first
        commands over a car's 200 ms cut-off."""
        start = self._track.start_state()
        self(start)
        if self.output == "torque":
            moving = start.copy()
            moving[3] = 2.0 * self.contingency.min_speed
            self(start, hold_safe=True)
            self(moving, hold_safe=True)
            assert self._safety is not None
            self._safety.replaced = 0
        self.reset()

    @property
    def plan(self) -> tuple[np.ndarray, np.ndarray] | None:
        """The current plan: stage states ``(N+1, nz)`` and inputs ``(N, nv)``, or None."""
        if self._Z is None or self._V is None:
            return None
        return self._Z.copy(), self._V.copy()

    @property
    def progress_reference(self) -> np.ndarray | None:
        """The centreline points ``(N+1, 2)`` (m, world) at the plan's progress states: where
        the contouring cost pulls each stage, or None without a plan."""
        if self._Z is None:
            return None
        x, y, _, _ = self._track.interpolate(self._Z[:, self._nxc])
        return np.column_stack([x, y])

    @property
    def last_command(self) -> np.ndarray:
        """The last command ``[delta, T]`` returned (zeros after a reset)."""
        return self._command.copy()

    @property
    def hold_safe_replaced(self) -> int:
        """Commands the hold-safety filter replaced so far (0 before the first hold-safe call)."""
        return 0 if self._safety is None else self._safety.replaced

    def stop(
        self, x: ArrayLike | None = None, reason: str = "stop requested", keep_plan: bool = False
    ) -> np.ndarray:
        """The safe-stop command for state ``x`` (straight wheels, brake until standing).

        Forgets the plan; with ``keep_plan`` (a short gap, e.g. a late state estimate) the
        plan is kept, shifted by a stage per call as time goes on, for the next call to start
        from, and its steering is held, until the stops in a row have used up half its
        horizon: a car that coasted a few periods is still near it, and a cold start from a
        moving car would take several periods to converge.
        """
        command = self._stop_command(x)
        self._held += 1
        if keep_plan and self._Z is not None and self._held <= self.problem.N // 2:
            self._Z, self._V = self._shifted()
            # the plan's steering, not straight wheels: a car that coasts straight on from a
            # bend at racing speed leaves the track before the next estimate comes
            command[0] = self._V[0, 0]
            self._command = command
        else:
            self.reset()
        self.status = MpccStatus("stop", 0.0, -1, math.nan, math.nan, 0.0, 0, reason)
        return self._out(command, None)

    def __call__(
        self,
        x: ArrayLike,
        speed_limit: float | None = None,
        elapsed: float | None = None,
        hold_safe: bool = False,
    ) -> np.ndarray:
        """The command for state ``x`` (the car's state now).

        Parameters
        ----------
        x : array_like
            ``[x_p, y_p, psi, v_x, v_y, omega]`` (m, rad, m/s, rad/s), optionally followed by
            the model's effect states (else they are taken from the plan, or at rest).
        speed_limit : float, optional
            A lower bound than ``progress_speed_max`` on the progress speed for this call, m/s
            (e.g. while the state estimate is degraded).
        elapsed : float, optional
            Time since the previous call, s: the plan is carried on by that many stages
            (rounded, 1 to N/2; default one stage). A loaded machine's late call otherwise
            starts from a plan one stage on while three or four have passed.
        hold_safe : bool, optional
            Return a command that is safe to hold through an outage
            (:mod:`~crs_core.control.contingency`).

        Returns
        -------
        numpy.ndarray, shape (2,)
            ``[delta, T]`` (or ``[delta, v_x]``), finite and within the limits.
        """
        started = time.perf_counter()
        self._hold_safe = bool(hold_safe) and self.output == "torque"
        state = np.asarray(x, dtype=float).ravel()
        if state.size not in (6, self._nxc) or not np.all(np.isfinite(state)):
            sizes = "6" if self._nxc == 6 else f"6 (the car state) or {self._nxc}"
            return self.stop(None, f"x: need {sizes} finite states, got {state.tolist()}")
        self._held = 0
        self._follow_steering(self.settings.dt if elapsed is None else float(elapsed))
        self._v_upper[2] = self.settings.progress_speed_max
        if speed_limit is not None and math.isfinite(speed_limit):
            self._v_upper[2] = min(max(float(speed_limit), 0.0), self._v_upper[2])
        z0 = self._initial_stage_state(state)
        stages = 1 if elapsed is None else round(float(elapsed) * self.settings.rate_hz)
        stages = min(max(stages, 1), self.problem.N // 2)
        cold = self._Z is None
        iterations_now = self.settings.cold_start_iterations if cold else 1
        Z: np.ndarray | None = None  # None: the iteration rolls V out (and checks it moves)
        if cold:
            Z, V = self._driving_guess(z0)
        else:
            V = self._shifted_inputs(stages)
            if self._off_plan(z0, stages):
                iterations_now = OFF_PLAN_ITERATIONS
                guesses = (self._moving_guess(z0, V), self._driving_guess(z0))
                Z, V = min(guesses, key=lambda g: self._merit(*g))
        iterations, reason, contour = 0, "", math.nan
        budget, iteration_time = self.settings.solve_time_budget, 0.0
        for iteration in range(iterations_now):
            iteration_started = time.perf_counter()
            if iteration and budget and iteration_started + iteration_time - started > budget:
                break
            try:
                step = self._sqp_iteration(z0, Z, V)
            except (RuntimeError, ValueError) as error:  # a solver that raised has failed
                reason = f"QP solver error: {error}"
                break
            if not iteration:
                self.last_guess = (step.guess[0].copy(), step.guess[1].copy(), step.refs)
            solution, contour = step.qp, step.contour
            Z, V = solution.Z, solution.V
            if not solution.success:
                reason = (
                    f"QP not solved (status {solution.status}, constraint violation "
                    f"{solution.violation:.3g})"
                )
                break
            iterations += solution.iterations
            iteration_time = time.perf_counter() - iteration_started
        if Z is None:  # the first iteration raised before it rolled the inputs out
            Z, V = self._moving_guess(z0, V)
        if not reason or (iterations_now > 1 and iterations):  # earlier iterations count
            return self._accept(Z, V, z0, contour, iterations, started)
        return self._fall_back(Z, V, z0, started, reason)

    # --- steps ---------------------------------------------------------------------------
    def _follow_steering(self, elapsed: float) -> None:
        """The car's steering angle now: it has followed the last command for ``elapsed`` s
        as the contingency settings' first-order lag."""
        decay = lag_decay(elapsed, self.contingency.steering_time_constant)
        target = float(self._command[0])
        self._steering = target + (self._steering - target) * decay

    def _is_model_state(self, state: np.ndarray) -> bool:
        """``state`` is the model's whole state, not the car state: it has the model's size,
        and a model whose car state is not its first six states is given the car state."""
        return state.size == self._nxc and (self.model.car_state_is_state or state.size != 6)

    def _initial_stage_state(self, state: np.ndarray) -> np.ndarray:
        nxc, model = self._nxc, self.model
        if model.car_state_is_state or not self._is_model_state(state):
            state = self._kinematic_at_low_speed(state)
        if self._is_model_state(state):
            car = state
        else:
            plant = model.plant.state_from_car(state, self._command, model.parameters.value)
            if self._Z is not None:  # effect states from the plan
                car = np.concatenate((plant, self._Z[1, len(plant) : nxc]))
            else:
                car = model.augmented_state(plant, self._command)
        if self._delay > 0:
            car = self._through_delay(car)
        near = None if self._Z is None else float(self._Z[1, nxc])
        theta = self.path.progress(car[0], car[1], near)
        return np.concatenate((car, [theta], self._command, [self._progress_speed]))

    def _kinematic_at_low_speed(self, state: np.ndarray) -> np.ndarray:
        """Below ``kinematic_speed`` the lateral velocity and yaw rate of ``state`` are replaced
        by the kinematic bicycle's at its ``v_x`` and the last steering command: at walking pace
        the tires' slip angles are undefined and an estimate's ``v_y`` and ``omega`` are noise
        (0.1-0.27 m/s and 0.2 rad/s at rest behind a lossy link), which the plan answered with
        full lock and full reverse torque."""
        vx = float(state[3])
        if abs(vx) >= self.settings.kinematic_speed:
            return state
        lf, lr = self._wheelbase_parts
        tan_delta = math.tan(float(self._command[0]))
        state = state.copy()
        state[4] = vx * lr * tan_delta / (lf + lr)
        state[5] = vx * tan_delta / (lf + lr)
        return state

    def _through_delay(self, car: np.ndarray) -> np.ndarray:
        """The state when a command issued now acts: carried over the model's input delay
        ``d`` under the commands still in flight (issued at the control rate during the last
        ``d`` s; the one issued ``j`` periods ago acts from ``d - j dt`` s after now)."""
        dt, d = self.settings.dt, self._delay
        numeric = self.model.numeric
        for j in range(len(self._in_flight), 0, -1):
            start = max(0.0, d - j * dt)
            end = min(d, d - (j - 1) * dt)
            if end > start:
                car = numeric.step(car, self._in_flight[-j], self.p, end - start)
        return car

    def _off_plan(self, z0: np.ndarray, stages: int) -> bool:
        """Whether the car is far from where the plan put it ``stages`` stages on (more than
        :data:`OFF_PLAN` in position m, yaw rad or speed m/s): then the previous plan is no
        linearisation point for one iteration, and the call makes :data:`OFF_PLAN_ITERATIONS`.
        After a link outage the plan had followed a dead-reckoned estimate; the one iteration
        from it at the car's true state gave full braking and full lock left and right in
        turn."""
        Z, _ = self._kept_plan()
        planned = Z[min(stages, self.problem.N)]
        position, yaw, speed = OFF_PLAN
        return bool(
            math.hypot(z0[0] - planned[0], z0[1] - planned[1]) > position
            or abs(float(wrap_angle(z0[2] - planned[2]))) > yaw
            or abs(z0[self._vx] - planned[self._vx]) > speed
        )

    def _shifted_inputs(self, stages: int) -> np.ndarray:
        """The plan's inputs shifted by ``stages``, the last held."""
        _, V = self._kept_plan()
        return np.vstack((V[stages:], np.repeat(V[-1:], stages, axis=0)))

    def _moving_guess(self, z0: np.ndarray, V: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``V`` rolled out from ``z0``; where the car stands in it (no stage reaches
        ``kinematic_speed``), :meth:`_driving_guess` instead."""
        Z = self._rolled_out(z0, V)
        if np.max(Z[:, self._vx]) >= self.settings.kinematic_speed:
            return Z, V
        return self._driving_guess(z0)

    def _driving_guess(self, z0: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The path follower's inputs over the horizon, rolled out on the model from ``z0``,
        with the progress speeds of the states they reach.

        A plan linearised at a standing car cannot see the steering: the slip angles, and with
        them every effect of ``delta``, vanish at ``v_x = 0``, so in a bend, or facing a few
        tenths of a radian off the path, the QP's best plan was to stay. From rest the MPCC
        stayed in 9 of 25 poses on the demo track (3 s each); it is linearised here at a car
        that drives off along the path instead."""
        N, nxc, dt = self.problem.N, self._nxc, self.settings.dt
        follower = self._drive_off
        follower.reset()
        numeric = self.model.numeric
        limit = float(self._v_upper[2])
        V = np.zeros((N, len(self._v_upper)))
        car = np.array(z0[:nxc], dtype=float)
        theta = np.empty(N + 1)
        theta[0] = z0[nxc]
        command = self._command
        for k in range(N):
            V[k, :2] = follower(k * dt, numeric.car_state(car, command, self.p), limit)
            command = V[k, :2]
            car = numeric.step(car, V[k, :2], self.p, dt)
            theta[k + 1] = self.path.progress(car[0], car[1], theta[k])
        V[:, 2] = np.clip(np.diff(theta) / dt, 0.0, limit)
        return self._rolled_out(z0, V), V

    def _sqp_iteration(self, z0: np.ndarray, Z: np.ndarray | None, V: np.ndarray) -> SqpStep:
        """One SQP iteration from the inputs ``V`` (``Z`` their rollout from ``z0``, or None
        for the iteration to roll them out and take :meth:`_driving_guess` where the car
        stands in them): the path at the guess's progress, the QP, :meth:`_step`. With the
        native solver all of it is one compiled call
        (:meth:`~crs_core.control.mpcc_native.NativeRti.sqp`, the same rule in C)."""
        native = self._native
        if native is not None:
            arguments = (self._weights, self.p, self._v_lower, self._v_upper, self._half_width)
            standing = self.settings.kinematic_speed if Z is None else None
            step = native.sqp(z0, V, *arguments, _FRACTIONS, standing)
            if step is None:
                _, V = self._driving_guess(z0)
                step = native.sqp(z0, V, *arguments, _FRACTIONS)
            assert step is not None
            return step
        if Z is None:
            Z, V = self._moving_guess(z0, V)
        refs = self._references(Z[:, self._nxc])
        solution = self._solve_qp(Z, V, refs)
        plan = self._step(z0, Z, V, solution.V) if solution.success else (Z, V)
        contour = float(np.asarray(self.problem.contouring_error(z0, refs[0])).ravel()[0])
        return SqpStep((Z, V), refs, replace(solution, Z=plan[0], V=plan[1]), contour)

    def _step(
        self, z0: np.ndarray, Z: np.ndarray, V: np.ndarray, V_qp: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """The plan towards the QP's inputs ``V_qp`` from the guess ``(Z, V)`` (``Z`` its
        rollout from ``z0``): the full step, or the first of its halvings (down to
        :data:`STEP_FRACTIONS`' last) whose rollout costs no more than the guess's
        (:meth:`_merit`); the guess itself if none costs less. A plan never costs more than
        the guess it came from.

        The QP sees the dynamics linearised at the guess. Past the tires' peak (full lock at
        speed, entering a bend too fast) less lock gives more lateral force, and the full step
        followed that slope from full right lock to full left lock: a car that came out of an
        outage at the hairpin's entry at 1.95 m/s was steered out of it and braked to a stand
        at the edge, a plan that costs 2.1 times one with its first input turned right."""
        reference = self._merit(Z, V)
        best = (reference, Z, V)
        for fraction in STEP_FRACTIONS:
            trial = V + fraction * (V_qp - V)
            rolled = self._rolled_out(z0, trial)
            cost = self._merit(rolled, trial)
            if cost < best[0]:
                best = (cost, rolled, trial)
            if cost <= reference:
                break
        return best[1], best[2]

    def _merit(self, Z: np.ndarray, V: np.ndarray) -> float:
        """The nonlinear cost of the plan ``(Z, V)`` (``Z`` a rollout of ``V``), the path at
        each stage's own progress (:meth:`MpccProblem.merit`)."""
        refs = self._references(Z[:, self._nxc])
        (cost,) = self._merit_function(Z.T, V.T, refs.T, self._weights, self.p, self._half_width)
        return float(cost[0])

    def _rolled_out(self, z0: np.ndarray, V: np.ndarray) -> np.ndarray:
        """The stage states of inputs ``V`` from ``z0`` under the nonlinear model: a guess
        the model can follow. The QP's plan satisfies only the dynamics linearised at the
        previous guess; continuing from it let the real-time iteration drift to states no
        car reaches, where the next linearisation broke down."""
        (states,) = self._rollout(z0, V.T, self._parameter_columns)
        return np.vstack((z0, states.T))

    def _kept_plan(self) -> tuple[np.ndarray, np.ndarray]:
        """The plan ``(Z, V)``, for the steps that run only while there is one."""
        if self._Z is None or self._V is None:
            raise RuntimeError("Mpcc: no plan to continue from")
        return self._Z, self._V

    def _shifted(self) -> tuple[np.ndarray, np.ndarray]:
        """The plan one stage on: its last input held for one more stage."""
        Z_kept, V_kept = self._kept_plan()
        V = np.vstack((V_kept[1:], V_kept[-1:]))
        Z = np.vstack((Z_kept[1:], Z_kept[-1:]))
        Z[-1] = np.asarray(self.problem.dynamics(Z[-2], V[-1], self.p)).ravel()
        return Z, V

    def _references(self, theta: np.ndarray) -> np.ndarray:
        """Linearisation points ``[X, Y, heading, theta]`` of the path at the guessed progress."""
        point = self.path.evaluate(theta)
        return np.column_stack((point.x, point.y, point.heading, theta))

    def qp_data(self, Z: np.ndarray, V: np.ndarray, refs: np.ndarray) -> tuple:
        """The QP of one SQP iteration from the guess ``Z`` (N+1, nz), ``V`` (N, nv) with the
        path linearised at ``refs`` (N+1, 4): its data in the order of
        :data:`~crs_core.control.mpcc_problem.QP_ARGUMENTS` (CasADi matrices), with this
        call's input bounds."""
        if self._rti is None:
            raise RuntimeError("Mpcc.qp_data: the CasADi QP is not built with solver='acados'")
        return self._rti.data(
            Z.T,
            V.T,
            refs.T,
            Z[0],
            self._weights,
            self.p,
            self._v_lower,
            self._v_upper,
            self._half_width,
        )

    def _solve_qp(self, Z: np.ndarray, V: np.ndarray, refs: np.ndarray) -> Iterate:
        """One SQP iteration from the guess; the new plan and whether it is usable. Data that
        are not finite never reach the solver (a failed iterate, status ``non-finite data``)."""
        compiled = self._native or self._acados
        if compiled is not None:
            return compiled.iterate(
                Z, V, refs, self._weights, self.p, self._v_lower, self._v_upper, self._half_width
            )
        rti = self._rti
        assert rti is not None
        data = self.qp_data(Z, V, refs)
        for name, value in zip(QP_ARGUMENTS, data, strict=True):
            if not value.is_regular():  # in C: a numpy copy of every nonzero took 1-1.4 ms
                return Iterate(Z, V, False, math.inf, -1, f"non-finite data in {name}")
        w_opt = rti.solver(**dict(zip(QP_ARGUMENTS, data, strict=True)))["x"]
        violation = float(rti.violation(w_opt, *data[2:7]))
        w = np.asarray(w_opt, dtype=float).ravel()
        stats = rti.solver.stats()
        N, nz, nv = self.problem.N, self.problem.nz, self.problem.nv
        stages = w[: N * (nz + nv)].reshape(N, nz + nv)
        return Iterate(
            np.vstack((stages[:, :nz], w[N * (nz + nv) :])),
            stages[:, nz:],
            bool(np.all(np.isfinite(w))) and violation <= self.settings.feasibility_tolerance,
            violation,
            int(stats.get("iter_count", -1)),
            str(stats.get("return_status", "")),
        )

    def _stop_command(self, x: ArrayLike | None) -> np.ndarray:
        """Straight wheels; braking torque ``-brake_gain v_x`` (within the limits) while the
        state ``x`` says the car moves forward, else none."""
        vx = 0.0
        if x is not None:
            state = np.asarray(x, dtype=float).ravel()
            index = self._vx if state.size == self.problem.nz else 3
            if state.size > index and math.isfinite(state[index]):
                vx = float(state[index])
        s = self.settings
        torque = min(max(-s.brake_gain * vx, s.torque_min), 0.0) if vx > 0.05 else 0.0
        return np.array([0.0, torque])

    def _accept(self, Z, V, z0, contour: float, iterations, started) -> np.ndarray:
        s = self.settings
        V[:, 0] = np.clip(V[:, 0], -s.steer_max, s.steer_max)
        V[:, 1] = np.clip(V[:, 1], s.torque_min, s.torque_max)
        self._never_into_reverse(V, float(z0[self._vx]))
        self._safe_to_hold(V, z0)
        self._Z, self._V, self._failures = Z, V, 0
        self._command = V[0, :2].copy()
        self._progress_speed = float(V[0, 2])
        self.status = MpccStatus(
            "solved",
            time.perf_counter() - started,
            iterations,
            float(z0[self._nxc]),
            float(contour),
            float(np.max(V[:, 3])),
            0,
        )
        # a velocity reference comes from states the model reaches (the QP's plan follows only
        # the linearised dynamics, far from them after a poor guess: once 12.97 m/s)
        return self._out(self._command, self._rolled_out(z0, V) if self.output == "velocity" else Z)

    def _never_into_reverse(self, V: np.ndarray, vx: float) -> None:
        """Limit the first stage's braking to the safe stop's, ``-brake_gain * v_x`` (none at
        or below standstill): a race never reverses, and full reverse torque held through a
        late control period drove a car that had just stopped backwards at 1.8 m/s."""
        V[0, 1] = max(V[0, 1], -self.settings.brake_gain * max(vx, 0.0))

    def _safe_to_hold(self, V: np.ndarray, z0: np.ndarray) -> None:
        """On a hold-safe call, replace the first stage's command by the hold-safety filter's
        (built at the first such call)."""
        if not self._hold_safe:
            return
        if self._safety is None:
            s = self.settings
            self._safety = HoldSafetyFilter(
                self._track,
                self.model,
                self._values,
                s.steer_max,
                (s.torque_min, s.torque_max),
                s.progress_speed_max,
                self.contingency,
            )
        V[0, :2] = self._safety(z0[: self._nxc], V[0, :2], self._steering)

    def _fall_back(self, Z, V, z0, started, reason: str) -> np.ndarray:
        self._failures += 1
        failures = self._failures
        if failures > self.settings.max_failures or self._Z is None:
            reason = f"{reason}; {failures} failed solves in a row"
            command = self.stop(z0, reason)
            mode, slack = "stop", 0.0
        else:  # the shifted previous plan: the guess is that plan shifted by one stage
            self._never_into_reverse(V, float(z0[self._vx]))
            self._safe_to_hold(V, z0)
            self._Z, self._V = Z, V
            self._command = V[0, :2].copy()
            command = self._out(self._command, Z)
            mode, slack = "fallback", float(np.max(V[:, 3]))
        self.status = MpccStatus(
            mode,
            time.perf_counter() - started,
            -1,
            float(z0[self._nxc]),
            math.nan,
            slack,
            failures,
            reason,  # after a stop, the reason it was given
        )
        return command

    def _out(self, command: np.ndarray, Z: np.ndarray | None) -> np.ndarray:
        if self._delay > 0:
            self._in_flight.append(command.copy())
        if self.output == "torque":
            return command.copy()
        speed = 0.0 if Z is None else float(Z[self._velocity_stage, self._vx])
        return np.array([command[0], min(max(speed, 0.0), self.settings.velocity_max)])


def _native_rti(problem: MpccProblem, path: ReferencePath) -> NativeRti | None:
    """The whole real-time iteration as one compiled call (built once into the cache); None,
    with a warning, where acados's HPIPM is missing (the iteration then runs in CasADi)."""
    from crs_core.acados_support import AcadosUnavailable

    try:
        from crs_core.control.mpcc_native import NativeRti

        return NativeRti(problem, path)
    except AcadosUnavailable as error:
        warnings.warn(
            f"MpccSettings(solver='native'): {error}; iterating with CasADi's HPIPM "
            "(solver='hpipm') instead",
            RuntimeWarning,
            stacklevel=3,
        )
        return None


def _acados_rti(problem: MpccProblem) -> AcadosRti:
    """acados's real-time iteration of ``problem`` (built once into the compile cache)."""
    from crs_core.acados_support import AcadosUnavailable

    try:
        from crs_core.control.mpcc_acados import AcadosRti

        return AcadosRti(problem)
    except AcadosUnavailable as error:
        raise AcadosUnavailable(f"MpccSettings(solver='acados'): {error}") from error
