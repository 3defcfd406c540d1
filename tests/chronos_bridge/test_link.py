"""CarLink over real loopback sockets: pairing, foreign senders, pings, rejects, commands; and
the host side under Wi-Fi-like arrival (the datagram filter and the converter, as the link runs
them): reordered, late, duplicated and lost car states.

The emulator's datagrams are converted in order and after an impaired link (seeded: 5 % loss,
1 % duplicates, each datagram delayed 5 + |N(0, 12 ms)| independently, which reorders them);
every measurement of the impaired run must be one of the in-order run's, published once.
"""

from __future__ import annotations

import math
import socket
import struct
import time
from collections import Counter

import numpy as np
import pytest

from chronos_bridge.car_state import PLANE_OFFSETS, CarStateConverter
from chronos_bridge.codec import (
    decode_from_car,
    decode_from_host,
    encode_car_state,
    encode_discovery_ping,
    encode_packet,
    encode_torque_command,
)
from chronos_bridge.emulator import TICK_S, CarEmulator
from chronos_bridge.link import BUCKETS, CarLink, DatagramFilter, field_key
from chronos_bridge.packets import CarState, Packet, Ping, Reference
from crs_core.errors import FieldError
from crs_core.measurements import Measurement, parse_lighthouse
from tests.chronos_bridge.bridge_builders import STAMP_US, make_state

NOW = 1_800_000_000.0


def _socket() -> socket.socket:
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    s.bind(("127.0.0.1", 0))
    s.settimeout(1.0)
    return s


def _poll_until(link: CarLink, received: int, now: float = NOW) -> list:
    """Poll until ``received`` datagrams were counted (loopback delivery is not instant)."""
    out: list = []
    deadline = time.monotonic() + 2.0
    while link.received < received and time.monotonic() < deadline:
        out += link.poll(now)
        time.sleep(0.001)
    out += link.poll(now)
    assert link.received == received, link.counts
    return out


@pytest.fixture
def link():
    warnings: list[str] = []
    with CarLink(port=0, warn=warnings.append) as lnk:
        lnk.warnings = warnings
        yield lnk


@pytest.fixture
def car():
    s = _socket()
    yield s
    s.close()


def test_learns_the_car_from_its_first_valid_datagram_and_ignores_others(link, car):
    foreign = _socket()
    try:
        car.sendto(b"\xff\xff garbage", link.address)  # invalid: does not pair
        foreign.sendto(b"\x08", link.address)  # invalid too
        _poll_until(link, 2)
        assert not link.paired
        car.sendto(encode_car_state(make_state(), STAMP_US), link.address)
        converted = _poll_until(link, 3)
        assert link.endpoint == car.getsockname()
        assert len(converted) == 1 and converted[0].telemetry.stamp == STAMP_US * 1e-6
        foreign.sendto(encode_car_state(make_state(), STAMP_US), link.address)  # valid, foreign
        foreign.sendto(encode_discovery_ping(), link.address)
        assert _poll_until(link, 5) == []
        assert link.counts["foreign"] == 2 and link.counts["car_state"] == 1
        assert link.endpoint == car.getsockname()  # still pinned
    finally:
        foreign.close()


def test_configured_car_ip_refuses_other_ips_before_pairing(car):
    with CarLink(port=0, car_ip="127.0.0.2", warn=lambda _: None) as link:
        car.sendto(encode_car_state(make_state()), link.address)  # from 127.0.0.1
        _poll_until(link, 1)
        assert link.counts["foreign"] == 1 and not link.paired


def test_configured_endpoint_is_paired_from_the_start(car):
    with CarLink(port=0, car_ip="127.0.0.1", car_port=car.getsockname()[1]) as link:
        assert link.paired
        assert link.send_command([0.1, 0.2], "torque", NOW)
        packet = decode_from_host(car.recvfrom(512)[0])
        ref = packet.contents
        assert isinstance(ref, Reference) and ref.longitudinal_velocity is None
        assert (ref.throttle, ref.angle) == pytest.approx((0.2, 0.1))
        assert packet.timestamp_us == int(NOW * 1e6)
        other = _socket()
        try:
            other.sendto(encode_car_state(make_state()), link.address)  # same IP, wrong port
            _poll_until(link, 1)
            assert link.counts["foreign"] == 1
        finally:
            other.close()


def test_answers_discovery_pings_only_when_asked(link, car):
    car.sendto(encode_discovery_ping(), link.address)
    _poll_until(link, 1)
    reply = decode_from_host(car.recvfrom(512)[0])
    assert reply.contents == Ping(False) and reply.timestamp_us is not None
    car.sendto(encode_packet(Packet(Ping(False))), link.address)
    _poll_until(link, 2)
    car.settimeout(0.1)
    with pytest.raises(TimeoutError):
        car.recvfrom(512)
    assert link.counts["ping"] == 2 and link.sent["ping_replies"] == 1


def test_commands_only_after_pairing_and_only_valid_ones(link, car):
    assert not link.send_command([0.0, 0.5], "torque", NOW)
    assert link.sent["unpaired"] == 1
    car.sendto(encode_discovery_ping(), link.address)
    _poll_until(link, 1)
    car.recvfrom(512)  # the ping reply
    assert link.send_command([-0.2, 1.5], "velocity", NOW)
    packet = decode_from_host(car.recvfrom(512)[0])
    assert packet.contents.longitudinal_velocity == 1.5 and packet.contents.throttle is None
    assert packet.contents.angle == pytest.approx(-0.2)
    for u, mode in (([math.nan, 0.0], "torque"), ([0.0, 2.0], "torque"), ([0, 9.0], "velocity")):
        assert not link.send_command(u, mode, NOW)
    assert not link.send_command([0.0, 0.0], "warp", NOW)
    assert link.sent["invalid_commands"] == 4 and link.sent["commands"] == 1
    assert any("command not sent: angle: not finite" in w for w in link.warnings)  # throttled


def test_every_datagram_lands_in_exactly_one_bucket_and_rejects_name_the_field(link, car):
    valid = encode_car_state(make_state(), STAMP_US)
    nan_gyro = bytearray(valid)
    z = struct.pack("<f", make_state().imu.angular_velocity[2])
    nan_gyro[nan_gyro.index(z) : nan_gyro.index(z) + 4] = struct.pack("<f", math.nan)
    sends = [
        valid,  # pairs
        b"\x00" * 300,  # oversize
        valid[:-7],  # truncated
        bytes(nan_gyro),  # NaN
        b"\x92\x06\x02\x08\x01",  # unknown oneof tag (field 98)
        encode_packet(Packet(Reference(throttle=0.1))),  # host-only content
        b"",  # empty: no contents
    ]
    for data in sends:
        car.sendto(data, link.address)
    out = _poll_until(link, len(sends), NOW + 10)
    assert len(out) == 1
    assert link.counts["car_state"] == 1 and link.counts["oversize"] == 1
    assert link.counts["undecodable"] + link.counts["invalid"] == 5
    assert "car_state.imu_data.angular_velocity.z" in link.rejected_fields
    assert "<unknown field>" in link.rejected_fields
    assert set(link.counts) == set(BUCKETS) and link.received == len(sends)
    # throttled: one warning for the burst, naming its first reject
    assert len(link.warnings) == 1 and "datagram: 300 bytes > 255" in link.warnings[0]
    assert "received 7: car_state 1, duplicate 0, ping 0, foreign 0, oversize 1" in link.summary()


def test_a_stamp_beyond_what_a_ros_time_holds_is_refused(link, car):
    """The codec accepts stamps up to 2100; a ROS Time's int32 seconds end in 2038."""
    car.sendto(encode_car_state(make_state(), (2**31) * 1_000_000), link.address)
    assert _poll_until(link, 1) == []
    assert link.counts["invalid"] == 1 and link.rejected_fields == {"timestamp": 1}


def test_stamps_on_receipt_without_a_packet_timestamp(link, car):
    car.sendto(encode_car_state(make_state()), link.address)
    (converted,) = _poll_until(link, 1, NOW)
    assert converted.telemetry.stamp == NOW
    assert all(m.stamp == NOW for m in converted.measurements)


def test_a_flood_is_read_in_bounded_polls(car):
    with CarLink(port=0, max_per_poll=10, warn=lambda _: None) as link:
        for _ in range(25):
            car.sendto(b"\x01", link.address)
        time.sleep(0.05)
        link.poll(NOW)
        assert link.received == 10
        _poll_until(link, 25)


def test_bad_settings_name_the_parameter():
    for settings, message in (
        ({"port": 0, "car_ip": "car.local"}, "car_ip: not an IPv4 address"),
        ({"port": 0, "car_port": 20211}, "car_port: needs car_ip"),
        ({"port": 70000}, "port: must be in"),
    ):
        with pytest.raises(FieldError, match=f"^{message}") as error:
            CarLink(**settings)
        assert error.value.field == message.split(":")[0]
    with CarLink(port=0) as taken:
        with pytest.raises(OSError, match="port: cannot bind"):
            CarLink(port=taken.address[1])


def test_field_keys_are_folded():
    assert field_key("car_state.lighthouse_sweeps[3].angle_0") == (
        "car_state.lighthouse_sweeps[].angle_0"
    )
    assert field_key("car_state.<field 12345>") == "car_state.<unknown field>"


def test_a_resent_datagram_is_converted_once_and_overtaken_ones_are_counted(link, car):
    """Wi-Fi may deliver a datagram twice and out of order: by its timestamp, or by its bytes
    when the car's clock is not synchronised."""
    stamped = [encode_car_state(make_state(), STAMP_US + k * 4000) for k in range(3)]
    bare = encode_car_state(make_state())
    for data in (stamped[0], stamped[2], stamped[1], stamped[2], bare, bare):
        car.sendto(data, link.address)
    out = _poll_until(link, 6)
    assert [c.telemetry.stamp for c in out] == [
        STAMP_US * 1e-6,
        (STAMP_US + 8000) * 1e-6,
        (STAMP_US + 4000) * 1e-6,
        NOW,
    ]
    assert link.counts["car_state"] == 4 and link.counts["duplicate"] == 2
    assert link.arrival["reordered"] == 1
    assert "duplicate 2" in link.summary() and "arrival: reordered 1" in link.summary()


def test_the_newest_command_is_repeated_for_a_while_then_no_more(car):
    """Wi-Fi loses datagrams in bursts and the car stops after 200 ms without a reference: the
    newest command is sent again, the same bytes, every repeat_period for repeat_for after it
    was first sent; a new command takes over; a controller that stops sending stops the car."""
    with CarLink(
        port=0,
        car_ip="127.0.0.1",
        car_port=car.getsockname()[1],
        repeat_period=0.01,
        repeat_for=0.1,
    ) as link:
        assert not link.repeat(0.0)  # nothing sent yet
        assert link.send_command([0.1, 0.2], "torque", NOW)
        original = car.recvfrom(512)[0]
        start = time.monotonic()
        repeats = [t for t in start + np.arange(0.001, 0.2, 0.001) if link.repeat(t)]
        assert np.allclose(np.diff(repeats), 0.01, atol=1.5e-3)  # every 10 ms ...
        assert 9 <= len(repeats) <= 10 and repeats[-1] - start <= 0.1  # ... for 0.1 s
        assert link.sent == {**link.sent, "commands": 1, "repeats": len(repeats)}
        car.settimeout(1.0)
        for _ in repeats:
            assert car.recvfrom(512)[0] == original  # its stamp is the first send's
        assert link.send_command([-0.1, 0.3], "torque", NOW + 0.1)
        newer = car.recvfrom(512)[0]
        assert link.repeat(time.monotonic() + 0.01)
        assert car.recvfrom(512)[0] == newer


def test_repeats_can_be_switched_off_and_bad_periods_name_the_field():
    with CarLink(port=0, car_ip="127.0.0.1", car_port=9, repeat_period=0.0) as link:
        link.send_command([0.0, 0.1], "torque", NOW)
        assert not link.repeat(time.monotonic() + 0.05)
    for field, value in (("repeat_period", -0.01), ("repeat_for", math.nan)):
        with pytest.raises(FieldError, match=field) as error:
            CarLink(port=0, **{field: value})
        assert error.value.field == field


# ------------------------------------------------- the host side under Wi-Fi-like arrival

SECONDS = 10.0


@pytest.fixture(scope="module")
def car_states() -> list[tuple[float, bytes]]:
    """(send time s, datagram) of every car state of a 10 s emulated drive."""
    emulator = CarEmulator(seed=5)
    command = encode_torque_command(0.15, 0.25, 1_760_000_000_000_000)
    out = []
    for k in range(round(SECONDS / TICK_S)):
        now = k * TICK_S
        if k % 5 == 0:
            emulator.receive(command, now)
        out += [(now, d) for d in emulator.step(now) if isinstance(_decode(d).contents, CarState)]
    return out


def _decode(datagram: bytes) -> Packet:
    return decode_from_car(datagram)


def impair(
    datagrams: list[tuple[float, bytes]], seed: int, loss: float = 0.05, duplicates: float = 0.01
) -> tuple[list[tuple[float, bytes]], set[int], int]:
    """Arrivals (receipt time s, datagram) in arrival order, the indices delivered, and how many
    duplicates arrived."""
    rng = np.random.default_rng(seed)
    arrivals, delivered, copies = [], set(), 0
    for index, (sent, datagram) in enumerate(datagrams):
        if rng.random() < loss:
            continue
        delivered.add(index)
        n = 2 if rng.random() < duplicates else 1
        copies += n - 1
        for _ in range(n):
            arrivals.append((sent + 0.005 + abs(rng.normal(0.0, 0.012)), index, datagram))
    arrivals.sort(key=lambda a: a[0])
    return [(t, d) for t, _, d in arrivals], delivered, copies


def run(arrivals: list[tuple[float, bytes]]):
    """What the link does with each datagram: drop duplicates, convert the rest."""
    datagrams, converter = DatagramFilter(), CarStateConverter()
    out: list[Measurement] = []
    for receipt, data in arrivals:
        packet = _decode(data)
        if datagrams.accept(packet, data, receipt):
            out += converter.convert(packet, receipt).measurements
    return datagrams, converter, out


def raw_angle0(m: Measurement) -> float:
    """The sweep's raw angle_0 on the wire (identifies the sweep whatever its plane)."""
    parsed = parse_lighthouse(m.sensor)
    assert parsed is not None
    return round(float(m.values[0]) - PLANE_OFFSETS[parsed[1]], 9)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_an_impaired_link_publishes_the_in_order_measurements_once(car_states, seed) -> None:
    _, clean, in_order = run(car_states)
    arrivals, delivered, copies = impair(car_states, seed)
    datagrams, converter, impaired = run(arrivals)
    # the impairment happened: overtaken datagrams, pairs whose plane 2 came first, duplicates
    assert datagrams.duplicates == copies > 0
    assert datagrams.reordered > 100 and converter.sweeps_out_of_order > 20
    # IMU and wheels: each delivered step exactly once, identical to the in-order one
    reference = {(m.sensor, m.stamp): m for m in in_order if m.sensor in ("imu", "wheel_encoders")}
    steps = Counter((m.sensor, m.stamp) for m in impaired if not m.sensor.startswith("light"))
    assert max(steps.values()) == 1
    for m in impaired:
        if not m.sensor.startswith("lighthouse"):
            np.testing.assert_array_equal(m.values, reference[(m.sensor, m.stamp)].values)
    assert sum(1 for s, _ in steps if s == "imu") == len(delivered)
    # Lighthouse: each sweep once, with the in-order run's plane (sensor) and values; its stamp
    # within the deck clock's 4 ms step (the offset is a minimum over the sweeps that came)
    by_sweep = {raw_angle0(m): m for m in in_order if m.sensor.startswith("lighthouse")}
    sweeps = [m for m in impaired if m.sensor.startswith("lighthouse")]
    assert len({raw_angle0(m) for m in sweeps}) == len(sweeps)
    for m in sweeps:
        expected = by_sweep[raw_angle0(m)]
        assert m.sensor == expected.sensor
        np.testing.assert_array_equal(m.values, expected.values)
        assert abs(m.stamp - expected.stamp) <= TICK_S
    # >= 95 % of the sweeps whose datagram was delivered are published
    carried = {
        round(s.angles[0], 9)
        for i in delivered
        for s in _decode(car_states[i][1]).contents.sweeps  # type: ignore[union-attr]
    }
    published_in_order = [a for a in by_sweep if a in carried]
    assert len(sweeps) >= 0.95 * len(published_in_order)
    assert clean.sweeps_out_of_order == 0 and clean.sweeps_duplicate == 0


# ---------------------------------------------------------------- the datagram filter


def test_datagram_filter_by_stamp_and_by_bytes() -> None:
    datagrams = DatagramFilter(memory_s=1.0)
    packets = [Packet(make_state(), STAMP_US + k * 4000) for k in range(4)]
    assert datagrams.accept(packets[1], b"1", 0.0) and datagrams.accept(packets[0], b"0", 0.0)
    assert datagrams.reordered == 1
    assert not datagrams.accept(packets[1], b"other bytes, same stamp", 0.0)
    # a stamp far behind the memory: the car's clock stepped back; accepted, memory afresh
    assert datagrams.accept(Packet(make_state(), STAMP_US - 5_000_000), b"x", 0.0)
    assert datagrams.accept(packets[1], b"1", 0.0)  # forgotten with the step back
    # without a timestamp: the same bytes within the memory (receipt time) are a duplicate
    bare = Packet(make_state(), None)
    assert datagrams.accept(bare, b"a", 10.0) and datagrams.accept(bare, b"b", 10.5)
    assert not datagrams.accept(bare, b"a", 10.9)
    assert datagrams.accept(bare, b"a", 11.2)  # older than the memory: a new one
    assert datagrams.duplicates == 2
    with pytest.raises(ValueError, match="memory_s"):
        DatagramFilter(memory_s=0.0)
