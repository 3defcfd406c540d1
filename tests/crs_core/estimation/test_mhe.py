"""Tests of crs_core.estimation.mhe: catch-up solves, the grid sets the discretisation."""

import numpy as np
import pytest

from crs_core.estimation import (
    MheSettings,
    make_estimator,
)
from tests.crs_core.estimation.conftest import _late_ticks, _position_error, _run


@pytest.mark.parametrize("late_s", [0.3, 1.0])
def test_catch_up_solves_bound_a_late_calls_work_and_keep_it_on_track(drive, late_s):
    """With ``catch_up_solves`` a late call solves only the newest nodes (the older ones are
    predicted, their data still in the window): the same estimates as solving every node
    when no call is late, within 5 mm of the truth when 5 % come late, and fewer solves."""
    on_time = list(np.arange(1 / 60, drive.duration - 0.5, 1 / 60))
    every = make_estimator("mhe", inputs="commanded")
    bounded = make_estimator("mhe", settings=MheSettings(catch_up_solves=2), inputs="commanded")
    np.testing.assert_array_equal(_run(bounded, drive, on_time)[0], _run(every, drive, on_time)[0])
    queries = _late_ticks(np.random.default_rng(7), drive.duration - 0.5, late_s)
    solves = {}
    for name, estimator in (("every", every), ("bounded", bounded)):
        count = [0]
        step = estimator._gauss_newton_step

        def counted(step=step, count=count):
            count[0] += 1
            step()

        estimator._gauss_newton_step = counted
        xs, _ = _run(estimator, drive, queries)
        solves[name] = count[0]
        error = _position_error(drive, queries, xs)
        assert error[np.asarray(queries) > 2.0].max() < 0.005, (name, error.max())
    assert solves["bounded"] < 0.9 * solves["every"], solves


def test_mhe_output_does_not_depend_on_who_queries(drive):
    """Extra queries at arbitrary stamps change nothing: the grid, not the callers, sets the
    nodes; the estimates at the 60 Hz stamps are bit for bit the same."""
    grid = list(np.arange(1, 240) / 60.0)
    rng = np.random.default_rng(0)
    extra = sorted(set(grid) | set(rng.uniform(0.01, 4.0, 300)))
    plain, _ = _run(make_estimator("mhe", "lh+imu+we", inputs="commanded"), drive, grid)
    both, _ = _run(make_estimator("mhe", "lh+imu+we", inputs="commanded"), drive, extra)
    index = [extra.index(t) for t in grid]
    np.testing.assert_array_equal(plain, both[index])


def test_mhe_stage_length_is_the_grid_whatever_the_query_rate(drive):
    """Queried at 23 Hz, the MHE still discretises at its 60 Hz grid (stages of 1/60 s)."""
    estimator = make_estimator("mhe", "lh+imu+we", inputs="commanded")
    queries = np.arange(1, 100) / 23.0
    xs, _ = _run(estimator, drive, queries)
    np.testing.assert_allclose(np.diff(estimator._times), 1 / 60, rtol=0, atol=1e-9)
    assert _position_error(drive, queries, xs)[queries > 2].max() < 0.01
