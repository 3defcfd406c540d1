"""The robust-estimation rows of ``crs bench estimation`` run on a short drive (no timing checks;
the figures themselves come from the benchmark command)."""

from __future__ import annotations

import math

from benchmarks.robust_estimation import (
    INPUT_VARIANTS,
    TIMING_PATTERNS,
    VARIANT_LABELS,
    format_markdown,
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


def test_the_docs_table_of_the_inputs_withheld_rows():
    """One Markdown row per inputs-withheld row, in the docs' units and words."""
    row = {
        "benchmark": "inputs_withheld",
        "estimator": "mhe",
        "sensors": "lh",
        "variant": "estimated_x0",
        "rmse": {
            "x": 0.0023,
            "y": 0.0022,
            "yaw": 0.0381,
            "vx": 0.0416,
            "vy": 0.0302,
            "omega": 0.662,
        },
        "worst": {
            "first_estimate_s": 0.0167,
            "first_in_bounds_s": None,
            "out_of_bounds_after_2s": 0.016,
            "max_position_error_after_1s_m": 0.0136,
        },
    }
    table = format_markdown([row, {"benchmark": "pose_solver"}])
    assert table.splitlines()[2] == (
        "| MHE | lh | no inputs, from x0 | 2.3 | 2.2 | 38.1 | 41.6 | 30.2 | 662 | 0.017 | never "
        "| 1.6 % | 13.6 |"
    )
    assert len(table.splitlines()) == 3 and set(VARIANT_LABELS) == set(INPUT_VARIANTS)
