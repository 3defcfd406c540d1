r"""How long an explicit RK4 step may be for the car model: measured, not guessed.

RK4 applied to :math:`\dot x = \lambda x` multiplies the state by
:math:`R(z) = 1 + z + z^2/2 + z^3/6 + z^4/24` with :math:`z = h\lambda`; a step is stable when
:math:`|R(h\lambda)| \le 1` for every eigenvalue :math:`\lambda` of the Jacobian
:math:`\partial f / \partial x`. :func:`largest_stable_step` bisects on :math:`h` over operating
points.
"""

from __future__ import annotations

from collections.abc import Iterable

import casadi as ca
import numpy as np

from crs_core.model.car_model import CarModel


def rk4_amplification(z: np.ndarray) -> np.ndarray:
    """:math:`|R(z)|` of the classical RK4 method."""
    return np.abs(1 + z + z**2 / 2 + z**3 / 6 + z**4 / 24)


def jacobian_eigenvalues(model: CarModel, x: np.ndarray, u: np.ndarray) -> np.ndarray:
    """Eigenvalues (1/s) of the dynamics Jacobian at state ``x`` and command ``u``."""
    jac = ca.Function(
        "A",
        [model.x_sym, model.u_sym, model.p_sym],
        [ca.jacobian(model.xdot_expression, model.x_sym)],
    )
    a = np.array(jac(x, u, model.parameters.vector()))
    return np.linalg.eigvals(a)


def largest_stable_step(
    model: CarModel, points: Iterable[tuple[np.ndarray, np.ndarray]], h_max: float = 0.2
) -> float:
    """Largest RK4 step (s) stable at every ``(x, u)`` in ``points`` (to 0.1 % relative)."""
    eigenvalues = np.concatenate([jacobian_eigenvalues(model, x, u) for x, u in points])
    lo, hi = 0.0, h_max
    while hi - lo > 1e-3 * hi:
        mid = (lo + hi) / 2
        if np.all(rk4_amplification(mid * eigenvalues) <= 1 + 1e-12):
            lo = mid
        else:
            hi = mid
    return lo


def operating_grid(
    speeds: Iterable[float], steers: Iterable[float] = (-0.34, 0.0, 0.34)
) -> list[tuple[np.ndarray, np.ndarray]]:
    """Steady-looking operating points: speed ``v_x``, steering, matching kinematic yaw rate."""
    points = []
    for vx in speeds:
        for delta in steers:
            omega = vx * np.tan(delta) / (0.04448988 + 0.04866242)
            points.append((np.array([0, 0, 0, vx, 0, omega]), np.array([delta, 0.3])))
    return points
