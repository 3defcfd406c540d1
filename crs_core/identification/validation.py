"""Open-loop validation of identified parameters (paper, Sec. VII-B).

From every sample ``j`` with a full horizon ahead (``t_j + horizon <= t_{L-1}``), the model is
simulated open loop under the recorded commands (held between samples, RK4 substeps no longer
than :data:`~crs_core.model.car_model.MAX_SUBSTEP`, aligned with the sample stamps), starting
from the state an EKF with the same parameters estimated at ``t_j``. The prediction is compared
at every sample inside the horizon ``(t_j, t_j + horizon]``:

* **position RMSE** (the paper's metric): the square root of the mean, over every start ``j``
  and every sample ``i`` inside its horizon, of the squared planar distance
  ``|p_pred(t_i; j) - p_ref(t_i)|^2``; the reference ``p_ref`` is the dataset's ``x`` (simulation
  truth, or on the real runs the car's own Lighthouse-based on-line estimate, *not* motion
  capture) or, without one, each sample's Lighthouse fix
  (:func:`~crs_core.identification.reference.position_reference`). The RMSE at the horizon's
  end alone is reported too.
* **per-channel RMS**: the same mean over the model's predicted sensor outputs minus the
  measured ``y`` (NaN samples skipped), per dataset column.

All starts are simulated at once (the model's RK4 step mapped over them).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import casadi as ca
import numpy as np

from crs_core.codegen import compile_functions
from crs_core.dataset import Y_CHANNELS, Dataset
from crs_core.errors import FieldError
from crs_core.identification.data import Y_LAYOUT, input_segments
from crs_core.identification.reference import position_reference
from crs_core.identification.solve import initial_trajectory
from crs_core.model import CarModel
from crs_core.model.car_model import MAX_SUBSTEP
from crs_core.parameters import ParameterSet

#: The paper's open-loop horizon, s.
DEFAULT_HORIZON_S = 2.0
#: The compiled maps take a multiple of this many starts (see :class:`OpenLoopPredictor`).
CAPACITY_STEP = 128


@dataclass
class OpenLoopPrediction:
    """Open-loop predictions from every start.

    Attributes
    ----------
    horizon_s : float
    starts : (S,) sample index of each start
    steps : int, samples per horizon (the most any start has)
    positions : (S, steps, 2) predicted x, y at samples ``start + 1 ... start + steps`` (NaN
        beyond the horizon)
    outputs : (S, steps, 13) predicted measurements (dataset columns), NaN beyond the horizon
    reference : (S, steps, 2) the reference positions at those samples (NaN where none)
    """

    horizon_s: float
    starts: np.ndarray
    steps: int
    positions: np.ndarray
    outputs: np.ndarray
    reference: np.ndarray


class OpenLoopPredictor:
    """Open-loop predictions over ``horizon_s`` from every ``every``-th start of ``dataset``.

    The start states are fixed at construction (an EKF run with ``model``'s parameters, or
    ``states``); the compiled RK4 step is built once, so :meth:`predict` can be called with many
    parameter vectors (the prediction-error fit does).
    """

    def __init__(
        self,
        dataset: Dataset,
        model: CarModel,
        horizon_s: float = DEFAULT_HORIZON_S,
        states: np.ndarray | None = None,
        every: int = 1,
    ) -> None:
        if not horizon_s > 0:
            raise FieldError("horizon", f"must be > 0 s, got {horizon_s}")
        if dataset.u is None:
            raise FieldError("dataset", "has no inputs (u.npy); open-loop prediction needs them")
        t = dataset.t
        if t[-1] - t[0] < horizon_s:
            raise FieldError(
                "horizon", f"{horizon_s} s is longer than the dataset ({t[-1] - t[0]:.2f} s)"
            )
        self.dataset, self.model, self.horizon_s = dataset, model, horizon_s
        self._u: np.ndarray = dataset.u
        self.reference = position_reference(dataset)
        self.states = initial_trajectory(dataset, model) if states is None else states
        self.end = np.searchsorted(t, t + horizon_s + 1e-9, side="right") - 1  # last in horizon
        self.starts = np.flatnonzero(t + horizon_s <= t[-1] + 1e-9)[::every]
        self.steps = int(np.max(self.end[self.starts] - self.starts))
        self._sub_u, self._sub_h = _substeps(dataset)
        n = len(self.starts)
        # compiled for the number of starts rounded up to a multiple of CAPACITY_STEP (a
        # compile per exact number made 20 of them in the test suite); the columns past n
        # repeat the last start
        capacity = CAPACITY_STEP * math.ceil(n / CAPACITY_STEP)
        self._padded = np.concatenate((self.starts, np.full(capacity - n, self.starts[-1])))
        functions = compile_functions(
            [
                model.step_function(1, "rk4_validation").map(
                    "rk4_validation_map", "serial", capacity, [], []
                ),
                ca.Function(
                    "h_validation",
                    [model.x_sym, model.u_sym, model.p_sym],
                    [ca.vertcat(*(model.output_expressions[name] for name, _ in Y_LAYOUT))],
                ).map("h_validation_map", "serial", capacity, [], []),
            ],
            f"fie_validation_{model.tag}_{model.n_base_stations}bs_{capacity}",
        )
        self._step, self._output = functions["rk4_validation_map"], functions["h_validation_map"]

    def predict(
        self,
        p: np.ndarray | None = None,
        outputs: bool = True,
        disturbances: np.ndarray | None = None,
    ) -> OpenLoopPrediction:
        """Predict with the model's parameter vector ``p`` (default: the model's own).

        ``disturbances`` (``(N - 1, nx)``, state units), when given, is added to the state at
        the end of every sample interval ``k`` (:math:`x_{k+1} = F(x_k, u_k) + d_k`): with a
        fit's process residuals (:func:`process_residuals`) the prediction retraces the fit's
        states.
        """
        t, u, starts, n = self.dataset.t, self._u, self.starts, len(self.starts)
        p = self.model.parameters.vector() if p is None else np.asarray(p, dtype=float)
        if disturbances is not None and disturbances.shape != (len(t) - 1, self.model.nx):
            raise FieldError(
                "disturbances",
                f"must be ({len(t) - 1}, {self.model.nx}), got {disturbances.shape}",
            )
        padded = self._padded
        capacity = len(padded)
        p_all = np.tile(p[:, None], (1, capacity))
        x = self.states[padded].T.copy()
        positions = np.full((n, self.steps, 2), np.nan)
        predicted = np.full((n, self.steps, len(Y_CHANNELS)), np.nan)
        for i in range(self.steps):
            k = padded + i  # interval being integrated, per start
            active = k + 1 <= self.end[padded]
            kk = np.minimum(k, len(t) - 2)
            for s in range(self._sub_h.shape[1]):
                h_s = np.where(active, self._sub_h[kk, s], 0.0)
                if not np.any(h_s > 0):
                    break
                x = self._step(x, self._sub_u[kk, s].T, p_all, h_s)[0].reshape(
                    self.model.nx, capacity, order="F"
                )
            if disturbances is not None:
                x = x + np.where(active, disturbances[kk].T, 0.0)
            ours = active[:n]
            positions[ours, i] = x[:2, :n][:, ours].T
            if outputs:
                u_next = u[np.minimum(kk + 1, len(t) - 1)].T
                y = self._output(x, u_next, p_all)[0].reshape(len(Y_CHANNELS), capacity, order="F")
                predicted[ours, i] = y[:, :n][:, ours].T
        index = np.minimum(starts[:, None] + 1 + np.arange(self.steps)[None, :], len(t) - 1)
        reference = np.where(
            np.isfinite(positions), self.reference.xy[index], np.nan
        )  # none beyond the horizon
        return OpenLoopPrediction(
            self.horizon_s, starts, self.steps, positions, predicted, reference
        )


def predict_open_loop(
    dataset: Dataset, model: CarModel, horizon_s: float = DEFAULT_HORIZON_S
) -> OpenLoopPrediction:
    """Predict from every start with ``model``'s parameters (initial states from its EKF)."""
    return OpenLoopPredictor(dataset, model, horizon_s).predict()


def _substeps(dataset: Dataset) -> tuple[np.ndarray, np.ndarray]:
    """Per sample interval: RK4 substeps (command, length), padded with zero lengths, from the
    same held-command segments as the FIE (:func:`~crs_core.identification.problem.
    input_segments`), each substep no longer than ``MAX_SUBSTEP``."""
    seg_u, seg_dt, seg_count = input_segments(dataset)
    pieces = []
    for k in range(len(seg_count)):
        row = []
        for j in range(seg_count[k]):
            n = max(1, math.ceil(seg_dt[k, j] / MAX_SUBSTEP - 1e-9))
            row += [(seg_u[k, j], seg_dt[k, j] / n)] * n
        pieces.append(row)
    width = max(len(r) for r in pieces)
    sub_u, sub_h = np.zeros((len(pieces), width, 2)), np.zeros((len(pieces), width))
    for k, row in enumerate(pieces):
        for j, (value, h) in enumerate(row):
            sub_u[k, j], sub_h[k, j] = value, h
    return sub_u, sub_h


def process_residuals(dataset: Dataset, model: CarModel, states: np.ndarray) -> np.ndarray:
    """A state trajectory's process residuals :math:`w_k = x_{k+1} - F(x_k, u_k)`, ``(N - 1,
    nx)`` in state units: ``F`` the model's RK4 step over each sample interval with the
    held-command substeps of the FIE and the open-loop predictions (``model``'s parameters)."""
    if states.shape != (len(dataset.t), model.nx):
        raise FieldError("states", f"must be ({len(dataset.t)}, {model.nx}), got {states.shape}")
    sub_u, sub_h = _substeps(dataset)
    step = model.step_function(1, "rk4_residual")
    intervals = len(dataset.t) - 1
    stepped = step.map(intervals)
    p_all = np.tile(model.parameters.vector()[:, None], (1, intervals))
    x = states[:-1].T
    for s in range(sub_h.shape[1]):
        x = np.asarray(stepped(x, sub_u[:, s].T, p_all, sub_h[None, :, s]))
    return np.asarray(states[1:] - x.T)


def horizon_index(dataset: Dataset, prediction: OpenLoopPrediction) -> np.ndarray:
    """Sample index of every prediction step, ``(S, steps)`` (clipped at the last sample)."""
    index = prediction.starts[:, None] + 1 + np.arange(prediction.steps)[None, :]
    return np.minimum(index, len(dataset.t) - 1)


def position_errors(prediction: OpenLoopPrediction) -> np.ndarray:
    """Predicted minus reference position, ``(S, steps, 2)`` m (NaN beyond the horizon and
    where the reference has none)."""
    return prediction.positions - prediction.reference


def validation_errors(dataset: Dataset, prediction: OpenLoopPrediction) -> dict:
    """Position RMSE (over the horizon and at its end, over the starts whose horizon's last
    sample has a reference; None without any reference) and per-channel RMS, JSON-ready."""
    index = horizon_index(dataset, prediction)
    position: dict[str, float | None] = dict.fromkeys(
        ("position_rmse_m", "position_rmse_at_horizon_m")
    )
    error = np.linalg.norm(position_errors(prediction), axis=2)
    valid = np.isfinite(error)
    if valid.any():
        predicted = np.isfinite(prediction.positions[..., 0])
        last = np.array([np.flatnonzero(row)[-1] for row in predicted])
        end_error = error[np.arange(len(last)), last]
        end_error = end_error[np.isfinite(end_error)]
        position = {
            "position_rmse_m": float(np.sqrt(np.mean(error[valid] ** 2))),
            "position_rmse_at_horizon_m": (
                float(np.sqrt(np.mean(end_error**2))) if end_error.size else None
            ),
        }
    measured = dataset.y[index]
    channel_error = prediction.outputs - measured
    channels = {}
    for c, name in enumerate(Y_CHANNELS):
        values = channel_error[..., c]
        values = values[np.isfinite(values)]
        channels[name] = float(np.sqrt(np.mean(values**2))) if values.size else None
    return {
        **position,
        "channel_rms": channels,
        "starts": len(prediction.starts),
    }


def validate(
    dataset: Dataset,
    model: CarModel,
    identified: ParameterSet,
    prior: ParameterSet | None = None,
    horizon_s: float = DEFAULT_HORIZON_S,
) -> tuple[dict, dict[str, OpenLoopPrediction]]:
    """Open-loop validation of ``identified`` (and ``prior``, side by side) on ``dataset``.

    ``model`` gives the structure (effects, stations); the parameter sets its values.
    Returns the JSON-ready summary and the predictions by label.
    """
    candidates = {"identified": identified}
    if prior is not None:
        candidates = {"prior": prior, **candidates}
    summary: dict = {
        "horizon_s": horizon_s,
        "reference": position_reference(dataset).description,
        "metric": (
            "position RMSE: sqrt of the mean over every start and every sample within the "
            "horizon of the squared planar distance between prediction and reference"
        ),
        "position_rmse_m": {},
        "position_rmse_at_horizon_m": {},
        "channel_rms": {},
    }
    predictions = {}
    for label, parameters in candidates.items():
        candidate = model.with_parameters(parameters)
        prediction = predict_open_loop(dataset, candidate, horizon_s)
        errors = validation_errors(dataset, prediction)
        summary["position_rmse_m"][label] = errors["position_rmse_m"]
        summary["position_rmse_at_horizon_m"][label] = errors["position_rmse_at_horizon_m"]
        summary["channel_rms"][label] = errors["channel_rms"]
        summary["starts"] = errors["starts"]
        predictions[label] = prediction
    return summary, predictions
