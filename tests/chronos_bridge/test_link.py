"""CarLink over real loopback sockets: pairing, foreign senders, pings, rejects, commands."""

from __future__ import annotations

import math
import socket
import struct
import time

import numpy as np
import pytest
from bridge_builders import STAMP_US, make_state

from chronos_bridge.codec import (
    decode_from_host,
    encode_car_state,
    encode_discovery_ping,
    encode_packet,
)
from chronos_bridge.link import BUCKETS, CarLink, field_key
from chronos_bridge.packets import Packet, Ping, Reference
from crs_core.errors import FieldError

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
