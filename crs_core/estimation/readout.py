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

from collections.abc import Callable, Sequence

import numpy as np

from crs_core.estimation.ekf import EkfSteps
from crs_core.estimation.noise import EstimatorNoise
from crs_core.measurements import Measurement
from crs_core.model import CarModel


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
        self._steps = EkfSteps(model, noise, gate_probability)

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
        ``(t0, t]`` (stamp order); ``command_at(s)`` is the command active at ``s``. A
        measurement is used only if it passes every check of the EKF's update."""
        now = t0
        for m in measurements:
            if m.stamp > now:
                x, P = self._steps.predict(x, P, command_at(now), m.stamp - now)
                now = m.stamp
            result = self._steps.update(x, P, command_at(now), m)
            if result.defined and result.within_gate and result.finite and result.closer:
                x, P = result.x, 0.5 * (result.P + result.P.T)
        return self._steps.predict(x, P, command_at(now), t - now)
