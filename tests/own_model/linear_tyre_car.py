"""A model written outside crs_core: a single-track car with linear tyres and rear drive only.

The textbook linear single-track model: the lateral tyre forces are proportional to the slip
angles (:math:`F_y = c\\,\\alpha`, cornering stiffnesses ``c_front``, ``c_rear`` N/rad), only the
rear axle drives (``drive`` N per unit torque command) and the car is slowed by a linear drag
(``drag`` N s/m). Its states have their own names (``px, py, heading, forward, lateral,
yaw_rate``), so it maps them to the car state itself. It is the example of docs/own-model.md and
is loaded by path in the tests (``--model tests/own_model/linear_tyre_car.py:LinearTyreCar``);
nothing in crs_core knows it.
"""

from __future__ import annotations

from typing import ClassVar

import casadi as ca
import numpy as np

from crs_core.model.plant import Plant
from crs_core.parameters import Parameter, ParameterSet

#: The slip angles' speed floor, m/s: below it the tyres see this speed (no division by zero).
SPEED_FLOOR = 0.3


class LinearTyreCar(Plant):
    """Linear tyres, rear-wheel drive, linear drag (module docstring)."""

    name = "linear_tyre"
    description = "single-track car, linear tyres, rear-wheel drive"
    states = (
        ("px", "m"),
        ("py", "m"),
        ("heading", "rad"),
        ("forward", "m/s"),
        ("lateral", "m/s"),
        ("yaw_rate", "rad/s"),
    )
    #: Each state is like the car state of the same place (the estimators' noise and bounds).
    like: ClassVar[dict[str, str]] = {
        "px": "x",
        "py": "y",
        "heading": "yaw",
        "forward": "vx",
        "lateral": "vy",
        "yaw_rate": "omega",
    }

    def parameters(self) -> ParameterSet:
        # name, value, unit, lower, upper, prior std, description
        rows = (
            ("m", 0.242, "kg", 0.1, 0.5, 0.01, "mass"),
            ("Iz", 0.0017, "kg m^2", 2e-4, 1e-2, 3e-4, "yaw inertia"),
            ("lf", 0.045, "m", 0.02, 0.08, 0.005, "centre of mass to front axle"),
            ("lr", 0.049, "m", 0.02, 0.08, 0.005, "centre of mass to rear axle"),
            ("c_front", 4.5, "N/rad", 0.5, 20.0, 1.0, "front cornering stiffness"),
            ("c_rear", 11.0, "N/rad", 0.5, 30.0, 2.0, "rear cornering stiffness"),
            ("drive", 0.95, "N", 0.1, 3.0, 0.1, "rear drive force per unit torque"),
            ("drag", 0.25, "N s/m", 0.0, 2.0, 0.05, "linear drag"),
            ("r", 0.0175, "m", 0.01, 0.03, 0.0005, "wheel radius"),
            ("b_car", 0.12, "m", 0.02, 0.2, 0.005, "track width the encoders see"),
        )
        return ParameterSet(
            [Parameter(n, v, u, lo, hi, sd, d, "own") for n, v, u, lo, hi, sd, d in rows]
        )

    def derivative(self, x, u, P):
        heading, forward, lateral, yaw_rate = x[2], x[3], x[4], x[5]
        steer, torque = u[0], u[1]
        speed = ca.fmax(ca.fabs(forward), SPEED_FLOOR)
        alpha_front = steer - (lateral + P("lf") * yaw_rate) / speed
        alpha_rear = -(lateral - P("lr") * yaw_rate) / speed
        fy_front = P("c_front") * alpha_front
        fy_rear = P("c_rear") * alpha_rear
        fx = P("drive") * torque - P("drag") * forward
        return ca.vertcat(
            forward * ca.cos(heading) - lateral * ca.sin(heading),
            forward * ca.sin(heading) + lateral * ca.cos(heading),
            yaw_rate,
            (fx - fy_front * ca.sin(steer)) / P("m") + lateral * yaw_rate,
            (fy_rear + fy_front * ca.cos(steer)) / P("m") - forward * yaw_rate,
            (P("lf") * fy_front * ca.cos(steer) - P("lr") * fy_rear) / P("Iz"),
        )

    def car_state(self, x, u, P):
        return x  # the same quantities as the car state, under other names

    def state_from_car(self, car, u, P):
        return np.asarray(car, dtype=float)
