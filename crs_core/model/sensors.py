r"""Sensor models of the Chronos car (paper, Sec. III-B), written once in CasADi.

All take the state ``x``, the *applied* input ``u`` (after any actuator effect) and the parameter
accessor ``P``. Channel order is fixed and named in :data:`SENSOR_CHANNELS`.

IMU note: an accelerometer senses specific force, the net external force per mass in body axes,
:math:`a = \dot v_{body} + \omega \times v`. The paper prints
:math:`\frac{1}{m}(\dots) + v_y\omega` and :math:`\frac{1}{m}(\dots) - v_x\omega`, which equals
:math:`\dot v_x, \dot v_y` (zero in a steady turn); here the accelerometer model is the specific
force, so a steady turn reads the centripetal acceleration :math:`a_y = v_x \omega`.
"""

from __future__ import annotations

import casadi as ca

from crs_core.model.bicycle import ParameterAccess, body_specific_force
from crs_core.model.lighthouse import rotation_from_angles, sweep_angles

N_PHOTODIODES = 4


def imu(x: ca.SX, u: ca.SX, P: ParameterAccess) -> ca.SX:
    """``[a_x, a_y, omega]``: body specific force (m/s^2) and yaw rate (rad/s)."""
    ax, ay = body_specific_force(x, u, P)
    return ca.vertcat(ax, ay, x[5])


def wheel_encoders(x: ca.SX, u: ca.SX, P: ParameterAccess) -> ca.SX:
    """Wheel angular speeds ``[fl, fr, rl, rr]`` in rad/s, no-skid (paper Eq. 2)."""
    vx, vy, omega, delta = x[3], x[4], x[5], u[0]
    half_track = 0.5 * P("b_car") * omega
    lateral_front = vy + P("lf") * omega
    return ca.vertcat(
        ca.cos(delta) * (vx - half_track) + ca.sin(delta) * lateral_front,
        ca.cos(delta) * (vx + half_track) + ca.sin(delta) * lateral_front,
        vx - half_track,
        vx + half_track,
    ) / P("r")


def lighthouse(x: ca.SX, station: int, P: ParameterAccess) -> tuple[ca.SX, ca.SX]:
    """Sweep angles (rad) of the 4 photodiodes, planes 1 and 2 of base station ``station``."""
    b = f"bs{station}_"
    rotation = rotation_from_angles(P(b + "phi1"), P(b + "phi2"), P(b + "phi3"))
    position = ca.vertcat(P(b + "x"), P(b + "y"), P(b + "z"))
    diodes = [(P(f"lh_d{k}_x"), P(f"lh_d{k}_y")) for k in range(N_PHOTODIODES)]
    first, second = sweep_angles(x[0:3], diodes, rotation, position, P(b + "dt1"), P(b + "dt2"))
    return ca.vertcat(*first), ca.vertcat(*second)


def pose(x: ca.SX) -> ca.SX:
    """Motion-capture pose ``[x, y, yaw]`` (m, m, rad)."""
    return x[0:3]
