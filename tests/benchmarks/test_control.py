"""The control benchmark's markdown tables from a hand-made result (the benchmark itself races
the MPCC for minutes and is not run here)."""

from __future__ import annotations

from benchmarks.control import format_table

SOLVE = {"median": 3.1, "p95": 4.2, "p99": 5.0, "max": 7.7}
RESULT = {
    "settings": {"solver": "osqp"},
    "solve_ms": SOLVE,
    "qp_iterations": {"median": 12.0},
    "peer": {
        "name": "IPOPT",
        "solve_ms": {"median": 40.0, "p95": 55.0, "p99": 61.0, "max": 80.0},
        "iterations_median": 9.0,
        "first_command_difference_median": 0.004,
    },
    "speedup_median": 12.9,
    "fallbacks": 0,
    "stops": 1,
    "qp_solvers": [
        {
            "solver": "osqp",
            "solve_ms": SOLVE,
            "qp_iterations_median": 12,
            "laps": 3,
            "lap_times_s": [8.123, 8.0],
            "controller_modes": "racing",
        }
    ],
    "closed_loop": [
        {
            "state": "truth",
            "blackout": False,
            "truth": "simulator",
            "laps": 3,
            "mean_lap_s": 8.0625,
            "boundary_violations": 0,
            "max_contouring_error_m": 0.03,
            "max_outside_m": -0.052,
            "solve_ms": SOLVE,
        },
        {
            "state": "mhe",
            "blackout": True,
            "truth": "simulator",
            "laps": 0,
            "mean_lap_s": None,
            "boundary_violations": 2,
            "max_contouring_error_m": 0.2,
            "max_outside_m": 0.01,
            "solve_ms": SOLVE,
        },
    ],
}


def _row(table: str, first_cell: str) -> list[str]:
    (line,) = [line for line in table.splitlines() if line.startswith(f"| {first_cell} |")]
    return [cell.strip() for cell in line.strip("|").split("|")]


def test_the_solver_the_peer_and_the_closed_loop_rows() -> None:
    table = format_table(RESULT)
    assert _row(table, "MPCC, real-time iteration + osqp") == [
        "MPCC, real-time iteration + osqp", "3.1", "4.2", "5.0", "7.7", "12 (QP)",
    ]  # fmt: skip
    assert _row(table, "peer: IPOPT") == ["peer: IPOPT", "40.0", "55.0", "61.0", "80.0", "9 (NLP)"]
    assert "speed-up (medians): 12.9x; fallbacks 0, stops 1;" in table
    assert "IPOPT's converged one by 0.004 (median" in table
    assert _row(table, "osqp") == ["osqp", "3.1", "5.0", "12", "3", "8.12, 8.00", "racing"]
    # the closest approach to the edge is minus the largest excursion outside
    assert _row(table, "truth") == [
        "truth", "no", "simulator", "3", "8.062", "0", "0.03", "0.052", "3.1 / 5.0",
    ]  # fmt: skip
    assert _row(table, "mhe") == [
        "mhe", "1.127 s per lap", "simulator", "0", "-", "2", "0.2", "-0.010", "3.1 / 5.0",
    ]  # fmt: skip
    # every table row has as many cells as its header
    blocks = [b for b in table.split("\n\n") if b.startswith("|")]
    assert len(blocks) == 3
    for block in blocks:
        widths = {line.count("|") for line in block.splitlines()}
        assert len(widths) == 1, block
