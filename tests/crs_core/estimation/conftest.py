"""Fixtures and helpers of the estimation tests: a simulated drive and how to replay it into an
estimator."""

import numpy as np
import pytest

from crs_core.analysis.angles import wrap_angle
from crs_core.measurements import in_stamp_order
from sim.replay import start_state
from sim.scenarios import standard_drive

KINDS = ["ekf", "mhe"]


@pytest.fixture(scope="module")
def drive(request: pytest.FixtureRequest):
    """8 s of the standard joystick drive, seed 3; a test asks for another seed with
    ``@pytest.mark.parametrize("drive", [seed], indirect=True)``."""
    return standard_drive(seed=getattr(request, "param", 3), duration=8.0)


def _events(result, with_inputs=True):
    return in_stamp_order(result.measurements, result.inputs if with_inputs else ())


def _run(estimator, result, queries, with_inputs=True, x0="truth", lag=0.0):
    """Deliver data up to each query time + ``lag``, then query; estimates (n, 6), statuses."""
    if x0 == "truth":
        estimator.reset(0.0, start_state(result))
    else:
        estimator.reset(0.0, x0)
    events, k, xs, statuses = _events(result, with_inputs), 0, [], []
    for t in queries:
        while k < len(events) and events[k].stamp <= t + lag:
            estimator.add(events[k])
            k += 1
        estimate = estimator.estimate(t)
        xs.append(estimate.x)
        statuses.append(estimate.status)
    return np.array(xs), statuses


def _position_error(result, queries, xs):
    truth = result.truth_at(np.asarray(queries))
    return np.hypot(*(xs[:, :2] - truth[:, :2]).T)


def _yaw_error(result, queries, xs):
    d = xs[:, 2] - result.truth_at(np.asarray(queries))[:, 2]
    return np.abs(wrap_angle(d))


def _late_ticks(rng, end, late_s):
    """60 Hz queries of which 5 % come ``late_s`` late (the ones in between are skipped)."""
    out, t = [], 0.0
    while True:
        t += late_s if rng.random() < 0.05 else 1 / 60
        if t > end:
            return out
        out.append(t)
