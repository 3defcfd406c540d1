"""rmw_zenoh's wire format (:mod:`ros4crs.zenoh.wire`) against values computed by hand.

No machine running ``rmw_zenoh_cpp`` was available to test against (it ships neither as a
wheel nor as a Debian package for this environment), so compatibility is by construction: the
expected keys, tokens and bytes below are written out by hand from the rmw_zenoh design document
(``docs/design.md``) and sources (``liveliness_utils.cpp``: token layout, name mangling, the QoS
string with rmw_zenoh's defaults reliable / volatile / keep-last 42 left empty;
``attachment_helpers.cpp``: the attachment; ``rmw_publisher_data.cpp``: the GID as XXH3-128 of
the token), never recomputed by the code under test. The type hashes are the ones rosidl wrote
into the installed ``share/<package>/msg/<Type>.json``.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import pytest

from crs_core.errors import FieldError
from ros4crs.zenoh import wire

IMU = "sensor_msgs/msg/Imu"
CAR_INPUT = "chronos_msgs/msg/CarInput"
IMU_HASH = "RIHS01_7d9a00ff131080897a5ec7e26e315954b8eae3353c3f995c55faf71574000b5b"
CAR_INPUT_HASH = "RIHS01_f41d71572105355f7a856ea88aa99d0f11eb2f5a6f672a8d93debed21250c1cf"
ZID = "1f2e3d4c5b6a79880123456789abcdef"
#: The publisher QoS of the suite's sensor streams (node_support.STREAM_OUT_QOS).
STREAM_OUT = wire.Qos("reliable", "transient_local", "keep_last", 100)
IMU_PUBLISHER = (
    f"@ros2_lv/0/{ZID}/0/3/MP/%/%/zenoh_link/%car1%sensors%imu/sensor_msgs::msg::dds_::Imu_/"
    f"{IMU_HASH}/:1:,100:,:,:,,"
)


@pytest.mark.parametrize(
    ("msgtype", "expected"),
    [(IMU, IMU_HASH), (CAR_INPUT, CAR_INPUT_HASH)],
)
def test_type_hash_is_rosidls(msgtype: str, expected: str) -> None:
    assert wire.type_hash(msgtype) == expected
    package, _, name = msgtype.split("/")
    installed = Path(sys.prefix) / "share" / package / "msg" / f"{name}.json"
    if installed.exists():
        hashes = json.loads(installed.read_text())["type_hashes"]
        assert hashes[0] == {"type_name": msgtype, "hash_string": expected}


def test_dds_type_names() -> None:
    assert wire.dds_type_name(IMU) == "sensor_msgs::msg::dds_::Imu_"
    assert wire.dds_type_name(CAR_INPUT) == "chronos_msgs::msg::dds_::CarInput_"
    assert wire.ros_type_name("chronos_msgs::msg::dds_::CarInput_") == CAR_INPUT
    with pytest.raises(FieldError, match="type"):
        wire.ros_type_name("chronos_msgs/msg/CarInput")


def test_topic_keys() -> None:
    assert wire.topic_key(0, "/car1/sensors/imu", IMU) == (
        f"0/car1/sensors/imu/sensor_msgs::msg::dds_::Imu_/{IMU_HASH}"
    )
    assert wire.topic_key(7, "/car1/input/", CAR_INPUT) == (
        f"7/car1/input/chronos_msgs::msg::dds_::CarInput_/{CAR_INPUT_HASH}"
    )


def test_attachment_bytes() -> None:
    gid = bytes(range(16))
    attachment = wire.Attachment(sequence=0x0102, source_timestamp_ns=0x0102030405060708, gid=gid)
    expected = (
        b"\x02\x01\x00\x00\x00\x00\x00\x00"  # int64 sequence, little endian
        b"\x08\x07\x06\x05\x04\x03\x02\x01"  # int64 source time [ns], little endian
        b"\x10"  # the GID's length
        b"\x00\x01\x02\x03\x04\x05\x06\x07\x08\x09\x0a\x0b\x0c\x0d\x0e\x0f"
    )
    assert attachment.encode() == expected
    assert wire.Attachment.decode(expected) == attachment


def test_attachment_equals_zenoh_serialization() -> None:
    from zenoh.ext import Int64, z_serialize

    gid = bytes(range(16, 32))
    serialized = z_serialize((Int64(5), Int64(1_700_000_000_000_000_000), gid)).to_bytes()
    assert wire.Attachment(5, 1_700_000_000_000_000_000, gid).encode() == serialized


@pytest.mark.parametrize(
    ("data", "reason"),
    [
        (b"", "expected 33 bytes, got 0"),
        (bytes(32), "expected 33 bytes, got 32"),
        (bytes(34), "expected 33 bytes, got 34"),
        (bytes(16) + b"\x0f" + bytes(16), "GID length byte must be 16, got 15"),
    ],
)
def test_bad_attachments_are_refused(data: bytes, reason: str) -> None:
    with pytest.raises(FieldError, match=f"^attachment: {reason}"):
        wire.Attachment.decode(data)


def test_mangling() -> None:
    assert wire.mangle("/car1/sensors/imu") == "%car1%sensors%imu"
    assert wire.mangle("/") == "%"
    assert wire.mangle("") == "%"
    assert wire.demangle("%car1%input") == "/car1/input"


@pytest.mark.parametrize(
    ("qos", "text"),
    [
        (wire.Qos(depth=7), "::,7:,:,:,,"),
        (wire.Qos(), "::,:,:,:,,"),
        (STREAM_OUT, ":1:,100:,:,:,,"),
        (wire.Qos("best_effort", "volatile", "keep_last", 10), "2::,10:,:,:,,"),
        (wire.Qos("reliable", "volatile", "keep_all", 1000), "::2,1000:,:,:,,"),
    ],
)
def test_qos_strings(qos: wire.Qos, text: str) -> None:
    assert wire.qos_string(qos) == text
    assert wire.parse_qos(text) == qos


def test_qos_of_other_machines() -> None:
    # rmw's "system default" (0) reads as rmw_zenoh's default; deadlines etc. are ignored
    assert wire.parse_qos("0:0:0,0:1,500:,:1,2,3") == wire.Qos()
    for bad in ("", "::,:,:,", "9::,:,:,:,,", "::,x:,:,:,,", "::1:,:,:,:,,"):
        with pytest.raises(FieldError, match="qos"):
            wire.parse_qos(bad)


def test_node_token() -> None:
    assert (
        wire.node_token(0, ZID, 0, "/", "zenoh_link") == f"@ros2_lv/0/{ZID}/0/0/NN/%/%/zenoh_link"
    )
    assert wire.node_token(151, ZID, 4, "/car1", "estimator") == (
        f"@ros2_lv/151/{ZID}/4/4/NN/%/%car1/estimator"
    )


def test_endpoint_tokens() -> None:
    publisher = wire.endpoint_token(
        "MP", 0, ZID, 0, 3, "/", "zenoh_link", "/car1/sensors/imu", IMU, STREAM_OUT
    )
    assert publisher == IMU_PUBLISHER
    subscription = wire.endpoint_token(
        "MS", 2, ZID, 1, 9, "/car1", "bridge", "/car1/input", CAR_INPUT,
        wire.Qos("best_effort", "volatile", "keep_last", 10),
    )  # fmt: skip
    assert subscription == (
        f"@ros2_lv/2/{ZID}/1/9/MS/%/%car1/bridge/%car1%input/"
        f"chronos_msgs::msg::dds_::CarInput_/{CAR_INPUT_HASH}/2::,10:,:,:,,"
    )


def test_gid_is_xxh3_128_of_the_token() -> None:
    # XXH3-128 of "" (seed 0) is 99aa06d3014798d8 6001c324468d497f (high, low): the GID is the
    # low half then the high half, each little endian
    assert wire.gid("").hex() == "7f498d4624c30160d8984701d306aa99"
    # XXH3-128 of IMU_PUBLISHER: 0d9444f9ff66dc98 4ee171d945570ba2
    assert wire.gid(IMU_PUBLISHER).hex() == "a20b5745d971e14e98dc66fff944940d"


def test_parse_tokens() -> None:
    endpoint = wire.parse_token(IMU_PUBLISHER)
    assert endpoint == wire.EndpointInfo(
        domain=0, zid=ZID, nid="0", eid="3", kind="MP", enclave="/", namespace="/",
        node="zenoh_link", topic="/car1/sensors/imu", msgtype=IMU, type_hash=IMU_HASH,
        qos=STREAM_OUT,
    )  # fmt: skip
    assert isinstance(endpoint, wire.EndpointInfo)
    assert endpoint.key() == f"0/car1/sensors/imu/sensor_msgs::msg::dds_::Imu_/{IMU_HASH}"
    node = wire.parse_token(f"@ros2_lv/3/{ZID}/2/2/NN/%/%car1/estimator")
    assert node == wire.NodeInfo(3, ZID, "2", "/", "/car1", "estimator")
    assert isinstance(node, wire.NodeInfo) and node.full_name == "/car1/estimator"


@pytest.mark.parametrize(
    "key",
    [
        "0/car1/input/chronos_msgs::msg::dds_::CarInput_/RIHS01_0",
        f"@ros2_lv/0/{ZID}/0/0/XX/%/%/node",
        f"@ros2_lv/x/{ZID}/0/0/NN/%/%/node",
        f"@ros2_lv/0/{ZID}/0/0/NN/%/%/node/extra",
        IMU_PUBLISHER.rsplit("/", 1)[0],
        IMU_PUBLISHER.replace("sensor_msgs::msg::dds_::Imu_", "Imu"),
        IMU_PUBLISHER.replace(":1:,100:", ":7:,100:"),
    ],
)
def test_malformed_tokens_are_refused(key: str) -> None:
    with pytest.raises(FieldError):
        wire.parse_token(key)
