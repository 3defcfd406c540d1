"""Tests of crs_core.model.lighthouse: the station rotation and the sweep-angle model."""

from __future__ import annotations

import math

import casadi as ca
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from crs_core.errors import FieldError
from crs_core.model.lighthouse import (
    RECORDED_BASE_STATION,
    BaseStation,
    angles_from_rotation,
    rotation_from_angles,
    sweep_angles,
)

ANGLES = [(0.3, -0.4, 2.0), (math.pi, 0.0, 2.498), (-1.2, 1.1, -0.7)]


@pytest.mark.parametrize("angles", ANGLES)
def test_rotation_is_rz_ry_rx_for_numbers_and_symbols(angles):
    """``R = Rz(phi3) Ry(phi2) Rx(phi1)``, against SciPy's intrinsic z-y-x Euler rotation."""
    phi1, phi2, phi3 = angles
    expected = Rotation.from_euler("ZYX", [phi3, phi2, phi1]).as_matrix()
    np.testing.assert_allclose(rotation_from_angles(*angles), expected, atol=1e-12)
    symbolic = rotation_from_angles(ca.DM(phi1), ca.DM(phi2), ca.DM(phi3))
    np.testing.assert_allclose(np.array(symbolic), expected, atol=1e-12)


@pytest.mark.parametrize("angles", ANGLES)
def test_angles_from_rotation_inverts_rotation_from_angles(angles):
    """The angles read back give the same rotation (a rounded matrix is projected first)."""
    rotation = rotation_from_angles(*angles)
    back = angles_from_rotation(np.round(rotation, 6))
    assert abs(back[1]) < math.pi / 2
    np.testing.assert_allclose(rotation_from_angles(*back), rotation, atol=1e-5)


def test_a_reflection_is_refused_naming_the_rotation():
    with pytest.raises(FieldError, match=r"^rotation: matrix is a reflection"):
        BaseStation.from_rotation(np.diag([1.0, 1.0, -1.0]), (0.0, 0.0, 2.0), 0.0, 0.0)


def _angles(pose, diode, station: BaseStation) -> tuple[float, float]:
    x, y, psi = ca.SX.sym("x"), ca.SX.sym("y"), ca.SX.sym("psi")
    first, second = sweep_angles(
        ca.vertcat(x, y, psi),
        [diode],
        ca.DM(station.rotation),
        ca.DM(station.position),
        station.dt1,
        station.dt2,
    )
    f = ca.Function("a", [x, y, psi], [first[0], second[0]])
    return tuple(float(v) for v in f(*pose))


@pytest.mark.parametrize("pose", [(1.0, 0.5, 0.3), (-0.8, 0.2, -2.0), (0.4, -1.0, 3.0)])
def test_each_light_plane_passes_through_the_photodiode_at_its_sweep_angle(pose):
    """Seen from the recorded station, plane ``l`` (tilted by ``t_l``, turned by its sweep angle
    ``a`` about the station's z axis) contains the photodiode: the plane's normal
    ``(sin a cos t, -cos a cos t, -sin t)`` is orthogonal to the diode's station-frame position.
    Without tilt offsets the two planes' angles lie symmetric about the diode's azimuth."""
    station = RECORDED_BASE_STATION
    diode = (-0.045, 0.015)
    x, y, psi = pose
    world = np.array(
        [
            x + math.cos(psi) * diode[0] - math.sin(psi) * diode[1],
            y + math.sin(psi) * diode[0] + math.cos(psi) * diode[1],
            0.0,
        ]
    )
    local = station.rotation.T @ (world - np.array(station.position))
    tilts = (-math.pi / 6 - station.dt1, math.pi / 6 - station.dt2)
    for a, t in zip(_angles(pose, diode, station), tilts, strict=True):
        normal = np.array([math.sin(a) * math.cos(t), -math.cos(a) * math.cos(t), -math.sin(t)])
        assert normal @ local == pytest.approx(0.0, abs=1e-12)
    level = BaseStation(station.angles, station.position, 0.0, 0.0)
    a1, a2 = _angles(pose, diode, level)
    assert 0.5 * (a1 + a2) == pytest.approx(math.atan2(local[1], local[0]), abs=1e-12)
