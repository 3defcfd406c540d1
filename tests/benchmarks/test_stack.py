"""The stack benchmark's bookkeeping: its busy loops, the worst case over repeats, its table (the
stack itself is replaced by recorded reports; nothing is launched).
"""

from __future__ import annotations

import contextlib
from collections import Counter
from pathlib import Path
from typing import Any

import pytest

from benchmarks import stack
from benchmarks.stack import busy_loops, format_markdown, format_table, stack_benchmark
from launch_scripts.sim_stack import StackOptions

#: What two repeats of a two-car stack reported (the fields the benchmark keeps, and one more).
REPORTS = [
    {
        "cars": {
            "car1": {
                "laps_completed": 3,
                "estimation_rmse": {"x": 0.002, "y": 0.004, "yaw": 0.01},
                "estimator_deadline_misses": 1,
                "estimator_reinitializations": 0,
            },
            "car2": {"laps_completed": 2, "estimator_deadline_misses": 0},
        },
        "cpu_percent": {"/car1/estimator": 40.0},
        "node_deaths": [],
        "ignored": "not kept",
    },
    {
        "cars": {
            "car1": {
                "laps_completed": 2,
                "estimation_rmse": {"x": 0.003, "y": 0.001, "yaw": 0.02},
                "estimator_deadline_misses": 0,
                "estimator_reinitializations": 2,
            },
            "car2": {
                "laps_completed": 4,
                "estimation_rmse": {"x": 0.005, "y": 0.006, "yaw": 0.03},
                "estimator_deadline_misses": 7,
            },
        },
    },
]


def test_busy_loops_start_and_always_stop_their_children():
    with busy_loops(1) as processes:
        assert len(processes) == 1 and processes[0].poll() is None
    assert processes[0].poll() is not None
    with pytest.raises(RuntimeError), busy_loops(1) as processes:
        assert processes[0].poll() is None
        raise RuntimeError("a failed race")
    assert processes[0].poll() is not None


@pytest.fixture
def result(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> dict[str, Any]:
    calls = []

    def fake_run_stack(cars, options, duration, out, domain_id):
        calls.append((cars, options, duration, out, domain_id))
        return REPORTS[options.seed - 1]

    monkeypatch.setattr(stack, "run_stack", fake_run_stack)
    out = stack_benchmark(2, "mhe", 30.0, 2, 0, tmp_path, domain_id=5)
    assert calls == [
        (2, StackOptions("mhe", seed=1), 30.0, tmp_path / "run1", 5),
        (2, StackOptions("mhe", seed=2), 30.0, tmp_path / "run2", 5),
    ]
    return out


def test_each_repeat_keeps_the_report_fields_and_the_worst_is_taken_per_car(result) -> None:
    assert result["runs"][0] == {
        key: REPORTS[0][key] for key in ("cars", "cpu_percent", "node_deaths")
    }
    assert result["runs"][1] == {"cars": REPORTS[1]["cars"]}
    assert result["worst"] == {
        # fewest laps; the larger of x and y RMSE, largest over the repeats; most misses
        "car1": {"laps": 2, "position_rmse_m": 0.004, "deadline_misses": 1},
        # a repeat without estimates counts as an infinite position error
        "car2": {"laps": 2, "position_rmse_m": float("inf"), "deadline_misses": 7},
    }
    settings = {k: result[k] for k in ("cars", "estimator", "duration_s", "repeats")}
    assert settings == {"cars": 2, "estimator": "mhe", "duration_s": 30.0, "repeats": 2}
    assert result["load_processes"] == 0


def test_the_table_has_a_line_per_repeat_and_car(result) -> None:
    assert format_table(result).splitlines() == [
        "2 car(s), mhe, 30 s, 0 busy process(es)",
        "  repeat 1 car1: 3 laps; RMSE x 2.0 mm, y 4.0 mm, yaw 10.0 mrad; 1 misses, "
        "0 re-initialisations",
        "  repeat 1 car2: 2 laps; no estimates; 0 misses, 0 re-initialisations",
        "  repeat 2 car1: 2 laps; RMSE x 3.0 mm, y 1.0 mm, yaw 20.0 mrad; 0 misses, "
        "2 re-initialisations",
        "  repeat 2 car2: 4 laps; RMSE x 5.0 mm, y 6.0 mm, yaw 30.0 mrad; 7 misses, "
        "0 re-initialisations",
    ]


def _car(laps: list[float], x: float, misses: int, median: float) -> dict[str, Any]:
    return {
        "laps_completed": len(laps),
        "lap_times_s": laps,
        "estimation_rmse": {"x": x, "y": 0.001, "yaw": 0.0068},
        "estimator_deadline_misses": misses,
        "estimator_updates": 2100 + misses,
        "estimator_reinitializations": 0,
        "latency_ms": {"sensor_to_input": {"median": median, "p95": 42.4}},
    }


def _cpu(car: str, simulator: float) -> dict[str, float]:
    return {
        f"/{car}/simulator": simulator,
        f"/{car}/estimator": 25.9,
        f"/{car}/controller": 6.6,
        "/recorder": 20.4,
    }


def _runs_result(runs: list[dict[str, Any]], repeats: int) -> dict[str, Any]:
    return {
        "command": "crs bench stack --cars 2 --repeats 2 --out x.json",
        "cars": len(runs[0]["cars"]),
        "estimator": "mhe",
        "duration_s": 40.0,
        "repeats": repeats,
        "load_processes": 0,
        "runs": runs,
    }


def test_the_docs_row_spans_every_car_and_repeat() -> None:
    runs = [
        {
            "cars": {
                "car1": _car([11.77, 11.8], 0.00083, 0, 32.2),
                "car2": _car([11.86, 11.8], 0.00092, 1, 35.4),
            },
            "cpu_percent_running": {**_cpu("car1", 17.9), **_cpu("car2", 19.4)},
            "peak_memory_mib": {"/car1/estimator": 134.2, "/recorder": 83.0},
            "node_deaths": [],
        },
        {
            "cars": {"car1": _car([11.8, 11.8], 0.0009, 0, 33.0)},
            "cpu_percent_running": _cpu("car1", 18.0),
            "peak_memory_mib": {"/car1/estimator": 120.0},
        },
    ]
    lines = format_markdown(_runs_result(runs, 2)).splitlines()
    assert lines[0].startswith("| command | car | laps (lap time) |")
    assert len({line.count("|") for line in lines[:3]}) == 1
    assert [cell.strip() for cell in lines[2].strip("|").split("|")] == [
        "`crs bench stack --cars 2 --repeats 2 --out x.json`",
        "1, 2 (2 repeats)",
        "2 in each of 3 car runs (11.77–11.86 s)",
        "0.83–0.92 / 1.00 mm",
        "0–1 in 2100–2101",
        "32–35 / 42 ms",
        "50.4–51.9 %",
        "20 %",
    ]
    assert lines[4] == (
        "40 s per run, MHE; node deaths: 0; re-initialisations: 0; yaw RMSE 6.8 mrad; peak "
        "memory per node 83–134 MiB."
    )


def test_one_car_once_shows_its_pipeline_node_by_node() -> None:
    run = {"cars": {"car1": _car([11.8], 0.00083, 0, 34.0)}, "cpu_percent": _cpu("car1", 17.9)}
    cells = format_markdown(_runs_result([run], 1)).splitlines()[2].strip("|").split("|")
    assert [cell.strip() for cell in cells[1:]] == [
        "1", "1 (11.80 s)", "0.83 / 1.00 mm", "0 in 2100", "34 / 42 ms",
        "50.4 % (17.9 + 25.9 + 6.6)", "20 %",
    ]  # fmt: skip


def test_with_the_visualizer_each_repeat_runs_again_watched_and_gets_a_row(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    calls = []

    def fake_run_stack(cars, options, duration, out, domain_id):
        calls.append((options.viz, out.name))
        return {**REPORTS[0], "cpu_percent": {"/visualizer": 12.0}}

    @contextlib.contextmanager
    def fake_viewer(port: int, seconds: float):
        assert port == stack.VIZ.port and seconds > 30.0
        yield Counter({"/viz/scene": 900})

    monkeypatch.setattr(stack, "run_stack", fake_run_stack)
    monkeypatch.setattr(stack, "foxglove_viewer", fake_viewer)
    result = stack_benchmark(2, "mhe", 30.0, 1, 0, tmp_path, viz=True)
    assert calls == [(None, "run1"), (stack.VIZ, "run1_viz")]
    assert result["runs_viz"][0]["viewer_messages"] == {"/viz/scene": 900}
    text = format_markdown({**result, "command": "crs bench stack --viz"})
    assert "`crs bench stack --viz` with the visualizer and a viewer |" in text
    assert "The visualizer: 12.0 % of one core for 2 car(s) (6.0 % per car)" in text
    assert "(900 messages in the run)" in text
