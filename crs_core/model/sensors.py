r"""Sensor models of the Chronos car (paper, Sec. III-B), written once in CasADi.

All take the car state ``car`` (:data:`~crs_core.model.plant.CAR_STATE_NAMES`), the *applied*
steering angle (after any actuator effect) where it matters and the parameter accessor ``P``, so
that every model (:class:`~crs_core.model.plant.Plant`) shares them; the dynamic bicycle's IMU is
written with its forces (:class:`~crs_core.model.bicycle.DynamicBicycle`).

IMU note: an accelerometer senses specific force, the net external force per mass in body axes,
:math:`a = \dot v_{body} + \omega \times v`. The paper prints
:math:`\frac{1}{m}(\dots) + v_y\omega` and :math:`\frac{1}{m}(\dots) - v_x\omega`, which equals
:math:`\dot v_x, \dot v_y` (zero in a steady turn); here the accelerometer model is the specific
force, so a steady turn reads the centripetal acceleration :math:`a_y = v_x \omega`.
"""

from __future__ import annotations

import casadi as ca

from crs_core.model.lighthouse import rotation_from_angles, sweep_angles
from crs_core.model.plant import ParameterAccess

N_PHOTODIODES = 4


def wheel_speeds(car: ca.SX, delta: ca.SX, P: ParameterAccess) -> ca.SX:
    """Wheel angular speeds ``[fl, fr, rl, rr]`` in rad/s, no-skid (paper Eq. 2), for car state
    ``car`` and applied steering angle ``delta`` (rad)."""
    vx, vy, omega = car[3], car[4], car[5]
    half_track = 0.5 * P("b_car") * omega
    lateral_front = vy + P("lf") * omega
    return ca.vertcat(
        ca.cos(delta) * (vx - half_track) + ca.sin(delta) * lateral_front,
        ca.cos(delta) * (vx + half_track) + ca.sin(delta) * lateral_front,
        vx - half_track,
        vx + half_track,
    ) / P("r")


def lighthouse(car: ca.SX, station: int, P: ParameterAccess) -> tuple[ca.SX, ca.SX]:
    """Sweep angles (rad) of the 4 photodiodes, planes 1 and 2 of base station ``station``, for
    the pose of car state ``car``."""
    b = f"bs{station}_"
    rotation = rotation_from_angles(P(b + "phi1"), P(b + "phi2"), P(b + "phi3"))
    position = ca.vertcat(P(b + "x"), P(b + "y"), P(b + "z"))
    diodes = [(P(f"lh_d{k}_x"), P(f"lh_d{k}_y")) for k in range(N_PHOTODIODES)]
    first, second = sweep_angles(car[0:3], diodes, rotation, position, P(b + "dt1"), P(b + "dt2"))
    return ca.vertcat(*first), ca.vertcat(*second)


def pose(car: ca.SX) -> ca.SX:
    """Motion-capture pose ``[x, y, yaw]`` (m, m, rad) of car state ``car``."""
    return car[0:3]
