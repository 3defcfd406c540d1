r"""Dynamic bicycle model of the Chronos car (paper, Sec. III-A), written once in CasADi.

State :math:`x = [x_p, y_p, \psi, v_x, v_y, \omega]` (world position m, yaw rad, body
velocities m/s, yaw rate rad/s), input :math:`u = [\delta, T]` (steering angle rad, normalised
torque command). Every function takes symbols and a parameter accessor ``P`` (``P["m"]`` is the
symbol of the mass), so the expressions are built once and turned into fast functions elsewhere.

Two documented choices where the paper's formulas leave a gap:

* **Low-speed slip angles.** For :math:`|v_x| < \epsilon` the slip angles are odd cubics
  :math:`b v_x + c v_x^3` whose value and slope match the arctangent branch at
  :math:`v_x = +\epsilon` (for :math:`v_x \ge 0`) or at :math:`v_x = -\epsilon` (for
  :math:`v_x < 0`). Slip is therefore :math:`C^1` across both junctions and zero at standstill, so
  a car at rest has no tire force even with the wheels turned. For the rear axle both sides share
  one cubic; for the front axle (which carries :math:`+\delta`) the two cubics differ in slope at
  :math:`v_x = 0` only (continuous there, kink proportional to :math:`\delta`).
* **Friction sign.** :math:`F_{fr} = \operatorname{sgn}(v_x)(C_{d2} v_x^2 + C_{d0}) + C_{d1} v_x`,
  identical to the paper's :math:`\operatorname{sgn}(v_x)(C_{d2}v_x^2 + C_{d1}v_x + C_{d0})` for
  :math:`v_x \ge 0` and odd in :math:`v_x` (the paper's form would make viscous drag push a
  reversing car). The sign is smoothed as :math:`\tanh(v_x / v_s)` with
  :data:`FRICTION_SIGN_SPEED` :math:`v_s`; it is exactly zero at :math:`v_x = 0`, so a car at
  rest with zero input stays at rest, and it has no discontinuity for the integrator to chatter
  on. Below :math:`v_s` (1 cm/s) Coulomb friction fades linearly.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import casadi as ca

#: Speed scale (m/s) of the smoothed friction sign :math:`\tanh(v_x / v_s)`.
FRICTION_SIGN_SPEED = 0.01

STATE_NAMES = ("x", "y", "yaw", "vx", "vy", "omega")
STATE_UNITS = ("m", "m", "rad", "m/s", "m/s", "rad/s")
INPUT_NAMES = ("steer", "torque")
INPUT_UNITS = ("rad", "-")

ParameterAccess = Callable[[str], ca.SX]


@dataclass(frozen=True)
class AxleForces:
    """Tire and drive forces in the wheel frames, N (see paper Fig. 3)."""

    fx_front: ca.SX
    fx_rear: ca.SX
    fy_front: ca.SX
    fy_rear: ca.SX
    friction: ca.SX


def _slip_with_low_speed_cubic(numerator: ca.SX, offset: ca.SX, vx: ca.SX, eps: ca.SX) -> ca.SX:
    r"""``atan(numerator / vx) + offset`` for :math:`|v_x| \ge \epsilon`, odd cubic inside.

    The cubic :math:`b v + c v^3` satisfies :math:`p(e) = a`, :math:`p'(e) = d` at
    :math:`e = \pm\epsilon` (sign of :math:`v_x`) with :math:`a = \arctan(N/e) + \text{offset}`
    and :math:`d = -N / (e^2 + N^2)`: :math:`c = (d - a/e) / (2e^2)`, :math:`b = (3a/e - d)/2`.
    """
    e = ca.if_else(vx >= 0, eps, -eps)
    a = ca.atan(numerator / e) + offset
    d = -numerator / (e**2 + numerator**2)
    c = (d - a / e) / (2 * e**2)
    b = (3 * a / e - d) / 2
    outside = ca.fabs(vx) >= eps
    safe_vx = ca.if_else(outside, vx, e)  # keeps the unused branch finite at vx = 0
    return ca.if_else(outside, ca.atan(numerator / safe_vx) + offset, b * vx + c * vx**3)


def slip_angles(x: ca.SX, u: ca.SX, P: ParameterAccess) -> tuple[ca.SX, ca.SX]:
    """Front and rear slip angles :math:`(\\alpha_f, \\alpha_r)`, rad."""
    vx, vy, omega = x[3], x[4], x[5]
    alpha_f = _slip_with_low_speed_cubic(-omega * P("lf") - vy, u[0], vx, P("eps"))
    alpha_r = _slip_with_low_speed_cubic(omega * P("lr") - vy, 0, vx, P("eps"))
    return alpha_f, alpha_r


def axle_forces(x: ca.SX, u: ca.SX, P: ParameterAccess) -> AxleForces:
    """Pacejka lateral forces, AWD-split motor force and friction (paper Sec. III-A)."""
    vx = x[3]
    alpha_f, alpha_r = slip_angles(x, u, P)
    fy_front = P("Df") * ca.sin(P("Cf") * ca.atan(P("Bf") * alpha_f))
    fy_rear = P("Dr") * ca.sin(P("Cr") * ca.atan(P("Br") * alpha_r))
    motor = (P("Cm1") - P("Cm2") * vx) * u[1]
    sign = ca.tanh(vx / FRICTION_SIGN_SPEED)
    friction = sign * (P("Cd2") * vx**2 + P("Cd0")) + P("Cd1") * vx
    return AxleForces(
        fx_front=(1 - P("gamma")) * motor,
        fx_rear=P("gamma") * motor,
        fy_front=fy_front,
        fy_rear=fy_rear,
        friction=friction,
    )


def body_specific_force(x: ca.SX, u: ca.SX, P: ParameterAccess) -> tuple[ca.SX, ca.SX]:
    """Net external force per mass in the body frame, m/s^2 (what an accelerometer senses)."""
    F = axle_forces(x, u, P)
    delta = u[0]
    ax = (F.fx_rear + F.fx_front * ca.cos(delta) - F.fy_front * ca.sin(delta) - F.friction) / P("m")
    ay = (F.fy_rear + F.fx_front * ca.sin(delta) + F.fy_front * ca.cos(delta)) / P("m")
    return ax, ay


def state_derivative(x: ca.SX, u: ca.SX, P: ParameterAccess) -> ca.SX:
    """Right-hand side :math:`\\dot x = f_c(x, u)` of the paper's Eq. (1)."""
    psi, vx, vy, omega = x[2], x[3], x[4], x[5]
    delta = u[0]
    F = axle_forces(x, u, P)
    ax, ay = body_specific_force(x, u, P)
    yaw_moment = (
        F.fy_front * P("lf") * ca.cos(delta)
        + F.fx_front * P("lf") * ca.sin(delta)
        - F.fy_rear * P("lr")
    )
    return ca.vertcat(
        vx * ca.cos(psi) - vy * ca.sin(psi),
        vx * ca.sin(psi) + vy * ca.cos(psi),
        omega,
        ax + vy * omega,
        ay - vx * omega,
        yaw_moment / P("Iz"),
    )
