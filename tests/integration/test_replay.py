"""Record a run of the stack, replay the bag through a fresh estimator node, compare offline."""

from __future__ import annotations

import numpy as np
import pytest
from rosbags.rosbag2 import Reader
from stack_probe import Probe, wait_for

from crs_core.estimation import make_estimator
from crs_core.model import CarModel
from launch_scripts.launcher import Launcher, NodeSpec
from launch_scripts.sim_stack import stack_nodes
from ros4crs.bag_replay import read_car, replay_estimator
from ros4crs.interfaces import typestore

pytestmark = pytest.mark.integration

DOMAIN_RECORD = 103
DOMAIN_REPLAY = 106

#: Seconds of driving to record once the car moves (the recorder may join a second or two
#: late: it discovers topics after they appear).
DRIVE_S = 8.0
#: The replayed estimator's lag: messages in flight up to this long (sim time = recorded time)
#: are not late. Far above the ms of a replay, so that a stalled process on a busy machine does
#: not make data late (late data would be dropped by the node but not offline).
REPLAY_LAG_S = 0.5
RATE_HZ = 60.0
REPLAYED_PREFIXES = ("/car1/sensors/", "/car1/input")
#: Node and offline estimates must agree to this (the stamps are float seconds, so they carry
#: ~0.2 us of rounding: a few 1e-7 m at 1 m/s).
MATCH_TOLERANCE = 1e-6


def _last_diagnostics(bag, topic: str):
    store = typestore()
    last = None
    with Reader(bag) as reader:
        wanted = [c for c in reader.connections if c.topic == topic]
        for connection, _, data in reader.messages(wanted):
            last = store.deserialize_cdr(bytes(data), connection.msgtype)
    return last


def test_replayed_bag_through_a_fresh_estimator_node_matches_offline_replay(tmp_path, warm_codegen):
    """A bag recorded from the stack replays through a fresh estimator node with the same
    estimates as the offline replay of the same bag through the core estimator.

    1. Record: simulator, EKF estimator, controller and a recorder of all of car 1's topics
       (``stack_nodes(..., record_all=True)``: 250 Hz IMU and encoders, Lighthouse, inputs)
       until the car has driven ``DRIVE_S`` s.
    2. Replay in a fresh domain: ``replayer_node`` publishes the recorded sensor and input
       topics with ``clock`` (``/clock`` on the recording's time axis) and
       ``min_subscribers`` 1 (starts once everything is connected); a new EKF estimator node
       runs with ``use_sim_time`` and lag ``REPLAY_LAG_S``, so it queries at recorded time -
       lag, exactly as live; a recorder captures its ``estimate/*``.
    3. Offline: ``bag_replay.read_car`` of the first bag, ``replay_estimator`` with a fresh
       ``make_estimator("ekf", ...)`` reset at the node's first published stamp with its first
       published state (its initial state), queried at the stamps the node published.

    Every estimate matches to ``MATCH_TOLERANCE`` (1e-6 in every state component); the node
    and the offline estimator counted the same late data (those stamped before the start).
    Measured (2-core machine, load ~2.5-3): ~430 estimates over the ~7 s replayed, all
    bit-identical to the offline ones (max difference 0; float-seconds stamp rounding could
    make them differ by ~1e-7, hence the tolerance); the whole test takes ~25 s.
    """
    from chronos_msgs.msg import CarState

    record_bag, replay_bag = tmp_path / "recorded", tmp_path / "replayed"
    nodes = stack_nodes(1, "ekf", 0.0, record_bag, seed=3, record_all=True)
    recording = Launcher(nodes, DOMAIN_RECORD, tmp_path / "record_logs")
    probe = Probe(DOMAIN_RECORD)
    truth = probe.collect(CarState, "/car1/ground_truth")

    def driven_enough() -> bool:
        moving = [msg for _, msg in truth if msg.vx > 0.2]
        if not moving:
            return False
        stamp = lambda msg: msg.header.stamp.sec + 1e-9 * msg.header.stamp.nanosec  # noqa: E731
        return stamp(truth[-1][1]) - stamp(moving[0]) >= DRIVE_S

    try:
        deaths = recording.run(120.0, until=driven_enough)
    finally:
        recording.stop()
        probe.close()
    assert not deaths, deaths
    assert driven_enough(), "the car did not drive"

    estimator_parameters = {
        "estimator": "ekf",
        "rate_hz": RATE_HZ,
        "lag": REPLAY_LAG_S,
        "use_sim_time": True,
    }
    consumers = Launcher(
        [
            NodeSpec("estimator", "ros4crs.estimator_node", "/car1", estimator_parameters),
            NodeSpec(
                "recorder",
                "ros4crs.recorder_node",
                "",
                {"output": str(replay_bag), "topics": "/car1/estimate/"},
            ),
        ],
        DOMAIN_REPLAY,
        tmp_path / "replay_logs",
    )
    replayer = Launcher(
        [
            NodeSpec(
                "replayer",
                "ros4crs.replayer_node",
                "",
                {
                    "bag": str(record_bag),
                    "topics": ",".join(REPLAYED_PREFIXES),
                    "clock": True,
                    "min_subscribers": 1,
                    "start_delay": 1.0,
                },
            )
        ],
        DOMAIN_REPLAY,
        tmp_path / "replay_logs",
    )
    probe = Probe(DOMAIN_REPLAY)
    try:
        consumers.start()
        # the recorder must be subscribed before the estimator publishes its initial state
        wait_for(
            lambda: probe.subscribers_of("/car1/estimate/state") == ["/recorder"],
            60.0,
            "the recorder to subscribe to the estimator",
        )
        replayer.start()
        (done,) = wait_for(replayer.poll, 120.0, "the end of the replay")
        assert done.returncode == 0, done.log_tail
        assert consumers.poll() == []
    finally:
        replayer.stop()
        consumers.stop()
        probe.close()

    recorded = read_car(record_bag, "/car1")
    published = read_car(replay_bag, "/car1").estimates
    t0, x0 = published[0]
    stamps = np.array([t for t, _ in published[1:]])
    node = np.array([x for _, x in published[1:]])
    assert np.all(np.diff(stamps) > 0)
    # the node estimated at its rate over the whole replay (up to the last stamp - lag)
    recorded_span = recorded.measurements[-1].stamp - recorded.measurements[0].stamp
    assert stamps[-1] - stamps[0] > recorded_span - REPLAY_LAG_S - 0.5, (stamps, recorded_span)
    assert len(stamps) > 0.8 * RATE_HZ * (stamps[-1] - stamps[0]), len(stamps)
    # the replay clock starts at the first replayed message's recorded (receive) time
    with Reader(record_bag) as reader:
        sensors = [c for c in reader.connections if c.topic.startswith("/car1/sensors/")]
        first_received = next(reader.messages(sensors))[1] * 1e-9
    # the node starts at its first update after the first measurement (within two periods)
    start_offset = t0 - (first_received - REPLAY_LAG_S)
    assert -1e-6 < start_offset < 2.0 / RATE_HZ + 0.01, (t0, first_received)

    estimator = make_estimator("ekf", "lh+imu+we", CarModel())
    offline = replay_estimator(recorded, estimator, stamps, x0, t0)
    error = np.abs(offline - node).max(axis=1)
    exact = int(np.sum(error == 0.0))
    print(
        f"{len(stamps)} estimates, {exact} identical, max difference {error.max():.3g}, "
        f"over {stamps[-1] - stamps[0]:.1f} s"
    )
    assert np.all(error < MATCH_TOLERANCE), (np.sum(error >= MATCH_TOLERANCE), error.max())
    diagnostics = _last_diagnostics(replay_bag, "/car1/estimate/diagnostics")
    assert diagnostics is not None
    assert diagnostics.late_measurements == estimator.diagnostics.late
    assert diagnostics.ignored_measurements == 0
    # the car drove during the replayed window: the comparison is not of a car at rest
    assert np.ptp(node[:, 0]) > 1.0
