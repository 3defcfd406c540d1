r"""Prediction-error fit: the parameters that minimise the open-loop validation metric itself.

The FIE (:mod:`~crs_core.identification.problem`) explains every measurement with a state
trajectory and process noise; the validation metric (:mod:`~crs_core.identification.validation`)
asks something else, how far open-loop predictions over a horizon drift from the reference. This
module fits the chosen parameters :math:`\theta` to that metric directly on the training data:

.. math:: \min_{\theta \in \Theta} \sum_{j \in S} \sum_{i \in (t_j, t_j + H]}
          \| p(t_i; x_j, \theta) - p_\mathrm{ref}(t_i) \|^2

over every ``every``-th start :math:`j` (start states fixed: an EKF run with the prior), with
bounded trust-region least squares (``scipy.optimize.least_squares``, finite-difference
Jacobian). No parameter vector of the model structure predicts the training data better under
this metric, so its error on held-out data is a *floor* for identified parameters of that
structure: a gap between the FIE's held-out error and this floor is identification, the rest is
the model (a missing effect, or noise in the reference). It is a diagnostic, slow by design
(one open-loop prediction per function evaluation), not a replacement for the FIE.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares

from crs_core.dataset import Dataset
from crs_core.errors import FieldError
from crs_core.identification.problem import check_fit, prior_std
from crs_core.identification.validation import (
    DEFAULT_HORIZON_S,
    OpenLoopPredictor,
    position_errors,
)
from crs_core.model import CarModel
from crs_core.parameters import ParameterSet

#: Every how many samples a prediction starts in the fit (1 = every sample, as validation).
DEFAULT_EVERY = 4


@dataclass
class PredictionErrorFit:
    """Result of :func:`fit_prediction_error`.

    Attributes
    ----------
    parameters : ParameterSet, the model's parameters with the fitted values
    fit : tuple of str, the fitted names
    rmse_initial_m, rmse_m : float, the training metric (position RMSE over the horizon, m) at
        the prior and at the optimum (over the fit's starts)
    evaluations : int, open-loop predictions evaluated (Jacobian columns included)
    time_s : float, wall time
    status : str, the optimiser's message
    """

    parameters: ParameterSet
    fit: tuple[str, ...]
    rmse_initial_m: float
    rmse_m: float
    evaluations: int
    time_s: float
    status: str


def fit_prediction_error(
    dataset: Dataset,
    model: CarModel,
    fit: Sequence[str],
    horizon_s: float = DEFAULT_HORIZON_S,
    every: int = DEFAULT_EVERY,
    max_iterations: int = 30,
    progress: Callable[[int, float], None] | None = None,
) -> PredictionErrorFit:
    """Fit ``fit`` (names of ``model``'s parameters; prior = the model's values) to the open-loop
    position error on ``dataset``; ``progress(evaluation, rmse_m)`` after each evaluation."""
    check_fit(model, fit)
    if every < 1:
        raise FieldError("every", f"must be >= 1, got {every}")
    started = time.perf_counter()
    predictor = OpenLoopPredictor(dataset, model, horizon_s, every=every)
    parameters = model.parameters
    columns = [parameters.index(name) for name in fit]
    theta0 = np.array([parameters.value(name) for name in fit])
    lower = np.array([parameters[name].lower for name in fit])
    upper = np.array([parameters[name].upper for name in fit])
    scale = np.array([prior_std(model, name) for name in fit])
    base = parameters.vector()
    evaluations = 0

    def residuals(theta: np.ndarray) -> np.ndarray:
        nonlocal evaluations
        p = base.copy()
        p[columns] = theta
        error = position_errors(predictor.predict(p, outputs=False))
        error = error[np.isfinite(error[..., 0])]
        evaluations += 1
        r = error.ravel() / np.sqrt(len(error))
        if progress is not None:
            progress(evaluations, float(np.linalg.norm(r)))
        return r

    rmse_initial = float(np.linalg.norm(residuals(theta0)))
    span = upper - lower
    start = np.clip(theta0, lower + 1e-6 * span, upper - 1e-6 * span)
    solution = least_squares(
        residuals,
        start,
        bounds=(lower, upper),
        x_scale=scale,
        diff_step=1e-3,
        max_nfev=max_iterations,
    )
    return PredictionErrorFit(
        parameters=parameters.updated(dict(zip(fit, solution.x.tolist(), strict=True))),
        fit=tuple(fit),
        rmse_initial_m=rmse_initial,
        rmse_m=float(np.linalg.norm(solution.fun)),
        evaluations=evaluations,
        time_s=time.perf_counter() - started,
        status=str(solution.message),
    )
