"""Bags written as the stack's recorder writes them, from a simulated run (for the tests of the
bag-as-dataset conversion and of the commands that take bags)."""

from __future__ import annotations

import itertools
from pathlib import Path
from typing import Any

import numpy as np
from rclpy.serialization import serialize_message
from rosbags.rosbag2 import StoragePlugin, Writer

from crs_core.measurements import InputSample, Measurement
from crs_core.model import CarModel
from ros4crs import conversions
from ros4crs.interfaces import typestore
from sim import SimulationResult, Simulator
from tests.sim.sim_runs import AT_REST, DRIVE, NOISY

#: The run's clock starts here in the bag (Unix time, as a real recording's).
T0 = 1_764_000_000.0
#: Seconds simulated.
DURATION = 2.0


def simulated_run() -> SimulationResult:
    """2 s of a noisy drive (with drop-outs and the motion capture on)."""
    return Simulator(CarModel(), NOISY, seed=5).run(DRIVE, DURATION, AT_REST)


def _type_name(msg: Any) -> str:
    return f"{type(msg).__module__.split('.')[0]}/msg/{type(msg).__name__}"


def write_bag(path: Path, messages: list[tuple[str, Any, float]]) -> Path:
    """A bag of ``(topic, message, receive time s)``."""
    store = typestore()
    with Writer(path, version=9, storage_plugin=StoragePlugin.MCAP) as writer:
        connections: dict[str, Any] = {}
        for topic, msg, received in messages:
            if topic not in connections:
                connections[topic] = writer.add_connection(topic, _type_name(msg), typestore=store)
            writer.write(connections[topic], round(received * 1e9), serialize_message(msg))
    return path


def _shifted(run: SimulationResult) -> tuple[list, list, list]:
    """The run's measurements, inputs and truth on the bag's clock."""
    measurements = [Measurement(T0 + m.stamp, m.sensor, m.values) for m in run.measurements]
    inputs = [InputSample(T0 + s.stamp, s.u) for s in run.inputs]
    truth = [(T0 + t, x) for t, x in zip(run.truth_t, run.truth_x, strict=True)]
    return measurements, inputs, truth


def stack_messages(
    run: SimulationResult, car: str = "/car1", truth: bool = True, estimates: bool = False
) -> list[tuple[str, Any, float]]:
    """What the recorder of the stack gets of ``run``: 10 ms sensor batches, the commands (and
    a velocity reference, which is no input), the truth and, optionally, estimates."""
    measurements, inputs, states = _shifted(run)
    out: list[tuple[str, Any, float]] = []
    last = max(m.stamp for m in measurements)
    edges = np.arange(T0, last + 0.02, 0.01)
    for start, end in itertools.pairwise(edges):
        batch = [m for m in measurements if start <= m.stamp < end]
        if batch:
            out.append((f"{car}/sensors/batch", conversions.batch_msg(batch), end + 0.001))
    for sample in inputs:
        out.append(
            (f"{car}/input", conversions.car_input_msg(sample.u, sample.stamp), sample.stamp)
        )
    out.append(
        (f"{car}/input", conversions.car_input_msg([0.0, 1.0], T0 + 1.0, "velocity"), T0 + 1)
    )
    for t, x in [*states[::5], states[-1]] if truth else ():
        out.append((f"{car}/ground_truth", conversions.car_state_msg(x, t), t))
    for t, x in states[::20] if estimates else ():
        out.append((f"{car}/estimate/state", conversions.car_state_msg(x, t), t + 0.02))
    return out


def two_car_bag(run: SimulationResult, path: Path) -> Path:
    """car1 with truth, car2 without, in one bag at ``path``."""
    messages = stack_messages(run) + stack_messages(run, "/car2", truth=False)
    return write_bag(path, sorted(messages, key=lambda m: m[2]))
