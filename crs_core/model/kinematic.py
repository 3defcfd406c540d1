r"""Kinematic bicycle: the car as two wheels that roll without slipping (CRS's second model).

State :math:`x = [x_p, y_p, \psi, v]` (world position m, yaw rad, speed of the centre of mass
along its velocity m/s), input :math:`u = [\delta, T]` as the dynamic model's. The velocity
points at the slip angle :math:`\beta = \arctan(l_r \tan\delta / (l_f + l_r))` from the heading,
and

.. math::

    \dot x_p = v \cos(\psi + \beta), \quad \dot y_p = v \sin(\psi + \beta), \quad
    \dot\psi = v \sin\beta / l_r, \quad
    \dot v = \bigl((C_{m1} - C_{m2} v) T - F_{fr}(v)\bigr) / m,

with the dynamic model's motor and friction laws (:func:`~crs_core.model.bicycle.motor_force`,
:func:`~crs_core.model.bicycle.friction_force`): all of the drive acts along the velocity. The
car state is :math:`v_x = v\cos\beta`, :math:`v_y = v\sin\beta`, :math:`\omega = \dot\psi`. It
has no tyres: it is the dynamic model's limit where the lateral accelerations stay far below the
grip (low speed, gentle steering), and the steady-state yaw rate
:math:`v_x \tan\delta / (l_f + l_r)` is the one the dynamic model reaches there. Where the car
slides (a fast corner, a spin) it is wrong, and docs/own-model.md shows how far.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import ClassVar

import casadi as ca
import numpy as np
from numpy.typing import ArrayLike

from crs_core.model.bicycle import friction_force, motor_force
from crs_core.model.chronos import dynamics_parameters
from crs_core.model.plant import ParameterAccess, Plant
from crs_core.parameters import ParameterSet

#: The dynamic model's parameters that the kinematic bicycle uses.
KINEMATIC_PARAMETERS = ("m", "lf", "lr", "Cm1", "Cm2", "Cd0", "Cd1", "Cd2", "r", "b_car")


def slip_angle(delta: ca.SX, P: ParameterAccess) -> ca.SX:
    """The centre of mass's velocity angle from the heading, rad, at steering angle ``delta``."""
    return ca.atan(P("lr") * ca.tan(delta) / (P("lf") + P("lr")))


class KinematicBicycle(Plant):
    """CRS's kinematic bicycle (module docstring): four states, ten parameters, no tyres."""

    name = "kinematic"
    description = "kinematic bicycle: rolling without slip, the drive along the velocity"
    states = (("x", "m"), ("y", "m"), ("yaw", "rad"), ("v", "m/s"))
    like: ClassVar[dict[str, str]] = {"v": "vx"}
    #: Its yaw follows the steering geometry and its velocity the heading; a real car that
    #: understeers or slides does neither, so the estimators let the pose move (measured on the
    #: simulated dynamic car at 0.8-1.1 m/s, docs/own-model.md: position RMSE 2.2-2.9 mm
    #: with these, up to 9.5 mm with the dynamic model's pose noise).
    process_std: ClassVar[dict[str, float]] = {"x": 0.05, "y": 0.05, "yaw": 0.3}
    #: Not the IMU: an understeering car turns slower than its steering geometry, and the gyro
    #: and the lateral accelerometer then pull the speed estimate down by as much (0.2-0.4 m/s
    #: on the simulated car at 1-1.5 m/s, docs/own-model.md); positions and wheel speeds it
    #: explains at every speed.
    explains: ClassVar[tuple[str, ...]] = ("lh", "we", "pose")
    #: Measured on the simulated dynamic car (docs/own-model.md): no boundary violation at
    #: 0.9 m/s, three at 1.05 m/s, eleven at 1.6 m/s, where the car slides.
    racing_speed: ClassVar[float | None] = 0.9
    #: The mass is not fitted: every force here is seen only per mass.
    default_fit = ("lf", "lr", "Cm1", "Cm2", "Cd0", "Cd1", "Cd2", "r", "b_car")

    def parameters(self) -> ParameterSet:
        """Mass, axle distances, motor, friction and encoder geometry (the dynamic model's
        values and priors)."""
        every = dynamics_parameters()
        return ParameterSet([every[name] for name in KINEMATIC_PARAMETERS])

    def derivative(self, x: ca.SX, u: ca.SX, P: ParameterAccess) -> ca.SX:
        """The module docstring's equations."""
        yaw, v = x[2], x[3]
        beta = slip_angle(u[0], P)
        return ca.vertcat(
            v * ca.cos(yaw + beta),
            v * ca.sin(yaw + beta),
            v * ca.sin(beta) / P("lr"),
            (motor_force(v, u[1], P) - friction_force(v, P)) / P("m"),
        )

    def car_state(self, x: ca.SX, u: ca.SX, P: ParameterAccess) -> ca.SX:
        """Pose, ``v`` resolved in body axes, and the yaw rate."""
        v = x[3]
        beta = slip_angle(u[0], P)
        return ca.vertcat(
            x[0], x[1], x[2], v * ca.cos(beta), v * ca.sin(beta), v * ca.sin(beta) / P("lr")
        )

    def state_from_car(self, car: ArrayLike, u: ArrayLike, P: Callable[[str], float]) -> np.ndarray:
        """The pose, and the body velocity projected on the direction the steering allows."""
        c, steer = np.asarray(car, dtype=float), float(np.asarray(u, dtype=float)[0])
        beta = float(np.arctan(P("lr") * np.tan(steer) / (P("lf") + P("lr"))))
        speed = float(c[3]) * np.cos(beta) + float(c[4]) * np.sin(beta)
        return np.array([c[0], c[1], c[2], speed])
