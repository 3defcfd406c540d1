"""The robust-estimation rows of ``crs bench estimation`` run on a short drive (no timing checks;
the figures themselves come from the benchmark command)."""

from __future__ import annotations

import math

from benchmarks.robust_estimation import (
    INPUT_VARIANTS,
    TIMING_PATTERNS,
    inputs_withheld_rows,
    pose_solver_rows,
)
from crs_core.analysis.metrics import STATE_NAMES


def _finite(value) -> bool:
    return isinstance(value, int | float) and math.isfinite(value)


def test_inputs_withheld_rows():
    rows = inputs_withheld_rows((0,), duration=3.0)
    assert len(rows) == 2 * 2 * len(INPUT_VARIANTS)
    assert {r["variant"] for r in rows} == set(INPUT_VARIANTS)
    for row in rows:
        assert row["benchmark"] == "inputs_withheld"
        assert all(_finite(row["rmse"][s]) for s in STATE_NAMES)
        (run,) = row["runs"]
        for key in (
            "first_estimate_s",
            "first_in_bounds_s",
            "out_of_bounds_after_2s",
            "max_position_error_after_1s_m",
            "lost_after_2s",
            "degraded_after_2s",
            "reinitializations",
            "fallbacks",
        ):
            assert _finite(run[key]), (row["variant"], key, run[key])
        assert run["converged_s"] is None or _finite(run["converged_s"])
    blind = [r for r in rows if r["variant"] == "estimated_blind"]
    assert all(r["runs"][0]["first_estimate_s"] > 1 / 60 for r in blind)  # it starts lost


def test_pose_solver_rows():
    rows = pose_solver_rows((0,), duration=2.0)
    assert [r["variant"] for r in rows] == ["stream", "static"]
    for row in rows:
        assert row["pairs"] > 50
        assert 0 < row["solved_fraction"] <= 1
        for key in ("position_error_mm", "yaw_error_mrad"):
            assert all(_finite(row[key][q]) for q in ("median", "p95", "max"))
        assert _finite(row["nees"]["mean"])
        assert all(_finite(row["solve_time_ms"][q]) for q in ("median", "p95"))
    assert _finite(rows[0]["motion_between_planes_mm"]["median"])


def test_timing_robustness_rows(timing_rows):
    assert [(r["estimator"], r["pattern"]) for r in timing_rows] == [
        (kind, pattern) for kind in ("ekf", "mhe") for pattern in TIMING_PATTERNS
    ]
    for row in timing_rows:
        assert row["non_finite"] == 0
        assert _finite(row["max_position_error_m"])
        assert sum(row["statuses"].values()) == row["runs"][0]["queries"]
        assert all(_finite(row["time_ms"][q]) for q in ("median", "p95", "max"))
    past = [r for r in timing_rows if r["pattern"] == "past_queries"]
    assert all(_finite(r["runs"][0]["max_position_error_past_queries_m"]) for r in past)
