"""replay_schedule: every item that has arrived by a query's time is delivered before that
query, in order; the estimate asked for is the one recorded.
"""

from __future__ import annotations

import numpy as np

from crs_core.estimation.base import Estimate
from crs_core.measurements import InputSample, Measurement
from sim.replay import replay_schedule, time_summary


class Recorder:
    """An estimator that logs what it is given and answers with the count it has seen."""

    def __init__(self) -> None:
        self.log: list[tuple] = []

    def reset(self, t: float, x0: np.ndarray | None = None) -> None:
        self.log.append(("reset", t, None if x0 is None else tuple(x0)))

    def add(self, item: object) -> None:
        self.log.append(("add", item.stamp))  # type: ignore[attr-defined]

    def estimate(self, t: float) -> Estimate:
        added = sum(1 for entry in self.log if entry[0] == "add")
        self.log.append(("estimate", t))
        return Estimate(t, np.full(6, float(added)), np.eye(6), "ok" if added else "lost")


def test_items_arrived_by_the_query_time_are_delivered_before_it() -> None:
    imu = Measurement(0.04, "imu", [0.0, 0.0, 0.1])
    deliveries = [
        (0.0, InputSample(0.0, np.array([0.0, 0.2]))),
        (0.05, imu),
        (0.1, Measurement(0.09, "wheel_encoders", [1.0, 1.0, 1.0, 1.0])),
        (0.1, Measurement(0.1, "imu", [0.0, 0.0, 0.1])),
        (0.25, Measurement(0.2, "imu", [0.0, 0.0, 0.1])),
    ]
    # (query time, stamp asked): the second asks for the past, the third after a late arrival
    queries = [(0.1, 0.1), (0.2, 0.15), (0.3, 0.3)]
    estimator = Recorder()
    run = replay_schedule(estimator, deliveries, queries, np.arange(6.0))  # type: ignore[arg-type]
    assert estimator.log == [
        ("reset", 0.0, (0.0, 1.0, 2.0, 3.0, 4.0, 5.0)),
        ("add", 0.0),
        ("add", 0.04),
        ("add", 0.09),
        ("add", 0.1),  # arrived exactly at the query time: delivered
        ("estimate", 0.1),
        ("estimate", 0.15),
        ("add", 0.2),
        ("estimate", 0.3),
    ]
    np.testing.assert_array_equal(run.stamps, [0.1, 0.15, 0.3])
    np.testing.assert_array_equal(run.estimates[:, 0], [4.0, 4.0, 5.0])
    assert run.statuses == ["ok", "ok", "ok"] and run.update_times_s.shape == (3,)


def test_a_blind_start_resets_without_a_state() -> None:
    estimator = Recorder()
    run = replay_schedule(estimator, [], [(0.5, 0.5)], None)  # type: ignore[arg-type]
    assert estimator.log == [("reset", 0.0, None), ("estimate", 0.5)]
    assert run.statuses == ["lost"]


def test_time_summary_is_in_milliseconds() -> None:
    summary = time_summary([0.001, 0.003, 0.002, 0.010])
    assert summary["median"] == 2.5 and summary["max"] == 10.0
    assert set(summary) == {"median", "p95", "p99", "max"}
    assert 3.0 < summary["p95"] <= summary["p99"] <= 10.0
