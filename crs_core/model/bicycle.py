r"""Dynamic bicycle model of the Chronos car (paper, Sec. III-A), written once in CasADi.

State :math:`x = [x_p, y_p, \psi, v_x, v_y, \omega]` (world position m, yaw rad, body
velocities m/s, yaw rate rad/s), input :math:`u = [\delta, T]` (steering angle rad, normalised
torque command). Every function takes symbols and a parameter accessor ``P`` (``P["m"]`` is the
symbol of the mass), so the expressions are built once and turned into fast functions elsewhere.

Two documented departures from the paper's formulas, both at low speed:

* **Low-speed slip angles.** The paper's cubics for :math:`|v_x| < \epsilon` vanish at
  :math:`v_x = 0` whatever :math:`v_y` and :math:`\omega`: a car that stopped while turning kept
  turning on the spot (0.5 rad/s for seconds in an emulated race, where a real car's tires stop
  it at once). Here the slip angle is :math:`\arctan(N / d(v_x)) + \delta\,\sigma(v_x)`, with
  :math:`N` the contact patch's lateral velocity term (:math:`-\omega l_f - v_y` front,
  :math:`\omega l_r - v_y` rear), :math:`d = |v_x|` and :math:`\sigma = \operatorname{sgn} v_x`
  for :math:`|v_x| \ge \epsilon` (the paper's formula going forward), and inside, with
  :math:`s = v_x / \epsilon`, the even quartic :math:`d = \epsilon(a + b s^2 + c s^4)`
  (:data:`STANDSTILL_DENOMINATOR` :math:`a`, value and slope matching :math:`|v_x|` at
  :math:`\pm\epsilon`, never below :math:`0.84\,\epsilon`) and the odd cubic
  :math:`\sigma = s(3 - s^2)/2`. So the slip is :math:`C^1` in :math:`v_x`; at rest the steering
  makes no force (no creeping) while a sliding or turning car is braked by its tires; and
  reversing, the steering acts with the sign of :math:`v_x` and the tires oppose the sliding
  (the paper's :math:`\arctan(N / v_x)` would push it).
* **Friction sign.** :math:`F_{fr} = \operatorname{sgn}(v_x)(C_{d2} v_x^2 + C_{d0}) + C_{d1} v_x`,
  identical to the paper's :math:`\operatorname{sgn}(v_x)(C_{d2}v_x^2 + C_{d1}v_x + C_{d0})` for
  :math:`v_x \ge 0` and odd in :math:`v_x` (the paper's form would make viscous drag push a
  reversing car). The sign is smoothed as :math:`\tanh(v_x / v_s)` with
  :data:`FRICTION_SIGN_SPEED` :math:`v_s`; it is exactly zero at :math:`v_x = 0`, so a car at
  rest with zero input stays at rest, and it has no discontinuity for the integrator to chatter
  on. Below :math:`v_s` (1 cm/s) Coulomb friction fades linearly.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import casadi as ca
import numpy as np

from crs_core.model.chronos import dynamics_parameters
from crs_core.model.plant import CAR_STATE_NAMES, CAR_STATE_UNITS, ParameterAccess, Plant
from crs_core.model.sensors import wheel_speeds
from crs_core.parameters import ParameterSet

#: Low-speed slip denominator at standstill, a fraction of ``eps``: 0.9 keeps the fastest
#: dynamics at rest within RK4's stable step at :data:`~crs_core.model.MAX_SUBSTEP`.
STANDSTILL_DENOMINATOR = 0.9

#: Speed scale (m/s) of the smoothed friction sign :math:`\tanh(v_x / v_s)`.
FRICTION_SIGN_SPEED = 0.01

#: The dynamic bicycle's states are the car state itself.
STATE_NAMES = CAR_STATE_NAMES
STATE_UNITS = CAR_STATE_UNITS


@dataclass(frozen=True)
class AxleForces:
    """Tire and drive forces in the wheel frames, N (see paper Fig. 3)."""

    fx_front: ca.SX
    fx_rear: ca.SX
    fy_front: ca.SX
    fy_rear: ca.SX
    friction: ca.SX


def _slip(numerator: ca.SX, steer: ca.SX | float, vx: ca.SX, eps: ca.SX) -> ca.SX:
    r"""Slip angle :math:`\arctan(N / d(v_x)) + \delta\,\sigma(v_x)`, rad (module docstring)."""
    s = vx / eps
    inside = ca.fabs(vx) < eps
    a = STANDSTILL_DENOMINATOR
    quartic = eps * (a + (3 - 4 * a) / 2 * s**2 + (2 * a - 1) / 2 * s**4)
    denominator = ca.if_else(inside, quartic, ca.fabs(vx))
    direction = ca.if_else(inside, s * (3 - s**2) / 2, ca.sign(vx))
    return ca.atan(numerator / denominator) + steer * direction


def slip_angles(x: ca.SX, u: ca.SX, P: ParameterAccess) -> tuple[ca.SX, ca.SX]:
    """Front and rear slip angles :math:`(\\alpha_f, \\alpha_r)`, rad."""
    vx, vy, omega = x[3], x[4], x[5]
    alpha_f = _slip(-omega * P("lf") - vy, u[0], vx, P("eps"))
    alpha_r = _slip(omega * P("lr") - vy, 0.0, vx, P("eps"))
    return alpha_f, alpha_r


def cornering_stiffness(D: float, C: float, B: float) -> float:
    r"""Slope of an axle's Pacejka curve :math:`F_y = D \sin(C \arctan(B \alpha))` at zero
    slip, :math:`\partial F_y / \partial \alpha |_{\alpha=0} = D C B` (N/rad): the linear
    tyre, which driving within the grip determines even where it leaves D and B apart."""
    return D * C * B


def peak_slip(C: float, B: float) -> float:
    r"""Slip angle at the peak of an axle's Pacejka curve, :math:`\tan(\pi / (2C)) / B`, rad
    (for :math:`C > 1`): a drive that stays below it bends the curve only so far."""
    return math.tan(math.pi / (2.0 * C)) / B


def grip_used(states: np.ndarray, inputs: np.ndarray, P: Callable[[str], float]) -> np.ndarray:
    r"""How much of each axle's grip a drive used: :math:`|F_y| / D` of the front and rear
    tyre (columns) per row of ``states`` (N x 6) and ``inputs`` (N x 2), with the numeric
    parameters ``P``; 1 at the peak of the Pacejka curve, where the drive would tell :math:`D`
    apart from :math:`B`."""

    def constant(name: str) -> ca.SX:
        return ca.SX(P(name))

    x, u = ca.SX.sym("x", 6), ca.SX.sym("u", 2)
    forces = axle_forces(x, u, constant)
    used = ca.vertcat(ca.fabs(forces.fy_front) / P("Df"), ca.fabs(forces.fy_rear) / P("Dr"))
    rows = ca.Function("grip_used", [x, u], [used]).map(len(states))
    return np.asarray(rows(np.asarray(states).T, np.asarray(inputs).T)).T


def motor_force(v: ca.SX, torque: ca.SX, P: ParameterAccess) -> ca.SX:
    """The motor's force (N) at speed ``v`` (m/s) under the applied torque command: the
    paper's :math:`(C_{m1} - C_{m2} v) T`."""
    return (P("Cm1") - P("Cm2") * v) * torque


def friction_force(v: ca.SX, P: ParameterAccess) -> ca.SX:
    """Rolling resistance and drag (N) at speed ``v`` (m/s), odd in ``v`` (module docstring)."""
    sign = ca.tanh(v / FRICTION_SIGN_SPEED)
    return sign * (P("Cd2") * v**2 + P("Cd0")) + P("Cd1") * v


def axle_forces(x: ca.SX, u: ca.SX, P: ParameterAccess) -> AxleForces:
    """Pacejka lateral forces, AWD-split motor force and friction (paper Sec. III-A)."""
    vx = x[3]
    alpha_f, alpha_r = slip_angles(x, u, P)
    fy_front = P("Df") * ca.sin(P("Cf") * ca.atan(P("Bf") * alpha_f))
    fy_rear = P("Dr") * ca.sin(P("Cr") * ca.atan(P("Br") * alpha_r))
    motor = motor_force(vx, u[1], P)
    friction = friction_force(vx, P)
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


class DynamicBicycle(Plant):
    """The paper's dynamic bicycle with Pacejka tyres and the all-wheel-drive split: the
    suite's default model, whose states are the car state."""

    name = "dynamic"
    description = "dynamic bicycle, Pacejka tyres, all-wheel drive (paper Sec. III-A)"
    states = tuple(zip(STATE_NAMES, STATE_UNITS, strict=True))
    #: The paper's 15 dynamics parameters and the wheel encoders' radius and track width (the
    #: encoders see the effective track width, not the nominal one: on real run 1 from the
    #: rough prior, validated on run 2, 0.230 m held out without them, 0.173 m with them).
    default_fit = (
        *("m", "Iz", "lf", "lr", "Df", "Cf", "Bf", "Dr", "Cr", "Br"),
        *("Cm1", "Cm2", "Cd0", "Cd1", "Cd2", "r", "b_car"),
    )

    def parameters(self) -> ParameterSet:
        """The paper's 15 parameters, ``gamma``, ``eps`` and the encoder geometry."""
        return dynamics_parameters()

    def derivative(self, x: ca.SX, u: ca.SX, P: ParameterAccess) -> ca.SX:
        """:func:`state_derivative`."""
        return state_derivative(x, u, P)

    def car_state(self, x: ca.SX, u: ca.SX, P: ParameterAccess) -> ca.SX:
        """The state itself."""
        return x

    def sensors(self, x: ca.SX, u: ca.SX, P: ParameterAccess) -> dict[str, ca.SX]:
        """The IMU from the axle forces (specific force and yaw rate) and the wheel encoders."""
        ax, ay = body_specific_force(x, u, P)
        return {"imu": ca.vertcat(ax, ay, x[5]), "wheel_encoders": wheel_speeds(x, u[0], P)}
