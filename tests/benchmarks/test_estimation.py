"""The estimation benchmark's table shows the robust-estimation rows (run on a short drive); its
docs Markdown from hand-made rows (the benchmark itself is not run)."""

from __future__ import annotations

from benchmarks.estimation import format_markdown, format_table
from benchmarks.robust_estimation import pose_solver_rows
from crs_core.analysis.metrics import STATE_NAMES


def test_table_shows_the_new_rows(timing_rows):
    table = format_table(timing_rows + pose_solver_rows((0,), duration=1.0))
    assert "timing robustness" in table
    assert "pose solver (stream" in table


def _accuracy(estimator: str, sensors: str, scale: float) -> dict:
    return {
        "benchmark": "accuracy",
        "estimator": estimator,
        "sensors": sensors,
        "rate_hz": 60.0,
        "rmse": dict.fromkeys(STATE_NAMES, 0.0015 * scale),
        "rmse_std": dict.fromkeys(STATE_NAMES, 0.0001 * scale),
        "seeds": [0, 1, 2, 3, 4],
    }


TIME = {"median": 0.781, "p95": 0.92, "p99": 0.98, "max": 1.957}
ROWS = [
    _accuracy("ekf", "lh", 1.0),
    _accuracy("mhe", "lh+imu+we", 100.0),
    {
        "benchmark": "blackout",
        "estimator": "ekf",
        "sensors": "lh+imu+we",
        "blackout_s": [9.0, 1.127],
        "position_error_at_end_m": {"mean": 0.006, "max": 0.0137},
        "time_to_recover_s": {"mean": 0.012, "max": 0.02},
        "seeds": [0, 1, 2],
    },
    {
        "benchmark": "speed",
        "estimator": "mhe",
        "sensors": "lh+imu+we",
        "rate_hz": 60.0,
        "horizon": 40,
        "time_ms": TIME,
        "seeds": [0],
    },
    {
        "benchmark": "speed",
        "estimator": "ekf",
        "sensors": "lh+imu+we",
        "per": "measurement",
        "time_ms": {"median": 0.0381, "p95": 0.052, "p99": 0.093, "max": 1.13},
        "seeds": [0],
    },
    {
        "benchmark": "peer",
        "estimator": "do-mpc-mhe",
        "sensors": "lh+imu+we",
        "rate_hz": 60.0,
        "time_ms": {"median": 81.3},
        "compared_with": "mhe",
        "ratio_to_ours": {"rmse": dict.fromkeys(STATE_NAMES, 1.074), "time_median": 100.2},
        "seeds": [0, 1],
    },
    {
        "benchmark": "real",
        "estimator": "mhe",
        "sensors": "lh+we+gyro",
        "run": "fie_mpc_lighthouse_1",
        "rmse_vs_onboard_estimate": {"x": 0.0031, "y": 0.0037, "yaw": 0.0274},
        "lighthouse_residual_rad": {"median": 0.00042, "p95": 0.0015},
    },
    {"benchmark": "inputs_withheld"},
]


def _cells(markdown: str, first: str) -> list[str]:
    (line,) = [line for line in markdown.splitlines() if line.startswith(f"| {first} |")]
    return [cell.strip() for cell in line.strip("|").split("|")]


def test_the_docs_markdown_has_every_table_of_the_estimation_section() -> None:
    markdown = format_markdown(ROWS)
    assert "Mean ± std over seeds 0–4, queried at 60 Hz:" in markdown
    assert _cells(markdown, "EKF") == [
        "EKF", "LH", "1.5±0.1", "1.5±0.1", "1.5±0.1", "1.5±0.1", "1.5±0.1", "2±0",
        "31 / 21 / 42 / 69 / 67",
    ]  # fmt: skip
    assert _cells(markdown, "MHE")[1:3] == ["LH+IMU+WE", "150.0±10.0"]
    assert (
        "**Blackout** (Lighthouse off for 1.127 s at t = 9 s, LH+IMU+WE, seeds 0–2): position "
        "error at the end of the outage EKF 6.0 mm (max 13.7);" in markdown
    )
    assert "EKF 12 ms (max 20) after the outage" in markdown
    assert _cells(markdown, "MHE M = 40 at 60 Hz") == [
        "MHE M = 40 at 60 Hz", "0.781 ms", "0.92 ms", "0.98 ms", "1.96 ms",
        "median ≤ 1 ms, p99 ≤ 3 ms",
    ]  # fmt: skip
    assert _cells(markdown, "EKF per measurement")[1:] == [
        "0.0381 ms", "0.052 ms", "0.093 ms", "1.13 ms", "≤ 0.2 ms",
    ]  # fmt: skip
    assert "(seeds 0–1, LH+IMU+WE, 60 Hz; ratio = peer / ours)" in markdown
    assert _cells(markdown, "do-mpc `MHE` (IPOPT)") == [
        "do-mpc `MHE` (IPOPT)", "our MHE", "81.3 ms", "100× slower",
        "1.07 / 1.07 / 1.07 / 1.07 / 1.07",
    ]  # fmt: skip
    assert _cells(markdown, "fie_mpc_lighthouse_1") == [
        "fie_mpc_lighthouse_1", "MHE", "LH+WE+GYRO", "3.1 / 3.7", "27", "0.42 / 1.50",
    ]  # fmt: skip
    # every table row has as many cells as its header; the robust rows are not shown
    for block in (b for b in markdown.split("\n\n") if b.startswith("|")):
        assert len({line.count("|") for line in block.splitlines()}) == 1, block
    assert "inputs withheld" not in markdown


def test_without_rows_of_a_kind_its_table_is_left_out() -> None:
    markdown = format_markdown(ROWS[:2])
    assert "Blackout" not in markdown and "Speed" not in markdown and "Peers" not in markdown
    assert not markdown.endswith("\n")


ACADOS_ROW = {
    "benchmark": "peer",
    "estimator": "acados-mhe",
    "sensors": "lh+imu+we",
    "rate_hz": 60.0,
    "rmse": dict.fromkeys(STATE_NAMES, 0.001),
    "time_ms": {"median": 1.36, "p95": 2.27, "p99": 3.57, "max": 3.91},
    "solve_ms": {"median": 0.502, "p95": 0.68, "p99": 1.2, "max": 2.49},
    "step_ms": {"median": 0.84, "p95": 1.1, "p99": 1.9, "max": 3.0},
    "fallbacks": 0,
    "compared_with": "mhe",
    "ours": {
        "rmse": dict.fromkeys(STATE_NAMES, 0.001),
        "time_ms": {"median": 1.03, "p95": 1.26, "p99": 2.0, "max": 2.18},
        "step_ms": {"median": 0.51, "p95": 0.7, "p99": 1.1, "max": 1.5},
        "inputs": "commanded",
        "fallbacks": 0,
    },
    "ratio_to_ours": {"rmse": dict.fromkeys(STATE_NAMES, 1.0), "time_median": 1.32},
    "seeds": [0, 1],
}


def test_the_acados_peer_shows_what_is_solver_and_what_is_python() -> None:
    markdown = format_markdown([*ROWS, ACADOS_ROW])
    assert _cells(markdown, "acados OCP (SQP-RTI, HPIPM) on our MHE's problem") == [
        "acados OCP (SQP-RTI, HPIPM) on our MHE's problem", "our MHE", "1.36 ms",
        "1.32× slower", "1.00 / 1.00 / 1.00 / 1.00 / 1.00",
    ]  # fmt: skip
    assert "`solve()` 0.502 / 0.68 ms" in markdown
    assert "Gauss-Newton step with marginalization 0.51 / 0.7 ms" in markdown
    table = format_table([ACADOS_ROW])
    assert "solve() median 0.502 ms (p95 0.680), step 0.840 ms vs ours' 0.510 ms" in table


def test_a_skipped_peer_says_why() -> None:
    skipped = {"benchmark": "peer", "estimator": "acados-mhe", "skipped": "not installed",
               "seeds": [0, 1]}  # fmt: skip
    markdown = format_markdown([*ROWS, skipped])
    assert "acados OCP (SQP-RTI, HPIPM) on our MHE's problem: skipped (not installed)." in markdown
    assert "peer acados-mhe: skipped (not installed)" in format_table([skipped])
