"""Tests of crs_core.estimation.health: an honest status (a wrong prior detected, a blackout
degraded)."""

import numpy as np
import pytest

from crs_core.estimation import (
    make_estimator,
)
from sim.replay import start_state
from sim.scenarios import standard_drive
from sim.sensors import Blackout
from tests.crs_core.estimation.conftest import KINDS, _events, _position_error


@pytest.mark.parametrize("kind", KINDS)
def test_wide_wrong_prior_is_detected_and_reinitialised(drive, kind):
    """Started 3 m and 3 rad off with a matching wide prior: the Lighthouse disagrees, the
    estimate says so (not ``ok``), re-initialises from the Lighthouse and then tracks."""
    x0 = start_state(drive) + np.array([3.0, -3.0, 3.0, 0.0, 0.0, 0.0])
    estimator = make_estimator(kind, "lh+imu+we")
    estimator.reset(0.0, x0, np.diag([9.0, 9.0, 9.0, 1.0, 1.0, 4.0]))
    queries = np.arange(1, 480) / 60.0
    events, k, xs, statuses = _events(drive), 0, [], []
    for t in queries:
        while k < len(events) and events[k].stamp <= t:
            estimator.add(events[k])
            k += 1
        estimate = estimator.estimate(t)
        xs.append(estimate.x)
        statuses.append(estimate.status)
    xs = np.array(xs)
    error = _position_error(drive, queries, xs)
    wrong = error > 0.5
    assert all(s != "ok" for s, w in zip(statuses, wrong, strict=True) if w)
    assert error[queries > 2.0].max() < 0.01
    assert np.all(np.isfinite(xs))


@pytest.mark.parametrize("kind", KINDS)
def test_status_says_degraded_during_a_lighthouse_blackout(kind):
    """Dead reckoning during a blackout is ``degraded`` with the reason; ``ok`` again after."""
    dark = standard_drive(seed=5, duration=6.0, blackouts=[Blackout("lighthouse", 3.0, 1.0)])
    estimator = make_estimator(kind, "lh+imu+we")
    estimator.reset(0.0, start_state(dark))
    events, k = _events(dark), 0
    found = {}
    for t in np.arange(1, 360) / 60.0:
        while k < len(events) and events[k].stamp <= t:
            estimator.add(events[k])
            k += 1
        estimate = estimator.estimate(t)
        found[round(t, 3)] = estimate
    during = found[3.8]
    assert during.status == "degraded" and "dead reckoning" in during.reason
    assert found[5.9].status == "ok" and found[5.9].reason == ""


@pytest.mark.parametrize("kind", KINDS)
def test_a_link_down_is_lost_after_a_second_and_reinitialised_when_it_is_back(kind):
    """No sample of any sensor from 3 to 5 s (the link to the car is down; commands still go
    in): dead reckoning at first, ``lost`` after ``lost_silent_s`` (1 s) with the reason, then
    re-initialised from the Lighthouse and tracking once the samples come again."""
    cut = [Blackout(sensor, 3.0, 2.0) for sensor in ("lighthouse", "imu", "wheel_encoders")]
    dark = standard_drive(seed=5, duration=6.0, blackouts=cut)
    estimator = make_estimator(kind, "lh+imu+we")
    estimator.reset(0.0, start_state(dark))
    events, k = _events(dark), 0
    queries = np.arange(1, 360) / 60.0
    found, xs = {}, []
    for t in queries:
        while k < len(events) and events[k].stamp <= t:
            estimator.add(events[k])
            k += 1
        estimate = estimator.estimate(t)
        found[round(t, 3)] = estimate
        xs.append(estimate.x)
    assert found[3.5].status == "degraded" and "dead reckoning" in found[3.5].reason
    lost = found[4.5]
    assert lost.status == "lost" and "no sample of any sensor for 1.0" in lost.reason, lost
    assert estimator.diagnostics.reinitializations == 1
    assert found[5.9].status == "ok"
    error = _position_error(dark, queries, np.array(xs))
    assert error[queries > 5.5].max() < 0.01
