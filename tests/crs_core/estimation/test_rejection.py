"""Tests of crs_core.estimation.rejection: the cap on consecutive rejections."""

from __future__ import annotations

import numpy as np

from crs_core.estimation.rejection import RejectionCap


def test_a_drifted_estimate_is_let_through_after_the_cap_a_burst_of_outliers_is_not():
    """After ``limit`` rejections in a row, a rejected innovation is taken only when it agrees
    with the median of the last ``window`` ones; then the run starts over."""
    cap = RejectionCap(limit=4, window=3, tolerance=1.0)
    drift = np.array([5.0, -3.0])
    assert [cap.override("lh", drift) for _ in range(4)] == [False] * 4
    assert cap.override("lh", drift + 0.5)  # the same innovation, sample after sample
    assert not cap.override("lh", drift)  # the run started over
    rng = np.random.default_rng(0)
    wild = [rng.uniform(-50, 50, 2) for _ in range(8)]
    cap.clear()
    assert not any(cap.override("lh", w) for w in wild)


def test_an_accepted_measurement_ends_the_run_of_its_sensor_only():
    cap = RejectionCap(limit=2, window=2, tolerance=1.0)
    for _ in range(2):
        cap.override("lh", np.ones(2))
        cap.override("imu", np.ones(2))
    cap.accepted("lh")
    assert not cap.override("lh", np.ones(2))
    assert cap.override("imu", np.ones(2))
