"""System identification: the FIE problem, its solution and uncertainty, open-loop validation."""

from crs_core.identification.data import FieData
from crs_core.identification.problem import DEFAULT_FIT, DYNAMICS_FIT, FieProblem, FieSettings
from crs_core.identification.solve import FieResult, identify, initial_trajectory

__all__ = [
    "DEFAULT_FIT",
    "DYNAMICS_FIT",
    "FieData",
    "FieProblem",
    "FieResult",
    "FieSettings",
    "identify",
    "initial_trajectory",
]
