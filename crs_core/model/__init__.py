"""The car models: the plants (dynamic and kinematic bicycles, or a researcher's own), their
sensors, effects and parameters, composed once in CasADi."""

from crs_core.model.car_model import MAX_SUBSTEP, CarModel, NumericModel
from crs_core.model.effects import EFFECTS, Effect
from crs_core.model.plant import CAR_STATE_NAMES, INPUT_NAMES, Plant

__all__ = [
    "CAR_STATE_NAMES",
    "EFFECTS",
    "INPUT_NAMES",
    "MAX_SUBSTEP",
    "CarModel",
    "Effect",
    "NumericModel",
    "Plant",
]
