"""Salvage of cut-off MCAP bags (ros4crs.bag_repair), on bags written with rosbags' Writer.

The expected salvage of a cut at byte offset ``cut`` is computed without the module under test:
messages are written in log-time order, each payload is unique, so the end offset of each
message record is found by searching its payload in the file (rosbags does not compress chunks
by default); a message is recoverable iff its record ends at or before the cut. For the bag with
compressed chunks the chunk offsets come from rosbags' own MCAP summary reader.
"""

from __future__ import annotations

import hashlib
import shutil
import struct
import warnings
import zlib
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest
from rosbags.interfaces import (
    Qos,
    QosDurability,
    QosHistory,
    QosLiveliness,
    QosReliability,
    QosTime,
)
from rosbags.rosbag2 import CompressionFormat, CompressionMode, Reader, StoragePlugin, Writer

from ros4crs.bag_repair import BagDamagedWarning, check, open_bag, repair
from ros4crs.interfaces import typestore

T0 = 1_700_000_000_000_000_000  # ns
STEP = 10_000_000  # ns between messages
COUNT = 300  # messages: Imu, CarState, String (30 KiB) in turn -> 3 MiB, 3 chunks
QOS = Qos(
    QosHistory.KEEP_LAST,
    7,
    QosReliability.BEST_EFFORT,
    QosDurability.VOLATILE,
    QosTime(0, 0),
    QosTime(0, 0),
    QosLiveliness.AUTOMATIC,
    QosTime(0, 0),
    False,
)

Message = tuple[str, int, bytes]  # topic, log time (ns), CDR bytes


def _serialize(i: int) -> tuple[str, str, bytes]:
    """Topic, message type and CDR bytes of the ``i``-th message (each one unique)."""
    store = typestore()
    types = store.types
    stamp = types["builtin_interfaces/msg/Time"](sec=1_700_000_000 + i // 100, nanosec=i * 1000)
    header = types["std_msgs/msg/Header"](stamp=stamp, frame_id=f"car{i}")
    kind = i % 3
    if kind == 0:
        vector = types["geometry_msgs/msg/Vector3"]
        msg = types["sensor_msgs/msg/Imu"](
            header=header,
            orientation=types["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0),
            orientation_covariance=np.full(9, -1.0),
            angular_velocity=vector(x=0.01 * i, y=0.0, z=1.5),
            angular_velocity_covariance=np.zeros(9),
            linear_acceleration=vector(x=0.5, y=-0.25 * i, z=9.81),
            linear_acceleration_covariance=np.zeros(9),
        )
        topic, msgtype = "/car/sensors/imu", "sensor_msgs/msg/Imu"
    elif kind == 1:
        msg = types["chronos_msgs/msg/CarState"](
            header=header,
            status=i % 3,
            x=0.1 * i,
            y=-0.2 * i,
            yaw=0.01 * i,
            vx=2.0,
            vy=0.1,
            omega=0.3,
            covariance=np.arange(36, dtype=np.float64) * i,
        )
        topic, msgtype = "/car/estimate/state", "chronos_msgs/msg/CarState"
    else:
        text = f"log line {i:05d} " + "abcdefgh" * 3840
        msg = types["std_msgs/msg/String"](data=text)
        topic, msgtype = "/car/log", "std_msgs/msg/String"
    return topic, msgtype, bytes(store.serialize_cdr(msg, msgtype))


def _write_bag(path: Path, compressed: bool = False) -> list[Message]:
    store = typestore()
    written = []
    writer = Writer(path, version=9, storage_plugin=StoragePlugin.MCAP)
    if compressed:
        writer.set_compression(CompressionMode.STORAGE, CompressionFormat.ZSTD)
    with writer:
        connections = {}
        for i in range(COUNT):
            topic, msgtype, data = _serialize(i)
            if topic not in connections:
                qos = [QOS] if topic == "/car/sensors/imu" else []
                connections[topic] = writer.add_connection(
                    topic, msgtype, typestore=store, offered_qos_profiles=qos
                )
            writer.write(connections[topic], T0 + i * STEP, data)
            written.append((topic, T0 + i * STEP, data))
    return written


def _read(reader: Reader) -> list[Message]:
    return [(c.topic, t, bytes(d)) for c, t, d in reader.messages()]


def _sha256(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def _size_text(size: int) -> str:
    return f"{size} B" if size < 1024 else f"{size / 1024:.1f} KiB"


@dataclass
class Layout:
    """The full bag and where its records end in its MCAP file (offsets in B)."""

    bag: Path
    data: bytes
    messages: list[Message]
    ends: list[int]  # end of each message record, in write order
    header_end: int  # end of the MCAP header record
    chunks: list[tuple[int, int, int]]  # chunk start, chunk record end, end of its indexes


@pytest.fixture(scope="module")
def layout(tmp_path_factory: pytest.TempPathFactory) -> Layout:
    bag = tmp_path_factory.mktemp("full") / "rec"
    messages = _write_bag(bag)
    data = (bag / "rec.mcap").read_bytes()
    ends, pos = [], 0
    for _, _, payload in messages:
        pos = data.index(payload, pos) + len(payload)
        ends.append(pos)
    (header_length,) = struct.unpack_from("<Q", data, 9)
    with Reader(bag) as reader:
        chunks = [
            (c.chunk_start_offset, c.chunk_start_offset + c.chunk_length, c.message_index_length)
            for c in reader.storage.storages[0].chunks
        ]
        assert _read(reader) == messages
    chunks = [(start, end, end + index) for start, end, index in chunks]
    return Layout(bag, data, messages, ends, 8 + 9 + header_length, chunks)


def _expected(layout: Layout, cut: int) -> int:
    return sum(end <= cut for end in layout.ends)


def _lost_in_data(layout: Layout, cut: int) -> int:
    """Bytes after the last complete message record, for a cut among the message records."""
    count = _expected(layout, cut)
    return cut - layout.ends[count - 1]


# name: (cut offset, bytes lost)
CUTS = {
    "header_only": (lambda L: L.header_end, lambda L, cut: 0),
    "first_message": (lambda L: L.ends[0], _lost_in_data),
    "mid_message": (lambda L: L.ends[41] - 1000, _lost_in_data),
    "record_boundary": (lambda L: L.ends[150], _lost_in_data),
    "mid_second_chunk": (lambda L: (L.chunks[1][0] + L.chunks[1][1]) // 2 + 3, _lost_in_data),
    "chunk_record_end": (lambda L: L.chunks[0][1], _lost_in_data),
    "in_message_index": (lambda L: L.chunks[0][1] + 5, lambda L, cut: 5),
    "after_message_index": (lambda L: L.chunks[0][2], lambda L, cut: 0),
    "before_footer": (lambda L: len(L.data) - 37, lambda L, cut: 0),
    "end_magic": (lambda L: len(L.data) - 8, lambda L, cut: 0),
    "one_byte_short": (lambda L: len(L.data) - 1, lambda L, cut: 7),
}


def _cut_copy(layout: Layout, directory: Path, cut: int, keep_metadata: bool) -> Path:
    bag = directory / "damaged"
    bag.mkdir()
    (bag / "rec.mcap").write_bytes(layout.data[:cut])
    if keep_metadata:
        shutil.copy(layout.bag / "metadata.yaml", bag / "metadata.yaml")
    return bag


def test_complete_bag_is_reported_complete_and_copied_identically(
    layout: Layout, tmp_path: Path
) -> None:
    report = check(layout.bag)
    assert report.complete and not report.metadata_missing and report.warning == ""
    assert report.messages == COUNT and report.lost_bytes == 0
    assert report.topics == {"/car/sensors/imu": 100, "/car/estimate/state": 100, "/car/log": 100}
    assert report.first_ns == T0 and report.last_ns == T0 + (COUNT - 1) * STEP
    assert report.duration_s == pytest.approx((COUNT - 1) * STEP / 1e9)
    assert "complete" in report.describe()

    out = tmp_path / "copy"
    repair(layout.bag, out)
    with Reader(layout.bag) as original, Reader(out) as copy:
        assert _read(copy) == layout.messages
        assert [(c.topic, c.msgtype, c.msgdef, c.digest, c.ext) for c in copy.connections] == [
            (c.topic, c.msgtype, c.msgdef, c.digest, c.ext) for c in original.connections
        ]

    with warnings.catch_warnings():
        warnings.simplefilter("error", BagDamagedWarning)
        with open_bag(layout.bag) as reader:
            assert reader.message_count == COUNT


@pytest.mark.parametrize("keep_metadata", [False, True], ids=["no_metadata", "metadata"])
@pytest.mark.parametrize("case", list(CUTS))
def test_truncated_bag_is_salvaged_up_to_its_last_complete_message(
    layout: Layout, tmp_path: Path, case: str, keep_metadata: bool
) -> None:
    cut_of, lost_of = CUTS[case]
    cut = cut_of(layout)
    expected = _expected(layout, cut)
    bag = _cut_copy(layout, tmp_path, cut, keep_metadata)
    report = check(bag)
    assert not report.complete
    assert report.metadata_missing is not keep_metadata
    assert report.messages == expected
    assert report.size == cut
    assert report.lost_bytes == lost_of(layout, cut)
    if keep_metadata:
        assert report.expected_messages == COUNT
        assert f"{COUNT - expected} messages lost" in report.warning
    if case in ("before_footer", "end_magic", "one_byte_short"):
        assert expected == COUNT
        assert report.files[0].data_complete
        assert "no message was lost" in report.warning or "0 messages lost" in report.warning
    if case in ("end_magic", "one_byte_short"):
        assert "end magic" in report.warning
    elif report.lost_bytes:
        assert f"the last {_size_text(report.lost_bytes)}" in report.warning
    else:
        assert "no partial record lost" in report.warning
    workdir = tmp_path / "work"
    workdir.mkdir()

    if not expected:
        with pytest.raises(ValueError, match=r"no complete message in rec\.mcap") as error:
            with open_bag(bag, workdir=workdir):
                pass
        assert "\n" not in str(error.value)
        return
    with pytest.warns(BagDamagedWarning) as caught, open_bag(bag, workdir=workdir) as reader:
        salvaged = _read(reader)
    assert salvaged == layout.messages[:expected]
    assert [str(w.message) for w in caught] == [report.warning]
    assert not any(workdir.iterdir())  # the temporary copy is gone


def test_an_mcap_file_is_a_bag_too(layout: Layout, tmp_path: Path) -> None:
    """The ``.mcap`` file alone (as ros2 bag and Foxglove take it): complete, it is checked and
    read as its folder is; cut off, it is salvaged the same way (no metadata.yaml is missing)."""
    whole = layout.bag / "rec.mcap"
    report = check(whole)
    assert report.complete and report.messages == COUNT and not report.metadata_missing
    with open_bag(whole) as reader:
        assert _read(reader) == layout.messages
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(layout.data[: layout.ends[150]])
    report = check(cut)
    assert not report.complete and not report.metadata_missing
    assert report.messages == 151
    with pytest.warns(BagDamagedWarning), open_bag(cut, workdir=tmp_path) as reader:
        assert _read(reader) == layout.messages[:151]
    repair(cut, tmp_path / "repaired")
    with Reader(tmp_path / "repaired") as reader:
        assert _read(reader) == layout.messages[:151]


def test_salvage_grows_with_the_cut_offset(layout: Layout, tmp_path: Path) -> None:
    counts = []
    cuts = [*range(layout.ends[0] - 50, len(layout.data), 250_000), len(layout.data) - 8]
    for i, cut in enumerate(cuts):
        bag = tmp_path / f"cut{i}"
        bag.mkdir()
        (bag / "rec.mcap").write_bytes(layout.data[:cut])
        counts.append(check(bag).messages)
        assert counts[-1] == _expected(layout, cut)
    assert counts == sorted(counts) and counts[0] == 0 and counts[-1] == COUNT


def test_repair_of_a_damaged_bag_gives_a_plain_readable_bag(layout: Layout, tmp_path: Path) -> None:
    cut = CUTS["mid_second_chunk"][0](layout)
    bag = _cut_copy(layout, tmp_path, cut, keep_metadata=False)
    damaged = bag / "rec.mcap"
    before = (damaged.stat().st_size, _sha256(damaged))
    out = tmp_path / "repaired"
    report = repair(bag, out)
    assert (damaged.stat().st_size, _sha256(damaged)) == before
    assert sorted(p.name for p in bag.iterdir()) == ["rec.mcap"]
    expected = _expected(layout, cut)
    assert report.messages == expected
    assert report.topics == {
        topic: sum(m[0] == topic for m in layout.messages[:expected])
        for topic in ("/car/sensors/imu", "/car/estimate/state", "/car/log")
    }
    assert report.last_ns == layout.messages[expected - 1][1]
    assert f"read {expected} messages up to {report.duration_s:.1f} s" in report.warning
    assert "messages up to" in report.warning  # the cut chunk's last log time is known
    with Reader(layout.bag) as original, Reader(out) as reader:
        assert _read(reader) == layout.messages[:expected]
        assert reader.message_count == expected
        assert [(c.topic, c.msgtype, c.msgdef, c.digest, c.ext) for c in reader.connections] == [
            (c.topic, c.msgtype, c.msgdef, c.digest, c.ext) for c in original.connections
        ]
        imu = next(c for c in reader.connections if c.topic == "/car/sensors/imu")
        assert imu.ext.offered_qos_profiles == [QOS]
    with pytest.raises(ValueError, match="exists already"):
        repair(bag, out)
    assert "cut off" in report.describe()


def test_a_cut_compressed_chunk_is_lost_and_said_so(tmp_path: Path) -> None:
    full = tmp_path / "zstd"
    messages = _write_bag(full, compressed=True)
    with Reader(full) as reader:
        chunks = reader.storage.storages[0].chunks
        assert all(c.compression == "zstd" for c in chunks) and len(chunks) >= 2
        first = chunks[1]
        cut = first.chunk_start_offset + first.chunk_length // 2
        expected = sum(sum(c.channel_count.values()) for c in chunks[:1])
    bag = tmp_path / "damaged"
    bag.mkdir()
    (bag / "zstd.mcap").write_bytes((full / "zstd.mcap").read_bytes()[:cut])
    report = check(bag)
    assert report.messages == expected
    assert report.files[0].unrecoverable_chunk
    assert report.lost_bytes == cut - first.chunk_start_offset
    assert "zstd-compressed chunk" in report.warning and "unknown" in report.warning
    with pytest.warns(BagDamagedWarning), open_bag(bag) as reader:
        assert _read(reader) == messages[:expected]


def test_bad_inputs_raise_a_one_line_value_error_naming_the_file(tmp_path: Path) -> None:
    empty = tmp_path / "empty"
    empty.mkdir()
    (tmp_path / "notes.txt").write_text("not a bag")
    junk = tmp_path / "junk"
    junk.mkdir()
    (junk / "junk.mcap").write_bytes(bytes(range(256)) * 8)
    sqlite = tmp_path / "sqlite"
    with Writer(sqlite, version=9, storage_plugin=StoragePlugin.SQLITE3) as writer:
        topic, msgtype, data = _serialize(2)
        writer.write(writer.add_connection(topic, msgtype, typestore=typestore()), T0, data)
    assert check(sqlite).complete  # a complete sqlite3 bag still opens ...
    with open_bag(sqlite) as reader:
        assert reader.message_count == 1
    cases = [
        (lambda: check(empty), "empty: not a bag folder"),
        (lambda: check(tmp_path / "nowhere"), "nowhere: not a bag folder"),
        (lambda: check(junk / "junk.mcap"), r"junk\.mcap: no MCAP magic"),
        (lambda: check(tmp_path / "notes.txt"), r"notes\.txt: not a bag folder or an \.mcap"),
        (lambda: repair(junk, tmp_path / "out1"), r"junk\.mcap: no MCAP magic"),
        (lambda: open_bag(junk).__enter__(), r"junk\.mcap: no MCAP magic"),
        (lambda: repair(sqlite, tmp_path / "out2"), r"sqlite\.db3: sqlite3 .*MCAP only"),
    ]
    for call, message in cases:
        with pytest.raises(ValueError, match=message) as error:
            call()
        assert "\n" not in str(error.value)
    (sqlite / "metadata.yaml").unlink()  # ... a damaged one is not salvaged
    with pytest.raises(ValueError, match=r"sqlite\.db3: sqlite3 bag .*MCAP only"):
        check(sqlite)
    assert not (tmp_path / "out1").exists() and not (tmp_path / "out2").exists()


def _message_start(layout: Layout, i: int) -> int:
    """Offset (B) of the ``i``-th message record (opcode, length, 22 B of fields, payload)."""
    return layout.ends[i] - len(layout.messages[i][2]) - 9 - 22


def _with_crcs(data: bytes, layout: Layout, wrong: int | None = None) -> bytearray:
    """``data`` with the CRC of every uncompressed chunk filled in (rosbags writes 0 = none).

    The chunk numbered ``wrong`` gets a CRC off by one.
    """
    patched = bytearray(data)
    for number, (start, end, _) in enumerate(layout.chunks):
        records = layout.data[start + 9 + CHUNK_HEAD : end]
        crc = zlib.crc32(records) + (number == wrong)
        struct.pack_into("<I", patched, start + 9 + 24, crc & 0xFFFF_FFFF)
    return patched


CHUNK_HEAD = 8 + 8 + 8 + 4 + 4 + 8  # log times, size, crc, empty compression, records size


def _in_chunk(layout: Layout) -> int:
    """Index of a message record a few records into the second chunk."""
    return _expected(layout, layout.chunks[1][0]) + 3


# name: (damaged file from the layout, salvaged messages, cut text, the cut chunk's end is known)
DAMAGE = {
    "empty_file": (lambda L: b"", 0, "an empty file", False),
    "in_start_magic": (lambda L: L.data[:4], 0, "an incomplete MCAP magic", False),
    "start_magic_only": (lambda L: L.data[:8], 0, "", False),
    "in_record_header": (
        lambda L: L.data[: L.chunks[1][0] + 5],
        "chunk1",
        "an incomplete record header",
        False,
    ),
    "in_chunk_header": (
        lambda L: L.data[: L.chunks[1][0] + 9 + 20],
        "chunk1",
        "an incomplete chunk header",
        False,
    ),
    "after_chunk_header": (
        lambda L: L.data[: L.chunks[1][0] + 9 + CHUNK_HEAD],
        "chunk1",
        "the start of a chunk without a complete record",
        True,
    ),
    "in_record_header_in_chunk": (
        lambda L: L.data[: _message_start(L, _in_chunk(L)) + 4],
        "in_chunk",
        "an incomplete record header inside a chunk",
        True,
    ),
    "in_message_fields_in_chunk": (
        lambda L: L.data[: _message_start(L, _in_chunk(L)) + 9 + 10],
        "in_chunk",
        "an incomplete message record inside a chunk",
        True,
    ),
    "in_message_data_in_chunk": (
        lambda L: L.data[: L.ends[_in_chunk(L)] - 1],
        "in_chunk",
        "an incomplete message record inside a chunk",
        True,
    ),
    "zeros_in_chunk": (
        lambda L: L.data[: _message_start(L, _in_chunk(L))] + bytes(200),
        "in_chunk",
        "bytes that are no MCAP record (opcode 0) inside a chunk",
        True,
    ),
    "zeros_after_chunk": (
        lambda L: L.data[: L.chunks[1][0]] + bytes(5000),
        "chunk1",
        "bytes that are no MCAP record (opcode 0)",
        False,
    ),
    "good_crcs": (
        lambda L: _with_crcs(L.data, L)[: L.ends[250] + 9 + 10],
        "cut",
        "an incomplete message record inside a chunk",
        True,
    ),
    "wrong_crc": (
        lambda L: _with_crcs(L.data, L, wrong=1)[: L.ends[250]],
        "chunk1",
        "a chunk that does not decompress (Chunk checksum mismatch.)",
        False,
    ),
    "corrupt_channel_metadata": (
        # a key length in the first channel's metadata map runs past the map: the channel is kept
        # (without the metadata it cannot read) and so are its messages
        lambda L: (
            L.data[: L.data.index(b"offered_qos_profiles") - 4]
            + struct.pack("<I", 500)
            + L.data[L.data.index(b"offered_qos_profiles") : L.ends[250] + 9 + 10]
        ),
        "cut",
        "an incomplete message record inside a chunk",
        True,
    ),
    "malformed_channel": (
        # the first channel's topic length (after its id and schema id) runs past the record
        lambda L: (
            L.data[: L.data.index(b"/car/sensors/imu") - 4]
            + struct.pack("<I", 1 << 20)
            + L.data[L.data.index(b"/car/sensors/imu") : L.ends[250]]
        ),
        0,
        "a chunk with a malformed channel record inside a chunk",
        False,
    ),
}


@pytest.mark.parametrize("case", list(DAMAGE))
def test_damage_around_and_inside_chunks_is_described(
    layout: Layout, tmp_path: Path, case: str
) -> None:
    damaged, salvaged, cut, chunk_end_known = DAMAGE[case]
    data = bytes(damaged(layout))
    if salvaged == "chunk1":  # everything before the second chunk
        salvaged = _expected(layout, layout.chunks[1][0])
    elif salvaged == "in_chunk":
        salvaged = _in_chunk(layout)
    elif salvaged == "cut":
        salvaged = _expected(layout, len(data))
    bag = tmp_path / "damaged"
    bag.mkdir()
    (bag / "rec.mcap").write_bytes(data)
    report = check(bag)
    file = report.files[0]
    assert not report.complete and not file.complete
    assert (report.messages, file.cut) == (salvaged, cut)
    assert file.size == len(data)
    if case.endswith("_in_chunk") or case in ("good_crcs", "corrupt_channel_metadata"):
        assert file.good_bytes == layout.ends[salvaged - 1]
    elif case in ("empty_file", "in_start_magic"):
        assert file.good_bytes == 0
    elif case == "start_magic_only":
        assert file.good_bytes == 8
    else:  # the walk stopped at the second chunk, or at the first for the malformed channel
        assert file.good_bytes == layout.chunks[0 if case == "malformed_channel" else 1][0]
    chunk_end_ns = None
    if chunk_end_known:  # the log time of the last message of the chunk the cut fell in
        cut_chunk = next(c for c in layout.chunks if c[0] < len(data) <= c[1])
        chunk_end_ns = layout.messages[_expected(layout, cut_chunk[1]) - 1][1]
    assert file.cut_chunk_end_ns == chunk_end_ns
    assert not file.unrecoverable_chunk and not file.data_complete
    if salvaged:
        out = tmp_path / "repaired"
        repair(bag, out)
        with Reader(out) as reader:
            assert _read(reader) == layout.messages[:salvaged]
