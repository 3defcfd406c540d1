"""The bridge benchmark's table: the direct-simulator and the emulated-car runs side by side, in
the units it names (the runs themselves launch two stacks and are not started here).
"""

from __future__ import annotations

from benchmarks.bridge import format_markdown, format_table

RESULT = {
    "estimator": "mhe",
    "duration_s": 30.0,
    "seed": 2,
    "runs": {
        "sim": {
            "car": {
                "laps_completed": 2,
                "lap_times_s": [9.126, 8.9],
                "estimation_rmse": {
                    "x": 0.0012,
                    "y": 0.00204,
                    "yaw": 0.0071,
                    "vx": 0.02,
                    "vy": 0.0,
                },
                "estimator_deadline_misses": 1,
                "estimator_updates": 1500,
                "latency_ms": {"sensor_to_estimate": {"median": 2.04, "p95": 5.96}},
            },
            "cpu_percent_running": {"/car1/estimator": 45.5, "/car1/controller": 20.0},
            "node_deaths": [],
        },
        "emulated": {
            "car": {
                "laps_completed": 0,
                "bridge_diagnostics": {"received": 7400, "sent": {"commands": 1480}},
            },
            "cpu_percent": {"/car1/bridge": 12.25},
            "node_deaths": [{"node": "/car1/estimator", "returncode": -11}],
        },
    },
}


def _cells(table: str, label: str) -> list[str]:
    (line,) = [line for line in table.splitlines() if line.startswith(label + "  ")]
    return line[len(label) :].split()


def test_the_runs_side_by_side_in_the_named_units() -> None:
    table = format_table(RESULT)
    lines = table.splitlines()
    assert lines[0] == "1 car, mhe, 30 s, seed 2"
    assert lines[1].split() == ["direct", "simulator", "emulated", "car", "over", "UDP"]
    assert _cells(table, "laps (lap times)") == ["2", "(9.13,", "8.90", "s)", "0", "(", "s)"]
    assert _cells(table, "RMSE x [mm]") == ["1.2", "-"]  # m -> mm; no estimates: "-"
    assert _cells(table, "RMSE y [mm]") == ["2.0", "-"]
    assert _cells(table, "RMSE yaw [mrad]") == ["7.1", "-"]
    assert _cells(table, "RMSE vx / vy [mm/s]") == ["20.0", "/", "0.0", "-", "/", "-"]
    assert _cells(table, "deadline misses / updates") == ["1", "/", "1500", "0", "/", "0"]
    assert _cells(table, "sensor -> estimate [ms] med / p95") == ["2.0", "/", "6.0", "-"]
    assert _cells(table, "command sent -> read by car [ms]") == ["-", "-"]
    assert _cells(table, "bridge received / commands sent") == ["-", "7400", "/", "1480"]
    assert _cells(table, "node deaths") == ["0", "1"]
    # CPU of the running phase where measured, else over the whole run; node names shortened
    assert lines[-2] == "CPU % once running, sim: estimator 45.5, controller 20"
    assert lines[-1] == "CPU % once running, emulated: bridge 12.25"


def test_the_docs_table_has_the_same_rows_in_markdown_and_the_cpu_per_process() -> None:
    lines = format_markdown(RESULT).splitlines()
    assert lines[:4] == [
        "1 car, mhe, 30 s, seed 2.",
        "",
        "| | direct simulator | emulated car over UDP |",
        "|---|---|---|",
    ]
    assert "| laps (lap times) | 2 (9.13, 8.90 s) | 0 ( s) |" in lines
    assert "| RMSE vx / vy [mm/s] | 20.0 / 0.0 | - / - |" in lines
    assert "| sensor → estimate [ms] med / p95 | 2.0 / 6.0 | - |" in lines
    assert "| bridge received / commands sent | - | 7400 / 1480 |" in lines
    assert "| node deaths | 0 | 1 |" in lines
    assert lines[-1] == (
        "| CPU once running (% of one core) | estimator 45.5, controller 20 | bridge 12.25 |"
    )
    # one row per figure of the text table, and the CPU row
    assert len(lines) - 4 == len(format_table(RESULT).splitlines()) - 4 + 1
