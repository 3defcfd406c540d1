r"""Extended Kalman filter, asynchronous and multi-rate, on the one car model.

Between events the state is propagated with the model's RK4 step (substeps of at most
:data:`~crs_core.model.MAX_SUBSTEP`) and the covariance with its Jacobian,
:math:`P^+ = A P A^\top + \operatorname{diag}(q)^2 h`. Each measurement updates with its own
sensor model (Joseph form). Innovations whose Mahalanobis distance :math:`\nu^\top S^{-1}\nu`
exceeds the :math:`\chi^2` quantile ``gate_probability`` are rejected, unless
``max_consecutive_rejections`` of that sensor were rejected in a row: then the next one is
accepted, so the filter recovers after an outage has let it drift. All prediction and update
maths is generated from the model and compiled (see :mod:`crs_core.codegen`).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import casadi as ca
import numpy as np
from scipy.stats import chi2

from crs_core.codegen import SX_OPTIONS, compile_functions
from crs_core.estimation.base import (
    Estimate,
    Estimator,
    RejectionCap,
    checked_initial_state,
)
from crs_core.estimation.noise import EstimatorNoise
from crs_core.integrators import rk4
from crs_core.measurements import InputSample, Measurement
from crs_core.model import MAX_SUBSTEP, CarModel


@dataclass(frozen=True)
class EkfSettings:
    """Tuning of :class:`ExtendedKalmanFilter`.

    Attributes
    ----------
    noise : EstimatorNoise
        Assumed process and measurement noise.
    gate_probability : float
        Innovations beyond this :math:`\\chi^2` quantile are rejected.
    max_consecutive_rejections : int
        After this many rejections of one sensor in a row, its next measurement is accepted.
    initial_std : tuple of float
        Initial standard deviation of ``[x, y, yaw, vx, vy, omega]`` when ``reset`` gets none.
    """

    noise: EstimatorNoise = field(default_factory=EstimatorNoise)
    gate_probability: float = 0.9999
    max_consecutive_rejections: int = 25
    initial_std: tuple[float, ...] = (0.5, 0.5, 0.5, 1.0, 0.5, 2.0)


def _wrap(angle: ca.SX) -> ca.SX:
    return ca.atan2(ca.sin(angle), ca.cos(angle))


def build_ekf_functions(model: CarModel) -> list[ca.Function]:
    """Predict and per-sensor update functions, generated from the model."""
    x, u, p = model.x_sym, model.u_sym, model.p_sym
    nx = model.nx
    P = ca.SX.sym("P", nx, nx)
    h = ca.SX.sym("h")
    q = ca.SX.sym("q", nx)
    x_next = rk4(lambda xx, uu: model.dynamics_function(xx, uu, p), x, u, h, 1)
    A = ca.jacobian(x_next, x)
    P_next = A @ P @ A.T + ca.diag(q**2) * h
    functions = [ca.Function("ekf_predict", [x, P, u, p, h, q], [x_next, P_next], SX_OPTIONS)]
    for sensor, expression in model.output_expressions.items():
        m = expression.numel()
        y = ca.SX.sym("y", m)
        r = ca.SX.sym("r", m)
        H = ca.jacobian(expression, x)
        innovation = y - expression
        if sensor == "pose":
            innovation = ca.vertcat(innovation[0], innovation[1], _wrap(innovation[2]))
        S = H @ P @ H.T + ca.diag(r**2)
        S_inv = ca.inv(S)
        K = P @ H.T @ S_inv
        I_KH = ca.DM.eye(nx) - K @ H
        P_new = I_KH @ P @ I_KH.T + K @ ca.diag(r**2) @ K.T
        d2 = innovation.T @ S_inv @ innovation
        functions.append(
            ca.Function(
                "ekf_update_" + sensor.replace("/", "_"),
                [x, P, u, p, y, r],
                [x + K @ innovation, P_new, d2, innovation],
                SX_OPTIONS,
            )
        )
    return functions


class ExtendedKalmanFilter(Estimator):
    """EKF over any subset of the car's sensors.

    Parameters
    ----------
    model : CarModel
        Estimation model (its parameters are the identified ones).
    sensors : str or set
        Sensor groups to use, e.g. ``"lh+imu+we"``.
    settings : EkfSettings, optional
    """

    def __init__(
        self, model: CarModel, sensors: frozenset[str] | str, settings: EkfSettings | None = None
    ) -> None:
        super().__init__(sensors)
        self.model = model
        self.settings = settings or EkfSettings()
        self._p = model.parameters.vector()
        tag = "_".join(e.name for e in model.effects) or "base"
        self._functions = compile_functions(
            build_ekf_functions(model), f"ekf_{tag}_{model.n_base_stations}bs"
        )
        self._q = self.settings.noise.process_std_for(model.nx)
        self._gates = {m: chi2.ppf(self.settings.gate_probability, m) for m in range(1, 9)}
        self._cap = RejectionCap(self.settings.max_consecutive_rejections)
        self.reset(0.0, np.zeros(6))

    def accepts(self, sensor: str) -> bool:
        return sensor in self.model.output_expressions

    def reset(self, t0: float, x0: np.ndarray, covariance: np.ndarray | None = None) -> None:
        x0 = checked_initial_state(x0)
        self._t = float(t0)
        self._x = self.model.initial_state(x0)
        if covariance is None:
            std = np.concatenate([self.settings.initial_std, np.full(self.model.nx - 6, 0.05)])
            covariance = np.diag(std**2)
        self._P = np.array(covariance, dtype=float)
        self._u = np.zeros(2)
        self._queue.clear()
        self._processed_until = t0
        self._cap.clear()

    # --- propagation and update -------------------------------------------------------
    def _predict(self, x: np.ndarray, P: np.ndarray, dt: float):
        if dt <= 0:
            return x, P
        n = max(1, math.ceil(dt / MAX_SUBSTEP - 1e-9))
        step = self._functions["ekf_predict"]
        for _ in range(n):
            x, P = step(x, P, self._u, self._p, dt / n, self._q)
        return x, P

    def _update(self, measurement: Measurement) -> None:
        function = self._functions["ekf_update_" + measurement.sensor.replace("/", "_")]
        std = self.settings.noise.measurement_std(measurement.sensor)
        x_new, P_new, d2, innovation = function(
            self._x, self._P, self._u, self._p, measurement.values, std
        )
        sensor = measurement.sensor
        if d2[0] > self._gates[measurement.values.size] and not self._cap.override(
            sensor, innovation / std
        ):
            self.diagnostics.rejected[sensor] += 1
            return
        if not (np.all(np.isfinite(x_new)) and np.all(np.isfinite(P_new))):
            self.diagnostics.rejected[measurement.sensor] += 1
            self.diagnostics.last_status = "update produced non-finite values; skipped"
            return
        self._cap.accepted(sensor)
        self._x, self._P = x_new, 0.5 * (P_new + P_new.T)
        self.diagnostics.processed[measurement.sensor] += 1

    def process(self, t: float) -> None:
        """Apply every queued event stamped up to ``t``."""
        for item in self._events_until(t):
            stamp = item.stamp
            self._x, self._P = self._predict(self._x, self._P, stamp - self._t)
            self._t = max(self._t, stamp)
            if isinstance(item, InputSample):
                self._u = item.u
            else:
                self._update(item)

    def estimate(self, t: float) -> Estimate:
        """Estimate at ``t``: all events up to ``t`` applied, then predicted to ``t``."""
        start = time.perf_counter()
        self.process(t)
        x, P = self._predict(self._x, self._P, t - self._t)
        self.diagnostics.last_solve_time_s = time.perf_counter() - start
        return Estimate(float(t), x[:6].copy(), P[:6, :6].copy(), "ok")
