r"""The model interface: what a model of a car's motion writes, and what the suite derives.

A :class:`Plant` is the one piece a researcher writes to bring a model: its states and inputs
with names and units, its parameters with priors and bounds, its dynamics and sensor outputs as
CasADi expressions, and how its state maps to the *car state*
:data:`CAR_STATE_NAMES` (world position m, yaw rad, body velocities m/s, yaw rate rad/s), the
quantities the suite publishes, compares with a reference and races on. Everything else is
derived from it once by :class:`~crs_core.model.car_model.CarModel`: the effects and terms
composed onto it, the Lighthouse sweep angles and the motion-capture pose from the car state's
pose, an IMU and wheel encoders from the car state where the plant does not model them itself,
the integrator, the compiled functions and their cache. docs/own-model.md is the page a newcomer
needs.

The defaults derive the sensors a plant does not write from its car state :math:`c(x, u)`:
the IMU's specific force is :math:`(\dot v_x - \omega v_y, \dot v_y + \omega v_x)` with
:math:`\dot v = \partial c / \partial x \; f(x, u)` (the input held), and the wheel encoders are
the no-skid wheel speeds of :func:`~crs_core.model.sensors.wheel_speeds` (for a plant with the
parameters ``lf``, ``r`` and ``b_car``).
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Callable
from typing import ClassVar

import casadi as ca
import numpy as np
from numpy.typing import ArrayLike

from crs_core.errors import FieldError
from crs_core.model.car_state import CAR_STATE_NAMES, CAR_STATE_UNITS
from crs_core.parameters import ParameterSet

__all__ = [
    "CAR_STATE_NAMES",
    "CAR_STATE_UNITS",
    "ENCODER_PARAMETERS",
    "INPUT_NAMES",
    "INPUT_UNITS",
    "ParameterAccess",
    "Plant",
    "derived_imu",
]

#: The inputs the stack commands a car with (a plant takes these, in this order).
INPUT_NAMES = ("steer", "torque")
INPUT_UNITS = ("rad", "-")
#: Parameters the default wheel-encoder output needs.
ENCODER_PARAMETERS = ("lf", "r", "b_car")

ParameterAccess = Callable[[str], ca.SX]


class Plant(ABC):
    """A model of a car's motion: states, parameters, dynamics, sensors.

    Subclass it, set :attr:`name`, :attr:`states` (the pose first: ``x, y, yaw`` or states
    like them, :attr:`like`) and :attr:`description`, and write
    :meth:`parameters`, :meth:`derivative` and :meth:`car_state` (the last two take the state
    ``x``, the *applied* input ``u = [steer rad, torque -]`` and a parameter accessor ``P``:
    ``P("m")`` is the symbol of the parameter ``m``). A plant whose states are named like the
    car state's needs no :meth:`car_state` of its own. Its constructor takes no arguments (a
    plant is rebuilt from its spec in worker processes).
    """

    #: Short name, used in generated code's names and in a parameter YAML's ``model:``.
    name: ClassVar[str] = ""
    #: One line saying what the model is.
    description: ClassVar[str] = ""
    #: The states, ``(name, unit)`` each, in order.
    states: ClassVar[tuple[tuple[str, str], ...]] = ()
    #: The inputs' names (the stack commands :data:`INPUT_NAMES`).
    inputs: ClassVar[tuple[str, ...]] = INPUT_NAMES
    #: For each state not named like a car state, the car state it is like
    #: (``{"v": "vx"}``): the estimators give it that state's noise, initial uncertainty and
    #: bounds.
    like: ClassVar[dict[str, str]] = {}
    #: Process noise (per sqrt(s)) of states whose model error is not the car state's they are
    #: like: where the model is wrong, the estimators must let the state move (the kinematic
    #: bicycle's yaw follows its steering geometry, which an understeering car does not).
    process_std: ClassVar[dict[str, float]] = {}
    #: The sensor groups (:data:`~crs_core.estimation.base.SENSOR_GROUPS`) whose readings of a
    #: real car the model explains: the estimators' default sensors are these.
    explains: ClassVar[tuple[str, ...]] = ("lh", "imu", "gyro", "we", "pose")
    #: The highest progress speed the MPCC plans with this model, m/s (None: its settings'):
    #: where a simple model holds on the car.
    racing_speed: ClassVar[float | None] = None
    #: The parameters ``crs sysid`` fits by default (empty: every one with a prior std > 0).
    default_fit: ClassVar[tuple[str, ...]] = ()
    #: Where it was loaded from (:func:`~crs_core.model.plants.load_plant` sets it).
    spec: str = ""

    @property
    def state_names(self) -> tuple[str, ...]:
        """The states' names."""
        return tuple(name for name, _ in self.states)

    @property
    def state_units(self) -> tuple[str, ...]:
        """The states' units."""
        return tuple(unit for _, unit in self.states)

    @abstractmethod
    def parameters(self) -> ParameterSet:
        """The model's parameters with values, units, bounds and prior standard deviations."""

    @abstractmethod
    def derivative(self, x: ca.SX, u: ca.SX, P: ParameterAccess) -> ca.SX:
        """The state derivative :math:`\\dot x = f(x, u)`, one entry per state."""

    def car_state(self, x: ca.SX, u: ca.SX, P: ParameterAccess) -> ca.SX:
        """The car state :data:`CAR_STATE_NAMES` at state ``x`` under applied input ``u``.

        The default picks the states of those names; a plant with other states writes its own.
        """
        missing = [n for n in CAR_STATE_NAMES if n not in self.state_names]
        if missing:
            raise FieldError(
                "model",
                f"{self.name} has no state {', '.join(missing)}: write its car_state()",
            )
        return ca.vertcat(*(x[self.state_names.index(n)] for n in CAR_STATE_NAMES))

    def state_from_car(self, car: ArrayLike, u: ArrayLike, P: Callable[[str], float]) -> np.ndarray:
        """A state whose car state is (nearest to) ``car`` under applied input ``u``, with the
        numeric parameter values ``P``: where an estimator or the simulator starts.

        The default sets the states named like the car state's and the others to 0.
        """
        values = dict(zip(CAR_STATE_NAMES, np.asarray(car, dtype=float).tolist(), strict=True))
        return np.array([values.get(name, 0.0) for name in self.state_names])

    def car_state_like(self, name: str) -> str | None:
        """The car state the state ``name`` is like: itself if it is one, else :attr:`like`'s."""
        return name if name in CAR_STATE_NAMES else self.like.get(name)

    def sensors(self, x: ca.SX, u: ca.SX, P: ParameterAccess) -> dict[str, ca.SX]:
        """Sensor outputs the plant models itself (``imu`` ``[ax, ay, omega]``, ``wheel_encoders``
        ``[fl, fr, rl, rr]`` rad/s); those it leaves out are derived (module docstring)."""
        return {}

    def validate(self) -> None:
        """Refuse a plant the suite cannot carry, in one line naming what is wrong."""
        if not self.name or not self.name.replace("_", "").isalnum():
            raise FieldError("model.name", f"must be a short identifier, got {self.name!r}")
        names = self.state_names
        if not names:
            raise FieldError(f"model {self.name}.states", "must name at least one state")
        if len(set(names)) != len(names):
            raise FieldError(f"model {self.name}.states", "state names must be distinct")
        for name in names:
            if not name.isidentifier():
                raise FieldError(f"model {self.name}.states", f"{name!r} is not an identifier")
        pose = [self.car_state_like(n) for n in names[:3]]
        if pose != ["x", "y", "yaw"]:
            raise FieldError(
                f"model {self.name}.states",
                "the first three must be the pose (x, y, yaw or states like them, Plant.like)",
            )
        for name, similar in self.like.items():
            if name not in names or similar not in CAR_STATE_NAMES:
                raise FieldError(
                    f"model {self.name}.like",
                    f"{name!r}: {similar!r} must map a state to one of "
                    f"{', '.join(CAR_STATE_NAMES)}",
                )

    def __repr__(self) -> str:
        return f"{type(self).__name__}({self.name})"


def derived_imu(car: ca.SX, x: ca.SX, xdot: ca.SX) -> ca.SX:
    """``[ax, ay, omega]``: the specific force in body axes (m/s^2) and the yaw rate (rad/s) of
    car state ``car`` (an expression of state ``x``, whose derivative is ``xdot``)."""
    vx, vy, omega = car[3], car[4], car[5]
    vx_dot = ca.jtimes(vx, x, xdot)
    vy_dot = ca.jtimes(vy, x, xdot)
    return ca.vertcat(vx_dot - omega * vy, vy_dot + omega * vx, omega)
