r"""Lighthouse V2 geometry and the sweep-angle measurement model (paper, Sec. III-B.3).

A base station spins two light planes about its own :math:`z` axis. Plane :math:`l` is tilted by
:math:`t_1 = -\pi/6 - \delta t_1` or :math:`t_2 = \pi/6 - \delta t_2`. A photodiode at
:math:`{}_{\mathcal L}p = (x, y, z)` in the station frame is hit when the plane passes through
it, at the sweep angle

.. math::

    \alpha_l = \operatorname{atan2}(y, x)
              + \arcsin\!\left(\frac{z \tan t_l}{\sqrt{x^2+y^2}}\right)

(the paper writes :math:`\tan^{-1}(y/x)`; ``atan2`` is identical for :math:`x > 0`, the region a
downward-looking station covers, and stays defined elsewhere). The station pose is
:math:`R_{bs} = R_z(\varphi_3) R_y(\varphi_2) R_x(\varphi_1)` (world from station) and
:math:`p_{bs}` (world, m). :func:`rotation_from_angles` takes numbers or CasADi symbols;
:func:`sweep_angles` builds CasADi expressions.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import casadi as ca
import numpy as np

from crs_core.errors import FieldError


def rotation_from_angles(phi1: Any, phi2: Any, phi3: Any) -> Any:
    r"""World-from-station rotation :math:`R_z(\varphi_3) R_y(\varphi_2) R_x(\varphi_1)`.

    Works for floats (returns ``np.ndarray``) and CasADi symbols (returns ``SX``/``MX``).
    """
    symbolic = any(isinstance(a, ca.SX | ca.MX | ca.DM) for a in (phi1, phi2, phi3))
    lib = ca if symbolic else np
    c1, s1 = lib.cos(phi1), lib.sin(phi1)
    c2, s2 = lib.cos(phi2), lib.sin(phi2)
    c3, s3 = lib.cos(phi3), lib.sin(phi3)
    rows = [
        [c3 * c2, c3 * s2 * s1 - s3 * c1, c3 * s2 * c1 + s3 * s1],
        [s3 * c2, s3 * s2 * s1 + c3 * c1, s3 * s2 * c1 - c3 * s1],
        [-s2, c2 * s1, c2 * c1],
    ]
    if symbolic:
        return ca.vertcat(*[ca.horzcat(*row) for row in rows])
    return np.array(rows, dtype=float)


def angles_from_rotation(rotation: np.ndarray) -> tuple[float, float, float]:
    r"""Inverse of :func:`rotation_from_angles` for :math:`|\varphi_2| < \pi/2`.

    The matrix is first projected onto SO(3) (published matrices are rounded).
    """
    u, _, vt = np.linalg.svd(np.asarray(rotation, dtype=float))
    r = u @ vt
    if np.linalg.det(r) < 0:
        raise FieldError("rotation", "matrix is a reflection (det < 0)")
    phi2 = -math.asin(max(-1.0, min(1.0, r[2, 0])))
    phi1 = math.atan2(r[2, 1], r[2, 2])
    phi3 = math.atan2(r[1, 0], r[0, 0])
    return phi1, phi2, phi3


@dataclass(frozen=True)
class BaseStation:
    """Pose and factory calibration of one Lighthouse V2 base station.

    Attributes
    ----------
    angles : tuple of float
        :math:`(\\varphi_1, \\varphi_2, \\varphi_3)` in rad, world-from-station rotation.
    position : tuple of float
        :math:`p_{bs}` in the world frame, m.
    dt1, dt2 : float
        Factory light-plane tilt offsets, rad.
    """

    angles: tuple[float, float, float]
    position: tuple[float, float, float]
    dt1: float
    dt2: float

    @classmethod
    def from_rotation(
        cls, rotation: np.ndarray, position: tuple[float, float, float], dt1: float, dt2: float
    ) -> BaseStation:
        x, y, z = map(float, position)
        return cls(angles_from_rotation(rotation), (x, y, z), dt1, dt2)

    @property
    def rotation(self) -> np.ndarray:
        return rotation_from_angles(*self.angles)


#: The base station of the real recordings in ``data/chronos_real`` (its README).
RECORDED_BASE_STATION = BaseStation.from_rotation(
    np.array(
        [
            [-0.00170188, 0.99949, 0.031886],
            [-0.367629, 0.0290278, -0.92952],
            [-0.929971, -0.0133041, 0.367392],
        ]
    ),
    (0.189362, 0.138069, 1.74295),
    dt1=-0.0508728,
    dt2=0.0464478,
)

#: Photodiode positions of the Lighthouse deck in the car body frame (x, y), m; z = 0.
RECORDED_PHOTODIODES: tuple[tuple[float, float], ...] = (
    (-0.045, 0.015),
    (-0.06, 0.015),
    (-0.045, -0.015),
    (-0.06, -0.015),
)


def sweep_angles(
    pose: ca.SX,
    photodiodes_body: list[tuple[ca.SX, ca.SX]],
    rotation: ca.SX,
    position: ca.SX,
    dt1: ca.SX,
    dt2: ca.SX,
) -> tuple[list[ca.SX], list[ca.SX]]:
    """Sweep angles of every photodiode for both light planes of one base station (symbolic).

    Parameters
    ----------
    pose : SX
        ``(x_p, y_p, psi)`` of the car in the world frame (m, m, rad); the car is planar, z = 0.
    photodiodes_body : list of (x, y)
        Photodiode positions in the body frame, m.
    rotation : SX 3x3
        World-from-station rotation :math:`R_{bs}`.
    position : SX 3-vector
        Station position :math:`p_{bs}` in the world frame, m.
    dt1, dt2 : SX
        Light-plane tilt offsets, rad.

    Returns
    -------
    first_plane, second_plane : list of SX
        One angle (rad) per photodiode and plane.
    """
    xp, yp, psi = pose[0], pose[1], pose[2]
    c, s = ca.cos(psi), ca.sin(psi)
    tilts = (-math.pi / 6 - dt1, math.pi / 6 - dt2)
    planes: tuple[list[ca.SX], list[ca.SX]] = ([], [])
    for bx, by in photodiodes_body:
        world = ca.vertcat(xp + c * bx - s * by, yp + s * bx + c * by, 0) - position
        local = rotation.T @ world  # station frame
        radius = ca.sqrt(local[0] ** 2 + local[1] ** 2)
        azimuth = ca.atan2(local[1], local[0])
        for plane, tilt in zip(planes, tilts, strict=True):
            plane.append(azimuth + ca.asin(local[2] * ca.tan(tilt) / radius))
    return planes
