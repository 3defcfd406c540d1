r"""Sweep angles of one base station and their derivatives, for calibration fits.

The angles are the model's own Lighthouse expressions
(:func:`crs_core.model.lighthouse.sweep_angles`, the function :class:`~crs_core.model.CarModel`
builds ``lighthouse/<s>/<l>`` from); only the station rotation is parametrised differently.
The model's Euler angles
:math:`R = R_z(\varphi_3) R_y(\varphi_2) R_x(\varphi_1)` lose a degree of freedom at
:math:`\varphi_2 = \pm\pi/2`, which is exactly a station looking straight down (the paper's
set-up), so the fit uses a local chart :math:`R = R_0\, R_z(\delta_3) R_y(\delta_2) R_x(\delta_1)`
around a start rotation :math:`R_0` (singular only 90 degrees away from it). The fitted station is
handed back as a :class:`~crs_core.model.lighthouse.BaseStation` (rotation matrix), and the
reports evaluate it through ``CarModel.output_function`` so both paths are cross-checked.

Station parameter vector (8): ``delta1..3`` (rad), ``x, y, z`` (m, world), ``dt1, dt2`` (rad).
"""

from __future__ import annotations

import math

import casadi as ca
import numpy as np

from crs_core.analysis.angles import wrap_angle
from crs_core.codegen import SX_OPTIONS, compile_functions
from crs_core.model.lighthouse import BaseStation, rotation_from_angles, sweep_angles
from crs_core.model.sensors import N_PHOTODIODES

#: Poses per call of the compiled functions (longer inputs are cut into chunks).
CHUNK = 128
#: Number of station parameters in the local chart.
N_STATION = 8
#: Number of photodiode parameters (x, y of each diode).
N_DIODES = 2 * N_PHOTODIODES
#: Largest symmetric tilt offset :func:`symmetric_tilt` hands to a start, rad (factory offsets
#: are a few degrees; beyond this the estimate is noise and the start uses 0).
MAX_START_TILT = 0.15
#: Smallest lever of the tilt in the homography :func:`symmetric_tilt` trusts (its docstring).
MIN_TILT_LEVER = 0.03


class SweepModel:
    """Batched sweep angles ``(8, N)`` (plane 1 diodes 0..3, then plane 2) with Jacobians.

    :meth:`evaluate` takes poses ``(N, 3)``, one station's chart parameters, its start rotation
    and the photodiodes, and returns the angles ``(N, 8)`` and the Jacobians w.r.t. the pose
    ``(N, 8, 3)``, the station parameters ``(N, 8, 8)`` and the photodiodes ``(N, 8, 8)``.
    """

    def __init__(self) -> None:
        pose = ca.SX.sym("pose", 3)
        theta = ca.SX.sym("theta", N_STATION)
        diodes = ca.SX.sym("diodes", N_DIODES)
        r0 = ca.SX.sym("r0", 3, 3)
        rotation = r0 @ rotation_from_angles(theta[0], theta[1], theta[2])
        body = [(diodes[2 * k], diodes[2 * k + 1]) for k in range(N_PHOTODIODES)]
        first, second = sweep_angles(pose, body, rotation, theta[3:6], theta[6], theta[7])
        y = ca.vertcat(*first, *second)
        full = ca.Function(
            "lh_calibration_sweeps",
            [pose, theta, diodes, r0],
            [
                y,
                ca.densify(ca.jacobian(y, pose)),
                ca.densify(ca.jacobian(y, theta)),
                ca.densify(ca.jacobian(y, diodes)),
            ],
            SX_OPTIONS,
        )
        values = ca.Function("lh_calibration_values", [pose, theta, diodes, r0], [y], SX_OPTIONS)
        shared = [1, 2, 3]  # theta, diodes, r0: one value for the whole chunk
        mapped = [
            full.map(f"{full.name()}_{CHUNK}", "serial", CHUNK, shared, []),
            values.map(f"{values.name()}_{CHUNK}", "serial", CHUNK, shared, []),
        ]
        compiled = compile_functions(mapped, f"lh_calibration_{CHUNK}")
        self._full, self._values = (compiled[f.name()] for f in mapped)

    def evaluate(
        self, poses: np.ndarray, theta: np.ndarray, rotation0: np.ndarray, diodes: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Angles and Jacobians at ``poses`` (N, 3) for one station (see class docstring)."""
        poses = np.asarray(poses, dtype=float).reshape(-1, 3)
        n = poses.shape[0]
        y, jq = np.zeros((n, 8)), np.zeros((n, 8, 3))
        jt, jd = np.zeros((n, 8, N_STATION)), np.zeros((n, 8, N_DIODES))
        shared = (
            np.asarray(theta, float),
            np.asarray(diodes, float).reshape(-1),
            np.asarray(rotation0, float),
        )
        for part, count, block in _chunks(poses):
            out = self._full(block, *shared)
            y[part] = out[0].T[:count]
            for target, jac in ((jq, out[1]), (jt, out[2]), (jd, out[3])):
                width = target.shape[2]
                target[part] = jac.reshape(8, CHUNK, width).transpose(1, 0, 2)[:count]
        return y, jq, jt, jd

    def angles(
        self, poses: np.ndarray, theta: np.ndarray, rotation0: np.ndarray, diodes: np.ndarray
    ) -> np.ndarray:
        """Angles only, ``(N, 8)``."""
        poses = np.asarray(poses, dtype=float).reshape(-1, 3)
        n = poses.shape[0]
        y = np.zeros((n, 8))
        shared = (
            np.asarray(theta, float),
            np.asarray(diodes, float).reshape(-1),
            np.asarray(rotation0, float),
        )
        for part, count, block in _chunks(poses):
            y[part] = self._values(block, *shared)[0].T[:count]
        return y


def station_from_chart(theta: np.ndarray, rotation0: np.ndarray) -> BaseStation:
    """The :class:`BaseStation` of chart parameters ``theta`` (8) around ``rotation0``."""
    rotation = np.asarray(rotation0) @ rotation_from_angles(*map(float, theta[0:3]))
    return BaseStation.from_rotation(
        rotation,
        (float(theta[3]), float(theta[4]), float(theta[5])),
        float(theta[6]),
        float(theta[7]),
    )


def bearings(alpha1: np.ndarray, alpha2: np.ndarray, dt1: float, dt2: float) -> np.ndarray:
    r"""Unit directions ``(N, 3)`` in the station frame from the two sweep angles of a diode.

    Inverts :math:`\alpha_l = \theta + \arcsin(\zeta \tan t_l)` (:math:`\zeta = z/r`): with
    :math:`a = \tan t_1`, :math:`b = \tan t_2`,
    :math:`\tan\theta = (b \sin\alpha_1 - a \sin\alpha_2)/(b \cos\alpha_1 - a \cos\alpha_2)`, on the
    branch with :math:`|\alpha_1 - \theta| < \pi/2`, and :math:`\zeta = \sin(\alpha_1-\theta)/a`;
    the direction is :math:`(\cos\theta, \sin\theta, \zeta)` normalised.
    """
    a = math.tan(-math.pi / 6 - dt1)
    b = math.tan(math.pi / 6 - dt2)
    alpha1, alpha2 = np.asarray(alpha1, dtype=float), np.asarray(alpha2, dtype=float)
    azimuth = np.arctan2(
        b * np.sin(alpha1) - a * np.sin(alpha2), b * np.cos(alpha1) - a * np.cos(alpha2)
    )
    azimuth = np.where(
        np.abs(wrap_angle(alpha1 - azimuth)) < math.pi / 2, azimuth, azimuth + math.pi
    )
    zeta = np.sin(alpha1 - azimuth) / a
    directions = np.stack([np.cos(azimuth), np.sin(azimuth), zeta], axis=-1)
    return directions / np.linalg.norm(directions, axis=-1, keepdims=True)


def station_from_bearings(
    world_xy: np.ndarray, directions: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    r"""Closed-form station pose from floor points and their bearings (planar DLT).

    A floor point :math:`P = (X, Y, 0)` is seen along :math:`d \propto M (P - p)` with
    :math:`M = R_{bs}^\top`, i.e. :math:`d \propto H (X, Y, 1)^\top` with
    :math:`H = [m_1\; m_2\; -M p]` (:func:`homography`), scaled so
    :math:`\|h_1\| + \|h_2\| = 2` and signed so the points lie ahead of the rays; :math:`M` is
    :math:`[h_1\; h_2\; h_1 \times h_2]` projected onto SO(3).

    Parameters
    ----------
    world_xy : (N, 2) floor points, m; N >= 4, not all on one line.
    directions : (N, 3) bearings in the station frame.

    Returns
    -------
    rotation, position : world-from-station rotation (3, 3) and station position (3,), m.
    """
    world_xy = np.asarray(world_xy, dtype=float)
    h = homography(world_xy, directions)
    h /= 0.5 * (np.linalg.norm(h[:, 0]) + np.linalg.norm(h[:, 1]))
    homogeneous = np.column_stack([world_xy, np.ones(len(world_xy))])
    if np.sum(np.einsum("ij,ij->i", (h @ homogeneous.T).T, directions)) < 0:
        h = -h
    m = np.column_stack([h[:, 0], h[:, 1], np.cross(h[:, 0], h[:, 1])])
    u, _, vt = np.linalg.svd(m)
    m = u @ np.diag([1.0, 1.0, np.linalg.det(u @ vt)]) @ vt
    position = -m.T @ h[:, 2]
    return m.T, position


def homography(world_xy: np.ndarray, directions: np.ndarray) -> np.ndarray:
    r"""The floor-to-bearing homography :math:`H` (3, 3), up to scale and sign.

    :math:`d \propto H (X, Y, 1)^\top`: each correspondence gives the rows of
    :math:`d \times H P = 0`; :math:`H` is their null vector (SVD, world points centred and
    scaled first). ``world_xy`` (N, 2) floor points, m; ``directions`` (N, 3) station frame.
    """
    world_xy = np.asarray(world_xy, dtype=float)
    centre = world_xy.mean(axis=0)
    scale = float(np.sqrt(np.mean(np.sum((world_xy - centre) ** 2, axis=1)))) or 1.0
    normalise = np.array(
        [[1 / scale, 0, -centre[0] / scale], [0, 1 / scale, -centre[1] / scale], [0, 0, 1]]
    )
    p = np.column_stack([(world_xy - centre) / scale, np.ones(len(world_xy))])
    d = np.asarray(directions, dtype=float)
    dx, dy, dz = d[:, 0:1], d[:, 1:2], d[:, 2:3]
    zero = np.zeros_like(p)
    # d x (H p) = 0, with H row-major in the unknown vector h = [row0, row1, row2]
    rows = np.concatenate(
        [
            np.hstack([zero, -dz * p, dy * p]),
            np.hstack([dz * p, zero, -dx * p]),
            np.hstack([-dy * p, dx * p, zero]),
        ]
    )
    _, _, vt = np.linalg.svd(rows, full_matrices=False)
    return vt[-1].reshape(3, 3) @ normalise


def symmetric_tilt(h: np.ndarray) -> float:
    r"""The symmetric tilt offset :math:`\delta` (``dt1 = delta``, ``dt2 = -delta``), rad, that
    makes the homography ``h`` of bearings computed with zero tilts a rigid one; 0 where the
    data cannot tell (or the value is implausible).

    Both planes tilted by :math:`\pi/6 + \delta` instead of :math:`\pi/6` leave the azimuth
    :math:`\theta` of a bearing unchanged and scale :math:`\zeta` by
    :math:`k = \tan(\pi/6 + \delta) / \tan(\pi/6)`: bearings computed with zero tilts are
    :math:`\operatorname{diag}(1, 1, k)` times the true ones, so their homography is
    :math:`H = \operatorname{diag}(1, 1, k) [m_1\; m_2\; -Mp]` with orthonormal :math:`m_1, m_2`.
    As in Zhang's camera calibration (the tilt plays the focal length), with
    :math:`w = 1/k^2`, :math:`h_{1x} h_{2x} + h_{1y} h_{2y} + w\, h_{1z} h_{2z} = 0` and
    :math:`|h_{1,xy}|^2 - |h_{2,xy}|^2 + w\,(h_{1z}^2 - h_{2z}^2) = 0`, solved for :math:`w`
    in least squares. Degenerate when the station's spin axis is normal to the floor
    (:math:`h_{1z} = h_{2z} = 0`): :math:`|b| / (|h_1|^2 + |h_2|^2)`, with
    :math:`b = (h_{1z} h_{2z}, h_{1z}^2 - h_{2z}^2)`, is about :math:`\sin^2(\lambda)/2` for a
    spin axis leaning :math:`\lambda` from the floor normal, and below
    :data:`MIN_TILT_LEVER` (:math:`\lambda` < 14 degrees) the estimate is noise (a station
    upright at 0.5 m, 3 m from the track: 0.15 rad off). The asymmetric part of the tilts
    (:math:`\theta` shifted in proportion to :math:`\zeta`) is not a homography and is left to
    the fit.
    """
    h1, h2 = h[:, 0], h[:, 1]
    a = np.array([h1[0] * h2[0] + h1[1] * h2[1], h1[:2] @ h1[:2] - h2[:2] @ h2[:2]])
    b = np.array([h1[2] * h2[2], h1[2] ** 2 - h2[2] ** 2])
    if not float(np.linalg.norm(b)) > MIN_TILT_LEVER * float(h1 @ h1 + h2 @ h2):
        return 0.0
    w = -float(a @ b) / float(b @ b)
    if not w > 0:
        return 0.0
    delta = math.atan(math.tan(math.pi / 6) / math.sqrt(w)) - math.pi / 6
    return delta if abs(delta) <= MAX_START_TILT else 0.0


def start_station(
    world_xy: np.ndarray,
    alpha1: np.ndarray,
    alpha2: np.ndarray,
    tilts: tuple[float, float] | None = None,
) -> BaseStation:
    """Closed-form start station from floor points and the two sweep angles seen there.

    Parameters
    ----------
    world_xy : (N, 2) floor points (photodiodes, or a point's centre), world frame, m.
    alpha1, alpha2 : (N,) their plane 1 and plane 2 sweep angles, rad.
    tilts : the station's ``(dt1, dt2)``, rad, or None when unknown: then
        :func:`symmetric_tilt` of the zero-tilt homography starts them (the start no prior
        geometry needs).

    Returns
    -------
    BaseStation
        Rotation and position from :func:`station_from_bearings` with those tilts.
    """
    world_xy = np.asarray(world_xy, dtype=float)
    if tilts is None:
        delta = symmetric_tilt(homography(world_xy, bearings(alpha1, alpha2, 0.0, 0.0)))
        tilts = (delta, -delta)
    rotation, position = station_from_bearings(world_xy, bearings(alpha1, alpha2, *tilts))
    return BaseStation.from_rotation(rotation, tuple(position), *tilts)


def _chunks(poses: np.ndarray):
    """``(rows, count, block)`` per ``CHUNK`` poses: the (3, CHUNK) input of the compiled
    functions, padded past ``count`` with its first pose (any valid pose)."""
    for begin in range(0, poses.shape[0], CHUNK):
        count = min(CHUNK, poses.shape[0] - begin)
        block = np.zeros((3, CHUNK))
        block[:, :count] = poses[begin : begin + count].T
        block[:, count:] = block[:, :1]
        yield slice(begin, begin + count), count, block
