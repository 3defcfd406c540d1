r"""Extended Kalman filter, asynchronous and multi-rate, on the one car model.

Between events the state is propagated with the model's RK4 step (substeps of at most
:data:`~crs_core.model.MAX_SUBSTEP`) and the covariance with its Jacobian,
:math:`P^+ = A P A^\top + \operatorname{diag}(q)^2 h`. Each measurement updates with its own
sensor model (Joseph form). Innovations whose Mahalanobis distance :math:`\nu^\top S^{-1}\nu`
exceeds the :math:`\chi^2` quantile ``gate_probability`` are rejected, unless
``max_consecutive_rejections`` of that sensor were rejected in a row and the rejected
innovations agree (:class:`~crs_core.estimation.base.RejectionCap`), so the filter recovers after
an outage has let it drift. An update that would leave the measurement further from the model
output than the prediction did (possible when the sensor model is strongly nonlinear, far from
the truth) is skipped, so an update never moves the estimate away from its data. All prediction
and update maths is generated from the model and compiled (see :mod:`crs_core.codegen`). On
request the filter sums the Gaussian log-likelihood of its innovations (the evidence the data
give a noise setting, :mod:`crs_core.estimation.noise_fit`).
"""

from __future__ import annotations

import bisect
import math
from dataclasses import dataclass

import casadi as ca
import numpy as np
from scipy.special import chdtri

from crs_core.codegen import SX_OPTIONS, compile_functions
from crs_core.errors import FieldError
from crs_core.estimation.base import Estimator, EstimatorSettings
from crs_core.estimation.noise import EstimatorNoise, initial_std_for
from crs_core.estimation.rejection import RejectionCap
from crs_core.integrators import rk4
from crs_core.measurements import InputSample, Measurement
from crs_core.model import MAX_SUBSTEP, CarModel

#: The EKF keeps its state after every event for this long (s), for queries in the past.
HISTORY_S = 2.0


@dataclass(frozen=True)
class EkfSettings(EstimatorSettings):
    """Tuning of :class:`ExtendedKalmanFilter` (plus :class:`EstimatorSettings`).

    Attributes
    ----------
    gate_probability : float
        Innovations beyond this :math:`\\chi^2` quantile are rejected.
    max_consecutive_rejections : int
        After this many rejections of one sensor in a row, a measurement whose innovation agrees
        with the previous rejected ones is accepted.
    innovation_likelihood : bool
        Sum the log-likelihood of every innovation whose model output is defined, gated or not
        (:attr:`ExtendedKalmanFilter.log_likelihood`); off by default (two log-determinants
        per update).
    """

    gate_probability: float = 0.9999
    max_consecutive_rejections: int = 25
    innovation_likelihood: bool = False

    def _check_relations(self) -> None:
        super()._check_relations()
        if not 0 < self.gate_probability < 1:
            raise FieldError("gate_probability", "must be in (0, 1)")
        if self.max_consecutive_rejections < 1:
            raise FieldError("max_consecutive_rejections", "must be >= 1")


def _wrap(angle: ca.SX) -> ca.SX:
    """Symbolic twin of :func:`crs_core.analysis.angles.wrap_angle` (differs only at ±pi)."""
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
        x_new = x + K @ innovation
        after = y - ca.substitute(expression, x, x_new)
        if sensor == "pose":
            after = ca.vertcat(after[0], after[1], _wrap(after[2]))
        functions.append(
            ca.Function(
                "ekf_update_" + sensor.replace("/", "_"),
                [x, P, u, p, y, r],
                [x_new, P_new, d2, innovation, ca.sumsqr(innovation / r), ca.sumsqr(after / r)],
                SX_OPTIONS,
            )
        )
    return functions


@dataclass(frozen=True)
class UpdateResult:
    r"""One measurement update, and which of the EKF's checks it passes.

    ``x``, ``P``: the updated state and covariance; ``normalised_innovation``: innovation over
    the measurement standard deviation; ``mahalanobis``: its :math:`\nu^\top S^{-1} \nu`;
    ``defined``: the model output exists at the prediction; ``within_gate``: the Mahalanobis
    distance is inside the gate; ``finite``: the update is finite; ``closer``: it leaves the
    measurement no further from the model output than the prediction did.
    """

    x: np.ndarray
    P: np.ndarray
    normalised_innovation: np.ndarray
    mahalanobis: float
    defined: bool
    within_gate: bool
    finite: bool
    closer: bool


class EkfSteps:
    """The EKF's compiled prediction and per-sensor update for one model and noise setting.

    Shared by :class:`ExtendedKalmanFilter` and the MHE's read-out
    (:mod:`~crs_core.estimation.readout`), so both predict and gate the same way.
    """

    def __init__(self, model: CarModel, noise: EstimatorNoise, gate_probability: float) -> None:
        self._functions = compile_functions(
            build_ekf_functions(model), f"ekf_{model.tag}_{model.n_base_stations}bs"
        )
        self._p = model.parameters.vector()
        self._q = noise.process_std_for(model)
        self._noise = noise
        # chi-square quantile: chdtri inverts the upper tail (lighter to import than scipy.stats)
        self._gates = {m: chdtri(m, 1.0 - gate_probability) for m in range(1, 9)}

    def predict(self, x: np.ndarray, P: np.ndarray, u: np.ndarray, dt: float):
        """State and covariance ``dt`` s later under command ``u`` (RK4 substeps <= 4 ms)."""
        if dt <= 0:
            return x, P
        n = max(1, math.ceil(dt / MAX_SUBSTEP - 1e-9))
        step = self._functions["ekf_predict"]
        for _ in range(n):
            x, P = step(x, P, u, self._p, dt / n, self._q)
        return x, P

    def update(
        self, x: np.ndarray, P: np.ndarray, u: np.ndarray, measurement: Measurement
    ) -> UpdateResult:
        """The Joseph-form update with ``measurement`` and its checks (nothing applied)."""
        sensor = measurement.sensor
        function = self._functions["ekf_update_" + sensor.replace("/", "_")]
        std = self._noise.measurement_std(sensor)
        x_new, P_new, d2, innovation, before, after = function(
            x, P, u, self._p, measurement.values, std
        )
        return UpdateResult(
            x_new,
            P_new,
            innovation / std,
            float(d2[0]),
            defined=bool(np.isfinite(d2[0])),
            within_gate=bool(d2[0] <= self._gates[measurement.values.size]),
            finite=bool(np.all(np.isfinite(x_new)) and np.all(np.isfinite(P_new))),
            closer=bool(after[0] <= before[0] * (1 + 1e-9) + 1e-12),
        )


class ExtendedKalmanFilter(Estimator):
    r"""EKF over any subset of the car's sensors.

    Parameters
    ----------
    model, sensors
        Estimation model (its parameters are the identified ones) and sensor groups, as for
        :class:`~crs_core.estimation.base.Estimator`.
    settings : EkfSettings, optional

    Attributes
    ----------
    log_likelihood : float
        With ``settings.innovation_likelihood``: the sum over the updates so far of
        :math:`-\tfrac12 (\nu^\top S^{-1}\nu + \log\det 2\pi S)`, the innovation
        :math:`\nu` with covariance :math:`S = H P H^\top + R` (:math:`\log\det S` from
        :math:`\det P^+ / \det P^- = \det R / \det S`); 0 otherwise.
    likelihood_terms : int
        The updates summed in :attr:`log_likelihood`.
    """

    def __init__(
        self, model: CarModel, sensors: frozenset[str] | str, settings: EkfSettings | None = None
    ) -> None:
        settings = settings or EkfSettings()
        super().__init__(sensors, model, settings)
        self.settings: EkfSettings = settings
        self._steps = EkfSteps(model, settings.noise, settings.gate_probability)
        self._p = model.parameters.vector()
        self._initial_std = initial_std_for(settings.initial_std, model)
        self._cap = RejectionCap(settings.max_consecutive_rejections)
        self.log_likelihood = 0.0
        self.likelihood_terms = 0
        self.reset(0.0, np.zeros(6))

    def accepts(self, sensor: str) -> bool:
        return sensor in self.model.output_expressions

    def model_sensors(self) -> list[str]:
        return list(self.model.output_expressions)

    def _reset_state(self, t0: float, x0: np.ndarray, covariance: np.ndarray | None) -> None:
        self._t = t0
        self._x = self.model.initial_state(x0, self._last_input)
        self._P = np.diag(self._initial_std**2)
        if covariance is not None:
            n = len(self.model.plant.states)
            self._P[:n, :n] = self.model.numeric.plant_covariance(
                covariance, self._x, self._last_input, self._p
            )
        self._u = np.array(self._last_input, dtype=float)
        self._cap.clear()
        self._history: list[tuple[float, np.ndarray, np.ndarray, np.ndarray]] = []
        self._remember()

    def current_state(self) -> np.ndarray:
        return self.model.numeric.car_state(self._x, self._u, self._p)

    def _command_at(self, t: float) -> np.ndarray:
        if t >= self._t or not self._history:
            return self._u
        k = bisect.bisect_right(self._history, t, key=lambda h: h[0]) - 1
        return self._history[max(k, 0)][3]

    # --- propagation and update -------------------------------------------------------
    def _update(self, measurement: Measurement) -> None:
        sensor, stamp = measurement.sensor, measurement.stamp
        result = self._steps.update(self._x, self._P, self._u, measurement)
        if self.settings.innovation_likelihood:
            self._add_likelihood(measurement.sensor, result)
        if not result.defined:  # the model output is undefined at the prediction
            self._reject(sensor, stamp)
            return
        if not result.within_gate and not self._cap.override(sensor, result.normalised_innovation):
            self._reject(sensor, stamp)
            return
        if not result.finite:
            self._reject(sensor, stamp)
            self._fallback_event(stamp, "update produced non-finite values; skipped")
            return
        if not result.closer:
            self._reject(sensor, stamp)
            self._fallback_event(stamp, f"{sensor} update moved away from the data; skipped")
            return
        self._cap.accepted(sensor)
        self._x, self._P = result.x, 0.5 * (result.P + result.P.T)
        self._accept(sensor, stamp)

    def _add_likelihood(self, sensor: str, result: UpdateResult) -> None:
        """Add the innovation's log-likelihood (:attr:`log_likelihood`), where it is finite."""
        if not (result.defined and result.finite and math.isfinite(result.mahalanobis)):
            return
        std = self.settings.noise.measurement_std(sensor)
        sign_before, before = np.linalg.slogdet(self._P)
        sign_after, after = np.linalg.slogdet(result.P)
        if sign_before <= 0 or sign_after <= 0:
            return
        log_det_s = 2.0 * float(np.sum(np.log(std))) + before - after
        self.log_likelihood -= 0.5 * (
            result.mahalanobis + log_det_s + std.size * math.log(2.0 * math.pi)
        )
        self.likelihood_terms += 1

    def process(self, t: float) -> None:
        """Apply every queued event stamped up to ``t``."""
        for item in self._events_until(t):
            stamp = item.stamp
            self._x, self._P = self._steps.predict(self._x, self._P, self._u, stamp - self._t)
            self._t = max(self._t, stamp)
            if isinstance(item, InputSample):
                self._u = item.u
            else:
                self._update(item)
            self._remember()

    def _remember(self) -> None:
        """Keep the state after each event for :data:`HISTORY_S` (queries in the past)."""
        self._history.append((self._t, self._x, self._P, self._u))
        if self._history[0][0] < self._t - 2 * HISTORY_S:
            cut = bisect.bisect_left(self._history, self._t - HISTORY_S, key=lambda h: h[0])
            del self._history[:cut]

    def _estimate(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        """All events up to ``t`` applied, then predicted to ``t``; a ``t`` before the newest
        event is predicted from the state kept after the last event at or before it."""
        self.process(t)
        if t >= self._t:
            return self._steps.predict(self._x, self._P, self._u, t - self._t)
        k = bisect.bisect_right(self._history, t, key=lambda h: h[0]) - 1
        if k < 0:
            oldest = self._history[0][0] if self._history else self._t
            raise FieldError(
                "t", f"{t:.3f} s is before the oldest state the EKF keeps ({oldest:.3f} s)"
            )
        stamp, x, P, u = self._history[k]
        return self._steps.predict(x, P, u, t - stamp)
