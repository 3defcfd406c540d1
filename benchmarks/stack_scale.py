"""``crs bench stack --cars 1,2,4,6``: how the stack's cost grows with the cars on one machine.

For each number of cars the whole stack (:func:`launch_scripts.sim_stack.run_stack`, ``crs
launch sim``) runs once, with ``load`` busy processes beside it if asked; per car it keeps the
pipeline's CPU once running (its shared process, or its nodes summed), its solvers' own CPU
over the run (the estimator's updates and the controller's decisions, as the nodes count them),
laps, estimation RMSE, the deadline misses among the estimator's updates, how starved its loop
was and where the car ended (raced, stood on the track, left it), and the peak memory of its
pipeline with its share of the recorder's. A yardstick of the host, the compiled model step
timed before and after the runs, lets a slow day and a fast day be compared.
"""

from __future__ import annotations

import statistics
from collections import Counter
from pathlib import Path
from typing import Any

import numpy as np

from benchmarks.machine import timing
from benchmarks.stack import busy_loops, span
from launch_scripts.sim_stack import PIPELINE_PROCESS, StackOptions, pipeline_cpu, run_stack

#: Calls of the model step per yardstick measurement.
YARDSTICK_CALLS = 20000


def yardstick() -> dict[str, float]:
    """The host's speed: one compiled RK4 step of the car model (µs per call, median and p95)."""
    from crs_core.model import CarModel
    from crs_core.model.car_model import NumericModel

    model = CarModel()
    step = NumericModel(model, backend="compiled").functions["rk4_step"]
    x, u, p = (
        np.array([0.3, -1.0, 0.2, 1.2, 0.05, 1.5]),
        np.array([0.2, 0.4]),
        model.parameters.vector(),
    )
    us = timing(lambda: step(x, u, p, 0.004), YARDSTICK_CALLS)
    return {"median_us": us["median_us"], "p95_us": us["p95_us"]}


def scale_benchmark(
    counts: list[int],
    estimator: str,
    duration: float,
    load: int,
    work_dir: Path,
    domain_id: int | None = None,
) -> dict[str, Any]:
    """Run the stack with each number of cars in ``counts`` (JSON-ready result: ``yardstick``
    before and after, ``scales``, one entry per count with its ``cars`` rows)."""
    before = yardstick()
    scales = []
    with busy_loops(load):
        for count in counts:
            print(f"[bench] {count} car(s)", flush=True)
            options = StackOptions(estimator, seed=count)
            report = run_stack(count, options, duration, work_dir / f"cars{count}", domain_id)
            scales.append(_scale_entry(count, report))
    return {
        "counts": list(counts),
        "estimator": estimator,
        "duration_s": duration,
        "load_processes": load,
        "yardstick": {"before": before, "after": yardstick()},
        "scales": scales,
    }


def _scale_entry(count: int, report: dict[str, Any]) -> dict[str, Any]:
    """One count's figures from its ``report.json``."""
    running = report.get("cpu_percent_running") or report.get("cpu_percent") or {}
    memory = report.get("peak_memory_mib") or {}
    solvers = report.get("solver_cpu_percent") or {}
    recorder_mib = memory.get("/recorder", 0.0)
    cars = []
    for car, c in report["cars"].items():
        rmse = c.get("estimation_rmse") or {}
        updates = c.get("estimator_updates", 0)
        pipeline_mib = memory.get(f"/{car}/{PIPELINE_PROCESS}")
        if pipeline_mib is None:
            pipeline_mib = sum(v for k, v in memory.items() if k.startswith(f"/{car}/"))
        cars.append(
            {
                "car": car,
                "pipeline_cpu_percent": round(pipeline_cpu(running, car), 1),
                "solver_cpu_percent": solvers.get(car),
                "laps": c.get("laps_completed", 0),
                "rmse_mm": {k: round(1e3 * rmse[k], 2) for k in ("x", "y")} if rmse else None,
                "deadline_misses": c.get("estimator_deadline_misses", 0),
                "updates": updates,
                "miss_fraction": round(c.get("estimator_deadline_misses", 0) / updates, 4)
                if updates
                else None,
                "overload": c.get("overload"),
                "outcome": c.get("outcome"),
                "memory_mib": round(pipeline_mib + recorder_mib / count, 1),
            }
        )
    return {
        "cars": count,
        "rows": cars,
        "recorder_cpu_percent": running.get("/recorder"),
        "node_deaths": report.get("node_deaths", []),
        "total_cpu_percent": round(sum(running.values()), 1),
        "startup_s": report.get("startup_s"),
    }


def format_markdown(result: dict[str, Any]) -> str:
    """The docs' table of a scale run: per number of cars, the spans over its cars."""
    lines = [
        "| cars | pipeline CPU per car | its solvers | recorder | laps | RMSE x / y | misses | "
        "starved | outcome | memory per car |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for scale in result["scales"]:
        rows = scale["rows"]
        outcomes = ", ".join(
            f"{n} {o}" for o, n in sorted(Counter(r["outcome"] for r in rows).items())
        )
        rmse = [r["rmse_mm"] for r in rows if r["rmse_mm"]]
        rmse_text = (
            span([m["x"] for m in rmse], ".2f") + " / " + span([m["y"] for m in rmse], ".2f")
        )
        misses = [100 * r["miss_fraction"] for r in rows if r["miss_fraction"] is not None]
        solvers = [r["solver_cpu_percent"] for r in rows if r["solver_cpu_percent"] is not None]
        recorder = scale["recorder_cpu_percent"]
        starved = sum(bool(r["overload"] and r["overload"]["starved"]) for r in rows)
        cells = [
            str(scale["cars"]),
            f"{span([r['pipeline_cpu_percent'] for r in rows], '.1f')} %",
            f"{span(solvers, '.1f')} %",
            f"{recorder:.1f} %" if recorder is not None else "–",
            span([r["laps"] for r in rows], "d"),
            f"{rmse_text} mm" if rmse else "–",
            f"{span(misses, '.1f')} %",
            f"{starved} of {len(rows)}",
            outcomes,
            f"{span([r['memory_mib'] for r in rows], '.0f')} MiB",
        ]
        lines.append("| " + " | ".join(cells) + " |")
    before, after = result["yardstick"]["before"], result["yardstick"]["after"]
    startups = [e["startup_s"] for e in result["scales"] if e.get("startup_s") is not None]
    counted = (
        f"(start-up included: {span(startups, '.1f')} s)" if startups else "(start-up included)"
    )
    lines += [
        "",
        f"{result['duration_s']:g} s per run {counted}, "
        f"{result['estimator'].upper()}, {result['load_processes']} busy processes beside it; "
        f"the host's yardstick (one compiled model step) {before['median_us']:g} µs before, "
        f"{after['median_us']:g} µs after. Pipeline CPU once running (10 s on), % of one core; "
        "its solvers: the estimator's updates and the controller's decisions over the run; "
        "memory: the pipeline process's peak plus its share of the recorder's.",
    ]
    return "\n".join(lines)


def plot(result: dict[str, Any], path: Path) -> None:
    """CPU per car (pipeline and its solvers, median over the cars) and in all against the
    number of cars, with the machine's two cores marked."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    counts = [scale["cars"] for scale in result["scales"]]
    pipeline = [
        statistics.median(r["pipeline_cpu_percent"] for r in scale["rows"])
        for scale in result["scales"]
    ]
    solvers = [
        statistics.median(
            r["solver_cpu_percent"] for r in scale["rows"] if r["solver_cpu_percent"] is not None
        )
        for scale in result["scales"]
    ]
    total = [scale["total_cpu_percent"] for scale in result["scales"]]
    figure, (per_car, whole) = plt.subplots(1, 2, figsize=(10, 4))
    per_car.plot(counts, pipeline, "o-", label="pipeline (simulator, estimator, controller)")
    per_car.plot(counts, solvers, "s-", label="its solvers (estimator updates, controller)")
    per_car.set(xlabel="cars", ylabel="% of one core, per car", ylim=(0, None))
    per_car.set_xticks(counts)
    per_car.legend(fontsize=8)
    per_car.grid(alpha=0.3)
    whole.plot(counts, total, "o-", label="all processes of the stack")
    whole.axhline(200, color="grey", linestyle="--", label="the machine (2 cores)")
    whole.set(xlabel="cars", ylabel="% of one core, in all", ylim=(0, None))
    whole.set_xticks(counts)
    whole.legend(fontsize=8)
    whole.grid(alpha=0.3)
    figure.suptitle("crs bench stack: the stack's CPU as the cars grow (once running)")
    figure.tight_layout()
    figure.savefig(path, dpi=110)
    plt.close(figure)
