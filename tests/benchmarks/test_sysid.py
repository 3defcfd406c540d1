"""The identification benchmark's docs table from a hand-made result (the benchmark itself
identifies for minutes and is not run here)."""

from __future__ import annotations

import pytest

from benchmarks.sysid import format_markdown


def _floor(train: float, held_out: float, evaluations: int) -> dict:
    return {
        "fit": ["m", "Iz", "Df"],
        "train_position_rmse_m": {"prior": 0.3, "fitted": train},
        "held_out_position_rmse_m": held_out,
        "evaluations": evaluations,
        "time_s": 257.2,
    }


def _real(prior: float, identified: float, floor: dict) -> dict:
    return {
        "position_rmse_m": {"prior": prior, "identified": identified},
        "prediction_error_floor": floor,
    }


RESULT = {
    "speed": {
        "real_run_1": {
            "samples": 1462,
            "parameters": 17,
            "time_s": 8.23,
            "build_s": 1.94,
            "iterations": 10,
            "time_per_iteration_s": 0.4612,
        },
        "simulated_3000": {
            "samples": 3000,
            "parameters": 17,
            "time_s": 17.6,
            "build_s": 3.0,
            "iterations": 10,
            "time_per_iteration_s": 1.07,
        },
    },
    "real": {
        "fie_mpc_lighthouse_1 -> fie_mpc_lighthouse_2": _real(
            0.3601, 0.1731, _floor(0.147, 0.162, 406)
        ),
        "fie_mpc_lighthouse_2 -> fie_mpc_lighthouse_1": _real(
            0.364, 0.182, _floor(0.153, 0.155, 376)
        ),
    },
    "simulated": {
        "duration_s": 60.0,
        "seeds": [0, 1],
        "truth_inside_2sigma_fraction": 5 / 6,
        "identifiable_within_3sigma": "3/4",
        "open_loop_2s_held_out": {"position_rmse_m": {"prior": 0.117, "identified": 0.011}},
        "runs": [
            {"z": {"m": 0.1, "Cf": 2.5, "Df": -1.0}, "not_identifiable": ["m"]},
            {"z": {"m": 0.3, "Cf": 0.2, "Df": 1.5}, "not_identifiable": ["m", "Cf"]},
        ],
    },
    "wall_time_s": 806.6,
}


def _figure(markdown: str, first: str) -> str:
    (line,) = [line for line in markdown.splitlines() if line.startswith(f"| {first}")]
    return line.strip("|").split("|")[1].strip()


#: The figure of each row of the docs table made from RESULT: (start of the row's label, figure).
FIGURES = [
    (
        "one real run (1462 samples, all sensors, 17 parameters)",
        "8.2 s including the 1.9 s build, 10 IPOPT iterations, 0.46 s each",
    ),
    (
        "3000 simulated samples",
        "17.6 s including the 3.0 s build, 10 IPOPT iterations, 1.07 s each",
    ),
    # the pairs are counted from the runs; a parameter is listed only when no seed identified it
    (
        "simulation, known truth",
        "within 3σ of the truth: 3 of the 4 (parameter, seed) pairs flagged identifiable; truth "
        "inside ±2σ for 5 / 6 = 83.3 % of (parameter, seed) pairs; m flagged unidentifiable on "
        "every seed",
    ),
    ("simulation, held-out run", "prior 0.117 m → identified **0.011 m**"),
    (
        "real, identify on run 1, validate on run 2 (17 parameters)",
        "prior 0.360 m → identified **0.173 m**",
    ),
    ("real, identify on run 2, validate on run 1", "prior 0.364 m → identified **0.182 m**"),
    (
        "real, prediction-error floor: the 3 dynamics parameters",
        "run 1 → 2: 0.147 m on run 1, **0.162 m** held out; run 2 → 1: 0.153 m on run 2, "
        "**0.155 m** held out (406 / 376 open-loop predictions, 257 / 257 s)",
    ),
]


@pytest.mark.parametrize(("first", "figure"), FIGURES, ids=[first for first, _ in FIGURES])
def test_each_figure_of_the_docs_table(first: str, figure: str) -> None:
    """Speed, coverage and cross-validation, each row's figure from the hand-made result."""
    assert _figure(format_markdown(RESULT), first) == figure


def test_the_docs_table_layout_and_the_total() -> None:
    markdown = format_markdown(RESULT)
    assert markdown.startswith("| | figure |\n|---|---|\n")
    assert markdown.endswith("\n\nThe whole benchmark: 807 s.")
    table = markdown.split("\n\n")[0].splitlines()
    assert len({line.count("|") for line in table}) == 1


def test_a_result_without_the_real_runs_has_no_real_rows() -> None:
    markdown = format_markdown({**RESULT, "real": {}})
    assert "real," not in markdown and "simulation, known truth" in markdown
