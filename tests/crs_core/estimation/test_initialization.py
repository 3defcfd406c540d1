"""Tests of crs_core.estimation.initialization: the blind start from Lighthouse fixes."""

import numpy as np
import pytest

from crs_core.estimation import (
    make_estimator,
)
from sim.scenarios import standard_drive
from tests.crs_core.estimation.conftest import KINDS, _position_error, _run, _yaw_error


@pytest.mark.parametrize("seed", [0, 4])
@pytest.mark.parametrize("kind", KINDS)
def test_blind_start_lighthouse_only_without_inputs(kind, seed):
    """No x0, no inputs, Lighthouse only: lost until the first fixes, then on track within
    1 s and tracking after (measured: first fix after 67 ms; position error after 1 s at most
    10-15 mm, yaw 0.15-0.19 rad in sharp steering changes, RMSE 2-3 mm / 35-45 mrad)."""
    result = standard_drive(seed=seed, duration=10.0)
    queries = np.arange(1, 600) / 60.0
    estimator = make_estimator(kind, "lh")
    xs, statuses = _run(estimator, result, queries, with_inputs=False, x0=None)
    assert statuses[0] == "lost"
    first = statuses.index("ok")
    assert queries[first] < 0.2
    assert estimator.mode == "estimated"  # auto: no command ever arrived
    assert np.all(np.isfinite(xs))
    after = queries >= 1.0
    position = _position_error(result, queries, xs)[after]
    yaw = _yaw_error(result, queries, xs)[after]
    assert position.max() < 0.025 and np.sqrt(np.mean(position**2)) < 0.006
    assert yaw.max() < 0.3 and np.sqrt(np.mean(yaw**2)) < 0.07
    assert "lost" not in statuses[first:]
