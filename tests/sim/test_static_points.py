"""grid_layout: points spread on a grid of cell centres inside the area, random yaws."""

from __future__ import annotations

import math

import numpy as np
import pytest

from crs_core.errors import FieldError
from sim.static_points import TRACK_AREA, grid_layout


def test_a_full_grid_is_the_cell_centres() -> None:
    # 3 x 2 area, 6 points: 3 columns x 2 rows of 1 m cells
    positions, yaws = grid_layout(6, (0.0, 3.0, 0.0, 2.0), seed=1)
    expected = [(x, y) for y in (0.5, 1.5) for x in (0.5, 1.5, 2.5)]
    np.testing.assert_allclose(positions, expected, atol=1e-12)
    assert yaws.shape == (6,) and np.all((yaws >= -math.pi) & (yaws < math.pi))


@pytest.mark.parametrize("n", [1, 2, 7, 20, 33])
def test_any_count_of_distinct_points_inside_the_area(n: int) -> None:
    x0, x1, y0, y1 = TRACK_AREA
    positions, yaws = grid_layout(n)
    assert positions.shape == (n, 2) and yaws.shape == (n,)
    assert np.all((positions[:, 0] > x0) & (positions[:, 0] < x1))
    assert np.all((positions[:, 1] > y0) & (positions[:, 1] < y1))
    assert len({tuple(p) for p in np.round(positions, 9)}) == n


def test_the_yaws_follow_the_seed() -> None:
    _, a = grid_layout(10, seed=3)
    _, b = grid_layout(10, seed=3)
    _, c = grid_layout(10, seed=4)
    np.testing.assert_array_equal(a, b)
    assert not np.allclose(a, c)


def test_no_points_is_refused() -> None:
    with pytest.raises(FieldError) as error:
        grid_layout(0)
    assert error.value.field == "n"
