"""Sensor models against independent references and the real recordings."""

from pathlib import Path

import numpy as np
import pytest
from scipy.optimize import brentq

from crs_core.analysis.consistency import channel_errors
from crs_core.dataset import Dataset
from crs_core.model import CarModel
from crs_core.model.chronos import base_station_from_parameters

REAL = Path(__file__).resolve().parents[3].parent / "shared" / "data" / "chronos_real"


@pytest.fixture(scope="module")
def model() -> CarModel:
    return CarModel()


def test_wheel_encoders_straight_driving(model):
    """Driving straight, all four wheels turn at v_x / r."""
    y = model.numeric.outputs(
        np.array([0, 0, 0, 1.3, 0, 0.0]), np.zeros(2), model.parameters.vector()
    )
    np.testing.assert_allclose(y["wheel_encoders"], 1.3 / model.parameters.value("r"), rtol=1e-14)


def test_wheel_encoders_pure_yaw(model):
    """Turning on the spot, right wheels run forward and left wheels backward at b/2 * omega / r."""
    omega = 2.0
    y = model.numeric.outputs(
        np.array([0, 0, 0, 0, 0, omega]), np.zeros(2), model.parameters.vector()
    )
    half = 0.5 * model.parameters.value("b_car") * omega / model.parameters.value("r")
    np.testing.assert_allclose(y["wheel_encoders"], [-half, half, -half, half], rtol=1e-14)


def test_front_wheels_follow_steering(model):
    """With steering, a front wheel's speed is the velocity of its hub along the wheel's heading."""
    P = model.parameters.value
    vx, vy, omega, delta = 1.0, 0.05, 1.5, 0.25
    y = model.numeric.outputs(
        np.array([0, 0, 0, vx, vy, omega]), np.array([delta, 0]), model.parameters.vector()
    )["wheel_encoders"]
    for k, side in ((0, 1.0), (1, -1.0)):  # fl at +b/2, fr at -b/2 (body y left)
        hub = np.array([vx - omega * side * P("b_car") / 2, vy + omega * P("lf")])
        heading = np.array([np.cos(delta), np.sin(delta)])
        assert y[k] == pytest.approx(hub @ heading / P("r"), rel=1e-12)


def test_accelerometer_reads_centripetal_acceleration_in_steady_turn(model):
    """In a steady turn the accelerometer senses a_y = v_x * omega (specific force)."""
    p = model.parameters.vector()
    u = np.array([0.15, 0.25])
    x = model.numeric.step(np.zeros(6), u, p, 30.0)
    xdot = model.numeric.f(x, u, p)
    assert np.max(np.abs(xdot[3:])) < 1e-8  # steady
    ax, ay, gyro = model.numeric.outputs(x, u, p)["imu"]
    vx, vy, omega = x[3:]
    assert ay == pytest.approx(vx * omega, rel=1e-6)
    assert ax == pytest.approx(-vy * omega, abs=1e-6)
    assert gyro == omega


def _sweep_angle_by_rotating_plane(point: np.ndarray, tilt: float) -> float:
    """Independent construction: the plane Rz(a) Rx(tilt) {x-z plane} that contains ``point``."""

    def normal(a):
        rz = np.array([[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1]])
        rx = np.array(
            [[1, 0, 0], [0, np.cos(tilt), -np.sin(tilt)], [0, np.sin(tilt), np.cos(tilt)]]
        )
        return rz @ rx @ np.array([0.0, 1.0, 0.0])

    azimuth = np.arctan2(point[1], point[0])
    return brentq(lambda a: normal(a) @ point, azimuth - 1.2, azimuth + 1.2, xtol=1e-14)


def test_lighthouse_matches_rotating_plane_geometry(model):
    """The paper's sweep-angle formula equals the rotating tilted plane construction to 1e-9 rad."""
    rng = np.random.default_rng(7)
    params = model.parameters
    p = params.vector()
    station = base_station_from_parameters(params, 0)
    diodes = [(params.value(f"lh_d{k}_x"), params.value(f"lh_d{k}_y")) for k in range(4)]
    tilts = (-np.pi / 6 - station.dt1, np.pi / 6 - station.dt2)
    worst = 0.0
    for _ in range(200):
        pose = np.array(
            [rng.uniform(-1.5, 1.5), rng.uniform(-1.1, 1.1), rng.uniform(-np.pi, np.pi)]
        )
        y = model.numeric.outputs(np.concatenate([pose, np.zeros(3)]), np.zeros(2), p)
        c, s = np.cos(pose[2]), np.sin(pose[2])
        for k, (bx, by) in enumerate(diodes):
            world = np.array([pose[0] + c * bx - s * by, pose[1] + s * bx + c * by, 0.0])
            local = station.rotation.T @ (world - np.array(station.position))
            for plane, tilt in zip(("lighthouse/0/1", "lighthouse/0/2"), tilts, strict=True):
                expected = _sweep_angle_by_rotating_plane(local, tilt)
                worst = max(worst, abs(y[plane][k] - expected))
    assert worst < 1e-9


@pytest.mark.parametrize("run", ["fie_mpc_lighthouse_1", "fie_mpc_lighthouse_2"])
def test_real_recordings_are_reproduced_by_the_sensor_models(run):
    """Recorded poses through the published geometry reproduce the recorded sweep angles.

    Found (both runs): Lighthouse median 0.9-1.2 mrad, p95 3.4-4.8 mrad per row; wheel speeds
    median 3.6-7.8 rad/s (0.06-0.14 m/s), p95 12-21 rad/s; yaw rate median 0.35-0.38 rad/s,
    p95 ~1.1 rad/s. The states are the car's on-line estimate (not ground truth) and the wheel
    and gyro rows are low-pass filtered, so these rows agree less well; a linear fit of the
    recorded yaw rate against the estimated one has slope ~1.18, a first discrepancy to explain.
    """
    if not (REAL / run).is_dir():
        pytest.skip("real recordings not available")
    errors = channel_errors(Dataset.load(REAL / run))
    for k in range(8):
        row = errors[list(errors)[k]]
        assert row["median"] < 2e-3 and row["p95"] < 6e-3, (k, row)
    for name in ("wheel_fl", "wheel_fr", "wheel_rl", "wheel_rr"):
        assert errors[name]["median"] < 10.0, errors[name]
    assert errors["yaw_rate"]["median"] < 0.5
