"""Tests of launch_scripts.stack_plot (the ``crs launch sim`` figure) on a tiny bag written here.

No ROS process: the bag is written with rosbags' Writer and the project's typestore.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from rosbags.rosbag2 import StoragePlugin, Writer

from crs_core.analysis.angles import wrap_angle
from launch_scripts.sim_stack import read_cars
from launch_scripts.stack_plot import estimate_errors, plot, state_track
from ros4crs.bag_replay import read_car
from ros4crs.interfaces import typestore

CAR_STATE = "chronos_msgs/msg/CarState"
T0 = 1_700_000_000.0
SIGMA = np.array([0.002, 0.001, 0.01, 0.1, 0.1, 0.1])  # m, m, rad, m/s, m/s, rad/s


def _car_state(seconds: float, state, covariance) -> object:
    store = typestore()
    sec = int(seconds)
    stamp = store.types["builtin_interfaces/msg/Time"](
        sec=sec, nanosec=min(round((seconds - sec) * 1e9), 999_999_999)
    )
    header = store.types["std_msgs/msg/Header"](stamp=stamp, frame_id="world")
    return store.types[CAR_STATE](
        header=header,
        status=0,
        x=float(state[0]),
        y=float(state[1]),
        yaw=float(state[2]),
        vx=float(state[3]),
        vy=float(state[4]),
        omega=float(state[5]),
        covariance=np.asarray(covariance, dtype=np.float64).ravel(),
    )


def _truth(t: np.ndarray) -> np.ndarray:
    """(n, 6): around a circle of 1 m, the yaw wrapped to [-pi, pi) (it jumps by 2 pi)."""
    yaw = wrap_angle(t + np.pi / 2)
    return np.stack([np.cos(t), np.sin(t), yaw, np.ones_like(t), 0 * t, np.ones_like(t)], axis=1)


def _write_bag(path: Path, cars: int) -> None:
    """Truth at 50 Hz from t0 + 0.1 s, estimates at 60 Hz from t0 over 8 s: x off by +1 mm,
    y by +3 mm (σ 1 mm: outside ±2σ), yaw by +5 mrad (σ 10 mrad); car 2 without covariance.
    Messages are written out of stamp order."""
    store = typestore()
    truth_t = T0 + 0.1 + np.arange(0.0, 7.8, 0.02)
    estimate_t = T0 + np.arange(0.0, 8.0, 1 / 60)
    offset = np.array([0.001, 0.003, 0.005, 0.0, 0.0, 0.0])
    writer = Writer(path, version=9, storage_plugin=StoragePlugin.MCAP)
    with writer:
        for car in range(1, cars + 1):
            truth = writer.add_connection(f"/car{car}/ground_truth", CAR_STATE, typestore=store)
            state = writer.add_connection(f"/car{car}/estimate/state", CAR_STATE, typestore=store)
            for t, x in zip(truth_t, _truth(truth_t - T0), strict=True):
                msg = _car_state(t, x, np.zeros(36))
                writer.write(truth, int(t * 1e9), bytes(store.serialize_cdr(msg, CAR_STATE)))
            covariance = np.diag(SIGMA**2) if car == 1 else np.zeros((6, 6))
            estimates = _truth(estimate_t - T0) + offset
            estimates[:, 2] = wrap_angle(estimates[:, 2])
            for k in np.r_[1 : len(estimate_t), 0]:  # the first estimate written last
                msg = _car_state(estimate_t[k], estimates[k], covariance)
                data = bytes(store.serialize_cdr(msg, CAR_STATE))
                writer.write(state, int(estimate_t[k] * 1e9), data)


@pytest.fixture(scope="module")
def bag(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("stack") / "bag"
    _write_bag(path, cars=2)
    return path


def _estimates(bag: Path, car: str):
    contents = read_car(bag, car)
    return state_track(contents.estimates, contents.estimate_sigmas)


def test_the_estimates_track_reads_the_covariance(bag: Path):
    """Stamps sorted, σ from the covariance diagonal, NaN where the covariance is all zeros."""
    estimates = _estimates(bag, "/car1")
    assert estimates.t.size == 480 and np.all(np.diff(estimates.t) > 0)
    assert estimates.sigma == pytest.approx(np.tile(SIGMA, (480, 1)))
    assert np.all(np.isnan(_estimates(bag, "/car2").sigma))
    assert _estimates(bag, "/car3").t.size == 0


def test_estimate_errors_wrap_the_yaw_and_stay_within_the_truth(bag: Path):
    """Errors in mm / mrad against the interpolated truth (no spike where the yaw wraps), NaN
    before the first truth stamp."""
    estimates = _estimates(bag, "/car1")
    errors, sigmas = estimate_errors(estimates, state_track(read_car(bag, "/car1").truth))
    inside = (estimates.t >= T0 + 0.1) & (estimates.t <= T0 + 0.1 + 7.78)
    assert np.all(np.isnan(errors[~inside])) and np.isfinite(errors[inside]).all()
    # linear interpolation of a circle: the chord is off by < 0.05 mm at 50 Hz
    assert errors[inside] == pytest.approx(np.tile([1.0, 3.0, 5.0], (inside.sum(), 1)), abs=0.06)
    assert sigmas[0] == pytest.approx([2.0, 1.0, 10.0])


def test_plot_writes_path_png(bag: Path, tmp_path: Path):
    """``plot`` writes path.png for two cars (one without covariance) and for one car."""
    for cars in (2, 1):
        out = tmp_path / str(cars)
        out.mkdir()
        plot(read_cars(bag, cars), cars, out, "ekf")
        data = (out / "path.png").read_bytes()
        assert data[:8] == b"\x89PNG\r\n\x1a\n" and len(data) > 20_000
