"""The bridge node against fake cars on loopback: fuzzing at the UDP boundary, two cars at once.

A fake car is a UDP socket in the test process sending valid ``CarState`` datagrams at 250 Hz
(stamped with the wall clock, as a car with SNTP does). The node is started with the Launcher
in a domain of its own; a Probe subscribes to every topic it publishes.
"""

from __future__ import annotations

import itertools
import json
import math
import random
import socket
import threading
import time
from pathlib import Path

import pytest

from chronos_bridge.car_state import IN_VIEW_RAD
from chronos_bridge.codec import (
    decode_from_host,
    encode_car_state,
    encode_discovery_ping,
    encode_torque_command,
)
from chronos_bridge.packets import (
    ACCEL_LIMIT,
    BATTERY_CURRENT_LIMIT,
    BATTERY_VOLTAGE_MAX,
    CAR_VELOCITY_LIMIT,
    GYRO_LIMIT,
    STEER_LIMIT,
    TIMESTAMP_MAX_US,
    TIMESTAMP_MIN_US,
    WHEEL_SPEED_LIMIT,
    Battery,
    CarState,
    Imu,
    LighthouseSweep,
)
from launch_scripts.launcher import Launcher, NodeSpec
from ros4crs import conversions
from tests.chronos_bridge.bridge_builders import BAD_FLOATS, make_state, tag, varint
from tests.integration.stack_probe import Probe, wait_for

pytestmark = pytest.mark.integration

DOMAIN_FUZZ = 121
DOMAIN_TWO_CARS = 122
N_FUZZ = 50_000
#: Fuzz datagrams per burst and the pause after each: ~5000 datagrams/s, ~10 s for 50 000.
BURST, PAUSE_S = 50, 0.009


def _free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _state(k: int, voltage: float = 7.5, sweeps: tuple = ()) -> CarState:
    """A valid car state (:func:`make_state`), its IMU varying with ``k``; ``voltage`` tells the
    cars apart."""
    phase = 0.01 * k
    return make_state(
        imu=Imu((-1.0, 0.5 * math.sin(phase), 9.8), (0.0, 0.0, math.cos(phase))),
        battery=Battery(voltage, -1.0),
        sweeps=sweeps,
    )


def _sweeps(k: int) -> tuple[LighthouseSweep, ...]:
    """A first and a second plane of station 0 (raw angles that land in view), every 5th step."""
    if k % 5:
        return ()
    sync = (1000 * k) % (1 << 24)
    return (
        LighthouseSweep((2.1, 2.1, 2.2, 2.2), 0, sync, sync),
        LighthouseSweep((4.2, 4.2, 4.3, 4.3), 1, sync + 50, sync),
    )


class FakeCar:
    """Sends a valid car state every 4 ms from its own socket until stopped; collects what
    the host sends back."""

    def __init__(self, port: int, voltage: float) -> None:
        self.socket = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.socket.bind(("127.0.0.1", 0))
        self.socket.settimeout(0.001)
        self.target, self.voltage = ("127.0.0.1", port), voltage
        self.sent, self.received = 0, []
        self.sent_stamps: list[float] = []  # the packet stamps, s
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)

    def start(self) -> FakeCar:
        self._thread.start()
        return self

    def _run(self) -> None:
        next_step, k = time.monotonic(), 0
        while not self._stop.is_set():
            stamp_us = time.time_ns() // 1000
            data = encode_car_state(_state(k, self.voltage, _sweeps(k)), stamp_us)
            self.socket.sendto(data, self.target)
            self.sent += 1
            self.sent_stamps.append(stamp_us * 1e-6)
            k += 1
            next_step += 0.004
            while time.monotonic() < next_step:
                try:
                    self.received.append(decode_from_host(self.socket.recvfrom(512)[0]))
                except TimeoutError:
                    pass
                except Exception as error:  # a host datagram the car cannot decode
                    self.received.append(error)

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(timeout=5.0)
        self.socket.close()


# --------------------------------------------------------------------------- fuzzing


def _seeds() -> list[bytes]:
    seeds = [encode_discovery_ping(), encode_torque_command(0.1, 0.2)]
    for k in range(0, 20, 5):
        seeds.append(encode_car_state(_state(k, sweeps=_sweeps(k)), time.time_ns() // 1000))
    seeds.append(encode_car_state(_state(3)))
    return seeds


def _mutate(rng: random.Random, seeds: list[bytes]) -> tuple[str, bytes]:
    """A named mutation of a valid seed (or random bytes)."""
    base = bytearray(rng.choice(seeds))
    kind = rng.choice(
        ["random", "truncated", "bitflip", "wiretype", "nan", "repeated", "oneof", "insert"]
    )
    if kind == "random":
        return kind, rng.randbytes(rng.randrange(0, 400))
    if kind == "truncated":
        return kind, bytes(base[: rng.randrange(len(base))])
    if kind == "bitflip":
        for _ in range(rng.randrange(1, 9)):
            i = rng.randrange(len(base))
            base[i] ^= 1 << rng.randrange(8)
    elif kind == "wiretype":
        i = rng.randrange(len(base))
        base[i] = (base[i] & ~7) | rng.randrange(8)
    elif kind == "nan":
        i = rng.randrange(max(1, len(base) - 4))
        base[i : i + 4] = rng.choice(BAD_FLOATS)
    elif kind == "repeated":  # many sweep (9) or frame (8) records inside car_state (3)
        record = bytes([rng.choice([0x42, 0x4A]), 20]) + rng.randbytes(20)
        body = record * rng.randrange(1, 200)
        return kind, bytes(base) + b"\x1a" + varint(len(body)) + body
    elif kind == "oneof":  # an unknown field / oneof tag, before or after
        field = tag(rng.choice([4, 5, 9, 11, 50, 98, 100, 2**20]), 2) + b"\x02\x08\x01"
        return kind, field + bytes(base) if rng.random() < 0.5 else bytes(base) + field
    else:
        i = rng.randrange(len(base) + 1)
        return kind, bytes(base[:i]) + rng.randbytes(rng.randrange(1, 8)) + bytes(base[i:])
    return kind, bytes(base)


def _kernel_drops(port: int) -> int:
    """Datagrams the kernel dropped for the UDP socket bound to ``port`` (``/proc/net/udp``)."""
    drops = 0
    for line in Path("/proc/net/udp").read_text().splitlines()[1:]:
        fields = line.split()
        if int(fields[1].split(":")[1], 16) == port:
            drops += int(fields[-1])
    return drops


def _bound(port: int) -> bool:
    """Whether a UDP socket is bound to ``port`` (the node is listening: datagrams sent before
    would be lost, not counted)."""
    lines = Path("/proc/net/udp").read_text().splitlines()[1:]
    return any(int(line.split()[1].split(":")[1], 16) == port for line in lines)


def _stamp_ok(header) -> bool:
    seconds = header.stamp.sec + 1e-9 * header.stamp.nanosec
    return TIMESTAMP_MIN_US * 1e-6 <= seconds <= TIMESTAMP_MAX_US * 1e-6


def _finite(*values: float) -> bool:
    return all(math.isfinite(v) for v in values)


def _malformed(topic: str, msg) -> str | None:
    """What is wrong with a published message (``None``: finite and in range)."""
    if not _stamp_ok(msg.header):
        return f"{topic} stamp {msg.header.stamp.sec}.{msg.header.stamp.nanosec:09d}"
    if topic == "imu":
        a, w = msg.linear_acceleration, msg.angular_velocity
        ok = _finite(a.x, a.y, a.z, w.x, w.y, w.z)
        ok = ok and max(abs(a.x), abs(a.y)) <= ACCEL_LIMIT and abs(w.z) <= GYRO_LIMIT
    elif topic == "wheel_speeds":
        values = (msg.front_left, msg.front_right, msg.rear_left, msg.rear_right)
        ok = _finite(*values) and max(map(abs, values)) <= WHEEL_SPEED_LIMIT
    elif topic == "lighthouse":
        ok = msg.plane in (1, 2) and msg.base_station <= 15 and _finite(*msg.angles)
        ok = ok and abs(msg.angles[0]) <= IN_VIEW_RAD and max(map(abs, msg.angles)) < 4 * math.pi
    elif topic == "battery":
        ok = _finite(msg.voltage, msg.current) and 0 <= msg.voltage <= BATTERY_VOLTAGE_MAX
        ok = ok and abs(msg.current) <= BATTERY_CURRENT_LIMIT
    elif topic == "steering":
        ok = list(msg.name) == ["steering"] and _finite(*msg.position, *msg.effort)
        ok = ok and abs(msg.position[0]) <= STEER_LIMIT and abs(msg.effort[0]) <= 1.0
    elif topic == "drive":
        ok = list(msg.name) == ["drive_motor"] and _finite(*msg.effort)
        ok = ok and abs(msg.effort[0]) <= 1.0
    else:
        x = msg.twist.linear.x
        ok = _finite(x) and abs(x) <= CAR_VELOCITY_LIMIT
    return None if ok else topic


#: The per-reading topic key (as in :func:`_malformed`) of each sensor in a ``SensorBatch``.
_READING_TOPIC = {"imu": "imu", "gyro": "gyro", "wheel_encoders": "wheel_speeds"}


def _collect_all(probe: Probe, namespace: str) -> dict[str, list]:
    """``(receive time, msg)`` per topic key; the readings of the bridge's ``sensors/batch``
    messages land under ``imu`` / ``gyro`` / ``wheel_speeds`` / ``lighthouse`` as the messages
    the bridge would publish for each with ``sensor_messages: each`` (same fields, stamps and
    frame), and any reading the batch conversion rejects under ``batch_rejected``."""
    from geometry_msgs.msg import TwistStamped
    from sensor_msgs.msg import BatteryState, JointState
    from std_msgs.msg import String

    from chronos_msgs.msg import SensorBatch
    from ros4crs.node_support import STREAM_QOS

    topics = {
        "battery": (BatteryState, "sensors/battery"),
        "steering": (JointState, "telemetry/steering"),
        "drive": (JointState, "telemetry/drive"),
        "velocity": (TwistStamped, "telemetry/velocity"),
        "diagnostics": (String, "bridge/diagnostics"),
    }
    collected = {k: probe.collect(t, f"{namespace}/{name}") for k, (t, name) in topics.items()}
    for key in ("imu", "gyro", "wheel_speeds", "lighthouse", "batch_rejected"):
        collected[key] = []

    def on_batch(batch) -> None:
        received = time.time()
        readings = conversions.batch_from_msg(batch)
        collected["batch_rejected"].extend((received, r) for r in readings.rejected)
        for m in readings.measurements:
            msg = conversions.measurement_to_msg(m, batch.header.frame_id)
            collected[_READING_TOPIC.get(m.sensor, "lighthouse")].append((received, msg))

    probe.node.create_subscription(SensorBatch, f"{namespace}/sensors/batch", on_batch, STREAM_QOS)
    return collected


def _diagnostics(collected: dict[str, list]) -> dict:
    return json.loads(collected["diagnostics"][-1][1].data) if collected["diagnostics"] else {}


def test_fuzzed_datagrams_never_crash_the_bridge_nor_publish_garbage(tmp_path):
    """>= 50 000 random and mutated datagrams from the car's endpoint plus valid packets from a
    foreign one, interleaved with the car's 250 Hz stream: the node stays up, publishes only
    finite in-range values, counts every datagram, and keeps publishing the car's data."""
    port = _free_port()
    launcher = Launcher(
        [NodeSpec("bridge", "ros4crs.bridge_node", "/car1", {"port": port})],
        DOMAIN_FUZZ,
        tmp_path / "logs",
    )
    probe = Probe(DOMAIN_FUZZ)
    collected = _collect_all(probe, "/car1")
    car = FakeCar(port, 7.5)
    foreign = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    foreign.bind(("127.0.0.1", 0))
    rng = random.Random(14)
    try:
        launcher.start()
        wait_for(lambda: _bound(port), 30.0, f"the bridge listening on UDP port {port}")
        car.start()
        wait_for(lambda: len(collected["imu"]) > 50, 30.0, "IMU messages from the paired car")
        seeds = _seeds()
        kinds: dict[str, int] = {}
        fuzz_start = time.time()
        for n in range(N_FUZZ):
            if rng.random() < 0.05:  # a valid packet, from a foreign endpoint
                kinds["foreign"] = kinds.get("foreign", 0) + 1
                foreign.sendto(rng.choice(seeds[2:]), ("127.0.0.1", port))
            else:
                kind, data = _mutate(rng, seeds)
                kinds[kind] = kinds.get(kind, 0) + 1
                car.socket.sendto(data, ("127.0.0.1", port))
            if n % BURST == BURST - 1:
                time.sleep(PAUSE_S)
        fuzz_end = time.time()
        time.sleep(0.5)  # the car keeps sending after the fuzz
        car.stop()
        sent = car.sent + N_FUZZ
        drops = _kernel_drops(port)

        def accounted() -> bool:
            return _diagnostics(collected).get("received", -1) + drops == sent

        wait_for(
            accounted,
            15.0,
            lambda: f"counts adding up to {sent} - {drops} dropped: {_diagnostics(collected)}",
        )
        diagnostics = _diagnostics(collected)
        assert launcher.poll() == [], "the bridge died"
        counts = diagnostics["counts"]
        assert counts["foreign"] == kinds["foreign"]
        assert counts["car_state"] >= car.sent - drops  # every car packet (and fuzzed valid ones)
        assert counts["error"] == 0 and diagnostics["publish_errors"] == 0
        assert counts["oversize"] > 0 and counts["undecodable"] > 0 and counts["invalid"] > 0
        bad = [
            problem
            for topic, messages in collected.items()
            if topic not in ("diagnostics", "gyro", "batch_rejected")
            for _, msg in messages
            if (problem := _malformed(topic, msg))
        ]
        assert bad == [], f"{len(bad)} malformed publishes, e.g. {bad[:5]}"
        assert collected["batch_rejected"] == []
        assert collected["gyro"] == []
        # the car was served throughout: no gap over 0.25 s in its IMU stream during the fuzz
        times = [t for t, _ in collected["imu"] if fuzz_start - 0.5 <= t <= fuzz_end + 0.5]
        gaps = [b - a for a, b in itertools.pairwise(times)]
        assert times and times[0] < fuzz_start + 0.25 and times[-1] > fuzz_end - 0.25
        # receipt gaps include the probe's own stalls (it shares the GIL with the fuzz loop)
        assert max(gaps) < 1.0, f"IMU stream stalled {max(gaps):.3f} s during the fuzz"
        stamps = sorted(
            m.header.stamp.sec + 1e-9 * m.header.stamp.nanosec for _, m in collected["imu"]
        )
        stamps = [t for t in stamps if fuzz_start <= t <= fuzz_end]
        windows = {int((t - fuzz_start) / 0.25) for t in stamps}
        # every 0.25 s window in which the car sent has its data published (the fake car is a
        # thread beside the fuzz loop: it can be starved of the GIL for a window near the end)
        sending = {
            int((t - fuzz_start) / 0.25) for t in car.sent_stamps if fuzz_start <= t <= fuzz_end
        }
        assert len(sending) >= int((fuzz_end - fuzz_start) / 0.25) - 2, "the fake car hardly sent"
        assert windows >= sending, "car not served"
        for topic in ("wheel_speeds", "lighthouse", "battery", "steering", "drive", "velocity"):
            assert collected[topic], topic
        print(
            f"\nbridge fuzz: {N_FUZZ} fuzz + {car.sent} car datagrams in "
            f"{fuzz_end - fuzz_start:.1f} s; kinds {kinds}; kernel drops {drops}; counts "
            f"{counts}; top fields "
            f"{sorted(diagnostics['rejected_fields'].items(), key=lambda kv: -kv[1])[:6]}; "
            f"largest IMU gap {max(gaps) * 1e3:.0f} ms; node CPU {launcher.cpu_seconds()}"
        )
    finally:
        car.stop()
        foreign.close()
        launcher.stop()
        probe.close()


def test_two_bridges_serve_two_cars_each_in_its_own_namespace(tmp_path):
    """Two bridge nodes (``/car1``, ``/car2``) on two ports with two fake cars: each publishes
    only its car's data (told apart by the battery voltage) and sends each ``input`` only to its
    own car."""
    from chronos_msgs.msg import CarInput

    ports = {"car1": _free_port(), "car2": _free_port()}
    voltages = {"car1": 7.25, "car2": 8.5}
    launcher = Launcher(
        [
            NodeSpec("bridge", "ros4crs.bridge_node", f"/{car}", {"port": port})
            for car, port in ports.items()
        ],
        DOMAIN_TWO_CARS,
        tmp_path / "logs",
    )
    probe = Probe(DOMAIN_TWO_CARS)
    collected = {car: _collect_all(probe, f"/{car}") for car in ports}
    cars = {car: FakeCar(port, voltages[car]) for car, port in ports.items()}
    try:
        launcher.start()
        for car in cars.values():
            car.start()
        for name in cars:
            wait_for(lambda n=name: len(collected[n]["battery"]) > 50, 30.0, f"{name} battery")
        for name in cars:
            wait_for(
                lambda n=name: collected[n]["lighthouse"] and collected[n]["wheel_speeds"],
                10.0,
                f"{name} Lighthouse and wheel-speed readings",
            )
        for name in cars:
            voltages_seen = {round(m.voltage, 3) for _, m in collected[name]["battery"]}
            assert voltages_seen == {voltages[name]}, (name, voltages_seen)
            assert collected[name]["lighthouse"] and collected[name]["wheel_speeds"]
            assert {m.header.frame_id for _, m in collected[name]["imu"]} == {f"{name}/base_link"}
        inputs = {n: probe.publisher(CarInput, f"/{n}/input") for n in cars}
        commands = {"car1": [0.1, 0.25], "car2": [-0.2, 0.75]}
        for name, publisher in inputs.items():
            for _ in range(5):
                publisher.publish(conversions.car_input_msg(commands[name], time.time()))
                time.sleep(0.02)

        def references(name: str) -> list:
            return [p.contents for p in cars[name].received if hasattr(p, "contents")]

        for name in cars:
            wait_for(lambda n=name: len(references(n)) >= 5, 10.0, f"{name} references")
        for name in cars:
            steer, torque = commands[name]
            for reference in references(name):
                assert reference.throttle == pytest.approx(torque)
                assert reference.angle == pytest.approx(steer)
        assert launcher.poll() == []
    finally:
        for car in cars.values():
            car.stop()
        launcher.stop()
        probe.close()
