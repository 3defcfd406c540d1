"""crs bench stack --cars 1,2,4,6: a count's figures from its report, the table and the plot."""

from __future__ import annotations

from benchmarks.stack_scale import _scale_entry, format_markdown, plot


def _report(cars: int) -> dict:
    return {
        "cars": {
            f"car{i}": {
                "laps_completed": 4,
                "estimation_rmse": {"x": 0.0008, "y": 0.001, "yaw": 0.005},
                "estimator_deadline_misses": 2,
                "estimator_updates": 2000,
                "overload": {"late_commands": 0, "starved": False},
                "outcome": "raced",
            }
            for i in range(1, cars + 1)
        },
        "cpu_percent_running": {
            **{f"/car{i}/pipeline": 30.0 + i for i in range(1, cars + 1)},
            "/recorder": 8.0,
        },
        "peak_memory_mib": {
            **{f"/car{i}/pipeline": 160.0 for i in range(1, cars + 1)},
            "/recorder": 80.0,
        },
        "solver_cpu_percent": {f"car{i}": 12.0 for i in range(1, cars + 1)},
        "node_deaths": [],
    }


def test_a_counts_entry_has_each_cars_cost_and_outcome():
    entry = _scale_entry(2, _report(2))
    assert entry["cars"] == 2 and entry["total_cpu_percent"] == 71.0
    first = entry["rows"][0]
    assert first["pipeline_cpu_percent"] == 31.0 and first["solver_cpu_percent"] == 12.0
    assert first["memory_mib"] == 200.0  # 160 + half the recorder's 80
    assert first["miss_fraction"] == 0.001 and first["rmse_mm"] == {"x": 0.8, "y": 1.0}


def test_the_table_and_the_plot(tmp_path):
    result = {
        "counts": [1, 2],
        "estimator": "mhe",
        "duration_s": 40.0,
        "load_processes": 0,
        "yardstick": {"before": {"median_us": 4.9}, "after": {"median_us": 5.0}},
        "scales": [_scale_entry(n, _report(n)) for n in (1, 2)],
    }
    table = format_markdown(result)
    rows = [line for line in table.splitlines() if line.startswith("| 2 ")]
    assert rows == [
        "| 2 | 31.0–32.0 % | 12.0 % | 8.0 % | 4 | 0.80 / 1.00 mm | 0.1 % | 0 of 2 | 2 raced "
        "| 200 MiB |"
    ]
    assert "4.9 µs before, 5 µs after" in table
    plot(result, tmp_path / "scale.png")
    assert (tmp_path / "scale.png").stat().st_size > 10_000
