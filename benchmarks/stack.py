"""``crs bench stack``: the launched ROS 2 stack measured, optionally on a loaded machine.

Each repeat runs :func:`launch_scripts.sim_stack.run_stack` (``crs launch sim``) into a folder of
its own and keeps, per car, laps, lap times, estimation RMSE (x, y, yaw, vx, vy) against the
simulator's truth, deadline misses, re-initialisations and latencies (median, p95), and per node
CPU (% of one core) and peak memory (MiB). ``load`` busy-looping processes run beside the stack
for the whole measurement (a machine that is busy with something else).
"""

from __future__ import annotations

import contextlib
import os
import signal
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from launch_scripts.sim_stack import rmse_text, run_stack

#: A process that keeps one core busy until it is killed.
BUSY_LOOP = "while True:\n    pass\n"


@contextlib.contextmanager
def busy_loops(count: int) -> Iterator[list[subprocess.Popen]]:
    """``count`` processes each keeping one core busy (``python -c "while True: pass"``, in
    sessions of their own so a Ctrl-C on the terminal does not reach them) for the ``with``
    block; killed (SIGKILL) and reaped when it ends, however it ends."""
    processes: list[subprocess.Popen] = []
    try:
        for _ in range(count):
            processes.append(
                subprocess.Popen(
                    [sys.executable, "-c", BUSY_LOOP],
                    start_new_session=True,
                    stdin=subprocess.DEVNULL,
                    stdout=subprocess.DEVNULL,
                )
            )
        yield processes
    finally:
        for process in processes:
            with contextlib.suppress(ProcessLookupError):
                os.killpg(process.pid, signal.SIGKILL)
            process.wait()


def stack_benchmark(
    cars: int,
    estimator: str,
    duration: float,
    repeats: int,
    load: int,
    work_dir: Path,
    domain_id: int | None = None,
) -> dict[str, Any]:
    """Run the stack ``repeats`` times with ``load`` busy processes beside it.

    Returns a JSON-ready dict: the settings, ``runs`` (per repeat: ``cars`` as in
    ``report.json``, ``cpu_percent``, ``cpu_percent_running``, ``peak_memory_mib``,
    ``node_deaths``) and ``worst`` (per car over the repeats: fewest laps, largest position
    RMSE, most deadline misses).
    """
    runs = []
    with busy_loops(load):
        for repeat in range(1, repeats + 1):
            print(f"[bench] repeat {repeat} of {repeats}", flush=True)
            report = run_stack(
                cars, estimator, duration, work_dir / f"run{repeat}", domain_id, seed=repeat
            )
            keys = ("cars", "cpu_percent", "cpu_percent_running", "peak_memory_mib", "node_deaths")
            runs.append({key: report[key] for key in keys if key in report})
    return {
        "cars": cars,
        "estimator": estimator,
        "duration_s": duration,
        "repeats": repeats,
        "load_processes": load,
        "runs": runs,
        "worst": _worst(runs),
    }


def _worst(runs: list[dict[str, Any]]) -> dict[str, dict[str, float]]:
    """Per car over the repeats: fewest laps, largest position RMSE (m), most misses."""
    worst: dict[str, dict[str, float]] = {}
    for run in runs:
        for car, result in run["cars"].items():
            rmse = result.get("estimation_rmse") or {}
            position = max(rmse.get("x", float("inf")), rmse.get("y", float("inf")))
            entry = worst.setdefault(
                car, {"laps": float("inf"), "position_rmse_m": 0.0, "deadline_misses": 0}
            )
            entry["laps"] = min(entry["laps"], result.get("laps_completed", 0))
            entry["position_rmse_m"] = max(entry["position_rmse_m"], position)
            entry["deadline_misses"] = max(
                entry["deadline_misses"], result.get("estimator_deadline_misses", 0)
            )
    return worst


def format_table(result: dict[str, Any]) -> str:
    """One line per car and repeat, for a person."""
    lines = [
        f"{result['cars']} car(s), {result['estimator']}, {result['duration_s']:g} s, "
        f"{result['load_processes']} busy process(es)"
    ]
    for k, run in enumerate(result["runs"], start=1):
        for car, c in run["cars"].items():
            errors = rmse_text(c.get("estimation_rmse"))
            lines.append(
                f"  repeat {k} {car}: {c.get('laps_completed', 0)} laps; {errors}; "
                f"{c.get('estimator_deadline_misses', 0)} misses, "
                f"{c.get('estimator_reinitializations', 0)} re-initialisations"
            )
    return "\n".join(lines)
