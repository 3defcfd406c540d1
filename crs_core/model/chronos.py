"""Parameters of the Chronos car: the identified values published with the real recordings.

The defaults are the values the CRS authors identified for the car in ``data/chronos_real``
(its README); bounds are physically admissible ranges, and ``prior_std`` the one-sigma width of
the Gaussian prior used by identification. The Lighthouse geometry defaults to the single base
station of those recordings, so simulated and real datasets are directly comparable.
"""

from __future__ import annotations

import math

import numpy as np

from crs_core.model.lighthouse import (
    RECORDED_BASE_STATION,
    RECORDED_PHOTODIODES,
    BaseStation,
    rotation_from_angles,
)
from crs_core.parameters import Parameter, ParameterSet

# name, value, unit, lower, upper, prior_std, group, description
_DYNAMICS = (
    ("m", 0.242, "kg", 0.1, 0.5, 0.01, "car", "mass"),
    ("Iz", 0.00165671, "kg m^2", 2e-4, 1e-2, 3e-4, "car", "yaw inertia about the centre of mass"),
    ("lf", 0.04448988, "m", 0.02, 0.08, 0.005, "car", "centre of mass to front axle"),
    ("lr", 0.04866242, "m", 0.02, 0.08, 0.005, "car", "centre of mass to rear axle"),
    ("Df", 0.6145578, "N", 0.05, 3.0, 0.1, "tire", "front Pacejka peak force"),
    ("Cf", 1.484958, "-", 0.5, 2.5, 0.1, "tire", "front Pacejka shape factor"),
    ("Bf", 5.19600518, "1/rad", 0.5, 20.0, 1.0, "tire", "front Pacejka stiffness factor"),
    ("Dr", 0.98898878, "N", 0.05, 3.0, 0.1, "tire", "rear Pacejka peak force"),
    ("Cr", 1.44614978, "-", 0.5, 2.5, 0.1, "tire", "rear Pacejka shape factor"),
    ("Br", 8.49942885, "1/rad", 0.5, 20.0, 1.0, "tire", "rear Pacejka stiffness factor"),
    ("Cm1", 0.9751147, "N", 0.1, 3.0, 0.1, "motor", "motor force per unit torque command"),
    ("Cm2", 0.02578073, "N s/m", 0.0, 1.0, 0.02, "motor", "back-EMF loss per unit torque"),
    ("Cd0", 0.02477582, "N", 0.0, 0.5, 0.01, "friction", "rolling resistance"),
    ("Cd1", 0.03031928, "N s/m", 0.0, 0.5, 0.01, "friction", "viscous drag"),
    ("Cd2", 0.08473512, "N s^2/m^2", 0.0, 0.5, 0.02, "friction", "quadratic drag"),
    ("gamma", 0.50199235, "-", 0.0, 1.0, 0.05, "motor", "share of motor force on rear axle"),
    ("eps", 0.2, "m/s", 0.01, 1.0, 0.0, "tire", "low-speed slip threshold"),
    ("r", 0.0175, "m", 0.01, 0.03, 0.0005, "encoder", "wheel radius"),
    # only the encoder model uses it: the track width the wheel speeds see. The real recordings
    # imply 0.040 m (r * (right - left) / yaw rate, front and rear alike) against 0.12 m wheel to
    # wheel, so the bound lets identification find that (0.05 m used to stop it).
    ("b_car", 0.12, "m", 0.02, 0.2, 0.005, "encoder", "track width seen by the wheel encoders"),
)

#: The rougher prior used before identification (``data/chronos_real`` README).
ROUGH_PRIOR = {
    "Df": 0.65,
    "Cf": 1.5,
    "Bf": 5.2,
    "Dr": 1.0,
    "Cr": 1.45,
    "Br": 8.5,
    "Cm1": 0.98028992,
    "Cm2": 0.01814131,
    "Cd0": 0.014,
    "Cd1": 0.014,
    "Cd2": 0.06,
    "lf": 0.05,
    "lr": 0.05,
    "Iz": 0.0016,
    "b_car": 0.088,
}


def dynamics_parameters() -> ParameterSet:
    """The 15 model parameters of the paper plus ``gamma``, ``eps`` and the encoder geometry."""
    return ParameterSet(
        [Parameter(n, v, u, lo, hi, sd, d, g) for n, v, u, lo, hi, sd, g, d in _DYNAMICS]
    )


def photodiode_parameters(
    photodiodes: tuple[tuple[float, float], ...] = RECORDED_PHOTODIODES,
) -> ParameterSet:
    """Photodiode positions ``lh_d{k}_x``, ``lh_d{k}_y`` in the body frame (shared by stations)."""
    out = []
    for k, (x, y) in enumerate(photodiodes):
        for axis, value in (("x", x), ("y", y)):
            out.append(
                Parameter(
                    f"lh_d{k}_{axis}",
                    value,
                    "m",
                    value - 0.05,
                    value + 0.05,
                    0.002,
                    f"photodiode {k} {axis} position, body frame",
                    "lighthouse",
                )
            )
    return ParameterSet(out)


def default_base_stations(n: int) -> tuple[BaseStation, ...]:
    """Station 0 is the recorded one; station ``i`` is it turned by ``2 pi i / n`` about world z.

    A stand-in geometry for multi-station simulations; calibrate real stations instead.
    """
    stations = []
    for i in range(n):
        turn = 2.0 * math.pi * i / n
        c, s = math.cos(turn), math.sin(turn)
        rz = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
        base = RECORDED_BASE_STATION
        stations.append(
            BaseStation.from_rotation(
                rz @ base.rotation, tuple(rz @ np.array(base.position)), base.dt1, base.dt2
            )
        )
    return tuple(stations)


def base_station_parameters(stations: tuple[BaseStation, ...]) -> ParameterSet:
    """Per station ``bs{i}_phi1..3`` (rad), ``bs{i}_x/y/z`` (m), ``bs{i}_dt1/2`` (rad)."""
    out = []
    for i, station in enumerate(stations):
        prefix = f"bs{i}_"
        for k, angle in enumerate(station.angles, start=1):
            out.append(
                Parameter(
                    f"{prefix}phi{k}",
                    angle,
                    "rad",
                    -2.0 * math.pi,
                    2.0 * math.pi,
                    0.05,
                    f"station {i} rotation angle phi{k} (R = Rz(phi3) Ry(phi2) Rx(phi1))",
                    "lighthouse",
                    period=2.0 * math.pi,
                )
            )
        for axis, value in zip("xyz", station.position, strict=True):
            out.append(
                Parameter(
                    f"{prefix}{axis}",
                    value,
                    "m",
                    value - 5.0,
                    value + 5.0,
                    0.05,
                    f"station {i} position {axis}, world frame",
                    "lighthouse",
                )
            )
        for k, value in ((1, station.dt1), (2, station.dt2)):
            out.append(
                Parameter(
                    f"{prefix}dt{k}",
                    value,
                    "rad",
                    value - 0.2,
                    value + 0.2,
                    0.0,
                    f"station {i} light-plane {k} tilt offset (factory)",
                    "lighthouse",
                )
            )
    return ParameterSet(out)


def base_station_from_parameters(params: ParameterSet, index: int) -> BaseStation:
    """Read station ``index`` back out of a parameter set."""
    p = f"bs{index}_"
    return BaseStation(
        (params.value(p + "phi1"), params.value(p + "phi2"), params.value(p + "phi3")),
        (params.value(p + "x"), params.value(p + "y"), params.value(p + "z")),
        params.value(p + "dt1"),
        params.value(p + "dt2"),
    )


__all__ = [
    "ROUGH_PRIOR",
    "base_station_from_parameters",
    "base_station_parameters",
    "default_base_stations",
    "dynamics_parameters",
    "photodiode_parameters",
    "rotation_from_angles",
]
