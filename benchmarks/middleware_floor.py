"""``crs bench floor``: what rclpy itself costs one car's pipeline, with no work done.

A stand-in pipeline process carries exactly one car's traffic (the topics, message types, QoS
and rates of ``crs launch sim``'s simulator, estimator and controller: a sensor batch every
``batch_period`` with the readings the default sensors produce in it, ground truth, the four
estimate topics, the command) and a stand-in recorder subscribes to every topic raw, as the
recorder does. The stand-ins build each message with the nodes' own builders
(:mod:`ros4crs.conversions`) and read every received message into numpy, and compute nothing
else: no physics, no sensors, no estimator, no controller, no
validation. Two variants: the pipeline with its own subscriptions (the batch and the command
into the estimator, the state into the controller, the command into the simulator), and
publishing only (what an in-process hand-off between the car's nodes would leave). The real
stack runs once per repeat in the same benchmark, so the floor is read as a share of what the
pipeline costs on the same host at the same hour; a yardstick of the host (the compiled model
step) is timed before and after.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from collections import Counter
from pathlib import Path
from typing import Any

import numpy as np

#: Seconds each stand-in runs before its CPU is counted (discovery, first matches).
WARM_UP_S = 3.0
#: Topics of one car (in namespace ``/car1``, ``/tf`` global) and who publishes them.
PUBLISHERS = {
    "sensors/batch": "simulator",
    "ground_truth": "simulator",
    "estimate/state": "estimator",
    "estimate/odometry": "estimator",
    "estimate/query": "estimator",
    "/tf": "estimator",
    "input": "controller",
}


def traffic() -> dict[str, Any]:
    """One car's traffic as ``crs launch sim`` makes it by default: the rates (Hz) of its
    topics and the readings in one sensor batch (name, values per reading, readings per batch)."""
    from crs_core.control.mpcc_problem import MpccSettings
    from crs_core.estimation.realtime import RealtimeSettings
    from crs_core.model import CarModel
    from ros4crs.sensor_output import SensorOutputSettings
    from ros4crs.simulator_node import DEFAULT_TRUTH_RATE_HZ
    from sim.sensors import SensorSuite

    period = SensorOutputSettings().batch_period
    sensors = SensorSuite()
    readings = [
        ("imu", 3, sensors.imu.rate_hz * period),
        ("wheel_encoders", 4, sensors.wheel_encoders.rate_hz * period),
    ]
    for station in range(CarModel().n_base_stations):
        for plane in (1, 2):
            readings.append(
                (f"lighthouse/{station}/{plane}", 4, sensors.lighthouse.rate_hz * period)
            )
    estimate_hz = RealtimeSettings().rate_hz
    return {
        "rates_hz": {
            "sensors/batch": 1.0 / period,
            "ground_truth": DEFAULT_TRUTH_RATE_HZ,
            **{topic: estimate_hz for topic, node in PUBLISHERS.items() if node == "estimator"},
            "input": MpccSettings().rate_hz,
        },
        "batch": readings,
    }


def _stand_in(role: str, seconds: float, subscribe: bool) -> dict[str, Any]:
    """Run one stand-in process's nodes for ``seconds``; its CPU (% of one core) after
    :data:`WARM_UP_S` and the messages it received per topic."""
    import rclpy
    from nav_msgs.msg import Odometry
    from rclpy.node import Node

    from chronos_msgs.msg import CarInput, CarState, EstimatorQuery, SensorBatch
    from crs_core.estimation.base import Estimate
    from crs_core.measurements import Measurement
    from ros4crs import conversions
    from ros4crs.node_support import LOG_QOS, STREAM_OUT_QOS, STREAM_QOS, make_executor
    from tf2_msgs.msg import TFMessage

    load = traffic()
    rng = np.random.default_rng(0)
    rates = load["rates_hz"]
    received: Counter[str] = Counter()
    # what the recorder subscribes with: transient-local where every publisher offers it
    recorded = {
        "sensors/batch": (SensorBatch, LOG_QOS),
        "ground_truth": (CarState, LOG_QOS),
        "estimate/state": (CarState, LOG_QOS),
        "estimate/odometry": (Odometry, LOG_QOS),
        "estimate/query": (EstimatorQuery, LOG_QOS),
        "/tf": (TFMessage, STREAM_QOS),
        "input": (CarInput, LOG_QOS),
    }

    def counted(topic: str, read):
        def callback(msg) -> None:
            received[topic] += 1
            read(msg)

        return callback

    class Simulator(Node):
        def __init__(self) -> None:
            super().__init__("simulator", namespace="/car1")
            self.batch = self.create_publisher(SensorBatch, "sensors/batch", STREAM_OUT_QOS)
            self.truth = self.create_publisher(CarState, "ground_truth", LOG_QOS)
            if subscribe:
                read = counted("input", lambda m: np.array([m.steer, m.torque]))
                self.create_subscription(CarInput, "input", read, STREAM_QOS)
            self.create_timer(1.0 / rates["sensors/batch"], self.on_batch)
            self.create_timer(1.0 / rates["ground_truth"], self.on_truth)
            self.carry = np.zeros(len(load["batch"]))

        def on_batch(self) -> None:
            now = time.time()
            self.carry += [per_batch for _, _, per_batch in load["batch"]]
            readings = []
            for k, (name, size, _) in enumerate(load["batch"]):
                while self.carry[k] >= 1.0:
                    self.carry[k] -= 1.0
                    stamp = now - 1e-6 * len(readings)
                    readings.append(Measurement(stamp, name, rng.random(size)))
            if readings:
                self.batch.publish(conversions.batch_msg(readings, "car1/base_link"))

        def on_truth(self) -> None:
            self.truth.publish(conversions.car_state_msg(rng.random(6), time.time()))

    class Estimator(Node):
        def __init__(self) -> None:
            super().__init__("estimator", namespace="/car1")
            if subscribe:
                read = counted("sensors/batch", lambda m: (np.asarray(m.values), list(m.sensors)))
                self.create_subscription(SensorBatch, "sensors/batch", read, STREAM_QOS)
                read = counted("input", lambda m: np.array([m.steer, m.torque]))
                self.create_subscription(CarInput, "input", read, STREAM_QOS)
            self.state = self.create_publisher(CarState, "estimate/state", LOG_QOS)
            self.odometry = self.create_publisher(Odometry, "estimate/odometry", LOG_QOS)
            self.query = self.create_publisher(EstimatorQuery, "estimate/query", LOG_QOS)
            self.tf = self.create_publisher(TFMessage, "/tf", 10)
            self.create_timer(1.0 / rates["estimate/state"], self.on_update)

        def on_update(self) -> None:
            now = time.time()
            estimate = Estimate(now, rng.random(6), np.eye(6))
            self.state.publish(conversions.car_state_msg(estimate.x, now, estimate.covariance))
            self.odometry.publish(conversions.odometry_msg(estimate, "car1/base_link"))
            newest = {"sensors/batch": now, "input": now}
            oldest = {stream: now - 10.0 for stream in newest}
            self.query.publish(conversions.query_msg(now, False, newest, oldest))
            self.tf.publish(conversions.transform_msg(estimate, "car1/base_link"))

    class Controller(Node):
        def __init__(self) -> None:
            super().__init__("controller", namespace="/car1")
            if subscribe:
                read = counted(
                    "estimate/state",
                    lambda m: (
                        np.array([m.x, m.y, m.yaw, m.vx, m.vy, m.omega]),
                        np.asarray(m.covariance).reshape(6, 6),
                    ),
                )
                self.create_subscription(CarState, "estimate/state", read, STREAM_QOS)
            self.command = self.create_publisher(CarInput, "input", STREAM_OUT_QOS)
            self.create_timer(1.0 / rates["input"], self.on_control)

        def on_control(self) -> None:
            self.command.publish(conversions.car_input_msg(np.array([0.1, 0.2]), time.time()))

    class Recorder(Node):
        def __init__(self) -> None:
            super().__init__("recorder")
            for topic, (kind, qos) in recorded.items():
                name = topic if topic.startswith("/") else f"/car1/{topic}"
                self.create_subscription(kind, name, counted(topic, bytes), qos, raw=True)

    rclpy.init()
    try:
        executor = make_executor()
        nodes = [Simulator(), Estimator(), Controller()] if role == "pipeline" else [Recorder()]
        for node in nodes:
            executor.add_node(node)
        end = time.monotonic() + seconds
        mark: tuple[float, float] | None = None
        while time.monotonic() < end:
            executor.spin_once(timeout_sec=0.1)
            if mark is None and time.monotonic() > end - seconds + WARM_UP_S:
                mark = (time.process_time(), time.monotonic())
                received.clear()
        assert mark is not None
        elapsed = time.monotonic() - mark[1]
        cpu = 100.0 * (time.process_time() - mark[0]) / elapsed
        for node in nodes:
            node.destroy_node()
    finally:
        rclpy.try_shutdown()
    return {
        "role": role,
        "cpu_percent": round(cpu, 2),
        "received_hz": {topic: round(n / elapsed, 1) for topic, n in sorted(received.items())},
    }


def _run_pair(seconds: float, subscribe: bool, domain: int) -> dict[str, Any]:
    """The stand-in recorder and pipeline side by side in ROS domain ``domain``."""
    env = {**os.environ, "ROS_DOMAIN_ID": str(domain)}
    command = [sys.executable, "-m", "benchmarks.middleware_floor", "--seconds"]
    recorder = subprocess.Popen(
        [*command, str(seconds + 1.0), "recorder"], env=env, stdout=subprocess.PIPE, text=True
    )
    time.sleep(0.5)
    flags = [] if subscribe else ["--publish-only"]
    pipeline = subprocess.run(
        [*command, str(seconds), *flags, "pipeline"],
        env=env,
        stdout=subprocess.PIPE,
        text=True,
        check=True,
    )
    out, _ = recorder.communicate(timeout=seconds + 30.0)
    if recorder.returncode:
        raise RuntimeError(f"the stand-in recorder exited with {recorder.returncode}")
    return {
        "pipeline": json.loads(pipeline.stdout.strip().splitlines()[-1]),
        "recorder": json.loads(out.strip().splitlines()[-1]),
    }


def floor_benchmark(
    duration: float, repeats: int, work_dir: Path, domain_id: int | None = None
) -> dict[str, Any]:
    """Per repeat: the stand-ins with the pipeline's subscriptions, publishing only, and the
    real one-car stack (``crs launch sim``, MHE), each ``duration`` s (JSON-ready)."""
    from benchmarks.stack_scale import yardstick
    from launch_scripts.sim_stack import StackOptions, pipeline_cpu, run_stack

    domain = domain_id if domain_id is not None else int(os.environ.get("ROS_DOMAIN_ID", "42"))
    before = yardstick()
    runs = []
    for repeat in range(repeats):
        print(f"[bench] repeat {repeat + 1} of {repeats}: the stand-ins", flush=True)
        with_subscriptions = _run_pair(duration, True, domain)
        publish_only = _run_pair(duration, False, domain)
        print(f"[bench] repeat {repeat + 1} of {repeats}: the real stack", flush=True)
        report = run_stack(
            1, StackOptions("mhe"), duration, work_dir / f"stack{repeat + 1}", domain
        )
        running = report.get("cpu_percent_running") or report.get("cpu_percent") or {}
        runs.append(
            {
                "floor": with_subscriptions,
                "floor_publish_only": publish_only,
                "stack": {
                    "pipeline_cpu_percent": round(pipeline_cpu(running, "car1"), 2),
                    "recorder_cpu_percent": running.get("/recorder"),
                    "laps": report["cars"]["car1"]["laps_completed"],
                },
            }
        )
    return {
        "duration_s": duration,
        "repeats": repeats,
        "traffic": traffic(),
        "yardstick": {"before": before, "after": yardstick()},
        "runs": runs,
    }


def _range(values: list[float], unit: str = " %") -> str:
    low, high = min(values), max(values)
    return f"{low:.1f}{unit}" if abs(high - low) < 0.05 else f"{low:.1f}–{high:.1f}{unit}"


def format_markdown(result: dict[str, Any]) -> str:
    """The floor beside the real pipeline: a Markdown table and a line of settings."""
    runs = result["runs"]
    floor = [r["floor"]["pipeline"]["cpu_percent"] for r in runs]
    alone = [r["floor_publish_only"]["pipeline"]["cpu_percent"] for r in runs]
    stack = [r["stack"]["pipeline_cpu_percent"] for r in runs]
    recorder_floor = [r["floor"]["recorder"]["cpu_percent"] for r in runs]
    recorder_stack = [r["stack"]["recorder_cpu_percent"] or 0.0 for r in runs]
    share = [f / s * 100.0 for f, s in zip(floor, stack, strict=True) if s > 0]
    rates = result["traffic"]["rates_hz"]
    published = sum(rates.values())
    lines = [
        "| one car | pipeline CPU | recorder CPU |",
        "|---|---|---|",
        f"| the stand-ins, no work, the pipeline's own subscriptions | {_range(floor)} | "
        f"{_range(recorder_floor)} |",
        f"| the stand-ins, no work, publishing only | {_range(alone)} | "
        f"{_range([r['floor_publish_only']['recorder']['cpu_percent'] for r in runs])} |",
        f"| `crs launch sim` (MHE, MPCC), the same run | {_range(stack)} | "
        f"{_range(recorder_stack)} |",
        "",
        f"{result['repeats']} repeat(s) of {result['duration_s']:g} s; CPU % of one core once "
        f"running; {published:.0f} messages/s published over {len(rates)} topics "
        f"({', '.join(f'{t} {r:g} Hz' for t, r in rates.items())}); the floor with "
        f"subscriptions is {_range(share)} of the real pipeline; the host's yardstick (one "
        f"compiled model step) {result['yardstick']['before']['median_us']:g} µs before, "
        f"{result['yardstick']['after']['median_us']:g} µs after.",
    ]
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(prog="python -m benchmarks.middleware_floor")
    parser.add_argument("role", choices=("pipeline", "recorder"))
    parser.add_argument("--seconds", type=float, required=True)
    parser.add_argument("--publish-only", action="store_true")
    args = parser.parse_args()
    print(json.dumps(_stand_in(args.role, args.seconds, not args.publish_only)), flush=True)


if __name__ == "__main__":
    main()
