"""A bag recorded by the stack reproduces its estimator's estimates, offline and through a node.

One recording (the module fixture) of the stack as ``crs launch sim`` runs it: simulator, MHE
estimator, controller and a recorder with the default ``--record all``. Then:

* offline, the core MHE fed from that bag as the node's query log (``estimate/query``) says
  reproduces every estimate the live node published, bit for bit, whatever the transport
  delays on the machine were;
* a fresh MHE node fed by the replayer node in another domain (``/clock`` on the recording's
  time axis) logs its own queries, and the offline MHE fed as those say reproduces its
  estimates too.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from rosbags.rosbag2 import Reader

from crs_core.estimation import MheSettings, make_estimator
from crs_core.model import CarModel
from launch_scripts.launcher import Launcher, NodeSpec
from launch_scripts.sim_stack import StackOptions, recorder_node, stack_nodes
from ros4crs.bag_replay import BagContents, read_car, replay_estimator
from ros4crs.interfaces import typestore
from tests.integration.stack_probe import Probe, launched, log_text, message_stamp, wait_for

pytestmark = pytest.mark.integration

DOMAIN_RECORD = 103
DOMAIN_REPLAY = 106
DOMAIN_LOOP = 111

#: Seconds of driving to record once the car moves. 5 s (it was 8) keep every check with
#: margin and save 3 s wherever the drive runs (recorded, replayed, looped twice); at 5 s:
#: 308-315 offline estimates compared (bound 240), 306-316 through the fresh node (bound
#: about 250), 2.35-2.49 m driven in x (bound 1 m), the looped EKF within 26 mm of the
#: track 1 s after each jump (median 9-11 mm; bounds 0.15 m and 0.05 m).
DRIVE_S = 5.0
#: The replayed estimator's lag (sim time = recorded time): the replayer node needs far more
#: than the live 20 ms, so that nothing it replays arrives after the node's query.
REPLAY_LAG_S = 0.5
RATE_HZ = 60.0
REPLAYED_PREFIXES = ("/car1/sensors/", "/car1/input")


@dataclass
class Recording:
    bag: Path
    contents: BagContents


def _mhe() -> object:
    """The estimator the node builds with its default parameters."""
    settings = MheSettings(rate_hz=RATE_HZ, catch_up_solves=2)
    return make_estimator("mhe", "lh+imu+we", CarModel(), settings)


def _compare(contents: BagContents, estimates: list[tuple[float, np.ndarray]]) -> np.ndarray:
    """Offline replay of ``contents`` fed as ``contents.queries`` say, against ``estimates``
    (the node's, by stamp): the largest absolute difference per estimate."""
    start = contents.queries[0]
    published = {round(t, 6): x for t, x in estimates}
    x0 = published[round(start.stamp, 6)]
    offline = replay_estimator(contents, _mhe(), contents.queries, x0)
    differences = []
    last = len(contents.queries) - 2
    for k, (query, estimate) in enumerate(zip(contents.queries[1:], offline[1:], strict=True)):
        node = published.get(round(query.stamp, 6))
        if node is None and k == last:
            continue  # the recording ended between the node's last query and its estimate
        if node is None:  # a lost estimate is not published (none here)
            assert estimate is None or estimate.status == "lost"
            continue
        differences.append(np.abs(estimate.x - node).max())
    return np.array(differences)


def _replayer(bag: Path, **parameters: Any) -> NodeSpec:
    """The replayer node of the recorded sensors and inputs (``REPLAYED_PREFIXES``) of ``bag``,
    with ``/clock``, once one subscriber is there; ``parameters`` added."""
    topics = ",".join(REPLAYED_PREFIXES)
    return NodeSpec(
        "replayer",
        "ros4crs.replayer_node",
        "",
        {"bag": str(bag), "topics": topics, "clock": True, "min_subscribers": 1, **parameters},
    )


@pytest.fixture(scope="module")
def recording(tmp_path_factory, warm_codegen) -> Recording:
    """The stack of ``crs launch sim`` (one car, MHE, default recording) until the car has
    driven ``DRIVE_S`` s."""
    from chronos_msgs.msg import CarState

    folder = tmp_path_factory.mktemp("recording")
    bag = folder / "bag"
    nodes = stack_nodes(1, StackOptions("mhe", seed=3), bag)
    with launched(nodes, DOMAIN_RECORD, folder / "logs") as (launcher, probe):
        truth = probe.collect(CarState, "/car1/ground_truth")

        def driven_enough() -> bool:
            moving = [msg for _, msg in truth if msg.vx > 0.2]
            if not moving:
                return False
            return message_stamp(truth[-1][1]) - message_stamp(moving[0]) >= DRIVE_S

        deaths = launcher.run(120.0, until=driven_enough)
    assert not deaths, deaths
    assert driven_enough(), "the car did not drive"
    return Recording(bag, read_car(bag, "/car1"))


def test_launch_bag_has_what_foxglove_and_the_replay_need(recording: Recording):
    """The default recording holds every sensor stream (in ``sensors/batch``), the inputs, the
    truth, the estimates as CarState, Odometry and TF (``world`` -> ``car1/base_link``) and the
    query log."""
    store = typestore()
    with Reader(recording.bag) as reader:
        counts = {c.topic: c.msgcount for c in reader.connections}
        types = {c.topic: c.msgtype for c in reader.connections}
        tf = next(
            store.deserialize_cdr(bytes(data), c.msgtype)
            for c, _, data in reader.messages([c for c in reader.connections if c.topic == "/tf"])
        )
    for topic in (
        "/car1/sensors/batch",
        "/car1/input",
        "/car1/ground_truth",
        "/car1/estimate/state",
        "/car1/estimate/odometry",
        "/car1/estimate/query",
        "/tf",
    ):
        assert counts.get(topic, 0) > 0, (topic, counts)
    assert types["/car1/sensors/batch"] == "chronos_msgs/msg/SensorBatch"
    sensors = {m.sensor for m in recording.contents.measurements}
    assert {"imu", "wheel_encoders", "lighthouse/0/1", "lighthouse/0/2"} <= sensors
    assert types["/car1/estimate/odometry"] == "nav_msgs/msg/Odometry"
    assert types["/tf"] == "tf2_msgs/msg/TFMessage"
    (transform,) = tf.transforms
    assert (transform.header.frame_id, transform.child_frame_id) == ("world", "car1/base_link")
    # the recorder joined the transient-local estimate topics from their first message
    assert recording.contents.queries[0].start


@pytest.mark.filterwarnings("error::ros4crs.bag_replay.ReplayIncompleteWarning")
def test_launch_bag_replays_offline_to_the_node_estimates_exactly(recording: Recording):
    """Offline, the core MHE fed from the bag as the node's query log says (each query: every
    message up to the newest stamp per stream the node had received) gives every published
    estimate bit for bit, whichever of the recorder and the estimator subscribed to a stream
    first (measured before the query log had each stream's first stamp and the streams'
    publishers were transient-local: 3 of 26 runs beside two busy loops differed by 9-34 mm
    from the second estimate on, the bag holding commands from before the estimator's first, or
    lacking its first ones; then 2 of 10 runs beside three memory-bound loops and a disk writer
    differed by 7-8 mm from the second estimate on, and one suite run on CI by 8.8 cm: the
    controller's first commands went out before the estimator subscribed, after its start, and
    only the recorder had them). Without the log (all data up to each stamp) the live node's
    estimates are not reproduced: data that arrived after a query stamped before it were
    used offline but not live (measured: mm-level differences in the first second, fading
    later; 0.1 m in vx at worst).
    """
    contents = recording.contents
    difference = _compare(contents, contents.estimates)
    print(f"{difference.size} estimates, max difference {difference.max():.3g}")
    # enough estimates that the exactness says something; not the rate (CI's loaded host
    # published 173 in the 5 s drive: the rate is the stack's load tests' and benchmarks' job)
    assert difference.size > 0.3 * RATE_HZ * DRIVE_S
    assert np.all(difference == 0.0), (np.sum(difference > 0), difference.max())


def test_bag_replayed_through_a_fresh_estimator_node_matches_offline(tmp_path, recording):
    """The recorded sensors and inputs, replayed by the replayer node (``/clock`` on the
    recording's time axis, started once everything is connected) into a fresh MHE node with
    ``use_sim_time`` and lag ``REPLAY_LAG_S``: the offline MHE fed as that node's query log says
    gives its estimates exactly, and the node estimated over the whole replay at its rate."""
    replay_bag = tmp_path / "replayed"
    consumers = Launcher(
        [
            NodeSpec(
                "estimator",
                "ros4crs.estimator_node",
                "/car1",
                {"estimator": "mhe", "lag": REPLAY_LAG_S, "use_sim_time": True},
            ),
            recorder_node(replay_bag, ["/car1/estimate/"]),
        ],
        DOMAIN_REPLAY,
        tmp_path / "logs",
    )
    replayer = Launcher(
        [_replayer(recording.bag, start_delay=1.0)], DOMAIN_REPLAY, tmp_path / "logs"
    )
    probe = Probe(DOMAIN_REPLAY)
    try:
        consumers.start()
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

    replayed = read_car(replay_bag, "/car1")
    # the recorded data, fed as the fresh node's own query log says
    contents = recording.contents
    contents_as_replayed = BagContents(
        contents.measurements, contents.inputs, replayed.estimates, [], 0, queries=replayed.queries
    )
    difference = _compare(contents_as_replayed, replayed.estimates)
    stamps = np.array([q.stamp for q in replayed.queries[1:]])
    recorded_span = contents.measurements[-1].stamp - contents.measurements[0].stamp
    print(f"{difference.size} estimates, max difference {difference.max():.3g}")
    assert stamps[-1] - stamps[0] > recorded_span - REPLAY_LAG_S - 0.5, (stamps, recorded_span)
    assert difference.size > 0.8 * RATE_HZ * (stamps[-1] - stamps[0])
    assert np.all(difference == 0.0), (np.sum(difference > 0), difference.max())
    # the car drove during the replayed window: the comparison is not of a car at rest
    assert np.ptp([x[0] for _, x in replayed.estimates]) > 1.0


def test_a_looped_replay_with_clock_keeps_producing_estimates_after_each_jump(
    tmp_path, recording: Recording
):
    """The replayer loops the recorded sensors and inputs with ``/clock`` (which jumps back at
    every start over); an EKF node with ``use_sim_time`` restarts at each jump instead of
    calling everything late, and keeps estimating on the car's track after two jumps."""
    from chronos_msgs.msg import CarState

    nodes = [
        NodeSpec(
            "estimator",
            "ros4crs.estimator_node",
            "/car1",
            {"estimator": "ekf", "lag": 0.2, "use_sim_time": True},
        ),
        _replayer(recording.bag, loop=True),
    ]
    with launched(nodes, DOMAIN_LOOP, tmp_path / "logs") as (launcher, probe):
        estimates = probe.collect(CarState, "/car1/estimate/state")

        def stamps() -> np.ndarray:
            return np.array([message_stamp(m) for _, m in estimates])

        def after_second_jump() -> int:
            t = stamps()
            jumps = np.flatnonzero(np.diff(t) < -1.0) if t.size > 1 else []
            return len(jumps) >= 2 and t.size - jumps[1] > 2 * RATE_HZ

        launcher.start()
        wait_for(after_second_jump, 150.0, lambda: f"two jumps ({stamps().size} estimates)")
        assert launcher.poll() == []
    t = stamps()
    jumps = np.flatnonzero(np.diff(t) < -1.0)
    positions = np.array([[m.x, m.y] for _, m in estimates])
    # after each jump the estimates follow the recorded drive again, on the track (half-width
    # 0.23 m): within a few mm of it usually; a blind restart from the Lighthouse once still
    # had 12.7 cm left 1-2 s after it (a fresh-clone suite run), hence 0.15 m
    truth = np.array([x[:2] for _, x in recording.contents.truth])
    for jump in jumps[:2]:
        later = positions[jump + 1 + int(RATE_HZ) :][: int(RATE_HZ)]  # 1 s after the restart
        nearest = np.min(np.linalg.norm(later[:, None, :] - truth[None, :, :], axis=2), axis=1)
        assert np.all(nearest < 0.15), nearest.max()
        assert np.median(nearest) < 0.05, np.median(nearest)
    log = log_text(tmp_path / "logs", "/car1/estimator")
    assert "the clock jumped back" in log and "restarting the estimator (restart 2)" in log
