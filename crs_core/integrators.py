r"""Explicit Runge-Kutta discretization of a continuous-time model.

The input is held constant over a step (zero-order hold, as the car's firmware applies it).
The step length is an argument, since recorded and simulated data are not uniformly sampled.
"""

from __future__ import annotations

from collections.abc import Callable

import casadi as ca


def rk4(
    rhs: Callable[[ca.SX, ca.SX], ca.SX], x: ca.SX, u: ca.SX, dt: ca.SX, substeps: int
) -> ca.SX:
    r"""State after ``dt`` seconds: ``substeps`` classical RK4 steps of ``dt / substeps``.

    Parameters
    ----------
    rhs : callable
        :math:`(x, u) \mapsto \dot x`.
    x, u : SX
        State and (held) input.
    dt : SX or float
        Step length, s.
    substeps : int
        Number of RK4 substeps (fixed when the expression is built).
    """
    if substeps < 1:
        raise ValueError("substeps must be >= 1")
    h = dt / substeps
    for _ in range(substeps):
        k1 = rhs(x, u)
        k2 = rhs(x + h / 2 * k1, u)
        k3 = rhs(x + h / 2 * k2, u)
        k4 = rhs(x + h * k3, u)
        x = x + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
    return x
