"""``crs bench stack``: the launched ROS 2 stack measured, optionally on a loaded machine.

Each repeat runs :func:`launch_scripts.sim_stack.run_stack` (``crs launch sim``) into a folder of
its own and keeps, per car, laps, lap times, estimation RMSE (x, y, yaw, vx, vy) against the
simulator's truth, deadline misses, re-initialisations and latencies (median, p95), and per node
CPU (% of one core) and peak memory (MiB). ``load`` busy-looping processes run beside the stack
for the whole measurement (a machine that is busy with something else). With ``viz`` each repeat
runs a second time with the visualizer (``crs launch sim --viz``) and a Foxglove viewer
subscribed to every channel it advertises (:mod:`benchmarks.foxglove_viewer`), so the node does
what a watching person makes it do: its CPU, and the stack's figures with it beside them.
"""

from __future__ import annotations

import contextlib
import os
import signal
import subprocess
import sys
from collections import Counter
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from launch_scripts.sim_stack import (
    PIPELINE_NODES,
    StackOptions,
    pipeline_cpu,
    rmse_text,
    run_stack,
)
from launch_scripts.visualizer import VizSettings

#: A process that keeps one core busy until it is killed.
BUSY_LOOP = "while True:\n    pass\n"
#: Where the benchmark's visualizer serves (not the defaults: a viewer of the user's may be open).
VIZ = VizSettings(port=18765, page_port=18766)


@contextlib.contextmanager
def foxglove_viewer(port: int, seconds: float) -> Iterator[Counter[str]]:
    """A viewer of the Foxglove server on ``port`` for ``seconds`` (in a thread of its own,
    waiting for the server to come up); yields the count of messages it got per topic, final
    once the block ends."""
    import asyncio
    import threading
    import time

    from benchmarks.foxglove_viewer import watch

    counts: Counter[str] = Counter()
    deadline = time.monotonic() + seconds

    def count(channel: dict[str, Any], payload: bytes) -> None:
        counts[channel["topic"]] += 1

    thread = threading.Thread(
        target=lambda: asyncio.run(watch(f"ws://127.0.0.1:{port}", deadline, count)),
        name="foxglove-viewer",
        daemon=True,
    )
    thread.start()
    try:
        yield counts
    finally:
        thread.join(timeout=max(deadline - time.monotonic(), 0.0) + 10.0)


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
    viz: bool = False,
) -> dict[str, Any]:
    """Run the stack ``repeats`` times with ``load`` busy processes beside it (with ``viz``, each
    repeat a second time with the visualizer and a viewer).

    Returns a JSON-ready dict: the settings, ``runs`` (per repeat: ``cars`` as in
    ``report.json``, ``cpu_percent``, ``cpu_percent_running``, ``peak_memory_mib``,
    ``node_deaths``; with ``viz`` also ``runs_viz``, the same and ``viewer_messages``, the
    messages the viewer got per topic) and ``worst`` (per car over the repeats without the
    visualizer: fewest laps, largest position RMSE, most deadline misses).
    """
    keys = ("cars", "cpu_percent", "cpu_percent_running", "peak_memory_mib", "node_deaths")
    runs, runs_viz = [], []
    with busy_loops(load):
        for repeat in range(1, repeats + 1):
            print(f"[bench] repeat {repeat} of {repeats}", flush=True)
            options = StackOptions(estimator, seed=repeat)
            report = run_stack(cars, options, duration, work_dir / f"run{repeat}", domain_id)
            runs.append({key: report[key] for key in keys if key in report})
            if not viz:
                continue
            print(f"[bench] repeat {repeat} of {repeats} with the visualizer", flush=True)
            options = StackOptions(estimator, seed=repeat, viz=VIZ)
            with foxglove_viewer(VIZ.port, duration + 30.0) as seen:
                report = run_stack(
                    cars, options, duration, work_dir / f"run{repeat}_viz", domain_id
                )
            runs_viz.append(
                {**{key: report[key] for key in keys if key in report}, "viewer_messages": seen}
            )
    return {
        "cars": cars,
        "estimator": estimator,
        "duration_s": duration,
        "repeats": repeats,
        "load_processes": load,
        "runs": runs,
        **({"runs_viz": runs_viz} if viz else {}),
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


def span(values: list[float], form: str) -> str:
    """``a–b`` of the formatted smallest and largest value, ``a`` when they are the same."""
    if not values:
        return "–"
    low, high = format(min(values), form), format(max(values), form)
    return low if low == high else f"{low}–{high}"


def _spans(items: list[dict[str, float]], keys: tuple[str, str], form: str, scale=1.0) -> str:
    """``span of the first key / span of the second`` over ``items``."""
    return " / ".join(span([scale * item[key] for item in items], form) for key in keys)


def format_markdown(result: dict[str, Any]) -> str:
    """The docs' row of the run (Markdown): per car over all repeats, the smallest and largest
    laps, lap time, position RMSE x / y (mm), deadline misses, sensor -> input latency (median /
    p95, ms), CPU of the car's simulator + estimator + controller and of the recorder (% of one
    core once running); then node deaths, re-initialisations, yaw RMSE and peak memory. With the
    visualizer runs, a second row for them and the visualizer's CPU."""
    rows, notes = [_row(result, result["runs"], "")], [_note(result, result["runs"])]
    if "runs_viz" in result:
        rows.append(_row(result, result["runs_viz"], " with the visualizer and a viewer"))
        cpu = [
            (run.get("cpu_percent_running") or run.get("cpu_percent") or {}).get("/visualizer", 0)
            for run in result["runs_viz"]
        ]
        messages = [sum(run.get("viewer_messages", {}).values()) for run in result["runs_viz"]]
        notes.append(
            f"The visualizer: {span(cpu, '.1f')} % of one core for {result['cars']} car(s) "
            f"({span([c / result['cars'] for c in cpu], '.1f')} % per car), its viewer "
            f"subscribed to every channel ({span(messages, 'd')} messages in the run)."
        )
    return "\n".join(
        [
            "| command | car | laps (lap time) | RMSE x / y | misses | sensor → input | "
            "pipeline CPU | recorder CPU |",
            "|---|---|---|---|---|---|---|---|",
            *rows,
            "",
            " ".join(notes),
        ]
    )


def _row(result: dict[str, Any], runs: list[dict[str, Any]], label: str) -> str:
    """One table row of ``runs`` (see :func:`format_markdown`); ``label`` follows the command."""
    cars = [(run, car, c) for run in runs for car, c in run["cars"].items()]
    laps = [c.get("laps_completed", 0) for _, _, c in cars]
    lap_times = [t for _, _, c in cars for t in c.get("lap_times_s", [])]
    rmse = [c["estimation_rmse"] for _, _, c in cars if c.get("estimation_rmse")]
    latency = [
        c["latency_ms"]["sensor_to_input"]
        for _, _, c in cars
        if (c.get("latency_ms") or {}).get("sensor_to_input")
    ]
    pipelines, recorder = [], []
    for run, car, _ in cars:
        cpu = run.get("cpu_percent_running") or run.get("cpu_percent") or {}
        nodes = [cpu[f"/{car}/{n}"] for n in PIPELINE_NODES if f"/{car}/{n}" in cpu]
        pipelines.append(nodes if nodes else [pipeline_cpu(cpu, car)])  # per node, or shared
        recorder += [cpu["/recorder"]] if "/recorder" in cpu else []
    pipeline = span([sum(p) for p in pipelines], ".1f") + " %"
    if len(pipelines) == 1 and len(pipelines[0]) > 1:
        pipeline += " (" + " + ".join(f"{v:g}" for v in pipelines[0]) + ")"
    who = ", ".join(sorted({car.removeprefix("car") for _, car, _ in cars}))
    if result["repeats"] > 1:
        who += f" ({result['repeats']} repeats)"
    if result.get("load_processes"):
        who += f", {result['load_processes']} busy processes"
    laps_text = span(laps, "d") + (f" in each of {len(cars)} car runs" if len(cars) > 1 else "")
    if lap_times:
        laps_text += f" ({span(lap_times, '.2f')} s)"
    misses = [c.get("estimator_deadline_misses", 0) for _, _, c in cars]
    updates = [c.get("estimator_updates", 0) for _, _, c in cars]
    row = [
        f"`{result.get('command', 'crs bench stack')}`{label}",
        who,
        laps_text,
        f"{_spans(rmse, ('x', 'y'), '.2f', 1e3)} mm",
        f"{span(misses, 'd')} in {span(updates, 'd')}",
        f"{_spans(latency, ('median', 'p95'), '.0f')} ms",
        pipeline,
        f"{span(recorder, '.0f')} %",
    ]
    return "| " + " | ".join(row) + " |"


def _note(result: dict[str, Any], runs: list[dict[str, Any]]) -> str:
    """The line under the table: run length, estimator, node deaths, re-initialisations, yaw
    RMSE and peak memory of ``runs``."""
    cars = [c for run in runs for c in run["cars"].values()]
    rmse = [c["estimation_rmse"] for c in cars if c.get("estimation_rmse")]
    deaths = sum(len(run.get("node_deaths", [])) for run in runs)
    reinit = [c.get("estimator_reinitializations", 0) for c in cars]
    memory = [m for run in runs for m in (run.get("peak_memory_mib") or {}).values()]
    return (
        f"{result['duration_s']:g} s per run, {result['estimator'].upper()}; node deaths: "
        f"{deaths}; re-initialisations: {span(reinit, 'd')}; yaw RMSE "
        f"{span([1e3 * r['yaw'] for r in rmse], '.1f')} mrad; peak memory per node "
        f"{span(memory, '.0f')} MiB."
    )
