"""Lighthouse pose solver and sweep pairing: accuracy, honest covariance, rejection, boundaries."""

import math

import numpy as np
import pytest

from crs_core.analysis.angles import wrap_angle
from crs_core.estimation.lighthouse_pose import (
    LighthouseFixes,
    LighthousePoseSolver,
    PoseFix,
    SweepPairer,
)
from crs_core.measurements import Measurement
from crs_core.model import CarModel
from crs_core.model.chronos import base_station_from_parameters

S1, S2 = "lighthouse/0/1", "lighthouse/0/2"


@pytest.fixture(scope="module")
def model():
    return CarModel()


@pytest.fixture(scope="module")
def model2():
    return CarModel(n_base_stations=2)


def _sweeps(model, pose, stations=(0,)):
    """Sweep angles of ``pose`` from the model's own compiled outputs."""
    y = model.numeric.outputs(np.r_[pose, 0.0, 0.0, 0.0], np.zeros(2), model.parameters.vector())
    return {f"lighthouse/{s}/{p}": y[f"lighthouse/{s}/{p}"] for s in stations for p in (1, 2)}


def _random_poses(rng, n):
    return np.column_stack(
        [rng.uniform(-1.5, 1.5, n), rng.uniform(-1.0, 1.0, n), rng.uniform(-np.pi, np.pi, n)]
    )


def _error(estimate, truth):
    d = np.asarray(estimate, dtype=float) - truth
    d[2] = wrap_angle(d[2])
    return d


def _reference_rotation(angles):
    p1, p2, p3 = angles
    rx = np.array([[1, 0, 0], [0, np.cos(p1), -np.sin(p1)], [0, np.sin(p1), np.cos(p1)]])
    ry = np.array([[np.cos(p2), 0, np.sin(p2)], [0, 1, 0], [-np.sin(p2), 0, np.cos(p2)]])
    rz = np.array([[np.cos(p3), -np.sin(p3), 0], [np.sin(p3), np.cos(p3), 0], [0, 0, 1]])
    return rz @ ry @ rx


def _reference_local_angles(local, station):
    """Independent numpy copy of the documented sweep formula for station-frame points (4, 3)."""
    tilts = (-np.pi / 6 - station.dt1, np.pi / 6 - station.dt2)
    r = np.hypot(local[:, 0], local[:, 1])
    azimuth = np.arctan2(local[:, 1], local[:, 0])
    return [azimuth + np.arcsin(local[:, 2] * np.tan(t) / r) for t in tilts]


def _reference_angles(model, pose, index):
    """Sweep angles of ``pose`` from the paper's formula (Sec. III-B.3), tests only."""
    params = model.parameters
    station = base_station_from_parameters(params, index)
    x, y, yaw = pose
    body = np.array([[params.value(f"lh_d{k}_{a}") for a in "xy"] for k in range(4)])
    c, s = np.cos(yaw), np.sin(yaw)
    world = np.column_stack(
        [x + c * body[:, 0] - s * body[:, 1], y + s * body[:, 0] + c * body[:, 1], np.zeros(4)]
    )
    local = (world - np.array(station.position)) @ _reference_rotation(station.angles)
    return _reference_local_angles(local, station)


def test_noise_free_poses_are_recovered_without_a_guess(model):
    solver = LighthousePoseSolver(model)
    rng = np.random.default_rng(1)
    poses = _random_poses(rng, 200)
    poses[:4, 2] = [math.pi, -math.pi + 1e-9, math.pi - 1e-9, 0.0]  # wrap edges
    for pose in poses:
        fix = solver.solve(_sweeps(model, pose), stamp=2.5)
        assert isinstance(fix, PoseFix)
        assert np.max(np.abs(_error(fix.pose, pose))) < 1e-6
        assert -math.pi < fix.pose[2] <= math.pi
        assert fix.stamp == 2.5 and fix.stations == (0,)
        assert fix.residual_rms < 1e-9
        assert np.all(np.linalg.eigvalsh(fix.covariance) > 0)


def test_covariance_is_honest_under_angle_noise(model):
    """The normalised estimation error squared averages 3 (the pose dimension)."""
    solver = LighthousePoseSolver(model, angle_std=1e-3)
    rng = np.random.default_rng(2)
    nees = []
    for pose in _random_poses(rng, 400):
        noisy = {k: v + rng.normal(0.0, 1e-3, 4) for k, v in _sweeps(model, pose).items()}
        fix = solver.solve(noisy)
        assert fix is not None
        e = _error(fix.pose, pose)
        nees.append(e @ np.linalg.solve(fix.covariance, e))
    assert 2.4 < np.mean(nees) < 3.6


def test_two_stations_shrink_the_covariance(model2):
    solver = LighthousePoseSolver(model2, angle_std=1e-3)
    rng = np.random.default_rng(3)
    for pose in _random_poses(rng, 20):
        both = _sweeps(model2, pose, stations=(0, 1))
        one = {k: v for k, v in both.items() if k.startswith("lighthouse/0/")}
        fix1, fix2 = solver.solve(one), solver.solve(both)
        assert fix1.stations == (0,) and fix2.stations == (0, 1)
        assert np.max(np.abs(_error(fix2.pose, pose))) < 1e-6
        assert np.trace(fix2.covariance) < np.trace(fix1.covariance)


def test_model_direction_matches_an_independent_reference(model2):
    rng = np.random.default_rng(4)
    for pose in _random_poses(rng, 10):
        sweeps = _sweeps(model2, pose, stations=(0, 1))
        for station in (0, 1):
            ref = _reference_angles(model2, pose, station)
            np.testing.assert_allclose(sweeps[f"lighthouse/{station}/1"], ref[0], atol=1e-12)
            np.testing.assert_allclose(sweeps[f"lighthouse/{station}/2"], ref[1], atol=1e-12)


def test_unreachable_or_inconsistent_angles_give_none(model):
    solver = LighthousePoseSolver(model)
    # points above the station: the rays point up (azimuth near +-pi) and miss the floor
    station = base_station_from_parameters(model.parameters, 0)
    local = np.column_stack([np.full(4, -1.0), 0.01 * np.arange(4), np.full(4, 0.1)])
    assert np.all((local @ _reference_rotation(station.angles).T)[:, 2] > 0)
    first, second = _reference_local_angles(local, station)
    assert np.all(np.abs(first) > 2.5)
    assert solver.solve({S1: first, S2: second}) is None
    sweeps = _sweeps(model, np.array([0.0, 0.0, 0.0]))
    # a start where the model is undefined (photodiodes outside the light planes)
    unreachable = np.array([0.0, 5.0, 0.0])
    assert np.all(np.isnan(_sweeps(model, unreachable)[S1]))
    assert solver.solve(sweeps, guess=unreachable) is None
    # one photodiode 50 mrad off: residual far above angle_std
    bad = {S1: sweeps[S1] + np.array([0.05, 0, 0, 0]), S2: sweeps[S2]}
    assert solver.solve(bad) is None
    lenient = LighthousePoseSolver(model, max_rms_ratio=1e6).solve(bad)
    assert lenient.residual_rms > 5 * solver.angle_std  # rejected by the rms test alone
    # only one plane: nothing to solve
    assert solver.solve({S1: sweeps[S1]}) is None
    # a guess near the truth converges to it
    fix = solver.solve(sweeps, guess=np.array([0.05, -0.05, 0.3]))
    assert np.max(np.abs(fix.pose)) < 1e-6


def test_boundaries_name_the_sensor(model):
    solver = LighthousePoseSolver(model)
    sweeps = _sweeps(model, np.array([0.2, 0.1, 1.0]))
    with pytest.raises(ValueError, match="lighthouse/5/1"):
        solver.solve({**sweeps, "lighthouse/5/1": np.zeros(4)})
    with pytest.raises(ValueError, match="imu"):
        solver.solve({**sweeps, "imu": np.zeros(3)})
    with pytest.raises(ValueError, match="lighthouse/0/2"):
        solver.solve({S1: sweeps[S1], S2: np.array([0.1, np.nan, 0.1, 0.1])})
    with pytest.raises(ValueError, match="guess"):
        solver.solve(sweeps, guess=np.array([0.0, np.inf, 0.0]))
    with pytest.raises(ValueError, match="angle_std"):
        LighthousePoseSolver(model, angle_std=0.0)


def _m(stamp, sensor, value=0.0):
    size = 3 if sensor == "imu" else 4
    return Measurement(stamp, sensor, np.full(size, value))


def test_sweep_pairer_pairs_within_gap_and_never_reuses():
    pairer = SweepPairer(max_gap=0.03)
    assert pairer.add(_m(0.0, "imu")) is None
    assert pairer.add(_m(1.000, S1, 0.1)) is None
    stamp, sweeps = pairer.add(_m(1.010, S2, 0.2))
    assert stamp == pytest.approx(1.005)
    assert set(sweeps) == {S1, S2}
    np.testing.assert_array_equal(sweeps[S1], np.full(4, 0.1))
    np.testing.assert_array_equal(sweeps[S2], np.full(4, 0.2))
    assert pairer.add(_m(1.020, S2, 0.3)) is None  # plane 1 already used
    assert pairer.add(_m(1.100, S1, 0.4)) is None  # newest plane 2 is 80 ms old
    stamp, sweeps = pairer.add(_m(1.110, S2, 0.5))
    assert stamp == pytest.approx(1.105) and sweeps[S1][0] == 0.4
    # another station pairs on its own
    assert pairer.add(_m(1.200, "lighthouse/1/2")) is None
    stamp, sweeps = pairer.add(_m(1.215, "lighthouse/1/1"))
    assert set(sweeps) == {"lighthouse/1/1", "lighthouse/1/2"}
    with pytest.raises(ValueError, match="max_gap"):
        SweepPairer(max_gap=-1.0)


def test_a_stream_of_sweeps_gives_fixes_at_most_every_min_interval_per_station(model2):
    """Sweeps of a parked car, paired and solved: the car's pose, each station's pairs solved
    no sooner than ``min_interval`` after its last fix."""
    pose = np.array([0.4, -0.3, 2.0])
    sweeps = _sweeps(model2, pose, stations=(0, 1))
    fixes = LighthouseFixes(LighthousePoseSolver(model2), min_interval=0.1)
    assert fixes.add(Measurement(3.0, S2, sweeps[S2])) is None
    fix = fixes.add(Measurement(3.01, S1, sweeps[S1]))
    assert fix.stamp == pytest.approx(3.005) and fix.stations == (0,)
    assert np.max(np.abs(_error(fix.pose, pose))) < 1e-6
    solved = []
    for k in range(1, 31):  # 0.6 s of both stations' planes at 50 Hz (20 ms apart)
        t = 3.0 + 0.02 * k
        for sensor in (S2, S1, "lighthouse/1/1", "lighthouse/1/2"):
            fix = fixes.add(Measurement(t + 0.001 * sensor.count("1"), sensor, sweeps[sensor]))
            if fix is not None:
                solved.append((fix.stations[0], fix.stamp))
    for station in (0, 1):
        stamps = np.array([t for s, t in solved if s == station])
        assert np.all(np.diff(stamps) >= 0.1 - 1e-9) and 5 <= len(stamps) <= 6
    with pytest.raises(ValueError, match="min_interval"):
        LighthouseFixes(LighthousePoseSolver(model2), min_interval=-0.1)
