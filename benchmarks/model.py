"""``crs bench model``: model evaluation speed and the simulator's real-time factor (JSON)."""

from __future__ import annotations

import sys
import time
from typing import Any

import numpy as np

from benchmarks.machine import machine, timing
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
    result = simulator.run(
        controller, sim_duration, np.array([track.start_x, track.start_y, track.start_yaw, 0, 0, 0])
    )
    elapsed = time.perf_counter() - start
    return {
        "machine": machine(),
        "command": " ".join(["crs", *sys.argv[1:]]) if sys.argv else "crs bench model",
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
