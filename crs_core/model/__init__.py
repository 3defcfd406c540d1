"""The Chronos car model: dynamics, sensors, effects and parameters, written once in CasADi."""

from crs_core.model.bicycle import INPUT_NAMES, STATE_NAMES
from crs_core.model.car_model import MAX_SUBSTEP, CarModel, NumericModel
from crs_core.model.effects import EFFECTS, Effect

__all__ = [
    "EFFECTS",
    "INPUT_NAMES",
    "MAX_SUBSTEP",
    "STATE_NAMES",
    "CarModel",
    "Effect",
    "NumericModel",
]
