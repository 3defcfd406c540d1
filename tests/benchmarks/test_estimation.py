"""The estimation benchmark's table shows the robust-estimation rows (run on a short drive)."""

from __future__ import annotations

from benchmarks.estimation import format_table
from benchmarks.robust_estimation import pose_solver_rows


def test_table_shows_the_new_rows(timing_rows):
    table = format_table(timing_rows + pose_solver_rows((0,), duration=1.0))
    assert "timing robustness" in table
    assert "pose solver (stream" in table
