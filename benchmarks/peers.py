r"""Peer estimators for comparison: filterpy's EKF and do-mpc's MHE on our model and data.

The project benchmarks its own :class:`~crs_core.estimation.ExtendedKalmanFilter` and
:class:`~crs_core.estimation.mhe.MovingHorizonEstimator` against two widely used open-source
implementations "on the same model and data". Both peers here sit behind the project's
:class:`~crs_core.estimation.base.Estimator` interface, so
:func:`sim.replay.replay` feeds them exactly what it feeds ours:

- ``filterpy-ekf`` (:class:`FilterpyEkf`): ``filterpy.kalman.ExtendedKalmanFilter`` does the
  covariance prediction and the measurement update algebra.
- ``do-mpc-mhe`` (:class:`DoMpcMhe`): a ``do_mpc.estimator.MHE`` solved by IPOPT.

Both use the same car model (:class:`~crs_core.model.CarModel`, identified parameters) and the
same noise settings (:class:`~crs_core.estimation.noise.EstimatorNoise` defaults; the MHE also
our :class:`~crs_core.estimation.mhe.MheSettings` horizon, rate and discount). The
comparison is about the estimator machinery, so the model functions themselves come from the
one CasADi definition; the EKF peer evaluates them compiled (:mod:`crs_core.codegen`), the MHE
peer hands the symbolic expressions to do-mpc, which builds its own NLP from them.
"""

from __future__ import annotations

import math
import time
import warnings
from collections.abc import Iterator
from contextlib import contextmanager

import casadi as ca
import numpy as np

from crs_core.analysis.angles import wrap_angle
from crs_core.codegen import SX_OPTIONS, compile_functions
from crs_core.estimation.base import Estimate, Estimator, checked_initial_state, sensor_group
from crs_core.estimation.ekf import EkfSettings
from crs_core.estimation.mhe import MheSettings, measurement_groups
from crs_core.integrators import rk4
from crs_core.measurements import InputSample, Measurement
from crs_core.model import MAX_SUBSTEP, CarModel

#: Peer estimator kinds accepted by :func:`make_peer`.
PEERS = ("filterpy-ekf", "do-mpc-mhe")


def _c_name(text: str) -> str:
    return "".join(c if c.isalnum() else "_" for c in text)


def _wrap_pose_residual(z: np.ndarray, predicted: np.ndarray) -> np.ndarray:
    """Pose innovation with the yaw difference wrapped to [-pi, pi) (our EKF wraps it alike)."""
    residual = z - predicted
    residual[2] = wrap_angle(residual[2])
    return residual


@contextmanager
def _quiet_do_mpc() -> Iterator[None]:
    """Silence do-mpc's import-time notes and CasADi's notice about its legacy numpy calls."""
    with warnings.catch_warnings():
        warnings.filterwarnings(
            "ignore", message=r"\s*casadi: a numpy function", category=FutureWarning
        )
        warnings.filterwarnings("ignore", message=r".*(ONNX|opcua|PyTorch)", category=UserWarning)
        yield


class FilterpyEkf(Estimator):
    r"""filterpy's extended Kalman filter, asynchronous and multi-rate, on the car model.

    Processing is the same as our :class:`~crs_core.estimation.ExtendedKalmanFilter`: events
    are taken in stamp order; before each one the filter is predicted to its stamp in RK4
    substeps of at most :data:`~crs_core.model.MAX_SUBSTEP`, then a measurement updates with
    its own sensor model. The algebra is filterpy's: per substep the state transition
    ``F`` (the Jacobian of the RK4 step) and ``Q = diag(q)^2 h`` are set and
    ``filterpy.kalman.ExtendedKalmanFilter.predict`` propagates the covariance; its
    ``predict_x`` (filterpy's documented hook for a nonlinear transition) is overridden to
    return the RK4 step's state. (``predict_update`` is not used: its prediction is linear,
    ``F x + B u``.) ``update`` is called with ``HJacobian``, ``Hx`` and ``R`` of the sensor
    (Joseph form; a wrapped yaw residual for ``pose``).

    There is no innovation gating and no check for non-finite updates: filterpy has neither.
    With our EKF's gate opened (``EkfSettings(gate_probability=1 - 1e-15)``) the two compute
    the same filter, which the tests use as a cross-check. The RK4 step, its Jacobian and the
    sensor models with their Jacobians are generated from the model and evaluated through
    :func:`crs_core.codegen.compile_functions` (the same fast model functions as ours: what is
    compared is the estimator machinery).

    Parameters
    ----------
    model, sensors
        Estimation model and sensor groups, as for :class:`~crs_core.estimation.base.Estimator`.
    settings : EkfSettings, optional
        Noise and initial standard deviations (the gate settings are not used).
    backend : {"compiled", "vm", None}, optional
        Backend of the model functions (see :func:`crs_core.codegen.compile_functions`).
    """

    def __init__(
        self,
        model: CarModel,
        sensors: frozenset[str] | str,
        settings: EkfSettings | None = None,
        backend: str | None = None,
    ) -> None:
        from filterpy.kalman import ExtendedKalmanFilter as FilterpyExtendedKalmanFilter

        class _RungeKuttaEkf(FilterpyExtendedKalmanFilter):
            """filterpy's EKF whose state prediction is a given next state (the RK4 step)."""

            def predict_x(self, u: object = 0) -> None:
                self.x = self.x_next

        super().__init__(sensors)
        self.model = model
        self.settings = settings or EkfSettings()
        self._p = model.parameters.vector()
        self._q = self.settings.noise.process_std_for(model)
        self._functions = compile_functions(
            self._build_functions(), self._library_name(model), backend
        )
        self._filter = _RungeKuttaEkf(dim_x=model.nx, dim_z=1)
        self._filter.x_next = np.zeros(model.nx)
        self.reset(0.0, np.zeros(6))

    @staticmethod
    def _library_name(model: CarModel) -> str:
        tag = "_".join(e.name for e in model.effects) or "base"
        return f"peer_filterpy_ekf_{tag}_{model.n_base_stations}bs"

    def _build_functions(self) -> list[ca.Function]:
        """RK4 step with its Jacobian, and every sensor model with its Jacobian."""
        model = self.model
        x, u, p, h = model.x_sym, model.u_sym, model.p_sym, ca.SX.sym("h")
        x_next = rk4(lambda xx, uu: model.dynamics_function(xx, uu, p), x, u, h, 1)
        functions = [
            ca.Function(
                "peer_step",
                [x, u, p, h],
                [ca.densify(x_next), ca.densify(ca.jacobian(x_next, x))],
                SX_OPTIONS,
            )
        ]
        for sensor, expression in model.output_expressions.items():
            name = _c_name(sensor)
            output = ca.densify(expression)
            functions.append(ca.Function(f"peer_h_{name}", [x, u, p], [output], SX_OPTIONS))
            jacobian = ca.densify(ca.jacobian(expression, x))
            functions.append(ca.Function(f"peer_H_{name}", [x, u, p], [jacobian], SX_OPTIONS))
        return functions

    def accepts(self, sensor: str) -> bool:
        return sensor in self.model.output_expressions

    def reset(self, t0: float, x0: np.ndarray, covariance: np.ndarray | None = None) -> None:
        x0 = checked_initial_state(x0)
        if covariance is None:
            std = np.concatenate([self.settings.initial_std, np.full(self.model.nx - 6, 0.05)])
            covariance = np.diag(std**2)
        self._filter.x = self.model.initial_state(x0)
        self._filter.P = np.array(covariance, dtype=float)
        self._t = float(t0)
        self._u = np.zeros(2)
        self._queue.clear()
        self._processed_until = t0

    def _predict(self, dt: float) -> None:
        """Predict the filter by ``dt`` s in RK4 substeps of at most ``MAX_SUBSTEP``."""
        if dt <= 0:
            return
        n = max(1, math.ceil(dt / MAX_SUBSTEP - 1e-9))
        h = dt / n
        step = self._functions["peer_step"]
        kf = self._filter
        kf.Q = np.diag(self._q**2) * h
        for _ in range(n):
            kf.x_next, kf.F = step(kf.x, self._u, self._p, h)
            kf.predict()

    def _update(self, measurement: Measurement) -> None:
        name = _c_name(measurement.sensor)
        h, H = self._functions[f"peer_h_{name}"], self._functions[f"peer_H_{name}"]
        std = self.settings.noise.measurement_std(measurement.sensor)
        residual = _wrap_pose_residual if measurement.sensor == "pose" else np.subtract
        self._filter.update(
            np.array(measurement.values),
            HJacobian=lambda x: H(x, self._u, self._p)[0],
            Hx=lambda x: h(x, self._u, self._p)[0],
            R=np.diag(std**2),
            residual=residual,
        )
        self.diagnostics.processed[measurement.sensor] += 1

    def estimate(self, t: float) -> Estimate:
        """Estimate at ``t``: all events up to ``t`` applied, then predicted to ``t``."""
        start = time.perf_counter()
        for item in self._events_until(t):
            self._predict(item.stamp - self._t)
            self._t = max(self._t, item.stamp)
            if isinstance(item, InputSample):
                self._u = item.u
            else:
                self._update(item)
        kf = self._filter
        saved = kf.x.copy(), kf.P.copy()
        self._predict(t - self._t)
        x, P = kf.x[:6].copy(), kf.P[:6, :6].copy()
        kf.x, kf.P = saved
        self.diagnostics.last_solve_time_s = time.perf_counter() - start
        return Estimate(float(t), x, P, "ok")


class DoMpcMhe(Estimator):
    r"""do-mpc's moving horizon estimator (IPOPT) on the car model; call at the MHE rate.

    A ``do_mpc.model.Model`` of type ``'discrete'`` has the state update
    ``x_{k+1} = F(x_k, u_k, dt_k) + w_k`` with ``F`` our RK4 step
    (:meth:`~crs_core.model.CarModel.step_function`, substeps sized for the nominal period
    ``1 / rate_hz``) and the measured outputs ``y_k = h(x_{k+1} + tau_k f(x_{k+1}, u_k), u_k)
    + v_k``: the stacked sensor models of the chosen groups (``imu``; ``gyro``;
    ``wheel_encoders``; ``lighthouse/<bs>/1`` and ``/2`` of every base station of the model;
    ``pose``), each evaluated at its sample's offset ``tau`` from the node (one Euler step of
    the dynamics ``f``). A ``do_mpc.estimator.MHE`` with ``n_horizon = MheSettings.horizon``
    stages uses do-mpc's default objective
    (:meth:`do_mpc.estimator.MHE.set_default_objective`)

    .. math::

        \|x_0 - \tilde x_0\|^2_{P_x} + \sum_{k<N} \|v_k\|^2_{P_{v,k}} + \|w_k\|^2_{P_{w,k}},

    with weights from our tuning passed as do-mpc (time-varying) parameters:
    :math:`P_{w,k} = \eta^{N-1-k} (\operatorname{diag}(q)^2 \Delta_k)^{-1}` (process noise
    per sqrt(s) of :class:`~crs_core.estimation.noise.EstimatorNoise`),
    :math:`P_{v,k} = \eta^{N-1-k} R^{-1}` on the channels that reported and 0 on the others,
    and :math:`P_x = \eta^{N_t} \operatorname{diag}(\sigma)^{-2}` with :math:`N_t` the stages
    in use. The arrival reference :math:`\tilde x_0` is do-mpc's, the previous solution's
    second node, except while the first node is still the initial guess, which is then the
    reference (as in ours). IPOPT starts from the previous solution as it stands (do-mpc's
    default warm start: not shifted). Known inputs are time-varying parameters (the command
    averaged over each stage), not MHE decision variables; so is the stage length
    :math:`\Delta_k` (time between calls, nominally ``1 / rate_hz``). At start-up the stages
    not yet in use have :math:`\Delta_k = 0` and :math:`w_k` fixed at 0 by its bounds
    (``lb_opt_x``/``ub_opt_x``), so they collapse onto the first node, which carries the
    initial guess, as our MHE's unused nodes do.

    Multi-rate data: each call adds one stage whose measurement vector holds, per sensor, the
    latest sample that arrived since the previous call (``combine="latest"``), or the mean of
    them all with weight :math:`n R^{-1}` and their mean offset (``combine="mean"``, as our
    MHE attaches samples to nodes). Sensors with no new sample get weight 0 for that stage.

    Where do-mpc cannot express ours exactly, this approximates:

    - The arrival cost is do-mpc's fixed quadratic: :math:`\sigma` is ``initial_std`` (or the
      ``reset`` covariance) while the initial guess is in the window, then ``arrival_std``.
      (Ours marginalizes what leaves the window.)
    - With ``combine="latest"`` the older samples of an interval are dropped (counted as
      ``ignored``).
    - The sensor models see the stage's average input, not the command at their stamp.
    - No outlier rejection and no soft bounds on speeds or on ``w`` (not in do-mpc's default
      objective).
    - do-mpc reports no covariance: the returned covariance is a placeholder, the arrival
      prior :math:`\operatorname{diag}(\sigma)^2` in force.

    Parameters
    ----------
    model, sensors
        Estimation model (its parameters are fixed, not estimated) and sensor groups, as for
        :class:`~crs_core.estimation.base.Estimator`.
    settings : MheSettings, optional
        Horizon, nominal rate, discount and noise (nothing else of it is used).
    combine : {"latest", "mean"}
        How the samples of one sensor between two calls become the stage's measurement.
    initial_std : tuple of float
        Standard deviations of the initial guess of ``[x, y, yaw, vx, vy, omega]`` (those of
        our EKF and MHE).
    arrival_std : tuple of float
        Standard deviations of the arrival cost once the initial guess has left the window.
    max_iter : int
        IPOPT's iteration limit (IPOPT's default is 3000). A real-time estimator needs a bound:
        with the car at rest (start-up, Lighthouse only) IPOPT was seen to reach the optimum
        and then stall short of its 1e-8 tolerance for all 3000 iterations (30 s). A capped
        solve returns IPOPT's last iterate with the status ``ipopt: Maximum_Iterations_Exceeded``.
    """

    def __init__(
        self,
        model: CarModel,
        sensors: frozenset[str] | str,
        settings: MheSettings | None = None,
        combine: str = "latest",
        initial_std: tuple[float, ...] = (0.5, 0.5, 0.5, 1.0, 0.5, 2.0),
        arrival_std: tuple[float, ...] = (0.05, 0.05, 0.05, 0.3, 0.3, 1.0),
        max_iter: int = 100,
    ) -> None:
        if combine not in ("latest", "mean"):
            raise ValueError(f"combine: {combine!r} must be 'latest' or 'mean'")
        super().__init__(sensors)
        self.model = model
        self.combine = combine
        self.max_iter = int(max_iter)
        self.settings = s = settings or MheSettings()
        self.groups = [g for g in measurement_groups(model) if sensor_group(g) in self.sensors]
        sizes = [model.output_expressions[g].numel() for g in self.groups]
        offsets = np.cumsum([0, *sizes])
        self._slot = {g: slice(offsets[i], offsets[i + 1]) for i, g in enumerate(self.groups)}
        self._ny = int(offsets[-1])
        self._inverse_variance = {g: 1.0 / s.noise.measurement_std(g) ** 2 for g in self.groups}
        self._q = s.noise.process_std_for(model)
        extra = np.full(model.nx - 6, 0.05)
        self._default_initial_weight = 1.0 / np.concatenate([initial_std, extra]) ** 2
        self._arrival_weight = 1.0 / np.concatenate([arrival_std, extra]) ** 2
        self._nominal_weight = s.rate_hz / self._q**2
        self._substeps = max(1, math.ceil(1.0 / s.rate_hz / MAX_SUBSTEP - 1e-9))
        self._build()
        self.reset(0.0, np.zeros(6))

    # --- the do-mpc problem -------------------------------------------------------------
    def _build(self) -> None:
        with _quiet_do_mpc():
            import do_mpc

        model, s, nx = self.model, self.settings, self.model.nx
        p = ca.DM(model.parameters.vector())
        dm = do_mpc.model.Model("discrete", "SX")
        x = dm.set_variable("_x", "x", shape=(nx, 1))
        u = dm.set_variable("_tvp", "u", shape=(2, 1))
        dt = dm.set_variable("_tvp", "dt", shape=(1, 1))
        dm.set_variable("_tvp", "wv", shape=(self._ny, 1))
        dm.set_variable("_tvp", "ww", shape=(nx, 1))
        tau = dm.set_variable("_tvp", "tau", shape=(len(self.groups), 1))
        dm.set_variable("_p", "arrival_weight", shape=(nx, 1))
        step = model.step_function(self._substeps, "peer_mhe_step")
        dm.set_rhs("x", step(x, u, p, dt), process_noise=True)
        xdot = model.dynamics_function(x, u, p)
        for g, group in enumerate(self.groups):
            h = model.output_function(group)
            dm.set_meas(_c_name(group), h(x + tau[g] * xdot, u, p), meas_noise=True)
        dm.setup()

        mhe = do_mpc.estimator.MHE(dm)
        mhe.settings.n_horizon = s.horizon
        mhe.settings.t_step = 1.0 / s.rate_hz
        mhe.settings.store_lagr_multiplier = False
        mhe.settings.store_solver_stats = []
        mhe.settings.supress_ipopt_output()  # print_level 0, sb yes, print_time 0
        # CasADi's notes on NaN at IPOPT's trial points (it backtracks from them) stay quiet
        mhe.settings.nlpsol_opts["show_eval_warnings"] = False
        mhe.settings.nlpsol_opts["ipopt.max_iter"] = self.max_iter
        mhe.set_default_objective(
            ca.diag(dm.p["arrival_weight"]),
            P_v=ca.diag(dm.tvp["wv"]),
            P_w=ca.diag(dm.tvp["ww"]),
        )
        self._tvp = mhe.get_tvp_template()
        self._p_values = mhe.get_p_template()
        self._y_values = mhe.get_y_template()
        mhe.set_tvp_fun(lambda _t: self._tvp)
        mhe.set_p_fun(lambda _t: self._p_values)
        mhe.set_y_fun(lambda _t: self._y_values)
        with _quiet_do_mpc():
            mhe.setup()
        self._mhe = mhe
        # flat indices into the templates, so each call fills them with numpy
        N = s.horizon
        self._tvp_index = {
            key: np.array([self._tvp.f["_tvp", k, key] for k in range(N)])
            for key in ("u", "dt", "wv", "ww", "tau")
        }
        self._y_index = np.array(
            [
                np.concatenate([self._y_values.f["y_meas", k, _c_name(g)] for g in self.groups])
                for k in range(N)
            ]
        )

    def accepts(self, sensor: str) -> bool:
        return sensor in self._slot

    def reset(self, t0: float, x0: np.ndarray, covariance: np.ndarray | None = None) -> None:
        x0 = checked_initial_state(x0)
        N = self.settings.horizon
        self._initial_weight = self._default_initial_weight.copy()
        if covariance is not None:
            cov = np.asarray(covariance, dtype=float)
            if cov.shape != (6, 6) or not np.all(np.isfinite(cov)):
                raise ValueError("covariance: needs a finite 6 x 6 matrix")
            self._initial_weight[:6] = 1.0 / np.clip(np.diag(cov), 1e-12, None)
        self._x_initial = self.model.initial_state(x0)
        self._t = float(t0)
        self._calls = 0
        self._Y = np.zeros((N, self._ny))
        self._WV = np.zeros((N, self._ny))  # n R^-1 on reported channels, before discounting
        self._U = np.zeros((N, 2))
        self._DT = np.zeros(N)
        self._TAU = np.zeros((N, len(self.groups)))
        self._inputs: list[InputSample] = [InputSample(float(t0), np.zeros(2))]
        covariance_now = np.diag(1.0 / self._initial_weight)[:6, :6]
        self._last = Estimate(float(t0), x0.copy(), covariance_now, "ok")
        self._queue.clear()
        self._processed_until = t0
        mhe = self._mhe
        mhe.reset_history()
        mhe.opt_x_num.master = ca.DM.zeros(mhe.n_opt_x)
        mhe.x0 = self._x_initial
        mhe.set_initial_guess()
        mhe.flags["initial_run"] = False  # no stale multipliers for the first solve
        for k in range(N):  # stages not in use: x_{k+1} = x_k exactly (dt = 0, w fixed at 0)
            mhe.lb_opt_x["_w", k] = np.zeros(self.model.nx)
            mhe.ub_opt_x["_w", k] = np.zeros(self.model.nx)

    def _command_average(self, t0: float, t1: float) -> np.ndarray:
        """Time average of the commanded input over ``[t0, t1]`` (zero-order hold)."""
        total = np.zeros(2)
        for k, sample in enumerate(self._inputs):
            end = self._inputs[k + 1].stamp if k + 1 < len(self._inputs) else math.inf
            overlap = min(end, t1) - max(sample.stamp, t0)
            if overlap > 0:
                total += sample.u * overlap
        while len(self._inputs) > 1 and self._inputs[1].stamp <= t1:
            self._inputs.pop(0)  # the command in force at t1 stays
        return total / (t1 - t0)

    def _add_stage(self, t: float, samples: dict[str, list[Measurement]]) -> None:
        """Shift the window by one stage ending at ``t`` holding ``samples``."""
        for buffer in (self._Y, self._WV, self._U, self._DT, self._TAU):
            buffer[:-1] = buffer[1:]
            buffer[-1] = 0.0
        for g, sensor in enumerate(self.groups):
            items = samples.get(sensor)
            if not items:
                continue
            if self.combine == "latest" and len(items) > 1:
                self.diagnostics.ignored[sensor] += len(items) - 1  # superseded in the stage
                items = items[-1:]
            slot = self._slot[sensor]
            self._Y[-1, slot] = np.mean([m.values for m in items], axis=0)
            self._WV[-1, slot] = len(items) * self._inverse_variance[sensor]
            self._TAU[-1, g] = np.mean([m.stamp for m in items]) - t
            self.diagnostics.processed[sensor] += len(items)
        self._U[-1] = self._command_average(self._t, t)
        self._DT[-1] = t - self._t
        self._t = float(t)
        self._calls += 1

    def _fill_templates(self) -> np.ndarray:
        """Write inputs, stage lengths, weights and measurements into do-mpc's templates.

        Returns the arrival weight in force (undiscounted).
        """
        s, N = self.settings, self.settings.horizon
        active = min(self._calls, N)
        first = N - active
        discount = s.discount ** np.arange(N - 1, -1, -1, dtype=float)  # stage k: eta^(N-1-k)
        ww = np.tile(self._nominal_weight, (N, 1))  # unused: w is fixed at 0 by its bounds
        ww[first:] = discount[first:, None] / (self._q[None, :] ** 2 * self._DT[first:, None])
        tvp = np.zeros(self._tvp.master.numel())
        tvp[self._tvp_index["u"]] = self._U
        tvp[self._tvp_index["dt"]] = self._DT[:, None]
        tvp[self._tvp_index["wv"]] = discount[:, None] * self._WV
        tvp[self._tvp_index["ww"]] = ww
        tvp[self._tvp_index["tau"]] = self._TAU
        self._tvp.master = ca.DM(tvp)
        y = np.zeros(self._y_values.master.numel())
        y[self._y_index] = self._Y
        self._y_values.master = ca.DM(y)
        initial_in_window = self._calls <= N
        weight = self._initial_weight if initial_in_window else self._arrival_weight
        self._p_values.master = ca.DM(s.discount**active * weight)
        if initial_in_window:
            mhe = self._mhe
            # do-mpc takes the arrival reference from node 1 of the previous solution; while
            # node 0 is still the initial time, the reference is the initial guess
            mhe.opt_x_num["_x", 1, -1] = self._x_initial
            # stage ``first`` comes into use now: free its w (fixed at 0 by ``reset``)
            mhe.lb_opt_x["_w", first] = np.full(self.model.nx, -np.inf)
            mhe.ub_opt_x["_w", first] = np.full(self.model.nx, np.inf)
        return weight

    def estimate(self, t: float) -> Estimate:
        """Add a stage ending at ``t`` with the data since the previous call, solve with IPOPT.

        A call at a time not after the previous one returns the previous estimate and leaves
        the new data queued.
        """
        if t <= self._t + 1e-9:
            return self._last
        start = time.perf_counter()
        samples: dict[str, list[Measurement]] = {}
        for item in self._events_until(t):
            if isinstance(item, InputSample):
                self._inputs.append(item)
            else:
                samples.setdefault(item.sensor, []).append(item)
        self._add_stage(t, samples)
        weight = self._fill_templates()
        mhe = self._mhe
        if mhe.data._time.shape[0] >= self.settings.horizon:
            mhe.reset_history()  # do-mpc's run log grows by appending; we do not use it
        with _quiet_do_mpc():
            x = np.asarray(mhe.make_step(self._Y[-1])).ravel()
        stats = mhe.solver_stats
        status = "ok" if stats.get("success") else f"ipopt: {stats.get('return_status')}"
        if not np.all(np.isfinite(x)):
            self.diagnostics.fallbacks += 1
            status = "fallback: non-finite solution; previous estimate kept"
            x = self._last.x
        self.diagnostics.last_status = status
        self.diagnostics.last_solve_time_s = time.perf_counter() - start
        covariance = np.diag(1.0 / weight)[:6, :6]
        self._last = Estimate(float(t), x[:6].copy(), covariance, status)
        return self._last


def make_peer(kind: str, sensors: str, rate_hz: float = 60.0) -> Estimator:
    """A peer estimator on the Chronos model with our default tuning.

    Parameters
    ----------
    kind : {"filterpy-ekf", "do-mpc-mhe"}
        Which peer (:data:`PEERS`).
    sensors : str
        Sensor groups, e.g. ``"lh+imu+we"``.
    rate_hz : float
        Rate at which :meth:`Estimator.estimate` will be called (sets the MHE's nominal
        period; the EKF is event-driven and ignores it).

    Returns
    -------
    Estimator
    """
    if kind == "filterpy-ekf":
        return FilterpyEkf(CarModel(), sensors)
    if kind == "do-mpc-mhe":
        return DoMpcMhe(CarModel(), sensors, MheSettings(rate_hz=rate_hz))
    raise ValueError(f"peer: unknown kind {kind!r} ({', '.join(PEERS)})")


__all__ = ["PEERS", "DoMpcMhe", "FilterpyEkf", "make_peer"]
