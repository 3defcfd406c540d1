"""The middleware floor's stand-ins carry one car's traffic: the stack's rates, every topic
reaching the stand-in recorder and the pipeline's own subscriptions, over real DDS."""

from __future__ import annotations

import pytest

from benchmarks.middleware_floor import PUBLISHERS, _run_pair, format_markdown, traffic

DOMAIN_FLOOR = 173


def test_traffic_is_the_default_stacks():
    load = traffic()
    assert load["rates_hz"] == {
        "sensors/batch": 100.0,
        "ground_truth": 50.0,
        "estimate/state": 60.0,
        "estimate/odometry": 60.0,
        "estimate/query": 60.0,
        "/tf": 60.0,
        "input": 30.0,
    }
    per_second = {name: per_batch * 100.0 for name, _, per_batch in load["batch"]}
    # IMU and encoders at 250 Hz, each plane of the one default station at 50 Hz
    assert per_second == pytest.approx(
        {"imu": 250.0, "wheel_encoders": 250.0, "lighthouse/0/1": 50.0, "lighthouse/0/2": 50.0}
    )


def test_every_topic_reaches_the_recorder_and_the_pipeline_reads_its_own():
    """(Publishing only is the same stand-in without its subscriptions: one flag.) Each
    stand-in counts from 3 s after its start (its warm-up): 6 s runs leave the pipeline 3 s
    to count in (a 4 s run left 1 s, and in a fresh clone, beside the other worker's
    compiling, the recorder once received no odometry in it)."""
    pair = _run_pair(6.0, True, DOMAIN_FLOOR)
    assert set(pair["recorder"]["received_hz"]) == set(PUBLISHERS)
    assert all(rate > 0 for rate in pair["recorder"]["received_hz"].values())
    assert set(pair["pipeline"]["received_hz"]) == {"sensors/batch", "input", "estimate/state"}
    assert pair["pipeline"]["cpu_percent"] > 0


def test_the_table_puts_the_floor_beside_the_real_pipeline():
    def run(floor: float, alone: float, stack: float) -> dict:
        return {
            "floor": {"pipeline": {"cpu_percent": floor}, "recorder": {"cpu_percent": 7.0}},
            "floor_publish_only": {
                "pipeline": {"cpu_percent": alone},
                "recorder": {"cpu_percent": 6.5},
            },
            "stack": {"pipeline_cpu_percent": stack, "recorder_cpu_percent": 10.0, "laps": 3},
        }

    result = {
        "duration_s": 20.0,
        "repeats": 2,
        "traffic": traffic(),
        "yardstick": {"before": {"median_us": 7.5}, "after": {"median_us": 7.6}},
        "runs": [run(18.0, 14.0, 54.0), run(19.0, 15.0, 57.0)],
    }
    text = format_markdown(result)
    assert "| 18.0–19.0 % | 7.0 % |" in text
    assert "| 14.0–15.0 % | 6.5 % |" in text
    assert "| 54.0–57.0 % | 10.0 % |" in text
    assert "420 messages/s published over 7 topics" in text
    assert "33.3 % of the real pipeline" in text
