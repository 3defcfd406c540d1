"""One call that builds an estimator with its settings (nodes, benchmarks, bag replay, CLI)."""

from __future__ import annotations

import casadi as ca

from crs_core.errors import FieldError
from crs_core.estimation.base import (
    Estimator,
    EstimatorSettings,
    parse_sensor_set,
    sensor_group,
)
from crs_core.estimation.ekf import EkfSettings, ExtendedKalmanFilter
from crs_core.estimation.inputs import InputModeEstimator
from crs_core.estimation.mhe import MheSettings, MovingHorizonEstimator
from crs_core.model import CarModel
from crs_core.model.car_model import COMMAND_EFFECTS

#: Estimator kinds :func:`make_estimator` builds.
KINDS = ("ekf", "mhe")
#: How an estimator treats the commanded inputs.
INPUT_MODES = ("auto", "commanded", "estimated")


#: The sensor groups a car's estimator uses unless told otherwise, of those its model explains.
STACK_SENSORS = ("lh", "imu", "we")


def default_sensors(model: CarModel) -> str:
    """``"lh+imu+we"``, without the groups ``model``'s plant does not explain
    (:attr:`~crs_core.model.plant.Plant.explains`: the kinematic bicycle's ``"lh+we"``)."""
    return "+".join(g for g in STACK_SENSORS if g in model.plant.explains)


def make_estimator(
    kind: str,
    sensors: str | frozenset[str] | None = None,
    model: CarModel | None = None,
    settings: EstimatorSettings | None = None,
    *,
    inputs: str = "auto",
) -> Estimator:
    """An EKF or MHE on ``model`` (default: the Chronos model) with ``settings``.

    Parameters
    ----------
    kind : {"ekf", "mhe"}
    sensors : str or set, optional
        Sensor groups, e.g. ``"lh+imu+we"``; default :func:`default_sensors`.
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
    if sensors is None:
        sensors = default_sensors(model)
    if model.estimated_inputs:
        raise FieldError("model", "give the commanded model; inputs='estimated' builds the other")
    if settings.online_parameters:
        model = model.with_online(settings.online_parameters, settings.online_reversion_s)
        check_online_reach(
            model, parse_sensor_set(sensors) if isinstance(sensors, str) else sensors
        )

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


def check_online_reach(model: CarModel, groups: frozenset[str]) -> None:
    """A :class:`~crs_core.errors.FieldError` naming ``online_parameters`` if an online
    parameter of ``model`` is one no data could inform (:func:`unseen_online_parameters`)."""
    unseen = unseen_online_parameters(model, groups)
    if unseen:
        raise FieldError(
            "online_parameters",
            f"{', '.join(unseen)}: neither the car's motion nor what the sensors "
            f"{'+'.join(sorted(groups))} read depends on it (nothing could inform it)",
        )


def unseen_online_parameters(model: CarModel, groups: frozenset[str]) -> list[str]:
    """The online parameters of ``model`` that neither the dynamics of its other states nor the
    outputs of the sensor ``groups`` depend on (symbolically): no data could ever inform them."""
    plain = model.nx - len(model.online)
    dynamics = model.xdot_expression[:plain]
    outputs = [
        expression
        for sensor, expression in model.output_expressions.items()
        if sensor_group(sensor) in groups
    ]
    unseen = []
    for k, name in enumerate(model.online.names):
        state = model.x_sym[plain + k]
        if not ca.depends_on(dynamics, state) and not any(
            ca.depends_on(output, state) for output in outputs
        ):
            unseen.append(name)
    return unseen


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
        model=model.plant,
    )
