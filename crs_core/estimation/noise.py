"""Noise settings the estimators assume (their tuning), shared by the EKF and the MHE, and the
``noise:`` section of a parameter YAML that carries a car's own (``crs tune-noise``)."""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field, fields, replace
from pathlib import Path
from typing import Any

import numpy as np

from crs_core.errors import FieldError
from crs_core.measurements import parse_lighthouse
from crs_core.model.car_model import ESTIMATED_INPUT_STATES, CarModel
from crs_core.model.effects import EFFECTS
from crs_core.model.online import STATE_PREFIX as ONLINE_STATE_PREFIX
from crs_core.model.plant import CAR_STATE_NAMES
from crs_core.model.terms import CLOCK_STATE
from crs_core.yaml_io import mapping_in_file

#: Defaults for the states effects add, by state name: process noise (per sqrt(s)) and the
#: initial standard deviation. Actuator lags follow their command closely (small noise); the
#: estimated inputs of an input-free model are random walks that must follow the driver; a
#: term's clock (:data:`~crs_core.model.terms.CLOCK_STATE`) runs as time does.
EXTRA_STATE_DEFAULTS: dict[str, tuple[float, float]] = {
    "steer_applied": (1e-3, 0.05),
    "torque_applied": (1e-3, 0.05),
    "steer_estimated": (1.0, 0.2),
    "torque_estimated": (3.0, 0.5),
    "clock": (1e-4, 1e-3),
}
#: Process noise and initial standard deviation of an extra state not in the table.
EXTRA_STATE_FALLBACK = (1e-3, 0.05)


@dataclass(frozen=True)
class EstimatorNoise:
    """Standard deviations assumed by an estimator.

    Attributes
    ----------
    process_std : tuple of float
        Continuous-time white process noise on ``[x, y, yaw, vx, vy, omega]`` (per sqrt(s)):
        the covariance added over ``dt`` is ``diag(process_std)^2 * dt``. Velocities carry most
        of it: they absorb model error in the tire and drive forces. Exactly 6 values.
    extra_process_std : mapping of str to float
        Process noise of the states effects add, by state name (``steer_applied``,
        ``torque_estimated``, ...), overriding :data:`EXTRA_STATE_DEFAULTS`.
    lighthouse_std : float
        Sweep angle, rad.
    imu_std : tuple of float
        ``a_x, a_y`` (m/s^2) and yaw rate (rad/s).
    gyro_std : float
        Yaw rate alone (rad/s).
    wheel_std : float or tuple of 4 floats
        Wheel speed, rad/s: one value for all wheels or ``fl, fr, rl, rr``.
    pose_std : tuple of float
        Motion capture ``x, y`` (m) and yaw (rad).
    """

    process_std: tuple[float, ...] = (0.02, 0.02, 0.02, 1.0, 1.0, 6.0)
    extra_process_std: Mapping[str, float] = field(default_factory=dict)
    lighthouse_std: float = 2e-3
    imu_std: tuple[float, float, float] = (1.0, 1.0, 0.06)
    gyro_std: float = 0.06
    wheel_std: float | tuple[float, float, float, float] = 2.5
    pose_std: tuple[float, float, float] = (0.003, 0.003, 0.01)

    def __post_init__(self) -> None:
        if len(self.process_std) != 6:
            raise FieldError(
                "noise.process_std",
                "needs 6 values (x, y, yaw, vx, vy, omega), got "
                f"{len(self.process_std)}; effect states go in extra_process_std by name",
            )
        for name in ("imu_std", "pose_std"):
            if len(getattr(self, name)) != 3:
                raise FieldError(f"noise.{name}", "needs 3 values")
        if isinstance(self.wheel_std, tuple | list) and len(self.wheel_std) != 4:
            raise FieldError("noise.wheel_std", "one value or 4 (fl, fr, rl, rr)")
        values = {
            "process_std": self.process_std,
            "extra_process_std": tuple(self.extra_process_std.values()),
            "lighthouse_std": (self.lighthouse_std,),
            "imu_std": self.imu_std,
            "gyro_std": (self.gyro_std,),
            "wheel_std": tuple(np.atleast_1d(self.wheel_std).tolist()),
            "pose_std": self.pose_std,
        }
        for name, entries in values.items():
            if not all(isinstance(v, int | float) and math.isfinite(v) and v > 0 for v in entries):
                raise FieldError(f"noise.{name}", "every standard deviation must be finite and > 0")

    def measurement_std(self, sensor: str) -> np.ndarray:
        """Per-channel standard deviation of a stream sensor."""
        if parse_lighthouse(sensor):
            return np.full(4, self.lighthouse_std)
        table = {
            "imu": self.imu_std,
            "gyro": (self.gyro_std,),
            "wheel_encoders": tuple(np.broadcast_to(self.wheel_std, 4)),
            "pose": self.pose_std,
        }
        return np.array(table[sensor], dtype=float)

    def process_std_for(self, model: CarModel) -> np.ndarray:
        """Process noise per state of ``model``: the plant's states from :attr:`process_std`
        (:func:`per_plant_state`), the others by name (an online parameter's is its random
        walk, :mod:`crs_core.model.online`).

        Entries for effect states this model lacks are allowed (one setting serves the
        commanded and the input-free model); names no model has are refused.
        """
        check_effect_state_names(self.extra_process_std, "noise.extra_process_std")
        defaults = {name: std for name, (std, _) in EXTRA_STATE_DEFAULTS.items()}
        defaults |= model.online.process_std
        extra = [
            self.extra_process_std.get(name, defaults.get(name, EXTRA_STATE_FALLBACK[0]))
            for name in model.state_names[len(model.plant.states) :]
        ]
        plant = per_plant_state(self.process_std, model, "noise.process_std")
        own = model.plant.process_std
        plant = [own.get(n, v) for n, v in zip(model.plant.state_names, plant, strict=True)]
        return np.array([*plant, *extra], dtype=float)


def check_effect_state_names(names: Iterable[str], field: str) -> None:
    """``ValueError`` naming ``field`` unless every name is a state some effect (or the
    input-free model) adds; settings may name states the current model lacks, so one setting
    serves the commanded and the input-free model."""
    known = {name for effect in EFFECTS.values() for name, _ in effect.states}
    known |= {name for name, _ in ESTIMATED_INPUT_STATES} | {CLOCK_STATE[0]}
    unknown = {name for name in names if not name.startswith(ONLINE_STATE_PREFIX)} - known
    if unknown:
        raise FieldError(
            field, f"{sorted(unknown)} are not effect states (known: {', '.join(sorted(known))})"
        )


def initial_std_for(base_std: tuple[float, ...], model: CarModel) -> np.ndarray:
    """Initial standard deviation per state of ``model``: ``base_std`` (the car state's) for
    the plant's states (:func:`per_plant_state`), defaults for the rest (an online
    parameter's: its prior's)."""
    defaults = {name: std for name, (_, std) in EXTRA_STATE_DEFAULTS.items()}
    defaults |= model.online.prior_std
    rest = model.state_names[len(model.plant.states) :]
    extra = [defaults.get(n, EXTRA_STATE_FALLBACK[1]) for n in rest]
    plant = per_plant_state(base_std, model, "initial_std")
    return np.array([*plant, *extra], dtype=float)


def per_plant_state(values: Sequence[float], model: CarModel, field: str) -> list[float]:
    """A setting given per car state (``values`` for :data:`CAR_STATE_NAMES`) for each state of
    ``model``'s plant: the value of the car state it is like (:meth:`~crs_core.model.plant.
    Plant.car_state_like`). A plant state like none of them is refused in one line."""
    names = CAR_STATE_NAMES
    table = dict(zip(names, values, strict=True))
    out = []
    for name in model.plant.state_names:
        similar = model.plant.car_state_like(name)
        if similar not in table:
            raise FieldError(
                field,
                f"gives {', '.join(names)}; state {name} of model {model.plant.name} is like "
                f"{similar or 'none of them'} (set its Plant.like)",
            )
        out.append(float(table[similar]))
    return out


#: The section of a parameter YAML holding the estimators' noise for that car.
NOISE_KEY = "noise"


def noise_in_file(path: str | Path | None, base: EstimatorNoise | None = None) -> EstimatorNoise:
    """``base`` (default :class:`EstimatorNoise`) with the entries of the parameter YAML
    ``path``'s ``noise:`` mapping (its field names; lists for tuples), or ``base`` itself where
    the file has none. ``FieldError`` naming ``noise.<field>`` in the file for an unknown field
    or a bad value."""
    base = base or EstimatorNoise()
    if path is None:
        return base
    entries = mapping_in_file(path).get(NOISE_KEY)
    if entries is None:
        return base
    where = f"{path}: {NOISE_KEY}"
    if not isinstance(entries, dict):
        raise FieldError(where, "must be a mapping of EstimatorNoise fields")
    known = [f.name for f in fields(EstimatorNoise)]
    values: dict[str, Any] = {}
    for key, value in entries.items():
        if key not in known:
            raise FieldError(f"{where}.{key}", f"unknown (known: {', '.join(known)})")
        values[key] = tuple(value) if isinstance(value, list) else value
    try:
        return replace(base, **values)
    except FieldError as error:
        raise FieldError(f"{path}: {error.field}", error.reason) from None
    except TypeError as error:
        raise FieldError(where, str(error)) from None


def with_noise(
    document: Mapping[str, Any], noise: EstimatorNoise, names: Sequence[str]
) -> dict[str, Any]:
    """A parameter YAML's ``document`` with the fields ``names`` of ``noise`` in its ``noise:``
    section (the section's other entries kept)."""
    section = document.get(NOISE_KEY)
    kept = dict(section) if isinstance(section, Mapping) else {}
    return {**document, NOISE_KEY: kept | noise_mapping(noise, names)}


def noise_mapping(noise: EstimatorNoise, names: Sequence[str]) -> dict[str, Any]:
    """The ``noise:`` entries ``names`` of ``noise`` as YAML-ready values (tuples as lists)."""
    out: dict[str, Any] = {}
    for name in names:
        value = getattr(noise, name)
        if isinstance(value, Mapping):
            out[name] = {str(k): float(v) for k, v in value.items()}
        elif isinstance(value, tuple | list):
            out[name] = [float(v) for v in value]
        else:
            out[name] = float(value)
    return out
