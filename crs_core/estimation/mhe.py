r"""Moving horizon estimation (paper Sec. V) as a real-time Gauss-Newton iteration.

Nodes :math:`x_0, \dots, x_M` sit on a fixed time grid of spacing :math:`\Delta = 1/`
``rate_hz``, anchored at the reset time; the grid, not the callers, sets the discretisation and
the horizon. The process noise is eliminated,
:math:`w_j = x_{j+1} - f(x_j, \bar u_j, \Delta)`, so the paper's NLP becomes a nonlinear
least-squares problem in the nodes alone,

.. math::

    \min_{x_0..x_M}\ \eta^{M_t}\|x_0 - \bar x_0\|^2_{P^{-1}}
      + \sum_j \eta^{M-1-j}\|x_{j+1} - f(x_j, \bar u_j, \Delta)\|^2_{(Q\Delta)^{-1}}
      + \sum_j \eta^{M-j} \sum_{s} n_{j,s}\,
        \|\bar y_{j,s} - h_s(\phi(x_j, \tau_{j,s}))\|^2_{R_s^{-1}}
      + \text{soft bounds},

with :math:`M_t = \min(t, M)` nodes in use at start-up. Measurements arrive on their own
clocks: each is attached to the node closing its interval; same-sensor samples at a node are
averaged (:math:`n_{j,s}` of them, mean stamp offset :math:`\tau_{j,s} \le 0`), and the node state
is moved to that offset by :math:`\phi`, one Euler step of the model, before the sensor model is
applied (each sensor with the mean of the commands active at its samples). Sensors that did
not report at a node contribute nothing; a Lighthouse blackout simply leaves those terms out.
The inputs of a stage are the time average of the commands over it. Bounds on states and on
:math:`w` are squared-hinge penalties (soft constraints), so the Gauss-Newton Hessian stays
block tridiagonal.

:meth:`~crs_core.estimation.base.Estimator.estimate` at time ``t`` creates every grid node due
by ``t``; each new node is a warm start by prediction followed by one Gauss-Newton step (the
real-time iteration; more with ``iterations``), so the result does not depend on how often or
when the estimate is queried. The estimate at ``t`` is the newest node predicted forward to
``t`` with the measurements since it (EKF steps, :mod:`~crs_core.estimation.readout`; the
window itself is untouched). A step is taken only if it lowers the cost (backtracking by
halving, :data:`STEP_FRACTIONS`; else the warm start is kept): the estimate never moves further
from the data than the prediction. If the cost is not finite, or the normal equations are not
positive definite, the window restarts from its newest finite state (or keeps the prediction);
when more than ``max_catch_up`` nodes are due at once (a stalled process), the estimator skips
ahead to the newest data instead of working through the backlog. Every such event is counted
and makes the status ``degraded``. With ``catch_up_solves`` only the newest few nodes of a late
call are solved (the others predicted), which bounds a call's work.

Why the grid: with node times taken from the callers, a late call made a long stage that the
fixed number of RK4 substeps (chosen for the nominal rate) integrated with steps far beyond
RK4's stability limit (6.8 ms at low speed, :mod:`crs_core.model.stability`): the estimate ran
away to hundreds of metres in loaded multi-car stacks.
"""

from __future__ import annotations

import bisect
import math
from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np

from crs_core.codegen import CompiledFunction, compile_functions
from crs_core.errors import FieldError
from crs_core.estimation.base import Estimator, EstimatorSettings
from crs_core.estimation.mhe_native import NativeGaussNewton
from crs_core.estimation.mhe_problem import (
    BandedGaussNewton,
    StepOutcome,
    build_mhe_function,
    measurement_groups,
    offset_output_functions,
)
from crs_core.estimation.noise import check_effect_state_names, initial_std_for, per_plant_state
from crs_core.estimation.readout import ForwardReadOut
from crs_core.estimation.rejection import RejectionCap
from crs_core.measurements import InputSample, Measurement
from crs_core.model import MAX_SUBSTEP, CarModel
from crs_core.settings import positive, within

#: Soft bounds of effect states by name (lower, upper); other effect states are unbounded.
EXTRA_STATE_BOUNDS: dict[str, tuple[float, float]] = {
    "steer_estimated": (-0.5, 0.5),
    "torque_estimated": (-1.5, 1.5),
}
_UNBOUNDED = 1e6
#: A query this close (in grid steps) before a node creates it: a query on a node, computed as
#: ``anchor + k / rate_hz`` like the node, can come out a rounding error (about 2e-7 s at Unix
#: times) short of it, and without the tolerance it would read out from the node before.
GRID_TOLERANCE = 1e-3
#: Backtracking of the Gauss-Newton step: the first fraction that lowers the cost is taken.
#: Down to 2^-11: with the input-free model on the real recordings, steps cut to 2^-5 still
#: failed hundreds of times, and keeping the prediction each time let the window drift away
#: by half a metre; cut further, every step succeeded (0 fallbacks, 8-9 mm).
STEP_FRACTIONS = tuple(0.5**k for k in range(12))


@dataclass(frozen=True)
class MheSettings(EstimatorSettings):
    """Tuning of :class:`MovingHorizonEstimator` (plus :class:`EstimatorSettings`).

    Attributes
    ----------
    horizon : int
        :math:`M`, number of stages.
    rate_hz : float
        Grid rate: nodes are ``1 / rate_hz`` s apart, whatever the query times.
    discount : float
        :math:`\\eta \\in (0, 1]`.
    arrival_floor_std : float
        The arrival information is floored at ``1 / arrival_floor_std^2`` per state, so
        directions the dropped data did not observe stay well posed.
    state_lower, state_upper : tuple of float
        Soft bounds on ``vx, vy, omega`` (m/s, m/s, rad/s).
    extra_state_bounds : mapping of str to (float, float)
        Soft bounds of effect states by name, overriding :data:`EXTRA_STATE_BOUNDS`.
    process_bound : tuple of float
        Soft bound on :math:`|w|` per base state per stage (6 values).
    bound_weight : float
        Weight (1/unit) of a bound violation.
    iterations : int
        Gauss-Newton iterations per new node (1 = real-time iteration).
    outlier_sigma : float
        A Lighthouse sample whose channel deviates from the prediction by more than this many
        standard deviations is dropped.
    max_consecutive_rejections : int
        After this many Lighthouse samples dropped in a row, one whose deviation agrees with
        the previous dropped ones is taken.
    max_catch_up : int or None
        Most nodes processed in one call; when more are due (a stalled process), the window
        restarts this many nodes before the newest data (default: the horizon).
    catch_up_solves : int or None
        Most nodes per call that get their Gauss-Newton ``iterations``; when more are due (a
        late call on a loaded machine), the older ones are only predicted and the solves go to
        the newest (their data still enter those solves: each covers the whole window). Bounds
        a call's work, so that a late call does not make the next one later still. None
        (default): every node solved, the result independent of when the estimate is queried.
    """

    horizon: int = 40
    rate_hz: float = positive(60.0)
    discount: float = within(0.95, low=0, high=1, low_open=True)
    arrival_floor_std: float = 10.0
    state_lower: tuple[float, float, float] = (-1.0, -2.0, -12.0)
    state_upper: tuple[float, float, float] = (5.0, 2.0, 12.0)
    extra_state_bounds: Mapping[str, tuple[float, float]] = field(default_factory=dict)
    process_bound: tuple[float, ...] = (0.05, 0.05, 0.1, 0.5, 0.5, 3.0)
    bound_weight: float = 1e3
    iterations: int = 1
    outlier_sigma: float = 30.0
    max_consecutive_rejections: int = 25
    max_catch_up: int | None = None
    catch_up_solves: int | None = None

    def _check_relations(self) -> None:
        super()._check_relations()
        if self.horizon < 1:
            raise FieldError("horizon", "must be >= 1")
        if self.iterations < 1:
            raise FieldError("iterations", "must be >= 1")
        if len(self.process_bound) != 6 or not all(b > 0 for b in self.process_bound):
            raise FieldError("process_bound", "needs 6 values > 0 (x, y, yaw, vx, vy, omega)")
        for name in ("state_lower", "state_upper"):
            if len(getattr(self, name)) != 3:
                raise FieldError(name, "needs 3 values (vx, vy, omega)")
        if self.max_catch_up is not None and self.max_catch_up < 1:
            raise FieldError("max_catch_up", "must be >= 1")
        if self.catch_up_solves is not None and self.catch_up_solves < 1:
            raise FieldError("catch_up_solves", "must be >= 1")


class MovingHorizonEstimator(Estimator):
    """MHE over any subset of the car's sensors on a fixed time grid.

    Parameters
    ----------
    model, sensors
        Estimation model and sensor groups, as for :class:`~crs_core.estimation.base.Estimator`.
    settings : MheSettings, optional
    """

    def __init__(
        self, model: CarModel, sensors: frozenset[str] | str, settings: MheSettings | None = None
    ) -> None:
        s = settings or MheSettings()
        super().__init__(sensors, model, s)
        self.settings: MheSettings = s
        self._p = model.parameters.vector()
        self.groups = measurement_groups(model)
        self._dt = 1.0 / s.rate_hz
        self._substeps = max(1, math.ceil(self._dt / MAX_SUBSTEP - 1e-9))
        blocks, cost, node_terms, sizes = build_mhe_function(
            model, s.horizon, self._substeps, self.groups
        )
        offset_outputs = offset_output_functions(model, self.groups)
        step = model.step_function(self._substeps, "mhe_predict")
        compiled = compile_functions(
            [blocks, cost, node_terms, step, *offset_outputs],
            f"mhe_{model.tag}_{model.n_base_stations}bs_M{s.horizon}_n{self._substeps}",
            driver=NativeGaussNewton.driver(blocks),
        )
        self._solve_blocks, self._cost = compiled["mhe_gn"], compiled["mhe_cost"]
        self._node_terms = compiled["mhe_node"]
        #: the Gauss-Newton step: one compiled call, or (in CasADi's VM) numpy and LAPACK
        self._step_solver: NativeGaussNewton | BandedGaussNewton
        if isinstance(self._solve_blocks, CompiledFunction):
            self._step_solver = NativeGaussNewton(
                self._solve_blocks.library, blocks, STEP_FRACTIONS
            )
        else:
            self._step_solver = BandedGaussNewton(self._solve_blocks, self._cost, STEP_FRACTIONS)
        self._predict = compiled["mhe_predict"]
        self._outputs = {
            g: compiled[f.name()] for g, f in zip(self.groups, offset_outputs, strict=True)
        }
        offsets = np.cumsum([0, *sizes])
        self._slot = {g: slice(offsets[i], offsets[i + 1]) for i, g in enumerate(self.groups)}
        self._group_index = {g: i for i, g in enumerate(self.groups)}
        self._std = {g: s.noise.measurement_std(g) for g in self.groups}
        # per measurement row: its group and 1 / std, for vectorised weights
        self._row_group = np.concatenate([np.full(n, i) for i, n in enumerate(sizes)])
        self._row_inverse_std = 1.0 / np.concatenate([self._std[g] for g in self.groups])
        self._bounds = self._bound_data(model, s)
        self._q = s.noise.process_std_for(model)
        self._default_initial_weight = 1.0 / initial_std_for(s.initial_std, model) ** 2
        # the arrival cost's discount per node on each state: the online parameters' past is
        # forgotten by their random walk, not by the discount (it halved their information
        # every 14 nodes, and they were left with what one window of data says)
        self._node_discount = np.where(
            np.arange(model.nx) < model.nx - len(model.online), s.discount, 1.0
        )
        # ... and of the process terms of stage j (age M - 1 - j), square-rooted: the online
        # parameters' random walk is not discounted with the data either (a discounted walk let
        # them wander in the window)
        stage_ages = np.arange(s.horizon - 1, -1, -1, dtype=float)
        self._process_discount = np.sqrt(self._node_discount[:, None] ** stage_ages[None, :])
        self._max_catch_up = s.max_catch_up or s.horizon
        self._cap = RejectionCap(s.max_consecutive_rejections)
        self._forward = ForwardReadOut(model, s.noise)
        self.reset(0.0, np.zeros(6))

    @staticmethod
    def _bound_data(model: CarModel, s: MheSettings) -> np.ndarray:
        names = model.state_names[len(model.plant.states) :]
        check_effect_state_names(s.extra_state_bounds, "extra_state_bounds")
        table = {**EXTRA_STATE_BOUNDS, **model.online.bounds, **s.extra_state_bounds}
        extra = [table.get(n, (-_UNBOUNDED, _UNBOUNDED)) for n in names]
        free = (-_UNBOUNDED,) * 3  # the pose is not bounded
        lower = per_plant_state((*free, *s.state_lower), model, "state_lower")[3:]
        upper = per_plant_state((*free, *s.state_upper), model, "state_upper")[3:]
        return np.concatenate(
            [
                per_plant_state(s.process_bound, model, "process_bound"),
                np.full(len(names), _UNBOUNDED),
                [s.bound_weight],
                lower,
                [lo for lo, _ in extra],
                upper,
                [hi for _, hi in extra],
                [s.bound_weight],
            ]
        )

    def accepts(self, sensor: str) -> bool:
        return sensor in self._slot

    def model_sensors(self) -> list[str]:
        return list(self.groups)

    def late_before(self) -> float:
        """Late data are still used while they fall inside the window."""
        return float(self._times[len(self._times) - self._active])

    def current_state(self) -> np.ndarray:
        return self.model.numeric.car_state(
            self._X[:, -1], self._command_at(self._times[-1]), self._p
        )

    # --- state of the window ------------------------------------------------------------
    def _reset_state(self, t0: float, x0: np.ndarray, covariance: np.ndarray | None) -> None:
        x = self.model.initial_state(x0, self._last_input)
        weight = self._default_initial_weight.copy()
        if covariance is not None:
            n = len(self.model.plant.states)
            plant = self.model.numeric.plant_covariance(covariance, x, self._last_input, self._p)
            weight[:n] = 1.0 / np.clip(np.diag(plant), 1e-12, None)
        self._input_history: list[InputSample] = [InputSample(t0, self._last_input)]
        self._pending: list[tuple[float, str, int, Measurement]] = []
        self._anchor = t0  # node k sits at anchor + k / rate_hz
        self._restart_window(0, x, weight)

    def _restart_window(self, node: int, x: np.ndarray, weight: np.ndarray) -> None:
        """A window of one node, grid node ``node``, holding ``x`` with prior ``weight``."""
        M, ny = self.settings.horizon, self._slot[self.groups[-1]].stop
        ng = len(self.groups)
        self._newest = node
        self._times = np.full(M + 1, self._anchor + node * self._dt)
        self._X = np.tile(x[:, None], (1, M + 1))
        self._active = 1  # nodes in use, at the end of the arrays
        self._ysum = np.zeros((ny, M + 1))
        self._count = np.zeros((ng, M + 1))
        self._tausum = np.zeros((ng, M + 1))
        self._U = np.zeros((2, M))
        self._usum = np.zeros((2 * ng, M + 1))  # commands at the stamps, per group
        self._DT = np.full((1, M), self._dt)
        self._arrival = x.copy()
        self._initial_weight = weight
        self._arrival_information: np.ndarray | None = None  # set once node 0 is marginalized
        self._last_blocks: tuple | None = None
        #: node 0's data in the last step (with online parameters only): x, y, wy, tau, ug
        self._last_node0: tuple | None = None
        self._node_covariance = np.diag(1.0 / weight)  # of the newest node, nx x nx
        self._cap.clear()

    def _command_average(self, t0: float, t1: float) -> np.ndarray:
        """Time average of the commanded input over ``[t0, t1]`` (zero-order hold)."""
        history = self._input_history
        if t1 <= t0:
            return self._command_at(t1)
        total = np.zeros(2)
        for k, sample in enumerate(history):
            start = max(sample.stamp, t0)
            end = min(history[k + 1].stamp if k + 1 < len(history) else math.inf, t1)
            if end > start:
                total += sample.u * (end - start)
        return total / (t1 - t0)

    def _command_at(self, t: float) -> np.ndarray:
        for sample in reversed(self._input_history):
            if sample.stamp <= t:
                return sample.u
        return self._input_history[0].u

    def _shift(self) -> None:
        """Append the next grid node; drop the oldest when the horizon is full."""
        M = self.settings.horizon
        if self._active == M + 1:
            self._marginalize_first_node()
        for array in (
            self._X,
            self._times,
            self._U,
            self._ysum,
            self._count,
            self._tausum,
            self._usum,
        ):
            array[..., :-1] = array[..., 1:]
        for array in (self._ysum, self._count, self._tausum, self._usum):
            array[:, -1] = 0.0
        self._newest += 1
        t_prev, t = self._times[-2], self._anchor + self._newest * self._dt
        self._times[-1] = t
        self._U[:, -1] = self._command_average(t_prev, t)
        self._X[:, -1] = self._predict(self._X[:, -2], self._U[:, -1], self._p, t - t_prev)[0]
        self._active = min(self._active + 1, M + 1)
        history = self._input_history  # keep the command active at the oldest node
        while len(history) > 1 and history[1].stamp <= self._times[M + 1 - self._active]:
            history.pop(0)

    def _attach(self, measurement: Measurement) -> None:
        """Add a measurement to the node that closes its interval ``(t_{j-1}, t_j]``.

        (Nearest-node attachment was tried: it leaves the newest node, whose estimate is
        published, only half an interval of data, and velocities came out about 30 % worse.)
        """
        times = self._times
        last = len(times) - 1
        j = last
        while j > 0 and measurement.stamp < times[j]:  # new data sits near the end
            j -= 1
        if j < last and measurement.stamp > times[j]:
            j += 1
        if j < len(times) - self._active:
            self.diagnostics.late += 1
            return
        sensor = measurement.sensor
        g = self._group_index[sensor]
        tau = measurement.stamp - times[j]
        command = self._command_at(measurement.stamp)
        if sensor.startswith("lighthouse") and not self._plausible(measurement, j, tau, command):
            return
        self._ysum[self._slot[sensor], j] += measurement.values
        self._count[g, j] += 1
        self._tausum[g, j] += tau
        self._usum[2 * g : 2 * g + 2, j] += command
        self._accept(sensor, measurement.stamp)

    def _plausible(self, measurement: Measurement, j: int, tau: float, command: np.ndarray) -> bool:
        """Outlier check of a Lighthouse sweep against the current trajectory."""
        predicted = self._outputs[measurement.sensor](self._X[:, j], command, self._p, tau)[0]
        sensor = measurement.sensor
        normalised = (measurement.values - predicted) / self._std[sensor]
        if not np.all(np.isfinite(normalised)):  # the sweep cannot reach the photodiodes
            self._reject(sensor, measurement.stamp)
            return False
        if np.max(np.abs(normalised)) > self.settings.outlier_sigma and not self._cap.override(
            sensor, normalised
        ):
            self._reject(sensor, measurement.stamp)
            return False
        self._cap.accepted(sensor)
        return True

    # --- one estimate -------------------------------------------------------------------
    def _estimate(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        """Take the data up to ``t``, create the grid nodes due by ``t``, read out at ``t``."""
        late_input = math.inf
        for item in self._events_until(t):
            if isinstance(item, InputSample):
                bisect.insort(self._input_history, item, key=lambda s: s.stamp)
                if item.stamp < self._times[-1]:
                    late_input = min(late_input, item.stamp)
            elif item.stamp <= self._times[-1]:
                self._attach(item)  # late, but inside the window
            else:
                bisect.insort(self._pending, (item.stamp, item.sensor, id(item), item))
        if late_input < math.inf:  # a command arrived after stages it acts on were made
            for j in range(len(self._times) - 1):
                if self._times[j + 1] > late_input:
                    self._U[:, j] = self._command_average(self._times[j], self._times[j + 1])
        due = math.floor((t - self._anchor) / self._dt + GRID_TOLERANCE) - self._newest
        if due > self._max_catch_up:
            self._skip_ahead(t, due)
            due = self._max_catch_up
        solves = self.settings.catch_up_solves or due
        for k in range(max(0, due)):
            self._shift()
            newest = self._times[-1]
            while self._pending and self._pending[0][0] <= newest:
                self._attach(self._pending.pop(0)[3])
            if k >= due - solves:
                for _ in range(self.settings.iterations):
                    self._gauss_newton_step()
        return self._read_out(t)

    def _read_out(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        """State and covariance at ``t``: the newest node carried forward over the data since
        it (EKF steps); a ``t`` inside the window: the node at or before it, predicted."""
        first = len(self._times) - self._active
        if t < self._times[first] - 1e-9:
            raise FieldError(
                "t",
                f"{t:.3f} s is before the oldest state the MHE keeps "
                f"({self._times[first]:.3f} s, the start of its window)",
            )
        last = len(self._times) - 1
        j = max(first, int(np.searchsorted(self._times[first:], t, side="right")) + first - 1)
        if j == last:
            recent = [m for stamp, _, _, m in self._pending if stamp <= t]
            return self._forward(
                float(self._times[j]),
                self._X[:, j],
                self._node_covariance,
                t,
                recent,
                self._command_at,
            )
        dt = t - self._times[j]
        u = self._command_average(self._times[j], t)
        x = self._predict(self._X[:, j], u, self._p, dt)[0] if dt > 1e-12 else self._X[:, j]
        return x, self._node_covariance

    def _skip_ahead(self, t: float, due: int) -> None:
        """Too many nodes due (a stalled process): restart the window ``max_catch_up`` nodes
        before ``t`` from the prediction, loosely, and drop the data before it."""
        k_start = self._newest + due - self._max_catch_up
        t_start = self._anchor + k_start * self._dt
        skipped = t_start - self._times[-1]
        u = self._command_average(self._times[-1], t_start)
        x = self.model.numeric.step(self._X[:, -1], u, self._p, skipped)
        if not np.all(np.isfinite(x)):
            x = self._X[:, -1].copy()
        dropped = 0
        while self._pending and self._pending[0][0] <= t_start:
            self._pending.pop(0)
            dropped += 1
        self.diagnostics.late += dropped
        self.diagnostics.skipped_s += skipped
        self._restart_window(k_start, x, self._default_initial_weight.copy())
        self._fallback_event(t, f"skipped {skipped:.2f} s of data after a stall")

    def _weights(self) -> tuple[np.ndarray, ...]:
        """``WP, Y, WY, TAU, UG`` of the generated functions: process weights, per node and
        sensor the mean value, measurement weights, mean stamp offset and mean command."""
        s, M = self.settings, self.settings.horizon
        first = M + 1 - self._active
        ages = np.arange(M, -1, -1, dtype=float)  # node j has age M - j
        node_discount = s.discount**ages
        wp = self._process_discount / np.sqrt(self._DT[0])[None, :] / self._q[:, None]
        wp[:, :first] = 0.0
        count = np.maximum(self._count, 1)
        row_count = self._count[self._row_group]
        y = self._ysum / count[self._row_group]
        wy = np.sqrt(row_count * node_discount) * self._row_inverse_std[:, None]
        wy[:, :first] = 0.0
        return wp, y, wy, self._tausum / count, self._usum / np.repeat(count, 2, axis=0)

    def _arrival_terms(self) -> tuple[int, np.ndarray]:
        """Index of the first node in use and the information of its prior."""
        first = self.settings.horizon + 1 - self._active
        if self._arrival_information is None:  # start-up: the initial guess, discounted
            weight = self._node_discount ** (self._active - 1) * self._initial_weight
            return first, np.diag(weight)
        return first, self._arrival_information

    def _gauss_newton_step(self) -> None:
        """One Gauss-Newton step of the window (compiled, :mod:`~crs_core.estimation.
        mhe_native`, or in numpy, :class:`~crs_core.estimation.mhe_problem.BandedGaussNewton`),
        and what follows from its outcome."""
        solver = self._step_solver
        stamp = float(self._times[-1])
        first, information = self._arrival_terms()

        def step() -> int:
            inputs = (self._X, self._U, self._DT, *self._weights(), self._p, self._bounds)
            if len(self.model.online) and first == 0:  # for the parameters' marginalisation
                self._last_node0 = tuple(
                    np.array(a[:, 0], dtype=float) for a in (self._X, *inputs[4:8])
                )
            return solver.step(inputs, first, information, self._arrival)

        outcome = step()
        if outcome == StepOutcome.NON_FINITE_COST and self._drop_undefined(solver.residuals):
            outcome = step()
        if outcome == StepOutcome.NON_FINITE_COST:
            self._restart(stamp, "non-finite cost")
        elif outcome == StepOutcome.NOT_POSITIVE_DEFINITE:
            self._fallback_event(stamp, "normal equations not positive definite")
        elif outcome == StepOutcome.NON_FINITE_STEP:
            self._restart(stamp, "non-finite step")
        else:
            self._last_blocks = solver.marginalization_blocks()
            if outcome == StepOutcome.TAKEN:
                self._X = np.array(solver.X)
                covariance = solver.covariance
                self._node_covariance = 0.5 * (covariance + covariance.T)
            else:
                self._fallback_event(
                    stamp, "Gauss-Newton step raised the cost; kept the prediction"
                )

    def _marginalize_first_node(self) -> None:
        """Fold node 0 (its arrival cost, measurements and first stage) into a prior on node 1.

        With the Gauss-Newton model of the last solve, the terms that leave the window are
        ``1/2 [d0; d1]^T [[D0, O0], [O0^T, S0]] [d0; d1] + [g0; g1]^T [d0; d1]`` in the deviations
        from its linearization point. Minimising over ``d0`` leaves ``1/2 d1^T L d1 + b^T d1``
        with ``L = S0 - O0^T D0^-1 O0`` and ``b = g1 - O0^T D0^-1 g0``: the prior mean is
        ``x1_lin - L^-1 b`` and its information ``L`` (the EKF prediction in information form),
        aged by one discount factor like every other term (not the online parameters: their
        random walk ages them).
        """
        if self._last_blocks is None:  # no solve yet or it failed: keep the current prior
            self._arrival = self._X[:, 1].copy()
            return
        information, b = self._marginal(*self._last_blocks[:5])
        if self._last_node0 is not None:
            information, b = self._keep_parameter_information(information, b)
        self._arrival = self._last_blocks[5] - np.linalg.solve(information, b)
        scale = np.sqrt(self._node_discount)
        self._arrival_information = scale[:, None] * information * scale[None, :]
        self._last_blocks = self._last_node0 = None

    def _marginal(
        self, D0: np.ndarray, O0: np.ndarray, S0: np.ndarray, g0: np.ndarray, g1: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """Node 0's terms minimised out: the information ``L`` and gradient ``b`` left on node 1
        (floored at ``1 / arrival_floor_std^2``)."""
        solved = np.linalg.solve(D0, np.column_stack([O0, g0]))
        information = S0 - O0.T @ solved[:, :-1]
        b = g1 - O0.T @ solved[:, -1]
        information = 0.5 * (information + information.T)
        information += np.eye(information.shape[0]) / self.settings.arrival_floor_std**2
        return information, b

    def _keep_parameter_information(
        self, information: np.ndarray, b: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        r"""The marginalisation with node 0's measurements at their full weight for the online
        parameters. In the window a sample's weight is discounted to :math:`\eta^M` by the
        time node 0 leaves (0.13 at M = 40, η = 0.95), which is right for the states (they
        forget) but left a parameter a seventh of each sample's information: its σ 1.7 times
        the EKF's. Node 0 is marginalised again with its measurement terms undiscounted (its
        Gauss-Newton block and gradient from ``mhe_node`` at both weights: the difference is
        what the discount took) and the result's difference added scaled by
        :math:`\eta^{M/2}` on the states' rows and columns, 1 on the parameters': the
        parameters' marginal information gains the full sample, the states' is as discounted
        as before."""
        s, nx = self.settings, self.model.nx
        assert self._last_node0 is not None and self._last_blocks is not None
        x, y, wy, tau, ug = self._last_node0
        D0, O0, S0, g0, g1, _ = self._last_blocks
        bounds = self._bounds[nx + 1 :]
        H, g = self._node_terms(x, ug, y, wy, tau, bounds, self._p)
        full_weight = wy * s.discount ** (-s.horizon / 2)  # weights are square roots
        H_full, g_full = self._node_terms(x, ug, y, full_weight, tau, bounds, self._p)
        full, b_full = self._marginal(D0 + H_full - H, O0, S0, g0 + g_full - g, g1)
        plain = nx - len(self.model.online)
        t = np.where(np.arange(nx) < plain, s.discount ** (s.horizon / 2), 1.0)
        return information + t[:, None] * (full - information) * t[None, :], b + t * (b_full - b)

    def _drop_undefined(self, residuals: np.ndarray) -> bool:
        """Drop measurements whose model output is undefined at the current trajectory.

        A trajectory far from the truth can put a photodiode outside a sweep's reach (the
        Lighthouse model's arcsin is undefined there). Those samples are removed from their
        nodes and counted as rejected. Returns whether anything was dropped.
        """
        bad = ~np.isfinite(residuals)
        if not bad.any():
            return False
        for g, group in enumerate(self.groups):
            nodes = np.nonzero(bad[self._slot[group]].any(axis=0))[0]
            for j in nodes:
                self._reject(group, float(self._times[j]), int(self._count[g, j]))
            if nodes.size:
                self._ysum[self._slot[group], nodes] = 0.0
                self._count[g, nodes] = 0.0
                self._tausum[g, nodes] = 0.0
                self._usum[2 * g : 2 * g + 2, nodes] = 0.0
        return True

    def _restart(self, stamp: float, reason: str) -> None:
        """The window cannot be solved: start over from its newest finite state, loosely.

        Keeps the commands and the data not yet attached; the newest node becomes the initial
        guess with the initial standard deviations, so new data pull the estimate back.
        """
        finite = np.nonzero(np.all(np.isfinite(self._X), axis=0))[0]
        x = self._X[:, finite[-1]].copy() if finite.size else self._arrival.copy()
        self._restart_window(self._newest, x, self._default_initial_weight.copy())
        self._fallback_event(stamp, f"{reason}; restarted from the last finite estimate")
