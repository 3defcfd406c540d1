"""The two-machine benchmark's tables from a recorded result (nothing is launched; the split
itself runs in tests/integration/test_several_machines.py)."""

from __future__ import annotations

from typing import Any

from benchmarks.several_machines import PARTS, format_markdown, format_table


def _car(median: float) -> dict[str, Any]:
    return {
        "laps_completed": 5,
        "lap_times_s": [6.77, 6.42],
        "estimation_rmse": {"x": 0.00081, "y": 0.001, "yaw": 0.0051, "vx": 0.008, "vy": 0.005},
        "latency_ms": {"sensor_to_input": {"median": median, "p95": 40.8}},
    }


RESULT = {
    "duration_s": 40.0,
    "one_machine": {
        "car": _car(29.3),
        "cpu_percent_running": {"/car1/simulator": 10.0, "/car1/estimator": 16.0, "/recorder": 6},
    },
    "two_machines": {
        "car": _car(36.7),
        "cpu_percent_running": {"/car1/simulator": 10.5, "/car1/controller": 17.5},
    },
    "link": {"bytes_per_s": {"a_to_b": 61373, "b_to_a": 95649}, "cpu_percent": {"A": 8.3, "B": 8}},
}


def test_the_split_puts_the_simulator_and_recorder_apart_from_the_estimator_and_controller():
    assert set(PARTS) == {"A", "B"}
    together = {name for nodes in PARTS.values() for name in nodes.split(",")}
    assert together == {"simulator", "recorder", "estimator", "controller"}


def test_markdown_has_a_row_per_setting_and_the_link_figures():
    text = format_markdown(RESULT)
    one, two = (line for line in text.splitlines() if line.startswith("| one") or "Zenoh" in line)
    assert "| 5 (6.42–6.77 s) | 0.81 / 1.00 mm | 29.3 / 40.8 ms | 26.0 % | – |" in one
    assert "36.7 / 40.8 ms | 28.0 % | 8.3 + 8 % |" in two  # the car's nodes, not the recorder
    assert "61.4 kB/s from A" in text and "95.6 kB/s back" in text


def test_table_for_a_person_names_both_runs_and_the_link():
    text = format_table(RESULT)
    assert "one machine: 5 laps" in text and "two machines: 5 laps" in text
    assert "61.4 kB/s A -> B, 95.6 kB/s B -> A; zenoh_link CPU 8.3 % (A), 8 % (B)" in text
