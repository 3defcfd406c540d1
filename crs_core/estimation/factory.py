"""One call that builds an estimator with its settings (nodes, benchmarks, bag replay, CLI)."""

from __future__ import annotations

from crs_core.errors import FieldError
from crs_core.estimation.base import Estimator, EstimatorSettings
from crs_core.estimation.ekf import EkfSettings, ExtendedKalmanFilter
from crs_core.estimation.inputs import InputModeEstimator
from crs_core.estimation.mhe import MheSettings, MovingHorizonEstimator
from crs_core.model import CarModel
from crs_core.model.car_model import COMMAND_EFFECTS

#: Estimator kinds :func:`make_estimator` builds.
KINDS = ("ekf", "mhe")
#: How an estimator treats the commanded inputs.
INPUT_MODES = ("auto", "commanded", "estimated")


def make_estimator(
    kind: str,
    sensors: str | frozenset[str] = "lh+imu+we",
    model: CarModel | None = None,
    settings: EstimatorSettings | None = None,
    *,
    inputs: str = "auto",
) -> Estimator:
    """An EKF or MHE on ``model`` (default: the Chronos model) with ``settings``.

    Parameters
    ----------
    kind : {"ekf", "mhe"}
    sensors : str or set
        Sensor groups, e.g. ``"lh+imu+we"``.
    model : CarModel, optional
        The estimation model with commanded inputs (its parameters, effects, stations).
    settings : EkfSettings or MheSettings, optional
        Defaults: ``EkfSettings()`` / ``MheSettings()`` (60 Hz grid, M = 40).
    inputs : {"auto", "commanded", "estimated"}
        ``commanded``: the model driven by the ``input`` stream. ``estimated``: the input-free
        model (``CarModel(estimated_inputs=True)``): steering and torque are random-walk states
        estimated from the sensors; commands are ignored. ``auto``: estimated until the first
        command arrives, then commanded (:class:`~crs_core.estimation.inputs.InputModeEstimator`).

    Returns
    -------
    Estimator
        Call ``reset(t0, x0)``, or ``reset(t0)`` for a blind start from the Lighthouse.
    """
    if kind not in KINDS:
        raise FieldError("estimator", f"must be 'ekf' or 'mhe', got {kind!r}")
    if inputs not in INPUT_MODES:
        raise FieldError("inputs", f"must be one of {', '.join(INPUT_MODES)}, got {inputs!r}")
    settings_type = EkfSettings if kind == "ekf" else MheSettings
    if settings is None:
        settings = settings_type()
    elif not isinstance(settings, settings_type):
        raise TypeError(f"settings: a {kind} needs {settings_type.__name__}, got {settings!r}")
    model = model or CarModel()
    if model.estimated_inputs:
        raise FieldError("model", "give the commanded model; inputs='estimated' builds the other")
    if settings.online_parameters:
        model = model.with_online(settings.online_parameters, settings.online_reversion_s)

    if inputs == "commanded":
        return _new_estimator(model, sensors, settings)
    estimated = _new_estimator(input_free_model(model), sensors, settings)
    if inputs == "estimated":
        return estimated
    return InputModeEstimator(estimated, _new_estimator(model, sensors, settings))


def _new_estimator(
    model: CarModel, sensors: str | frozenset[str], settings: EstimatorSettings
) -> Estimator:
    """The EKF or MHE that ``settings`` are for (:func:`make_estimator` checked them)."""
    if isinstance(settings, EkfSettings):
        return ExtendedKalmanFilter(model, sensors, settings)
    if isinstance(settings, MheSettings):
        return MovingHorizonEstimator(model, sensors, settings)
    raise TypeError(f"settings: EkfSettings or MheSettings, got {settings!r}")


def input_free_model(model: CarModel) -> CarModel:
    """The input-free twin of ``model``: same parameters, stations and sensor effects."""
    effects = [e.name for e in model.effects if e.name not in COMMAND_EFFECTS]
    return CarModel(
        effects,
        model.n_base_stations,
        parameters=model.parameters,
        estimated_inputs=True,
        online_parameters=model.online.names,
        online_reversion_s=model.online.reversion_s,
    )
