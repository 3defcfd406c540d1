r"""The estimators' process noise fitted to a recording: the noise under which the data are most
likely.

How far an estimator lets the car's pose move off what its velocities integrate to (the process
noise of ``x, y, yaw``), and how far the velocities off the model's forces, is a property of how
well the model fits *this* car: a car that follows the model wants little, a real car with
effects the model lacks more. The defaults of :class:`~crs_core.estimation.noise.EstimatorNoise`
are set for the real Chronos recordings. :func:`fit_process_noise` chooses a scale per group of
process-noise entries (:data:`PROCESS_GROUPS`) that maximises the EKF's innovation
log-likelihood on a recording (:attr:`~crs_core.estimation.ekf.ExtendedKalmanFilter.
log_likelihood`; the prediction-error form of the likelihood, the standard maximum-likelihood
tuning of a Kalman filter): a coarse grid over :attr:`NoiseFitSettings.scales` per group, then a
golden-section search in ``log10`` of the scale around the best grid point, one group after the
other. The measurement noise stays as it is (the sensors' datasheets and the recordings set it).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from functools import partial
from typing import Any

import numpy as np

from crs_core.dataset import Dataset
from crs_core.errors import FieldError
from crs_core.estimation.ekf import EkfSettings, ExtendedKalmanFilter
from crs_core.estimation.noise import EstimatorNoise
from crs_core.model import CarModel
from crs_core.settings import Settings, positive

#: Groups of :attr:`EstimatorNoise.process_std` entries scaled together, by name: the pose
#: ``x, y, yaw`` and the velocities ``vx, vy, omega``.
PROCESS_GROUPS: dict[str, tuple[int, ...]] = {"pose": (0, 1, 2), "velocity": (3, 4, 5)}
#: The golden ratio's conjugate, the golden-section search's step.
_GOLDEN = (math.sqrt(5.0) - 1.0) / 2.0


@dataclass(frozen=True)
class NoiseFitSettings(Settings):
    """What :func:`fit_process_noise` fits and how finely.

    Attributes
    ----------
    groups : tuple of str
        The groups of :data:`PROCESS_GROUPS` fitted, in this order (each once).
    scales : tuple of float
        The grid of scales (on the starting noise) tried first per group, increasing.
    tolerance : float
        The golden-section search stops when its bracket is this narrow in ``log10`` of the
        scale (0.05: about 12 %).
    sensors : str
        The sensor groups the EKF uses (``"auto"``: every group the recording has that the
        model explains, :func:`~crs_core.estimation.offline.available_sensors`).
    """

    groups: tuple[str, ...] = ("pose",)
    scales: tuple[float, ...] = (0.03, 0.1, 0.3, 1.0, 3.0, 10.0)
    tolerance: float = positive(0.05)
    sensors: str = "auto"

    def _check_relations(self) -> None:
        unknown = [g for g in self.groups if g not in PROCESS_GROUPS]
        if not self.groups or unknown or len(set(self.groups)) != len(self.groups):
            raise FieldError(
                "groups",
                f"one or more of {', '.join(PROCESS_GROUPS)}, each once; got "
                f"{', '.join(self.groups) or 'none'}",
            )
        pairs = zip(self.scales, self.scales[1:], strict=False)
        if len(self.scales) < 3 or any(not (math.isfinite(a) and 0 < a < b) for a, b in pairs):
            raise FieldError("scales", "needs 3 or more increasing finite values > 0")


@dataclass
class NoiseFit:
    """The fitted noise and the evidence for it.

    Attributes
    ----------
    noise : EstimatorNoise
        The starting noise with the fitted process noise.
    scales : dict of str to float
        The fitted scale of each group on the starting noise.
    log_likelihood : float
        The EKF's innovation log-likelihood under :attr:`noise` (nats).
    start_log_likelihood : float
        The same under the starting noise.
    updates : int
        The innovations summed.
    evaluations : list of dict
        Every noise tried: ``group``, ``scale``, ``process_std`` (6 values) and
        ``log_likelihood``, in the order tried.
    """

    noise: EstimatorNoise
    scales: dict[str, float]
    log_likelihood: float
    start_log_likelihood: float
    updates: int
    evaluations: list[dict[str, Any]] = field(default_factory=list)

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready."""
        return {
            "process_std": list(self.noise.process_std),
            "scales": dict(self.scales),
            "log_likelihood": self.log_likelihood,
            "start_log_likelihood": self.start_log_likelihood,
            "updates": self.updates,
            "evaluations": self.evaluations,
        }


def innovation_log_likelihood(
    dataset: Dataset, model: CarModel, noise: EstimatorNoise, sensors: str = "auto"
) -> tuple[float, int]:
    """The EKF's innovation log-likelihood over ``dataset`` under ``noise`` (nats) and the
    number of innovations summed (blind start, the recorded commands; ``FieldError`` naming
    ``inputs`` for a recording without them)."""
    from crs_core.estimation.offline import data_span, estimate_dataset

    settings = EkfSettings(noise=noise, innovation_likelihood=True)
    end = data_span(dataset)[1]
    result = estimate_dataset(
        dataset, "ekf", sensors, model=model, settings=settings, inputs="commanded", at=[end]
    )
    estimator = result.estimator
    assert isinstance(estimator, ExtendedKalmanFilter)
    return estimator.log_likelihood, estimator.likelihood_terms


def scaled(noise: EstimatorNoise, group: str, scale: float) -> EstimatorNoise:
    """``noise`` with the process noise of ``group`` multiplied by ``scale``."""
    std = list(noise.process_std)
    for i in PROCESS_GROUPS[group]:
        std[i] *= scale
    return replace(noise, process_std=tuple(std))


def fit_process_noise(
    dataset: Dataset,
    model: CarModel,
    start: EstimatorNoise | None = None,
    settings: NoiseFitSettings | None = None,
    progress: Callable[[str], None] | None = None,
) -> NoiseFit:
    """The process noise that maximises the innovation likelihood of ``dataset`` (the module).

    Parameters
    ----------
    dataset : Dataset
        A recording with commands (a steady drive: a car that changes while it is recorded asks
        for more noise than it has).
    model : CarModel
        The estimation model, its parameters the car's identified ones.
    start : EstimatorNoise, optional
        The noise scaled (default: the estimators' own); its measurement noise is kept.
    settings : NoiseFitSettings, optional
    progress : callable, optional
        Called with a line per noise tried.
    """
    settings = settings or NoiseFitSettings()
    current = start or EstimatorNoise()
    evaluations: list[dict[str, Any]] = []
    cache: dict[tuple[float, ...], tuple[float, int]] = {}

    def evaluate(group: str, scale: float) -> float:
        noise = scaled(current, group, scale)
        key = _cache_key(noise)
        if key not in cache:
            cache[key] = innovation_log_likelihood(dataset, model, noise, settings.sensors)
            evaluations.append(
                {
                    "group": group,
                    "scale": scale,
                    "process_std": list(noise.process_std),
                    "log_likelihood": cache[key][0],
                }
            )
            if progress is not None:
                progress(
                    f"{group} x {scale:.3g}: process_std "
                    f"{', '.join(f'{v:.4g}' for v in noise.process_std)}, "
                    f"log-likelihood {cache[key][0]:.1f} ({cache[key][1]} innovations)"
                )
        return cache[key][0]

    start_likelihood = evaluate(settings.groups[0], 1.0)
    fitted: dict[str, float] = {}
    for group in settings.groups:
        scale = _maximise(partial(evaluate, group), settings.scales, settings.tolerance)
        fitted[group] = scale
        current = scaled(current, group, scale)
    best, updates = cache[_cache_key(current)]
    return NoiseFit(current, fitted, best, start_likelihood, updates, evaluations)


def _cache_key(noise: EstimatorNoise) -> tuple[float, ...]:
    """A noise setting's process noise, rounded so that the same scale reached two ways is one
    evaluation."""
    return tuple(round(v, 12) for v in noise.process_std)


def _maximise(f: Callable[[float], float], grid: Sequence[float], tolerance: float) -> float:
    """The maximiser of ``f`` over scales: the best of ``grid``, refined by a golden-section
    search in ``log10`` between its neighbours (a grid end is kept where the best lies there:
    the search does not extrapolate)."""
    logs = [math.log10(s) for s in grid]
    values = [f(s) for s in grid]
    k = int(np.argmax(values))
    if k in (0, len(grid) - 1):
        return grid[k]
    a, b = logs[k - 1], logs[k + 1]
    c, d = b - _GOLDEN * (b - a), a + _GOLDEN * (b - a)
    fc, fd = f(10.0**c), f(10.0**d)
    while b - a > tolerance:
        if fc >= fd:
            b, d, fd = d, c, fc
            c = b - _GOLDEN * (b - a)
            fc = f(10.0**c)
        else:
            a, c, fc = c, d, fd
            d = a + _GOLDEN * (b - a)
            fd = f(10.0**d)
    candidates = [(values[k], logs[k]), (fc, c), (fd, d)]
    return 10.0 ** max(candidates)[1]
