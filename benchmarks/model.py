"""``crs bench model``: model evaluation speed and the simulator's real-time factor (JSON)."""

from __future__ import annotations

import time
from typing import Any

import numpy as np

from benchmarks.machine import format_ms, timing
from crs_core.control.path_following import PathFollower
from crs_core.model import CarModel
from crs_core.model.car_model import NumericModel
from crs_core.track import load_demo_track
from sim.sensors import SensorSuite
from sim.simulator import Simulator


def model_benchmark(repeats: int = 20000, sim_duration: float = 60.0) -> dict[str, Any]:
    """Per-call times of the compiled and VM model functions, and the simulator's speed."""
    model = CarModel()
    p = model.parameters.vector()
    x = np.array([0.3, -1.0, 0.2, 1.2, 0.05, 1.5])
    u = np.array([0.2, 0.4])
    rows = []
    for backend in ("compiled", "vm"):
        numeric = NumericModel(model, backend=backend)
        step = numeric.functions["rk4_step"]
        n = repeats if backend == "compiled" else repeats // 10
        rows.append(
            {
                "backend": numeric.backend,
                "f": timing(lambda numeric=numeric: numeric.f(x, u, p), n),
                "rk4_step": timing(lambda step=step: step(x, u, p, 0.004), n),
                "all_sensor_outputs": timing(lambda numeric=numeric: numeric.outputs(x, u, p), n),
                "calls": n,
            }
        )
    track = load_demo_track()
    controller = PathFollower(track, model.parameters.value("lf") + model.parameters.value("lr"))
    simulator = Simulator(model, SensorSuite(), seed=0)
    start = time.perf_counter()
    result = simulator.run(controller, sim_duration, track.start_state())
    elapsed = time.perf_counter() - start
    return {
        "model_evaluation": rows,
        "simulator": {
            "simulated_s": sim_duration,
            "wall_s": round(elapsed, 3),
            "real_time_factor": round(sim_duration / elapsed, 1),
            "measurements": len(result.measurements),
            "sensors": "imu 250 Hz, wheel encoders 250 Hz, lighthouse 2 planes x 50 Hz",
            "controller_hz": 50,
        },
    }


#: The docs' names of the model functions' backends and of the functions timed.
BACKENDS = {"compiled": "compiled C (ctypes)", "vm": "CasADi VM"}
FUNCTIONS = {
    "f": "f(x, u, p), per call",
    "rk4_step": "one RK4 step",
    "all_sensor_outputs": "all sensor outputs",
}


def format_markdown(result: dict[str, Any]) -> str:
    """The docs' account of a run (Markdown): median (p95) time per call of each model function
    on each backend (µs), then the simulator's wall time (s) and real-time factor.

    Parameters
    ----------
    result : dict
        The benchmark's JSON (:func:`model_benchmark`): ``model_evaluation`` (times in µs) and
        ``simulator`` (times in s).

    Returns
    -------
    str
        Markdown: a table and a line on the simulator.
    """
    rows = result["model_evaluation"]
    names = [BACKENDS.get(r["backend"], r["backend"]) for r in rows]
    lines = [
        "| | " + " | ".join(names) + " |",
        "|---|" + "---|" * len(rows),
    ]
    for key, label in FUNCTIONS.items():
        cells = [
            f"{format_ms(r[key]['median_us'])} µs median (p95 {format_ms(r[key]['p95_us'])})"
            for r in rows
        ]
        lines.append(f"| {label} | " + " | ".join(cells) + " |")
    calls = ", ".join(f"{r['calls']} calls {name}" for r, name in zip(rows, names, strict=True))
    sim = result["simulator"]
    lines += [
        "",
        f"Per function {calls}. Simulator, {sim['simulated_s']:g} s with all sensors "
        f"({sim['sensors']}) and the path follower at {sim['controller_hz']:g} Hz: "
        f"{sim['wall_s']:.2f} s wall, **real-time factor {sim['real_time_factor']:.0f}**.",
    ]
    return "\n".join(lines)
