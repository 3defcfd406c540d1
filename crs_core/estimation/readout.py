r"""The MHE's read-out between grid nodes: its newest node carried forward with the new data.

The MHE's nodes sit on a fixed grid, so a query at ``t`` usually falls after the newest node
:math:`t_M`, with measurements in :math:`(t_M, t]` that no node holds yet. :class:`ForwardReadOut`
starts from the newest node's state and covariance (the MHE's Gauss-Newton marginal) and runs
extended-Kalman steps over those measurements, in stamp order, to ``t``: prediction with the
model's RK4 step and Jacobian, update per sensor (Joseph form), innovations beyond the
:math:`\chi^2` gate skipped. The functions are the EKF's, generated from the same model. Nothing
of the MHE changes: the read-out is recomputed from the node at every query, so querying never
alters the estimator.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence

import numpy as np
from scipy.stats import chi2

from crs_core.codegen import compile_functions
from crs_core.estimation.ekf import build_ekf_functions
from crs_core.estimation.noise import EstimatorNoise
from crs_core.measurements import Measurement
from crs_core.model import MAX_SUBSTEP, CarModel


class ForwardReadOut:
    """EKF steps from a node to a query time (see the module docstring).

    Parameters
    ----------
    model : CarModel
    noise : EstimatorNoise
        The MHE's process and measurement noise.
    gate_probability : float
        Innovations beyond this :math:`\\chi^2` quantile are skipped.
    """

    def __init__(
        self, model: CarModel, noise: EstimatorNoise, gate_probability: float = 0.9999
    ) -> None:
        self._functions = compile_functions(
            build_ekf_functions(model), f"ekf_{model.tag}_{model.n_base_stations}bs"
        )
        self._p = model.parameters.vector()
        self._q = noise.process_std_for(model.state_names)
        self._noise = noise
        self._gates = {m: chi2.ppf(gate_probability, m) for m in range(1, 9)}

    def __call__(
        self,
        t0: float,
        x: np.ndarray,
        P: np.ndarray,
        t: float,
        measurements: Sequence[Measurement],
        command_at: Callable[[float], np.ndarray],
    ) -> tuple[np.ndarray, np.ndarray]:
        """State and covariance at ``t`` from ``(x, P)`` at ``t0`` and the measurements in
        ``(t0, t]`` (stamp order); ``command_at(s)`` is the command active at ``s``."""
        now = t0
        for m in measurements:
            x, P = self._predict(x, P, now, m.stamp, command_at)
            now = max(now, m.stamp)
            update = self._functions["ekf_update_" + m.sensor.replace("/", "_")]
            std = self._noise.measurement_std(m.sensor)
            x_new, P_new, d2, _, before, after = update(
                x, P, command_at(now), self._p, m.values, std
            )
            accept = (
                np.isfinite(d2[0])
                and d2[0] <= self._gates[m.values.size]
                and after[0] <= before[0] * (1 + 1e-9) + 1e-12
                and np.all(np.isfinite(x_new))
            )
            if accept:
                x, P = x_new, 0.5 * (P_new + P_new.T)
        return self._predict(x, P, now, t, command_at)

    def _predict(self, x, P, t0: float, t1: float, command_at) -> tuple[np.ndarray, np.ndarray]:
        dt = t1 - t0
        if dt <= 0:
            return x, P
        n = max(1, math.ceil(dt / MAX_SUBSTEP - 1e-9))
        step, u = self._functions["ekf_predict"], command_at(t0)
        for _ in range(n):
            x, P = step(x, P, u, self._p, dt / n, self._q)
        return x, P
