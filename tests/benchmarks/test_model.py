"""The model benchmark's docs table, from a hand-written result (the timing itself is not run
here)."""

from __future__ import annotations

from benchmarks.model import format_markdown


def _times(median: float, p95: float) -> dict[str, float]:
    return {"median_us": median, "p95_us": p95, "max_us": 10 * p95}


RESULT = {
    "model_evaluation": [
        {
            "backend": "compiled",
            "f": _times(4.41, 6.4),
            "rk4_step": _times(5.6, 9.12),
            "all_sensor_outputs": _times(5.6, 9.8),
            "calls": 20000,
        },
        {
            "backend": "vm",
            "f": _times(74.04, 88.0),
            "rk4_step": _times(54.0, 61.0),
            "all_sensor_outputs": _times(1234.5, 1500.2),
            "calls": 2000,
        },
    ],
    "simulator": {
        "simulated_s": 60.0,
        "wall_s": 1.334,
        "real_time_factor": 45.0,
        "sensors": "imu 250 Hz",
        "controller_hz": 50,
    },
}


def test_a_row_per_function_a_column_per_backend_in_microseconds() -> None:
    lines = format_markdown(RESULT).splitlines()
    assert lines[:5] == [
        "| | compiled C (ctypes) | CasADi VM |",
        "|---|---|---|",
        "| f(x, u, p), per call | 4.41 µs median (p95 6.4) | 74 µs median (p95 88) |",
        "| one RK4 step | 5.6 µs median (p95 9.12) | 54 µs median (p95 61) |",
        "| all sensor outputs | 5.6 µs median (p95 9.8) | 1234 µs median (p95 1500) |",
    ]


def test_the_simulator_line_gives_its_wall_time_and_real_time_factor() -> None:
    last = format_markdown(RESULT).splitlines()[-1]
    assert last == (
        "Per function 20000 calls compiled C (ctypes), 2000 calls CasADi VM. Simulator, 60 s with "
        "all sensors (imu 250 Hz) and the path follower at 50 Hz: 1.33 s wall, **real-time "
        "factor 45**."
    )
