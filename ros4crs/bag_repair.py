"""Check and salvage ROS 2 bags whose MCAP file was cut off (killed recorder, full disk, copy).

rosbags writes the MCAP summary, footer and end magic, and ``metadata.yaml``, only when the bag
is closed, so a cut-off bag does not open (``File end magic is invalid``). :func:`check` reports
what such a bag still holds, :func:`repair` writes a new complete bag from it and
:func:`open_bag` opens any bag, repairing a damaged one into a temporary copy (with a
:class:`BagDamagedWarning`).

Salvaged: every message whose record lies complete in the file before the cut, in file order,
with its log time, raw bytes and channel (topic, message type and definition, serialization
format, offered QoS profiles). Records are walked from the start of the file: whole chunks, and
the complete records at the front of a cut *uncompressed* chunk (rosbags' writer does not
compress its chunks unless asked to). The copy is uncompressed: chunks and zstd-compressed
messages (rosbags' ``message`` compression mode) are stored decompressed.

Not salvageable, reported as lost: the bytes after the last complete record (an incomplete
record; a cut *compressed* chunk, whose messages cannot be counted: its header only gives the
log time of its last message); and what was never written to the file: rosbags keeps the current
chunk (up to 1 MiB of messages) in memory until it is full, so a killed recorder loses that
much, which the file cannot tell (when ``metadata.yaml`` survived, as for a bag cut by a copy,
its message count does tell how many were lost). Publish times and sequence numbers are not
kept (the rosbags writer stores publish time = log time). Bags stored as sqlite3 or as
file-compressed ``.mcap.zstd`` are checked only when complete: salvage supports MCAP only.
"""

from __future__ import annotations

import re
import shutil
import struct
import sys
import tempfile
import warnings
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path, PurePath

import yaml
from rosbags.rosbag2 import Reader, StoragePlugin, Writer
from rosbags.rosbag2.metadata import parse_qos
from rosbags.rosbag2.storage_mcap import decompress
from rosbags.typesys import Stores, get_types_from_idl, get_types_from_msg, get_typestore

from crs_core.yaml_io import load_yaml

if sys.version_info >= (3, 14):  # the zstd module rosbags itself uses
    from compression import zstd
else:
    from backports import zstd

__all__ = ["BagCheck", "BagDamagedWarning", "FileCheck", "check", "open_bag", "repair"]

MAGIC = b"\x89MCAP0\r\n"
_ZSTD_FRAME = b"\x28\xb5\x2f\xfd"  # a CDR payload starts with 0x00, never with this
_RECORD = struct.Struct("<BQ")  # opcode, body length (B)
_MESSAGE = struct.Struct("<HIQQ")  # channel id, sequence, log time, publish time (ns)
_CHUNK = struct.Struct("<QQQI")  # first/last log time (ns), uncompressed size (B), crc
_FOOTER = struct.Struct("<BQQQI")  # opcode, length, summary start, summary offset start, crc
_U16 = struct.Struct("<H")
_U32 = struct.Struct("<I")
_U64 = struct.Struct("<Q")
HEADER, FOOTER, SCHEMA, CHANNEL, MESSAGE, CHUNK, DATA_END = 1, 2, 3, 4, 5, 6, 15
_RECORD_NAMES = {
    1: "header",
    2: "footer",
    3: "schema",
    4: "channel",
    5: "message",
    6: "chunk",
    7: "message index",
    8: "chunk index",
    9: "attachment",
    10: "attachment index",
    11: "statistics",
    12: "metadata",
    13: "metadata index",
    14: "summary offset",
    15: "data end",
}


class BagDamagedWarning(UserWarning):
    """A bag was damaged (cut off); it was read up to its last complete message."""


def _size_text(size: int) -> str:
    """``size`` (B) as a short human text, e.g. ``3.1 KiB``."""
    if size < 1024:
        return f"{size} B"
    for unit in ("KiB", "MiB", "GiB"):
        size /= 1024
        if size < 1024 or unit == "GiB":
            return f"{size:.1f} {unit}"
    raise AssertionError  # unreachable


@dataclass(frozen=True)
class FileCheck:
    """What one storage file of a bag holds.

    Attributes
    ----------
    path : Path
        The storage file.
    size : int
        Its size (B).
    complete : bool
        It ends with an MCAP footer and the end magic (for sqlite3: it opened).
    good_bytes : int
        Offset (B) just after the last complete record read (``size`` when complete).
    cut : str
        What the bytes after ``good_bytes`` are, e.g. ``an incomplete message record inside a
        chunk``; empty when nothing (or only part of the end magic) follows.
    data_complete : bool
        The data section ends with its DataEnd record: no message is missing from the file.
    cut_chunk_end_ns : int or None
        Log time (ns) of the last message of the chunk the cut fell in (from its header).
    unrecoverable_chunk : bool
        The cut fell in a compressed chunk: its messages are lost and their number unknown.
    """

    path: Path
    size: int
    complete: bool
    good_bytes: int
    cut: str = ""
    data_complete: bool = False
    cut_chunk_end_ns: int | None = None
    unrecoverable_chunk: bool = False

    @property
    def lost_bytes(self) -> int:
        """Bytes (B) after the last complete record."""
        return self.size - self.good_bytes


@dataclass(frozen=True)
class BagCheck:
    """What a bag holds and what of it is lost; see :func:`check`.

    Attributes
    ----------
    path : Path
        The bag folder.
    storage : str
        ``mcap`` or ``sqlite3``.
    complete : bool
        ``metadata.yaml`` is there, rosbags' ``Reader`` opens the bag and every MCAP file has its
        footer and end magic.
    files : tuple of FileCheck
        The storage files, in order.
    messages : int
        Complete (recoverable) messages.
    topics : dict of str to int
        Complete messages per topic.
    first_ns, last_ns : int or None
        Earliest and latest log time (ns) of those messages.
    metadata_missing : bool
        ``metadata.yaml`` is missing or unreadable.
    expected_messages : int or None
        Messages the bag had when closed, from ``metadata.yaml`` (None when missing).
    unreadable_messages : int
        Complete messages on channels without a schema (not recoverable by rosbags).
    reader_error : str
        Why rosbags' ``Reader`` did not open the bag (empty when it did).
    """

    path: Path
    storage: str
    complete: bool
    files: tuple[FileCheck, ...]
    messages: int
    topics: dict[str, int]
    first_ns: int | None
    last_ns: int | None
    metadata_missing: bool = False
    expected_messages: int | None = None
    unreadable_messages: int = 0
    reader_error: str = ""

    @property
    def size(self) -> int:
        """Total size (B) of the storage files."""
        return sum(f.size for f in self.files)

    @property
    def lost_bytes(self) -> int:
        """Bytes (B) after the last complete record, summed over the files."""
        return sum(f.lost_bytes for f in self.files)

    @property
    def duration_s(self) -> float:
        """Time (s) from the first to the last recoverable message (0 without messages)."""
        if self.first_ns is None or self.last_ns is None:
            return 0.0
        return (self.last_ns - self.first_ns) / 1e9

    def _relative_s(self, stamp_ns: int) -> float:
        return (stamp_ns - (self.first_ns or 0)) / 1e9

    def _file_loss(self, file: FileCheck) -> list[str]:
        parts = []
        if file.cut.startswith("only the end magic"):
            parts.append(file.cut)
        elif not file.good_bytes:
            parts.append(f"it holds no complete record ({file.cut})")
        elif file.cut == "" and not file.lost_bytes:
            parts.append("it ends just after a complete record (no partial record lost)")
        elif file.lost_bytes:
            what = f" ({file.cut})" if file.cut else ""
            parts.append(f"the last {_size_text(file.lost_bytes)}{what} were lost")
        if file.cut_chunk_end_ns is not None and self.first_ns is not None:
            held = "held" if file.unrecoverable_chunk else "had"
            end_s = self._relative_s(file.cut_chunk_end_ns)
            parts.append(f"the cut chunk {held} messages up to {end_s:.1f} s")
        return parts

    @property
    def warning(self) -> str:
        """One line on what was read and lost (empty for a complete bag)."""
        if self.complete:
            return ""
        damaged = [f for f in self.files if not f.complete]
        if damaged:
            names = ", ".join(f.path.name for f in damaged)
            lead = f"{names} {'is' if len(damaged) == 1 else 'are'} cut off"
        elif self.metadata_missing:
            lead = f"{self.path.name}: metadata.yaml is missing"
        else:
            lead = f"{self.path.name} does not open ({self.reader_error})"
        read = f"read {self.messages}"
        if self.expected_messages is not None:
            read += f" of {self.expected_messages}"
        read += " message" if (self.expected_messages or self.messages) == 1 else " messages"
        if self.messages:
            read += f" up to {self.duration_s:.1f} s"
        parts = [f"{lead}: {read}"]
        for file in damaged:
            parts += self._file_loss(file)
        if self.expected_messages is not None:
            lost = self.expected_messages - self.messages - self.unreadable_messages
            parts.append(f"{lost} message{'' if lost == 1 else 's'} lost")
        elif damaged and all(f.data_complete for f in damaged):
            parts.append("the data section is complete, so no message was lost")
        elif any(f.unrecoverable_chunk for f in damaged):
            parts.append("the number of messages in the cut chunk and after it is unknown")
        elif damaged:
            parts.append("how many messages followed the cut is unknown")
        if self.unreadable_messages:
            parts.append(f"{self.unreadable_messages} messages without a schema were skipped")
        if self.metadata_missing and damaged:
            parts.append("metadata.yaml is missing")
        return "; ".join(parts)

    def describe(self) -> str:
        """A few human lines: state, files, messages, topics and the warning."""
        state = "complete" if self.complete else "damaged"
        lines = [f"bag {self.path} ({self.storage}, {state}, {_size_text(self.size)})"]
        for file in self.files:
            if file.complete:
                lines.append(f"  {file.path.name}: {_size_text(file.size)}, complete")
            else:
                lines.append(
                    f"  {file.path.name}: {_size_text(file.size)}, cut off: "
                    f"{_size_text(file.lost_bytes)} after offset {file.good_bytes} B lost"
                    + (f" ({file.cut})" if file.cut else "")
                )
        count = f"{self.messages}"
        if not self.complete and self.expected_messages is not None:
            count += f" of {self.expected_messages}"
        line = f"  messages: {count}"
        if self.first_ns is not None and self.last_ns is not None:
            line += (
                f" over {self.duration_s:.1f} s "
                f"(log times {self.first_ns / 1e9:.3f} s to {self.last_ns / 1e9:.3f} s)"
            )
        lines.append(line)
        for topic, count in sorted(self.topics.items()):
            lines.append(f"    {topic}: {count}")
        if self.metadata_missing:
            lines.append("  metadata.yaml: missing")
        if not self.complete:
            lines.append(f"  warning: {self.warning}")
        return "\n".join(lines)


class _ShortError(Exception):
    """A record body ends before one of its fields."""


class _Cursor:
    """Reads little-endian MCAP fields from a record body."""

    def __init__(self, data: bytes | memoryview, pos: int = 0, end: int | None = None) -> None:
        self.data = data
        self.pos = pos
        self.end = len(data) if end is None else end

    def take(self, layout: struct.Struct) -> tuple:
        if self.pos + layout.size > self.end:
            raise _ShortError
        values = layout.unpack_from(self.data, self.pos)
        self.pos += layout.size
        return values

    def blob(self) -> bytes:
        (size,) = self.take(_U32)
        if self.pos + size > self.end:
            raise _ShortError
        value = bytes(self.data[self.pos : self.pos + size])
        self.pos += size
        return value

    def text(self) -> str:
        return self.blob().decode()


@dataclass
class _Channel:
    """A channel with its schema resolved; ``msgtype`` is empty without a schema."""

    topic: str
    msgtype: str
    schema_encoding: str
    msgdef: str
    encoding: str
    metadata: dict[str, str]


OnChannel = Callable[[int, _Channel], None]
OnMessage = Callable[[int, int, bytes], None]


class _Scan:
    """One pass over the records of an MCAP file, up to its first incomplete record."""

    def __init__(
        self, path: Path, on_channel: OnChannel | None = None, on_message: OnMessage | None = None
    ) -> None:
        self.path = path
        self.size = path.stat().st_size
        self.on_channel = on_channel
        self.on_message = on_message
        self.schemas: dict[int, tuple[str, str, str]] = {}
        self.channels: dict[int, _Channel] = {}
        self.messages = 0
        self.unreadable = 0
        self.topics: dict[str, int] = {}
        self.first_ns: int | None = None
        self.last_ns: int | None = None
        self.good = 0
        self.cut = ""
        self.data_end = False
        self.complete = False
        self.cut_chunk_end_ns: int | None = None
        self.unrecoverable_chunk = False

    def result(self) -> FileCheck:
        return FileCheck(
            self.path,
            self.size,
            self.complete,
            self.good,
            self.cut,
            self.data_end,
            self.cut_chunk_end_ns,
            self.unrecoverable_chunk,
        )

    def run(self) -> _Scan:
        with self.path.open("rb") as stream:
            start = stream.read(len(MAGIC))
            if start != MAGIC:
                if not MAGIC.startswith(start):
                    raise ValueError(f"{self.path}: no MCAP magic at the start: not an MCAP file")
                self.cut = "an incomplete MCAP magic" if start else "an empty file"
                return self
            self.good = pos = len(MAGIC)
            while pos < self.size:
                head = stream.read(_RECORD.size)
                if len(head) < _RECORD.size:
                    self.cut = "an incomplete record header"
                    break
                op, length = _RECORD.unpack(head)
                name = _RECORD_NAMES.get(op, f"0x{op:02x}")
                end = pos + _RECORD.size + length
                if op == 0:
                    self.cut = "bytes that are no MCAP record (opcode 0)"
                    break
                if end > self.size:
                    if op == CHUNK:
                        self._chunk(stream.read(), pos + _RECORD.size, length)
                    else:
                        present = _size_text(self.size - pos)
                        self.cut = f"an incomplete {name} record, {present} of {length + 9} B"
                    break
                if op in (SCHEMA, CHANNEL, MESSAGE, CHUNK):
                    body = stream.read(length)
                    if op == CHUNK:
                        if not self._chunk(body, pos + _RECORD.size, length):
                            break
                    elif not self._record(op, body, 0, length):
                        self.cut = f"a malformed {name} record"
                        break
                elif op == FOOTER:
                    self.good = end
                    stream.seek(end)
                    self._end(stream)
                    break
                else:
                    stream.seek(end)
                self.data_end = self.data_end or op == DATA_END
                self.good = pos = end
        return self

    def _end(self, stream) -> None:
        tail = stream.read()
        if tail == MAGIC:
            self.complete = True
        elif MAGIC.startswith(tail):
            missing = len(MAGIC) - len(tail)
            self.cut = f"only the end magic is cut off ({missing} of its {len(MAGIC)} B missing)"
        else:
            self.cut = f"{len(tail)} B after the footer that are no end magic"

    def _record(self, op: int, data: bytes | memoryview, start: int, end: int) -> bool:
        """Handle one complete schema, channel or message record; False if malformed."""
        body = _Cursor(data, start, end)
        try:
            if op == MESSAGE:
                channel_id, _, log_time, _ = body.take(_MESSAGE)
                self._message(channel_id, log_time, data, body.pos, end)
            elif op == SCHEMA:
                (schema_id,) = body.take(_U16)
                self.schemas.setdefault(schema_id, (body.text(), body.text(), body.text()))
            elif op == CHANNEL:
                channel_id, schema_id = body.take(_U16) + body.take(_U16)
                topic, encoding = body.text(), body.text()
                if channel_id not in self.channels:
                    name, schema_encoding, msgdef = self.schemas.get(schema_id, ("", "", ""))
                    metadata = _string_map(body.blob())
                    channel = _Channel(topic, name, schema_encoding, msgdef, encoding, metadata)
                    self.channels[channel_id] = channel
                    if name and self.on_channel is not None:
                        self.on_channel(channel_id, channel)
        except (_ShortError, UnicodeDecodeError):
            return False
        return True

    def _message(self, channel_id: int, log_time: int, data, start: int, end: int) -> None:
        channel = self.channels.get(channel_id)
        if channel is None or not channel.msgtype:
            self.unreadable += 1
            return
        self.messages += 1
        self.topics[channel.topic] = self.topics.get(channel.topic, 0) + 1
        self.first_ns = log_time if self.first_ns is None else min(self.first_ns, log_time)
        self.last_ns = log_time if self.last_ns is None else max(self.last_ns, log_time)
        if self.on_message is not None:
            self.on_message(channel_id, log_time, bytes(data[start:end]))

    def _chunk(self, body: bytes, offset: int, length: int) -> bool:
        """Handle a chunk of ``length`` (B) whose body (maybe cut) starts at file ``offset`` (B).

        Returns False to stop the scan (a cut or malformed chunk).
        """
        partial = len(body) < length
        head = _Cursor(body)
        try:
            _, end_ns, size, crc = head.take(_CHUNK)
            compression = head.text()
            (packed_size,) = head.take(_U64)
        except (_ShortError, UnicodeDecodeError):
            self.cut = "an incomplete chunk header" if partial else "a malformed chunk record"
            return False
        if partial:
            self.cut_chunk_end_ns = end_ns
            if compression:
                self.unrecoverable_chunk = True
                present = f"{_size_text(len(body) + 9)} of {_size_text(length + 9)}"
                self.cut = f"an incomplete {compression}-compressed chunk, {present}, unreadable"
                return False
            records = memoryview(body)[head.pos : head.pos + packed_size]
            done, stop = self._records(records, offset + head.pos)
            self.cut = stop or ("" if done else "the start of a chunk without a complete record")
            return False
        if head.pos + packed_size > len(body):
            self.cut = "a malformed chunk record"
            return False
        try:
            records = decompress(body[head.pos : head.pos + packed_size], compression, size, crc)
        except Exception as error:  # rosbags' ReaderError, or lz4/zstd errors
            self.cut = f"a chunk that does not decompress ({error})"
            return False
        done, stop = self._records(memoryview(records), None)
        if done != len(records):
            self.cut = f"a chunk with {stop}"
            return False
        return True

    def _records(self, data: memoryview, offset: int | None) -> tuple[int, str]:
        """Handle the complete records in ``data``: the end of the last (B) and what stopped.

        With a file ``offset`` (an uncompressed cut chunk), ``good`` advances record by record.
        """
        pos = 0
        while pos < len(data):
            if pos + _RECORD.size > len(data):
                return pos, "an incomplete record header inside a chunk"
            op, length = _RECORD.unpack_from(data, pos)
            name = _RECORD_NAMES.get(op, f"0x{op:02x}")
            end = pos + _RECORD.size + length
            if op == 0:  # e.g. the zeros a crash can leave in place of unwritten data
                return pos, "bytes that are no MCAP record (opcode 0) inside a chunk"
            if end > len(data):
                return pos, f"an incomplete {name} record inside a chunk"
            if op in (SCHEMA, CHANNEL, MESSAGE) and not self._record(
                op, data, pos + _RECORD.size, end
            ):
                return pos, f"a malformed {name} record inside a chunk"
            pos = end
            if offset is not None:
                self.good = offset + pos
        return pos, ""


def _string_map(data: bytes) -> dict[str, str]:
    """An MCAP ``map<string, string>`` body (without its length prefix)."""
    cursor = _Cursor(data)
    result = {}
    try:
        while cursor.pos < cursor.end:
            key = cursor.text()
            result[key] = cursor.text()
    except (_ShortError, UnicodeDecodeError):
        pass
    return result


def _natural_key(path: Path) -> list:
    return [int(part) if part.isdigit() else part for part in re.split(r"(\d+)", path.name)]


def _load_metadata(bag: Path) -> dict | None:
    """The ``rosbag2_bagfile_information`` of ``metadata.yaml`` (None if missing/unreadable)."""
    try:
        info = load_yaml((bag / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    except (OSError, yaml.YAMLError, TypeError, KeyError):
        return None
    return info if isinstance(info, dict) else None


def _storage_files(bag: Path, info: dict | None) -> tuple[str, list[Path]]:
    """Storage identifier and files of ``bag``, from ``metadata.yaml`` or the folder."""
    if info is not None:
        try:
            storage = str(info["storage_identifier"])
            files = [bag / PurePath(name).name for name in info["relative_file_paths"]]
        except (KeyError, TypeError):
            pass
        else:
            if missing := [f.name for f in files if not f.is_file()]:
                raise ValueError(f"{bag}: storage file(s) {missing} of metadata.yaml are missing")
            if files:
                return storage, files
    mcap = sorted(bag.glob("*.mcap"), key=_natural_key)
    packed = sorted(bag.glob("*.mcap.zstd"), key=_natural_key)
    sqlite = sorted(bag.glob("*.db3"), key=_natural_key)
    if mcap or packed:
        return "mcap", mcap or packed
    if sqlite:
        return "sqlite3", sqlite
    raise ValueError(f"{bag}: not a bag folder (no metadata.yaml, no .mcap or .db3 file)")


def _one_line(error: BaseException) -> str:
    return " ".join(str(error).split()) or type(error).__name__


def _footer_ok(path: Path) -> bool:
    """``path`` ends with an MCAP footer record and the end magic."""
    size = path.stat().st_size
    if size < len(MAGIC) + _FOOTER.size + len(MAGIC):
        return False
    with path.open("rb") as stream:
        stream.seek(size - _FOOTER.size - len(MAGIC))
        tail = stream.read()
    op, length, *_ = _FOOTER.unpack_from(tail)
    return op == FOOTER and length == _FOOTER.size - _RECORD.size and tail.endswith(MAGIC)


def _complete_check(bag: Path, storage: str, files: list[Path], info: dict | None) -> BagCheck:
    """The report of a bag rosbags opens (raises what rosbags raises otherwise)."""
    with Reader(bag) as reader:
        topics: dict[str, int] = {}
        for connection in reader.connections:
            topics[connection.topic] = topics.get(connection.topic, 0) + connection.msgcount
        count = reader.message_count
        first = reader.start_time if count else None
        last = reader.end_time - 1 if count else None
    checks = tuple(FileCheck(f, f.stat().st_size, True, f.stat().st_size, "", True) for f in files)
    expected = info.get("message_count") if info else None
    return BagCheck(bag, storage, True, checks, count, topics, first, last, False, expected)


def check(bag: str | Path) -> BagCheck:
    """Report whether a bag is complete and, if damaged, what of it can be read.

    Parameters
    ----------
    bag : str or Path
        The bag folder (holding ``metadata.yaml`` and the storage file(s)), or one ``.mcap``
        file (as ros2 bag and Foxglove take it).

    Returns
    -------
    BagCheck
        Complete, or what its MCAP file(s) hold up to the last complete record.

    Raises
    ------
    ValueError
        Not a bag folder or an ``.mcap`` file; a storage file without MCAP magic; a damaged
        sqlite3 or file-compressed bag (salvage supports MCAP only).
    """
    path = Path(bag)
    single_file = path.is_file() and path.suffix == ".mcap"
    if single_file:
        info, storage, files = None, "mcap", [path]
    elif path.is_dir():
        info = _load_metadata(path)
        storage, files = _storage_files(path, info)
    else:
        state = "another kind of file" if path.exists() else "missing"
        raise ValueError(f"{path}: not a bag folder or an .mcap file ({state})")
    reader_error = ""
    is_mcap = storage == "mcap" and all(f.suffix == ".mcap" for f in files)
    described = info is not None or single_file
    if described and (not is_mcap or all(_footer_ok(f) for f in files)):
        try:
            return _complete_check(path, storage, files, info)
        except Exception as error:  # whatever rosbags raises on a bag it cannot open
            reader_error = _one_line(error)
    elif not described:
        reader_error = "metadata.yaml is missing or unreadable"
    else:
        reader_error = "an MCAP file has no footer and end magic"
    if storage != "mcap":
        raise ValueError(
            f"{files[0]}: {storage} bag that rosbags cannot open ({reader_error}); "
            "salvage supports MCAP only"
        )
    if not is_mcap:
        raise ValueError(
            f"{files[0]}: file-compressed bag that rosbags cannot open ({reader_error}); "
            "salvage supports uncompressed .mcap files only"
        )
    scans = [_Scan(f).run() for f in files]
    topics: dict[str, int] = {}
    for scan in scans:
        for topic, count in scan.topics.items():
            topics[topic] = topics.get(topic, 0) + count
    firsts = [s.first_ns for s in scans if s.first_ns is not None]
    lasts = [s.last_ns for s in scans if s.last_ns is not None]
    expected = info.get("message_count") if info else None
    return BagCheck(
        path,
        storage,
        False,
        tuple(s.result() for s in scans),
        sum(s.messages for s in scans),
        topics,
        min(firsts) if firsts else None,
        max(lasts) if lasts else None,
        metadata_missing=not described,
        expected_messages=expected if isinstance(expected, int) else None,
        unreadable_messages=sum(s.unreadable for s in scans),
        reader_error=reader_error,
    )


def _type_hash(msgtype: str, encoding: str, msgdef: str) -> str | None:
    """RIHS01 hash of ``msgtype`` from its schema text (None if it does not parse)."""
    try:
        if encoding == "ros2msg":
            types = get_types_from_msg(msgdef, msgtype)
        else:
            types = get_types_from_idl(msgdef)
        store = get_typestore(Stores.EMPTY)
        store.register(types)
        return store.hash_rihs01(msgtype)
    except Exception:  # any parse or registration failure of a foreign definition
        pass
    try:
        from ros4crs.interfaces import typestore

        return typestore().hash_rihs01(msgtype)
    except Exception:  # type unknown to the suite's typestore as well
        return None


class _Copier:
    """Adds the channels and writes the messages of scanned files into a rosbags writer."""

    def __init__(self, writer: Writer, hashes: dict[tuple[str, str], str]) -> None:
        self.writer = writer
        self.hashes = hashes
        self.connections: dict[tuple, object] = {}
        self.by_channel: dict[int, object] = {}
        self.cdr: set[int] = set()
        self.path = Path()

    def channel(self, channel_id: int, channel: _Channel) -> None:
        text = channel.metadata.get("offered_qos_profiles", "")
        try:
            qos = parse_qos(text) if text else []
        except Exception:  # QoS in a form rosbags does not parse: not recoverable
            qos = []
        key = (channel.topic, channel.msgtype, channel.encoding, repr(qos))
        if key not in self.connections:
            digest = self.hashes.get((channel.topic, channel.msgtype)) or _type_hash(
                channel.msgtype, channel.schema_encoding, channel.msgdef
            )
            if not digest:
                raise ValueError(
                    f"{self.path}: cannot determine the type hash of {channel.msgtype} "
                    f"({channel.topic}) from its definition"
                )
            self.connections[key] = self.writer.add_connection(
                channel.topic,
                channel.msgtype,
                msgdef=channel.msgdef,
                rihs01=digest,
                serialization_format=channel.encoding,
                offered_qos_profiles=qos,
            )
        self.by_channel[channel_id] = self.connections[key]
        if channel.encoding == "cdr":
            self.cdr.add(channel_id)

    def message(self, channel_id: int, log_time: int, data: bytes) -> None:
        if channel_id in self.cdr and data[:4] == _ZSTD_FRAME:  # CompressionMode.MESSAGE
            data = zstd.decompress(data)
        self.writer.write(self.by_channel[channel_id], log_time, data)

    def copy(self, files: tuple[FileCheck, ...]) -> None:
        for file in files:
            self.path = file.path
            self.by_channel, self.cdr = {}, set()
            _Scan(file.path, self.channel, self.message).run()


def _write_salvage(report: BagCheck, out: Path) -> None:
    """Write the recoverable messages of ``report``'s bag as a new bag at ``out``."""
    if out.exists() or out.is_symlink():
        raise ValueError(f"{out}: exists already; repair writes a new bag")
    if out.resolve().is_relative_to(report.path.resolve()):
        raise ValueError(f"{out}: inside the bag {report.path}; repair never writes into it")
    first = report.files[0].path
    if report.storage != "mcap":
        raise ValueError(f"{first}: {report.storage} storage; salvage supports MCAP only")
    if packed := [f.path for f in report.files if f.path.suffix != ".mcap"]:
        raise ValueError(f"{packed[0]}: file-compressed; salvage supports .mcap files only")
    if not report.messages:
        names = ", ".join(f"{f.path.name} ({_size_text(f.size)})" for f in report.files)
        raise ValueError(
            f"{report.path}: no complete message in {names} (rosbags writes messages in "
            "chunks of 1 MiB: a recorder killed before its first chunk was written leaves none)"
        )
    hashes = {}
    info = _load_metadata(report.path) or {}
    for entry in info.get("topics_with_message_count") or []:
        try:
            meta = entry["topic_metadata"]
            if meta.get("type_description_hash"):
                hashes[(meta["name"], meta["type"])] = meta["type_description_hash"]
        except (KeyError, TypeError, AttributeError):
            continue
    writer = Writer(out, version=9, storage_plugin=StoragePlugin.MCAP)
    writer.open()
    try:
        _Copier(writer, hashes).copy(report.files)
        writer.close()
    except BaseException:
        writer.abort()
        shutil.rmtree(out, ignore_errors=True)  # created by writer.open above
        raise


def repair(bag: str | Path, out: str | Path) -> BagCheck:
    """Write every complete message of ``bag`` into a new complete MCAP bag at ``out``.

    Connections (topic, type and definition, serialization format, offered QoS) and log
    times (ns) are kept, messages are in file order. The input is only read.

    Parameters
    ----------
    bag : str or Path
        The (damaged or complete) bag folder, or ``.mcap`` file.
    out : str or Path
        The new bag folder; must not exist.

    Returns
    -------
    BagCheck
        The report of ``bag``: what was salvaged and what was lost.

    Raises
    ------
    ValueError
        As :func:`check`; a sqlite3 bag; ``out`` exists; no complete message at all.
    """
    report = check(bag)
    _write_salvage(report, Path(out))
    return report


@contextmanager
def open_bag(
    bag: str | Path,
    *,
    on_damage: Callable[[BagCheck], None] | None = None,
    workdir: str | Path | None = None,
) -> Iterator[Reader]:
    """Open a bag with rosbags, repairing a damaged MCAP bag into a temporary copy first.

    Parameters
    ----------
    bag : str or Path
        The bag folder, or ``.mcap`` file.
    on_damage : callable, optional
        Called with the :class:`BagCheck` of a damaged bag; by default a
        :class:`BagDamagedWarning` with its ``warning`` text is emitted.
    workdir : str or Path, optional
        Where the temporary repaired copy goes (the system's temporary directory by default);
        it is deleted on exit.

    Yields
    ------
    rosbags.rosbag2.Reader
        An open reader on the bag, or on its repaired copy.

    Raises
    ------
    ValueError
        As :func:`repair`, for a bag that cannot be read at all.
    """
    report = check(bag)
    if report.complete:
        with Reader(Path(bag)) as reader:
            yield reader
        return
    with tempfile.TemporaryDirectory(prefix="crs-bag-repair-", dir=workdir) as tmp:
        copy = Path(tmp) / (report.path.resolve().name.removesuffix(".mcap") or "bag")
        _write_salvage(report, copy)
        if on_damage is None:
            warnings.warn(report.warning, BagDamagedWarning, stacklevel=3)
        else:
            on_damage(report)
        with Reader(copy) as reader:
            yield reader
