"""What open-loop prediction shows and the smoothed fit hides.

The FIE's state follows the data: a slow drift the model lacks (a battery losing torque over the
run) is absorbed by its process residuals :math:`w_k = x_{k+1} - F(x_k, u_k)` and leaves the
measurement residuals white (:mod:`~crs_core.discrepancy.residuals` sees nothing). Predicted
open loop from the fit's states, the same model misses by the sum of those residuals carried
through the horizon, and a drift adds up where noise averages out. :func:`diagnose_prediction`
compares the two: the open-loop position gap over the horizon from every start (the fit's own
states as start and reference), and the gap of the *same drive* with the same residuals in
shuffled order (blocks of :data:`BLOCK_S` permuted over the run: their size kept, their order in
time, and with it any link to time into the run, speed or torque, lost). Their ratio, the
*coherence*, is about 1 for white process noise and below 1 where the residuals are the fit's
wiggles around a right model (they cancel over a horizon); a model missing a slow or
regime-bound term has residuals that add up, a coherence well above 1. Where the per-start gap
grows (time into the run, speed, torque, ...) is reported as for a channel.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any

import numpy as np

from crs_core.dataset import Dataset
from crs_core.discrepancy.residuals import regime_regressors, where_entry
from crs_core.discrepancy.statistics import correlation, regime_regression, worst_regime
from crs_core.errors import FieldError
from crs_core.identification.validation import (
    OpenLoopPredictor,
    horizon_index,
    process_residuals,
)
from crs_core.model import CarModel

#: The channel name of the open-loop prediction in a verdict's ``where``.
PREDICTION_CHANNEL = "open_loop_prediction"
#: Spacing of the prediction starts, s.
START_EVERY_S = 0.25
#: Length of the blocks of process residuals the shuffle permutes, s.
BLOCK_S = 0.25
#: Shuffled orders the gap of the same drive is taken over (their median).
SHUFFLES = 20
#: A coherence above this is structure (clean simulated runs: 0.40-0.54; a battery losing 30 %
#: of its torque over 60 s: 1.90-2.00).
COHERENCE_MAX = 1.5


@dataclass
class PredictionDiagnosis:
    """The open-loop prediction's diagnosis.

    Attributes
    ----------
    horizon_s : float
        Prediction horizon, s.
    starts : int
        Prediction starts (every :data:`START_EVERY_S` with a full horizon ahead).
    gap : float
        Position RMSE over every start and every sample of its horizon, m: the fit's states
        predicted open loop from the fit's state at the start, against the fit's states.
    shuffled_gap : float
        The same with the fit's process residuals added in shuffled order (median over
        :data:`SHUFFLES` orders), m: what the same drive gives when the model's misses are
        noise.
    shuffled_range : tuple of float
        Smallest and largest gap over the shuffled orders, m.
    coherence : float
        ``gap / shuffled_gap``.
    structured : bool
        ``coherence > COHERENCE_MAX`` and ``gap`` larger than every shuffled order's.
    correlations : dict of str to dict of str to float
        Per error series, each regime variable's correlation with it (descriptive: the starts'
        horizons overlap). The series, one value per start, means over its horizon: ``gap``
        (the planar distance, m), ``along`` and ``across`` (the signed miss along and across
        the fit's heading at each sample, m: ``along`` > 0 where the car got further than
        predicted); the regime variables (:func:`~crs_core.discrepancy.residuals.
        regime_regressors`) are means over the start's horizon.
    strongest : dict
        The series and regime variable of the largest absolute correlation:
        ``{"series", "regressor", "correlation"}``.
    regime_r2 : float
        :math:`R^2` of the strongest series regressed on every regime variable (descriptive).
    worst_regime : dict
        The quartile bin of the strongest regime variable with the largest gap
        (``{"regressor", "low", "high", "rms", "share"}``, ``rms`` in m).
    """

    horizon_s: float
    starts: int
    gap: float
    shuffled_gap: float
    shuffled_range: tuple[float, float]
    coherence: float
    structured: bool
    correlations: dict[str, dict[str, float]]
    strongest: dict[str, Any]
    regime_r2: float
    worst_regime: dict[str, Any]

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready fields."""
        out = asdict(self)
        out["shuffled_range"] = list(self.shuffled_range)
        return out

    def where(self) -> dict[str, Any]:
        """The misfit's channel and regime in the form of
        :func:`~crs_core.discrepancy.residuals.where_misfit` (``normalized_rms``: the
        coherence; ``rms``: the gap in the worst regime, m)."""
        return where_entry(
            PREDICTION_CHANNEL, self.worst_regime, self.coherence, self.regime_r2, self.gap, []
        )


def diagnose_prediction(
    data: Dataset,
    model: CarModel,
    states: np.ndarray,
    horizon_s: float,
    seed: int = 0,
) -> PredictionDiagnosis:
    """Diagnose ``model``'s open-loop predictions on ``data`` from a fit's ``states``.

    Parameters
    ----------
    data : Dataset
        The fitted data (stamps, commands).
    model : CarModel
        The fitted model (its parameters are used).
    states : (N, nx) array
        The fit's state trajectory on ``data.t`` (start states and reference).
    horizon_s : float
        Prediction horizon, s (shortened to half the data when they are shorter).
    seed : int
        Seed of the shuffled orders.
    """
    t = data.t
    if len(t) < 3 or data.u is None:
        raise FieldError("data", "open-loop prediction needs inputs and at least 3 samples")
    horizon = min(horizon_s, 0.5 * float(t[-1] - t[0]))
    dt = float(np.median(np.diff(t)))
    every = max(1, round(START_EVERY_S / dt))
    predictor = OpenLoopPredictor(data, model, horizon, states=states, every=every)
    plain = predictor.predict(outputs=False)
    index = horizon_index(data, plain)
    inside = np.isfinite(plain.positions[..., 0])
    real = np.where(inside[..., None], states[index, :2] - plain.positions, np.nan)
    residuals = process_residuals(data, model, states)
    rng = np.random.default_rng(seed)
    shuffled = []
    for _ in range(SHUFFLES):
        order = _block_order(len(residuals), max(1, round(BLOCK_S / dt)), rng)
        moved = predictor.predict(outputs=False, disturbances=residuals[order])
        shuffled.append(_rms(moved.positions - plain.positions))
    gap, median = _rms(real), float(np.median(shuffled))
    coherence = gap / median if median > 0 else float("inf") if gap > 0 else 0.0

    yaw = states[index, 2]
    along = np.cos(yaw) * real[..., 0] + np.sin(yaw) * real[..., 1]
    across = -np.sin(yaw) * real[..., 0] + np.cos(yaw) * real[..., 1]
    series = {
        "gap": np.sqrt(np.nanmean(np.sum(real**2, axis=2), axis=1)),
        "along": np.nanmean(along, axis=1),
        "across": np.nanmean(across, axis=1),
    }
    regressors = regime_regressors(t, model.numeric.car_states(states, data.u), data.u)
    names = list(regressors)
    design = np.column_stack(
        [
            [
                float(np.mean(values[s : e + 1]))
                for s, e in zip(plain.starts, predictor.end[plain.starts], strict=True)
            ]
            for values in regressors.values()
        ]
    )
    correlations = {
        label: {name: correlation(design[:, j], values) for j, name in enumerate(names)}
        for label, values in series.items()
    }
    label, regressor = max(
        ((label, name) for label in series for name in names),
        key=lambda pair: abs(correlations[pair[0]][pair[1]]),
    )
    r2, _ = regime_regression(series[label], design)
    return PredictionDiagnosis(
        horizon_s=horizon,
        starts=len(plain.starts),
        gap=gap,
        shuffled_gap=median,
        shuffled_range=(float(min(shuffled)), float(max(shuffled))),
        coherence=float(coherence),
        structured=bool(coherence > COHERENCE_MAX and gap > max(shuffled)),
        correlations=correlations,
        strongest={
            "series": label,
            "regressor": regressor,
            "correlation": correlations[label][regressor],
        },
        regime_r2=r2,
        worst_regime=worst_regime(series["gap"], design[:, names.index(regressor)], regressor),
    )


def _block_order(n: int, block: int, rng: np.random.Generator) -> np.ndarray:
    """A permutation of ``range(n)`` that moves whole blocks of ``block`` indices (the last,
    shorter one included)."""
    blocks = [np.arange(s, min(s + block, n)) for s in range(0, n, block)]
    return np.concatenate([blocks[i] for i in rng.permutation(len(blocks))])


def _rms(errors: np.ndarray) -> float:
    """RMS of the planar distance over every finite (start, sample), m."""
    squared = np.sum(errors**2, axis=-1)
    return float(np.sqrt(np.mean(squared[np.isfinite(squared)])))
