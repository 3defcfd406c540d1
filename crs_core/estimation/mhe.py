r"""Moving horizon estimation (paper Sec. V) as a real-time Gauss-Newton iteration.

Nodes :math:`x_0, \dots, x_M` sit at the times of the last :math:`M+1` calls of
:meth:`MovingHorizonEstimator.estimate`. The process noise is eliminated,
:math:`w_j = x_{j+1} - f(x_j, \bar u_j, \Delta_j)`, so the paper's NLP becomes a nonlinear
least-squares problem in the nodes alone,

.. math::

    \min_{x_0..x_M}\ \eta^{M_t}\|x_0 - \bar x_0\|^2_{P^{-1}}
      + \sum_j \eta^{M-1-j}\|x_{j+1} - f(x_j, \bar u_j, \Delta_j)\|^2_{(Q\Delta_j)^{-1}}
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

Each call shifts the horizon (warm start by prediction), runs one Gauss-Newton step (the
real-time iteration of the acados-based original; more with ``iterations``) and solves the
banded normal equations with LAPACK. Stage and node residuals, their Jacobians and the Hessian
blocks come from one generated and compiled function of the car model. If the cost or the step
is not finite, or the normal equations are not positive definite, the estimate falls back to
the model prediction (the warm start) and the status says so. A Lighthouse sample far from the
prediction (``outlier_sigma``) is dropped, unless ``max_consecutive_rejections`` were dropped in
a row.
"""

from __future__ import annotations

import bisect
import math
import time
from dataclasses import dataclass, field

import casadi as ca
import numpy as np
from scipy.linalg.lapack import dpbtrf, dpbtrs

from crs_core.codegen import SX_OPTIONS, compile_functions
from crs_core.estimation.base import Estimate, Estimator, RejectionCap, checked_initial_state
from crs_core.estimation.noise import EstimatorNoise
from crs_core.integrators import rk4
from crs_core.measurements import InputSample, Measurement, lighthouse_sensor
from crs_core.model import MAX_SUBSTEP, CarModel


@dataclass(frozen=True)
class MheSettings:
    """Tuning of :class:`MovingHorizonEstimator`.

    Attributes
    ----------
    horizon : int
        :math:`M`, number of stages.
    rate_hz : float
        Nominal call rate; sets the RK4 substeps of a stage (longer stages are integrated with
        proportionally longer substeps).
    discount : float
        :math:`\\eta \\in (0, 1]`.
    noise : EstimatorNoise
        Process noise :math:`Q` (per second) and measurement noise :math:`R`.
    initial_std : tuple of float
        Standard deviations of the initial guess: the arrival cost until the first node leaves
        the window (``reset`` may pass a covariance instead). From then on the arrival cost is
        the marginal of what leaves the window (see the module docstring).
    arrival_floor_std : float
        The arrival information is floored at ``1 / arrival_floor_std^2`` per state, so
        directions the dropped data did not observe stay well posed.
    state_lower, state_upper : tuple of float
        Soft bounds on ``vx, vy, omega`` (m/s, m/s, rad/s).
    process_bound : tuple of float
        Soft bound on :math:`|w|` per base state per stage.
    bound_weight : float
        Weight (1/unit) of a bound violation.
    iterations : int
        Gauss-Newton iterations per call (1 = real-time iteration).
    outlier_sigma : float
        A Lighthouse sample whose channel deviates from the prediction by more than this many
        standard deviations is dropped.
    max_consecutive_rejections : int
        After this many Lighthouse samples dropped in a row, the next one is taken.
    """

    horizon: int = 40
    rate_hz: float = 60.0
    discount: float = 0.95
    noise: EstimatorNoise = field(default_factory=EstimatorNoise)
    initial_std: tuple[float, ...] = (0.5, 0.5, 0.5, 1.0, 0.5, 2.0)
    arrival_floor_std: float = 10.0
    state_lower: tuple[float, float, float] = (-1.0, -2.0, -12.0)
    state_upper: tuple[float, float, float] = (5.0, 2.0, 12.0)
    process_bound: tuple[float, ...] = (0.05, 0.05, 0.1, 0.5, 0.5, 3.0)
    bound_weight: float = 1e3
    iterations: int = 1
    outlier_sigma: float = 30.0
    max_consecutive_rejections: int = 25

    def __post_init__(self) -> None:
        if self.horizon < 1:
            raise ValueError("horizon: must be >= 1")
        if not 0 < self.discount <= 1:
            raise ValueError("discount: must be in (0, 1]")
        if not self.rate_hz > 0:
            raise ValueError("rate_hz: must be > 0")
        if self.iterations < 1:
            raise ValueError("iterations: must be >= 1")


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


def build_mhe_function(model: CarModel, horizon: int, substeps: int, groups: list[str]):
    """One function returning the Gauss-Newton blocks of the whole horizon.

    Inputs: ``X`` (nx, M+1), ``U`` (2, M), ``DT`` (1, M), ``WP`` (nx, M) process weights,
    ``Y`` (ny, M+1), ``WY`` (ny, M+1) measurement weights, ``TAU`` (ng, M+1) offsets, ``UG``
    (2, M+1) node inputs, ``p``, ``BND`` bound data. Outputs: diagonal blocks ``D``
    (nx, nx (M+1)), upper blocks ``O`` (nx, nx M), gradient ``G`` (nx, M+1), cost, and the
    weighted measurement residuals ``RY`` (ny, M+1), and stage 0's contributions to node 1
    (``S0`` block and ``g0b`` gradient) for the marginalization of node 0.
    """
    nx, p = model.nx, model.p_sym
    xa, xb = ca.SX.sym("xa", nx), ca.SX.sym("xb", nx)
    u, dt = ca.SX.sym("u", 2), ca.SX.sym("dt")
    wp = ca.SX.sym("wp", nx)
    wbound = ca.SX.sym("wbound", nx + 1)  # per-state |w| bound, then weight
    predicted = rk4(lambda xx, uu: model.dynamics_function(xx, uu, p), xa, u, dt, substeps)
    w = xb - predicted
    r_stage = ca.vertcat(wp * w, wbound[nx] * _hinge(w, -wbound[:nx], wbound[:nx]))
    Ja, Jb = ca.jacobian(r_stage, xa), ca.jacobian(r_stage, xb)
    stage = ca.Function(
        "stage",
        [xa, xb, u, dt, wp, wbound, p],
        [Ja.T @ Ja, Ja.T @ Jb, Jb.T @ Jb, Ja.T @ r_stage, Jb.T @ r_stage, ca.sumsqr(r_stage)],
        SX_OPTIONS,
    )
    sizes = [model.output_expressions[g].numel() for g in groups]
    ny = sum(sizes)
    y, wy = ca.SX.sym("y", ny), ca.SX.sym("wy", ny)
    ng = len(groups)
    tau, ug = ca.SX.sym("tau", ng), ca.SX.sym("ug", 2 * ng)
    xstate_bounds = ca.SX.sym("xbnd", 7)  # vx, vy, omega lower; upper; weight
    predicted_y = [
        h(xa, ug[2 * g : 2 * g + 2], p, tau[g])
        for g, h in enumerate(offset_output_functions(model, groups))
    ]
    r_y = wy * (y - ca.vertcat(*predicted_y))
    r_bounds = xstate_bounds[6] * _hinge(xa[3:6], xstate_bounds[0:3], xstate_bounds[3:6])
    r_node = ca.vertcat(r_y, r_bounds)
    Jn = ca.jacobian(r_node, xa)
    node = ca.Function(
        "node",
        [xa, ug, y, wy, tau, xstate_bounds, p],
        [Jn.T @ Jn, Jn.T @ r_node, ca.sumsqr(r_node), r_y],
        SX_OPTIONS,
    )
    # the horizon is assembled in MX so the generated code loops over the (SX) stage and node
    # functions instead of inlining M copies of them
    M = horizon
    X, P = ca.MX.sym("X", nx, M + 1), ca.MX.sym("p", p.numel())
    U, DT, WP = ca.MX.sym("U", 2, M), ca.MX.sym("DT", 1, M), ca.MX.sym("WP", nx, M)
    Y, WY = ca.MX.sym("Y", ny, M + 1), ca.MX.sym("WY", ny, M + 1)
    TAU, UG = ca.MX.sym("TAU", ng, M + 1), ca.MX.sym("UG", 2 * ng, M + 1)
    BND = ca.MX.sym("BND", nx + 1 + 7)
    # serial on purpose: OpenMP gained ~10 % alone but stalled to >10 ms per call when other
    # processes (simulator, controller) shared the two cores
    stage_map, node_map = stage.map(M, "serial"), node.map(M + 1, "serial")
    s_aa, s_ab, s_bb, s_ga, s_gb, s_cost = stage_map(
        X[:, :M], X[:, 1:], U, DT, WP, ca.repmat(BND[: nx + 1], 1, M), ca.repmat(P, 1, M)
    )
    n_h, n_g, n_cost, n_ry = node_map(
        X, UG, Y, WY, TAU, ca.repmat(BND[nx + 1 :], 1, M + 1), ca.repmat(P, 1, M + 1)
    )
    zero_block = ca.MX.zeros(nx, nx)
    zero_col = ca.MX.zeros(nx, 1)
    D = n_h + ca.horzcat(s_aa, zero_block) + ca.horzcat(zero_block, s_bb)
    G = n_g + ca.horzcat(s_ga, zero_col) + ca.horzcat(zero_col, s_gb)
    cost = ca.sum2(s_cost) + ca.sum2(n_cost)
    return ca.Function(
        "mhe_gn",
        [X, U, DT, WP, Y, WY, TAU, UG, P, BND],
        [ca.densify(v) for v in (D, s_ab, G, cost, n_ry, s_bb[:, :nx], s_gb[:, 0])],
        ["X", "U", "DT", "WP", "Y", "WY", "TAU", "UG", "p", "BND"],
        ["D", "O", "G", "cost", "RY", "S0", "g0b"],
    ), sizes


class _Band:
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


class MovingHorizonEstimator(Estimator):
    """MHE over any subset of the car's sensors; call :meth:`estimate` at the MHE rate.

    Parameters
    ----------
    model : CarModel
        Estimation model.
    sensors : str or set
        Sensor groups to use, e.g. ``"lh+imu+we"``.
    settings : MheSettings, optional
    """

    def __init__(
        self, model: CarModel, sensors: frozenset[str] | str, settings: MheSettings | None = None
    ) -> None:
        super().__init__(sensors)
        self.model = model
        self.settings = s = settings or MheSettings()
        self._p = model.parameters.vector()
        self.groups = measurement_groups(model)
        self._substeps = max(1, math.ceil(1.0 / s.rate_hz / MAX_SUBSTEP - 1e-9))
        function, sizes = build_mhe_function(model, s.horizon, self._substeps, self.groups)
        tag = "_".join(e.name for e in model.effects) or "base"
        offset_outputs = offset_output_functions(model, self.groups)
        compiled = compile_functions(
            [function, model.step_function(self._substeps, "mhe_predict"), *offset_outputs],
            f"mhe_{tag}_{model.n_base_stations}bs_M{s.horizon}_n{self._substeps}",
        )
        self._solve_blocks = compiled["mhe_gn"]
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
        self._band = _Band(model.nx, s.horizon + 1)
        nx = model.nx
        self._bounds = np.concatenate(
            [
                np.resize(s.process_bound, nx),
                [s.bound_weight],
                s.state_lower,
                s.state_upper,
                [s.bound_weight],
            ]
        )
        self._q = s.noise.process_std_for(nx)
        extra = np.full(nx - 6, 0.05)
        self._default_initial_weight = 1.0 / np.concatenate([s.initial_std, extra]) ** 2
        self._cap = RejectionCap(s.max_consecutive_rejections)
        self.reset(0.0, np.zeros(6))

    def accepts(self, sensor: str) -> bool:
        return sensor in self._slot

    def late_before(self) -> float:
        """Late data are still used while they fall inside the window."""
        return float(self._times[len(self._times) - self._active])

    # --- state of the window ------------------------------------------------------------
    def reset(self, t0: float, x0: np.ndarray, covariance: np.ndarray | None = None) -> None:
        x0 = checked_initial_state(x0)
        M, ny = self.settings.horizon, self._slot[self.groups[-1]].stop
        ng = len(self.groups)
        self._times = np.full(M + 1, float(t0))
        self._X = np.tile(self.model.initial_state(x0)[:, None], (1, M + 1))
        self._active = 1  # nodes in use, at the end of the arrays
        self._ysum = np.zeros((ny, M + 1))
        self._count = np.zeros((ng, M + 1))
        self._tausum = np.zeros((ng, M + 1))
        self._U = np.zeros((2, M))
        self._usum = np.zeros((2 * ng, M + 1))  # commands at the stamps, per group
        self._DT = np.full((1, M), 1.0 / self.settings.rate_hz)
        self._arrival = self._X[:, 0].copy()
        self._initial_weight = self._default_initial_weight.copy()
        self._arrival_information: np.ndarray | None = None  # set once node 0 is marginalized
        self._last_blocks: tuple | None = None
        if covariance is not None:
            cov = np.asarray(covariance, dtype=float)
            if cov.shape != (6, 6) or not np.all(np.isfinite(cov)):
                raise ValueError("covariance: needs a finite 6 x 6 matrix")
            self._initial_weight[:6] = 1.0 / np.clip(np.diag(cov), 1e-12, None)
        self._input_history: list[InputSample] = [InputSample(float(t0), np.zeros(2))]
        self._queue.clear()
        self._processed_until = t0
        self._covariance = np.diag(1.0 / self._initial_weight)[:6, :6]
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

    def _shift(self, t: float) -> None:
        """Append a node at ``t``; drop the oldest when the horizon is full."""
        M = self.settings.horizon
        if self._active == M + 1:
            self._marginalize_first_node()
        for array in (
            self._X,
            self._times,
            self._U,
            self._DT,
            self._ysum,
            self._count,
            self._tausum,
            self._usum,
        ):
            array[..., :-1] = array[..., 1:]
        for array in (self._ysum, self._count, self._tausum, self._usum):
            array[:, -1] = 0.0
        t_prev = self._times[-2]
        dt = t - t_prev
        self._times[-1] = t
        self._DT[0, -1] = dt
        self._U[:, -1] = self._command_average(t_prev, t)
        self._X[:, -1] = self._predict(self._X[:, -2], self._U[:, -1], self._p, dt)[0]
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
        self.diagnostics.processed[sensor] += 1

    def _plausible(self, measurement: Measurement, j: int, tau: float, command: np.ndarray) -> bool:
        """Outlier check of a Lighthouse sweep against the current trajectory."""
        predicted = self._outputs[measurement.sensor](self._X[:, j], command, self._p, tau)[0]
        sensor = measurement.sensor
        normalised = (measurement.values - predicted) / self._std[sensor]
        if np.max(np.abs(normalised)) > self.settings.outlier_sigma and not self._cap.override(
            sensor, normalised
        ):
            self.diagnostics.rejected[sensor] += 1
            return False
        self._cap.accepted(sensor)
        return True

    # --- one estimate -------------------------------------------------------------------
    def estimate(self, t: float) -> Estimate:
        """Add a node at ``t``, attach the data up to ``t``, run the Gauss-Newton step(s)."""
        start = time.perf_counter()
        events = list(self._events_until(t))
        late_input = math.inf
        for item in events:
            if isinstance(item, InputSample):
                bisect.insort(self._input_history, item, key=lambda s: s.stamp)
                if item.stamp < self._times[-1]:
                    late_input = min(late_input, item.stamp)
        if late_input < math.inf:  # a command arrived after stages it acts on were made
            for j in range(len(self._times) - 1):
                if self._times[j + 1] > late_input:
                    self._U[:, j] = self._command_average(self._times[j], self._times[j + 1])
        if t > self._times[-1] + 1e-6:
            self._shift(t)
        for item in events:
            if isinstance(item, Measurement):
                self._attach(item)
        status = "ok"
        for _ in range(self.settings.iterations):
            status = self._gauss_newton_step()
        self.diagnostics.last_status = status
        self.diagnostics.last_solve_time_s = time.perf_counter() - start
        return Estimate(float(t), self._X[:6, -1].copy(), self._covariance.copy(), status)

    def _weights(self) -> tuple[np.ndarray, ...]:
        """Process and measurement weights; per node and sensor the mean value, stamp offset
        and command."""
        s, M = self.settings, self.settings.horizon
        first = M + 1 - self._active
        ages = np.arange(M, -1, -1, dtype=float)  # node j has age M - j
        node_discount = s.discount**ages
        wp = np.sqrt(s.discount ** ages[1:] / self._DT[0])[None, :] / self._q[:, None]
        wp[:, :first] = 0.0
        count = np.maximum(self._count, 1)
        row_count = self._count[self._row_group]
        y = self._ysum / count[self._row_group]
        wy = np.sqrt(row_count * node_discount) * self._row_inverse_std[:, None]
        wy[:, :first] = 0.0
        return wp, wy, y, self._tausum / count, self._usum / np.repeat(count, 2, axis=0)

    def _gauss_newton_step(self) -> str:
        M, nx = self.settings.horizon, self.model.nx
        first = M + 1 - self._active
        wp, wy, y, tau, ug = self._weights()
        D, upper, G, cost, residuals, stage0_block, stage0_gradient = self._solve_blocks(
            self._X, self._U, self._DT, wp, y, wy, tau, ug, self._p, self._bounds
        )
        if not np.isfinite(cost[0]) and self._drop_undefined(residuals):
            wp, wy, y, tau, ug = self._weights()
            D, upper, G, cost, residuals, stage0_block, stage0_gradient = self._solve_blocks(
                self._X, self._U, self._DT, wp, y, wy, tau, ug, self._p, self._bounds
            )
        if not np.isfinite(cost[0]):
            return self._restart("non-finite cost")
        if self._arrival_information is None:  # start-up: the initial guess, discounted
            weight = self.settings.discount ** (self._active - 1) * self._initial_weight
            information = np.diag(weight)
        else:
            information = self._arrival_information
        D[:, first * nx : (first + 1) * nx] += information
        G[:, first] += information @ (self._X[:, first] - self._arrival)
        for j in range(first):  # unused nodes: keep them where they are
            D[:, j * nx : (j + 1) * nx] = np.eye(nx)
            G[:, j] = 0.0
            if j < M:
                upper[:, j * nx : (j + 1) * nx] = 0.0
        ab = self._band.matrix(D, upper)
        ab[-1] += 1e-9  # Levenberg-Marquardt floor against rank deficiency
        factor, info = dpbtrf(ab)
        if info != 0:
            return self._fallback("normal equations not positive definite")
        rhs = np.zeros((ab.shape[1], 7))
        rhs[:, 0] = -G.ravel(order="F")
        rhs[M * nx + np.arange(6), 1 + np.arange(6)] = 1.0  # unit vectors of the newest node
        solution, info = dpbtrs(factor, rhs)
        step = solution[:, 0].reshape((nx, M + 1), order="F")
        covariance = solution[M * nx : M * nx + 6, 1:]
        if not np.all(np.isfinite(step)):
            return self._restart("non-finite step")
        self._last_blocks = (
            D[:, :nx].copy(),
            upper[:, :nx].copy(),
            stage0_block,
            G[:, 0].copy(),
            stage0_gradient,
            self._X[:, 1].copy(),
        )
        self._X += step
        self._covariance = 0.5 * (covariance + covariance.T)
        return "ok"

    def _marginalize_first_node(self) -> None:
        """Fold node 0 (its arrival cost, measurements and first stage) into a prior on node 1.

        With the Gauss-Newton model of the last solve, the terms that leave the window are
        ``1/2 [d0; d1]^T [[D0, O0], [O0^T, S0]] [d0; d1] + [g0; g1]^T [d0; d1]`` in the deviations
        from its linearization point. Minimising over ``d0`` leaves ``1/2 d1^T L d1 + b^T d1``
        with ``L = S0 - O0^T D0^-1 O0`` and ``b = g1 - O0^T D0^-1 g0``: the prior mean is
        ``x1_lin - L^-1 b`` and its information ``L`` (the EKF prediction in information form),
        aged by one discount factor like every other term.
        """
        if self._last_blocks is None:  # no solve yet or it failed: keep the current prior
            self._arrival = self._X[:, 1].copy()
            return
        D0, O0, S0, g0, g1, x1_lin = self._last_blocks
        solved = np.linalg.solve(D0, np.column_stack([O0, g0]))
        information = S0 - O0.T @ solved[:, :-1]
        b = g1 - O0.T @ solved[:, -1]
        information = 0.5 * (information + information.T)
        information += np.eye(information.shape[0]) / self.settings.arrival_floor_std**2
        self._arrival = x1_lin - np.linalg.solve(information, b)
        self._arrival_information = self.settings.discount * information
        self._last_blocks = None

    def _fallback(self, reason: str) -> str:
        """Keep the predicted trajectory (already in place from the shift) and say why."""
        self.diagnostics.fallbacks += 1
        return f"fallback: {reason}; estimate is the model prediction"

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
            if nodes.size:
                self.diagnostics.rejected[group] += int(self._count[g, nodes].sum())
                self._ysum[self._slot[group], nodes] = 0.0
                self._count[g, nodes] = 0.0
                self._tausum[g, nodes] = 0.0
                self._usum[2 * g : 2 * g + 2, nodes] = 0.0
        return True

    def _restart(self, reason: str) -> str:
        """The window cannot be solved: start over from its newest finite state, loosely.

        Keeps the commands and the data not yet attached; the newest node becomes the initial
        guess with the initial standard deviations, so new data pull the estimate back.
        """
        finite = np.nonzero(np.all(np.isfinite(self._X[:6]), axis=0))[0]
        x0 = self._X[:6, finite[-1]].copy() if finite.size else self._arrival[:6].copy()
        t0 = float(self._times[-1])
        history, queue = list(self._input_history), list(self._queue)
        self.reset(t0, x0)
        self._input_history, self._queue = history, queue
        self.diagnostics.fallbacks += 1
        return f"fallback: {reason}; restarted from the last finite estimate"
