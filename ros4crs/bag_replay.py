"""Offline replay of a bag straight into the ``crs_core`` estimators, without ROS.

Reads the sensor and input topics of one car from a bag (rosbags, no rclpy), converts them with
the same :mod:`ros4crs.conversions` the nodes use, and feeds an estimator. Queried at the stamps
an estimator node published (``estimate/state`` in the same bag, or any list of stamps), it
reproduces that node's estimates: the node does exactly the same, in the same stamp order.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from rosbags.rosbag2 import Reader

from crs_core.estimation.base import Estimator
from crs_core.measurements import InputSample, Measurement, in_stamp_order
from ros4crs import conversions
from ros4crs.interfaces import typestore

_FAMILY_OF_TOPIC = {topic: family for family, topic in conversions.TOPICS.items()}


@dataclass
class BagContents:
    """One car's data from a bag, in stamp order."""

    measurements: list[Measurement]
    inputs: list[InputSample]
    estimates: list[tuple[float, np.ndarray]]
    truth: list[tuple[float, np.ndarray]]
    malformed: int
    deadline_misses: int = 0
    updates: int = 0


def read_car(bag: str | Path, namespace: str = "") -> BagContents:
    """Sensors, inputs, published estimates and ground truth of the car in ``namespace``."""
    store = typestore()
    prefix = namespace.rstrip("/") + "/" if namespace else "/"
    measurements, inputs, estimates, truth = [], [], [], []
    malformed = 0
    diagnostics = None
    with Reader(bag) as reader:
        wanted = [c for c in reader.connections if c.topic.startswith(prefix)]
        for connection, _, data in reader.messages(wanted):
            relative = connection.topic[len(prefix) :]
            family = _FAMILY_OF_TOPIC.get(relative)
            if family is None:
                continue
            msg = store.deserialize_cdr(bytes(data), connection.msgtype)
            try:
                if family in conversions.SENSOR_PARSERS:
                    measurements.append(conversions.SENSOR_PARSERS[family](msg))
                elif family == "input":
                    inputs.append(InputSample(*conversions.input_from_msg(msg)))
                elif family == "state":
                    estimates.append(conversions.state_from_msg(msg))
                elif family == "ground_truth":
                    truth.append(conversions.state_from_msg(msg))
                elif family == "diagnostics":
                    diagnostics = msg
            except ValueError:
                malformed += 1
    measurements.sort(key=lambda m: (m.stamp, m.sensor))
    inputs.sort(key=lambda s: s.stamp)
    contents = BagContents(measurements, inputs, estimates, truth, malformed)
    if diagnostics is not None:
        contents.deadline_misses = int(diagnostics.deadline_misses)
        contents.updates = int(diagnostics.updates)
    return contents


def read_receive_times(bag: str | Path, namespace: str) -> dict[str, list[tuple[float, float]]]:
    """``(header stamp, recorder receive time)`` in s for sensors, estimates and inputs."""
    store = typestore()
    prefix = namespace.rstrip("/") + "/"
    kinds = {"sensors/": "sensor", "estimate/state": "estimate", "input": "input"}
    out: dict[str, list[tuple[float, float]]] = {kind: [] for kind in kinds.values()}
    with Reader(bag) as reader:
        for connection, received, data in reader.messages(
            [c for c in reader.connections if c.topic.startswith(prefix)]
        ):
            relative = connection.topic[len(prefix) :]
            kind = next((k for key, k in kinds.items() if relative.startswith(key)), None)
            if kind is None:
                continue
            msg = store.deserialize_cdr(bytes(data), connection.msgtype)
            out[kind].append((conversions.seconds_from_stamp(msg.header.stamp), received * 1e-9))
    return out


def replay_estimator(
    contents: BagContents,
    estimator: Estimator,
    stamps: Iterable[float],
    x0: np.ndarray,
    t0: float,
) -> np.ndarray:
    """Estimates (n, 6) at ``stamps``, the estimator reset to ``x0`` at ``t0`` first.

    Data are delivered up to each stamp before it is queried, as in the node (which publishes
    its initial state at ``t0``); data stamped before ``t0`` count as late there and here.
    """
    estimator.reset(t0, x0)
    events = in_stamp_order(contents.measurements, contents.inputs)
    out, k = [], 0
    for t in stamps:
        while k < len(events) and events[k].stamp <= t:
            estimator.add(events[k])
            k += 1
        out.append(estimator.estimate(t).x)
    return np.array(out)
