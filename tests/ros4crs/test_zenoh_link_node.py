"""The Zenoh link node (:mod:`ros4crs.zenoh_link_node`): two "machines" on one host.

Machine A is ROS domain 152, machine B domain 153 (both domain 154 on Zenoh); each runs a link
node as a process, joined by Zenoh over loopback (A listens, B listens and connects to A). Probe
nodes in this process (one rclpy context per domain) publish on A and receive on B: the same
messages, a transient-local topic published before B started (history), nothing of a malformed
sample put straight on the key (counted in B's diagnostics), and samples again after A is killed
and restarted.
"""

from __future__ import annotations

import itertools
import json
import os
import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from ros4crs.node_support import STREAM_OUT_QOS, STREAM_QOS
from ros4crs.zenoh import wire
from ros4crs.zenoh.session import ZenohSettings, open_session
from ros4crs.zenoh_link_node import EchoFilter
from tests.integration.stack_probe import Probe, wait_for

DOMAIN_A, DOMAIN_B = 152, 153
#: The domain id in the Zenoh keys and tokens: the same on both machines (their ROS domains differ).
LINK_DOMAIN = 154
PORT_A, PORT_B = 17531, 17532
IMU_TOPIC, INPUT_TOPIC, HISTORY_TOPIC = "/car1/sensors/imu", "/car1/input", "/car1/estimate/log"
RESTART_TOPIC = "/car1/sensors/restarted"


def _start_link(domain: int, name: str, log: Path, *params: str) -> subprocess.Popen:
    env = dict(os.environ, ROS_DOMAIN_ID=str(domain), ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
    args = [sys.executable, "-m", "ros4crs.zenoh_link_node", "--ros-args", "-r", f"__node:={name}"]
    for param in (f"domain:={LINK_DOMAIN}", "topics:=/car1", *params):
        args += ["-p", param]
    with log.open("a") as out:
        return subprocess.Popen(args, env=env, stdout=out, stderr=subprocess.STDOUT)


def _stop(process: subprocess.Popen, sig: int = signal.SIGINT) -> None:
    if process.poll() is None:
        process.send_signal(sig)
        try:
            process.wait(timeout=10)
        except subprocess.TimeoutExpired:
            process.kill()
            process.wait()


def _link_a(log: Path) -> subprocess.Popen:
    return _start_link(DOMAIN_A, "link_a", log, f"listen:=tcp/127.0.0.1:{PORT_A}")


def _imu(i: int):
    from sensor_msgs.msg import Imu

    msg = Imu()
    msg.header.frame_id = "car1/imu"
    msg.header.stamp.sec, msg.header.stamp.nanosec = 100 + i, 250_000 * i
    msg.linear_acceleration.x, msg.angular_velocity.z = 0.5 * i, -0.01 * i
    return msg


def _car_input(i: int):
    from chronos_msgs.msg import CarInput

    msg = CarInput(mode=CarInput.MODE_TORQUE, steer=0.01 * i, torque=0.2, velocity=0.0)
    msg.header.stamp.sec = i
    return msg


def _send_until_received(publisher, make, received: list, what: str, timeout: float = 15.0):
    """Publish ``make(i)`` for i = 1, 2, ... every 50 ms until one arrives (the link and DDS
    matched), then 20 more; returns them."""
    deadline = time.monotonic() + timeout
    i = 0
    while not received:
        i += 1
        publisher.publish(make(i))
        time.sleep(0.05)
        if time.monotonic() > deadline:
            pytest.fail(f"nothing received on {what} within {timeout} s")
    sent = [make(1000 + k) for k in range(20)]
    for msg in sent:
        publisher.publish(msg)
        time.sleep(0.005)
    return sent


@pytest.fixture(scope="module")
def machines(tmp_path_factory: pytest.TempPathFactory) -> Iterator[dict]:
    log = tmp_path_factory.mktemp("zenoh_link") / "links.log"
    from sensor_msgs.msg import Imu
    from std_msgs.msg import String

    from chronos_msgs.msg import CarInput

    probe_a = Probe(DOMAIN_A, "probe_a")
    probe_b = Probe(DOMAIN_B, "probe_b")
    links: dict[str, subprocess.Popen] = {}
    try:
        # published on A before B's link starts: B still gets it (Zenoh cache + history)
        history = probe_a.node.create_publisher(Imu, HISTORY_TOPIC, STREAM_OUT_QOS)
        for i in range(5):
            history.publish(_imu(i))
        links["a"] = _link_a(log)
        time.sleep(1.0)
        b_params = (f"listen:=tcp/127.0.0.1:{PORT_B}", f"connect:=tcp/127.0.0.1:{PORT_A}")
        links["b"] = _start_link(DOMAIN_B, "link_b", log, *b_params)
        yield {
            "a": probe_a,
            "b": probe_b,
            "links": links,
            "log": log,
            "imu": probe_a.node.create_publisher(Imu, IMU_TOPIC, STREAM_QOS),
            "input": probe_a.node.create_publisher(CarInput, INPUT_TOPIC, STREAM_QOS),
            "imu_b": probe_b.collect(Imu, IMU_TOPIC),
            "input_b": probe_b.collect(CarInput, INPUT_TOPIC),
            "diagnostics_b": probe_b.collect(String, "/zenoh_link/diagnostics"),
        }
    finally:
        for process in links.values():
            _stop(process)
        probe_a.close()
        probe_b.close()
        print(log.read_text(errors="replace")[-3000:])


def test_messages_cross_between_domains(machines: dict) -> None:
    received = machines["imu_b"]
    sent = _send_until_received(machines["imu"], _imu, received, IMU_TOPIC, timeout=25.0)
    wait_for(lambda: [m for _, m in received[-20:]] == sent, 5.0, "the 20 IMU messages on B")
    received = machines["input_b"]
    sent = _send_until_received(machines["input"], _car_input, received, INPUT_TOPIC)
    wait_for(lambda: [m for _, m in received[-20:]] == sent, 5.0, "the 20 inputs on B, in order")


def test_transient_local_history_reaches_a_late_machine(machines: dict) -> None:
    from sensor_msgs.msg import Imu

    received: list = []
    machines["b"].node.create_subscription(Imu, HISTORY_TOPIC, received.append, STREAM_OUT_QOS)
    wait_for(lambda: len(received) >= 5, 10.0, f"the 5 messages of {HISTORY_TOPIC} on B")
    assert received[:5] == [_imu(i) for i in range(5)]


def _settled(received: list, quiet: float = 0.5) -> int:
    """The number of messages in ``received`` once none has arrived for ``quiet`` s (those
    on the way have landed; a loaded machine delivers the last ones late)."""
    count = -1
    while len(received) != count:
        count = len(received)
        time.sleep(quiet)
    return count


def test_malformed_samples_are_dropped_and_counted(machines: dict) -> None:
    _send_until_received(machines["imu"], _imu, machines["imu_b"], IMU_TOPIC)
    count = _settled(machines["imu_b"])
    key = wire.topic_key(LINK_DOMAIN, IMU_TOPIC, "sensor_msgs/msg/Imu")
    attachment = wire.Attachment(1, time.time_ns(), bytes(16)).encode()
    settings = ZenohSettings("peer", connect=(f"tcp/127.0.0.1:{PORT_B}",))
    with open_session(settings) as session:
        time.sleep(1.0)  # connected, and B's subscriber known
        session.put(key, b"\x00\x01\x00\x00garbage")  # no attachment
        session.put(key, b"\x00\x01\x00\x00garbage", attachment=attachment)  # bad CDR
        session.put(key, b"\x00\x01\x00\x00", attachment=b"short")  # bad attachment

        def dropped() -> dict:
            reports = machines["diagnostics_b"]
            report = json.loads(reports[-1][1].data) if reports else {}
            return report.get("import", {}).get(IMU_TOPIC, {}).get("dropped", {})

        wait_for(
            lambda: all(dropped().get(r) for r in ("no_attachment", "cdr", "bad_attachment")),
            5.0,
            lambda: f"the three drops in B's diagnostics, saw {dropped()}",
        )
    time.sleep(0.3)
    assert len(machines["imu_b"]) == count  # none of them was published
    report = json.loads(machines["diagnostics_b"][-1][1].data)
    assert report["import"][IMU_TOPIC]["samples"] >= 20
    assert any("/link_a" in names for names in report["far_sessions"].values())
    assert machines["links"]["b"].poll() is None  # still running


def test_a_foreign_rmw_zenoh_publisher_is_imported(machines: dict) -> None:
    """A session announcing a node and publishers as rmw_zenoh does: its samples are published
    on B; those on a key whose type hash is not the local type's are dropped."""
    from rclpy.serialization import serialize_message

    from chronos_msgs.msg import CarInput

    msgtype = "chronos_msgs/msg/CarInput"
    received = machines["b"].collect(CarInput, "/car1/foreign")
    settings = ZenohSettings("peer", connect=(f"tcp/127.0.0.1:{PORT_B}",))
    with open_session(settings) as session:
        zid = str(session.zid())
        tokens = [
            wire.node_token(LINK_DOMAIN, zid, 0, "/car1", "foreign"),
            wire.endpoint_token(
                "MP", LINK_DOMAIN, zid, 0, 1, "/car1", "foreign", "/car1/foreign", msgtype,
                wire.Qos(depth=10),
            ),
            wire.endpoint_token(
                "MP", LINK_DOMAIN, zid, 0, 2, "/car1", "foreign", "/car1/other_version", msgtype,
                wire.Qos(depth=10), hash_="RIHS01_" + "0" * 64,
            ),
        ]  # fmt: skip
        declared = [session.liveliness().declare_token(t) for t in tokens]
        good = wire.topic_key(LINK_DOMAIN, "/car1/foreign", msgtype)
        stale = wire.topic_key(LINK_DOMAIN, "/car1/other_version", msgtype, "RIHS01_" + "0" * 64)
        gid = wire.gid(tokens[1])
        deadline = time.monotonic() + 10.0
        sequence = 0
        while not received:
            sequence += 1
            attachment = wire.Attachment(sequence, time.time_ns(), gid).encode()
            data = serialize_message(_car_input(sequence))
            session.put(good, data, attachment=attachment)
            session.put(stale, data, attachment=attachment)
            time.sleep(0.05)
            assert time.monotonic() < deadline, "nothing of the foreign publisher on B"
        assert received[0][1] in [_car_input(k) for k in range(1, sequence + 1)]

        def drops() -> dict:
            report = json.loads(machines["diagnostics_b"][-1][1].data)
            return report["import"].get("/car1/other_version", {}).get("dropped", {})

        def dropped_after_another() -> bool:
            # B may subscribe to the stale key after the loop above ended: keep putting
            attachment = wire.Attachment(next(numbers), time.time_ns(), gid).encode()
            session.put(stale, serialize_message(_car_input(1)), attachment=attachment)
            return bool(drops().get("type_hash"))

        numbers = itertools.count(sequence + 1)
        wait_for(dropped_after_another, 10.0, lambda: f"type_hash drops, saw {drops()}")
        report = json.loads(machines["diagnostics_b"][-1][1].data)
        assert report["far_sessions"][zid] == ["/car1/foreign"]
        # B announces its subscription of the topic as rmw_zenoh does (an MS token)
        replies = session.liveliness().get(wire.liveliness_prefix(LINK_DOMAIN), timeout=2.0)
        tokens = [wire.parse_token(str(reply.ok.key_expr)) for reply in replies if reply.ok]
        subscriptions = [t for t in tokens if isinstance(t, wire.EndpointInfo) and t.kind == "MS"]
        assert any(
            t.topic == "/car1/foreign" and t.node == "link_b" and t.msgtype == msgtype
            for t in subscriptions
        ), subscriptions
        assert report["import"]["/car1/other_version"]["samples"] == 0
        for token in declared:
            token.undeclare()


def test_a_restarted_far_link_is_found_again(machines: dict) -> None:
    links = machines["links"]
    _stop(links["a"], signal.SIGKILL)
    time.sleep(0.5)
    links["a"] = _link_a(machines["log"])
    received = machines["imu_b"]
    before = len(received)
    deadline = time.monotonic() + 25.0
    i = 0
    while len(received) == before:
        i += 1
        machines["imu"].publish(_imu(2000 + i))
        time.sleep(0.05)
        assert time.monotonic() < deadline, "no samples on B after A's link restarted"
    assert received[-1][1].header.stamp.sec >= 2100


def test_a_far_node_that_restarts_is_found_again(machines: dict) -> None:
    """A far publisher gone (its node stopped): A's link withdraws the export; a new one on the
    same topic (the node restarted): B receives again, nothing else restarted."""
    from sensor_msgs.msg import Imu

    node = machines["a"].node
    received = machines["b"].collect(Imu, RESTART_TOPIC)
    publisher = node.create_publisher(Imu, RESTART_TOPIC, STREAM_QOS)
    _send_until_received(publisher, _imu, received, RESTART_TOPIC)
    node.destroy_publisher(publisher)
    withdrawn = f"export of {RESTART_TOPIC} withdrawn"
    wait_for(lambda: withdrawn in machines["log"].read_text(errors="replace"), 10.0, withdrawn)
    publisher = node.create_publisher(Imu, RESTART_TOPIC, STREAM_QOS)
    before = len(received)
    deadline = time.monotonic() + 20.0
    i = 0
    while len(received) == before:
        i += 1
        publisher.publish(_imu(3000 + i))
        time.sleep(0.05)
        assert time.monotonic() < deadline, "no samples on B after the far node came back"
    assert received[-1][1].header.stamp.sec > 3000


def test_a_volatile_topic_crosses_only_while_a_far_machine_subscribes(machines: dict) -> None:
    """A publisher on A that nobody on B listens to has no subscriber at all (A's link does not
    export it: a controller then builds no plan for a viewer that is not there); a subscription
    on B brings A's link to subscribe and the messages across; when it goes, A's link lets go."""
    from chronos_msgs.msg import CarInput

    topic = "/car1/controller/unwatched"
    publisher = machines["a"].node.create_publisher(CarInput, topic, STREAM_QOS)
    time.sleep(2.0)  # several polls of both links
    assert publisher.get_subscription_count() == 0
    node_b = machines["b"].node
    received: list = []
    subscription = node_b.create_subscription(
        CarInput, topic, lambda msg: received.append(msg), STREAM_QOS
    )
    wait_for(lambda: publisher.get_subscription_count() == 1, 10.0, "A's link subscribing")
    deadline = time.monotonic() + 10.0
    while not received:
        publisher.publish(_car_input(1))
        time.sleep(0.05)
        assert time.monotonic() < deadline, "nothing on B while it subscribes"
    node_b.destroy_subscription(subscription)
    wait_for(lambda: publisher.get_subscription_count() == 0, 10.0, "A's link letting go")
    withdrawn = f"export of {topic} withdrawn (no far subscriber)"
    wait_for(lambda: withdrawn in machines["log"].read_text(errors="replace"), 5.0, withdrawn)
    machines["a"].node.destroy_publisher(publisher)


def test_echo_filter_drops_each_own_payload_once() -> None:
    echo = EchoFilter(size=2)
    echo.add(b"a")
    echo.add(b"a")
    echo.add(b"b")  # forgets the first b"a"
    assert echo.take(b"a") and not echo.take(b"a")
    assert echo.take(b"b") and not echo.take(b"c")
