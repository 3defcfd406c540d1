"""rmw_zenoh's wire format (ROS 2 Jazzy, rmw_zenoh 0.2.4 and later): names, keys, tokens, GIDs.

Pure functions, no ROS: what a ROS 2 machine running ``rmw_zenoh_cpp`` puts on Zenoh, built and
read from the rmw_zenoh design document (``docs/design.md``) and sources
(``liveliness_utils.cpp``, ``attachment_helpers.cpp``, ``qos.cpp``, ``rmw_publisher_data.cpp``).

* A topic's samples travel on the key :func:`topic_key`,
  ``<domain>/<topic without the leading and trailing '/'>/<DDS type>/<RIHS01 type hash>``, with
  the CDR bytes (encapsulation header included) as payload and the 33-byte :class:`Attachment`
  (sequence number, source time, publisher GID). A sample without one is dropped by rmw_zenoh.
* Discovery is by liveliness tokens under ``@ros2_lv/<domain>/``: one per node (``NN``,
  :func:`node_token`) and one per publisher (``MP``) or subscription (``MS``)
  (:func:`endpoint_token`), read back with :func:`parse_token`::

    @ros2_lv/<domain>/<zid>/<nid>/<nid>/NN/<enclave>/<namespace>/<node>
    @ros2_lv/<domain>/<zid>/<nid>/<eid>/MP/<enclave>/<namespace>/<node>/<topic>/<type>/<hash>/<qos>

  Names are mangled (:func:`mangle`: ``/`` becomes ``%``), so the root namespace and the default
  enclave ``/`` are ``%``. ``zid`` is the Zenoh session id as Zenoh prints it, ``nid`` and ``eid``
  are per-session counters (decimal), the QoS is rmw_zenoh's compact string (:func:`qos_string`).
* An endpoint's GID (:func:`gid`) is the XXH3-128 hash of its liveliness key: the low 64 bits
  then the high 64 bits, each little endian (the ``xxhash`` package computes XXH3-128).
"""

from __future__ import annotations

import struct
from dataclasses import dataclass

from crs_core.errors import FieldError

__all__ = [
    "ADMIN_SPACE",
    "ATTACHMENT_SIZE",
    "DEFAULT_DEPTH",
    "Attachment",
    "EndpointInfo",
    "NodeInfo",
    "Qos",
    "dds_type_name",
    "demangle",
    "endpoint_token",
    "gid",
    "liveliness_prefix",
    "mangle",
    "node_token",
    "parse_qos",
    "parse_token",
    "qos_string",
    "ros_type_name",
    "topic_key",
    "type_hash",
]

#: The key space of rmw_zenoh's liveliness tokens.
ADMIN_SPACE = "@ros2_lv"
#: Size of the attachment, bytes: int64 sequence, int64 time, length byte 16, 16-byte GID.
ATTACHMENT_SIZE = 33
_ATTACHMENT = struct.Struct("<qqB16s")
_GID_SIZE = 16
#: rmw_zenoh's history depth when a QoS gives none (``qos.cpp``); left out of the QoS string.
DEFAULT_DEPTH = 42
#: Entity kinds of the tokens: node, publisher, subscription, service server, service client.
KINDS = ("NN", "MP", "MS", "SS", "SC")

# rmw's enum values (rmw/types.h), as rmw_zenoh writes them in the QoS string; rmw_zenoh's
# defaults (reliable, volatile, keep-last) are written as empty fields.
_RELIABILITY = {"reliable": 1, "best_effort": 2}
_DURABILITY = {"transient_local": 1, "volatile": 2}
_HISTORY = {"keep_last": 1, "keep_all": 2}
_DEFAULTS = {"reliability": "reliable", "durability": "volatile", "history": "keep_last"}


@dataclass(frozen=True)
class Qos:
    """The QoS an endpoint announces (the part rmw_zenoh acts on).

    Attributes
    ----------
    reliability : {"reliable", "best_effort"}
    durability : {"volatile", "transient_local"}
    history : {"keep_last", "keep_all"}
    depth : int
        History depth, messages (> 0).

    Deadline, lifespan and liveliness are always announced as rmw_zenoh's defaults (infinite,
    automatic); when read they are ignored.
    """

    reliability: str = "reliable"
    durability: str = "volatile"
    history: str = "keep_last"
    depth: int = DEFAULT_DEPTH

    def __post_init__(self) -> None:
        for name, values in (
            ("reliability", _RELIABILITY),
            ("durability", _DURABILITY),
            ("history", _HISTORY),
        ):
            if getattr(self, name) not in values:
                raise FieldError(f"qos.{name}", f"one of {', '.join(values)}, got {self!r}")
        if self.depth <= 0:
            raise FieldError("qos.depth", f"must be > 0, got {self.depth}")


def qos_string(qos: Qos) -> str:
    """rmw_zenoh's compact QoS string: ``reliability:durability:history,depth:deadline_s,
    deadline_ns:lifespan_s,lifespan_ns:liveliness,lease_s,lease_ns``, each field empty when it is
    rmw_zenoh's default (``::,7:,:,:,,`` is reliable, volatile, keep-last 7)."""

    def field(name: str, values: dict[str, int]) -> str:
        value = getattr(qos, name)
        return "" if value == _DEFAULTS[name] else str(values[value])

    depth = "" if qos.depth == DEFAULT_DEPTH else str(qos.depth)
    reliability = field("reliability", _RELIABILITY)
    durability = field("durability", _DURABILITY)
    history = field("history", _HISTORY)
    return f"{reliability}:{durability}:{history},{depth}:,:,:,,"


def parse_qos(text: str) -> Qos:
    """The :class:`Qos` of a QoS string (:func:`qos_string`); ``FieldError`` naming ``qos`` if
    it is malformed. rmw's ``system default`` values read as rmw_zenoh's defaults."""
    parts = text.split(":")
    if len(parts) != 6 or [len(p.split(",")) for p in parts[2:]] != [2, 2, 2, 3]:
        raise FieldError("qos", f"not an rmw_zenoh QoS string: {text!r}")
    history, depth = parts[2].split(",")

    def policy(name: str, value: str, values: dict[str, int]) -> str:
        if value in ("", "0"):  # empty: rmw_zenoh's default; 0: the system default
            return _DEFAULTS[name]
        for key, number in values.items():
            if value == str(number):
                return key
        raise FieldError(f"qos.{name}", f"unsupported value {value!r} in {text!r}")

    if depth and not depth.isdigit():
        raise FieldError("qos.depth", f"not a number: {text!r}")
    return Qos(
        reliability=policy("reliability", parts[0], _RELIABILITY),
        durability=policy("durability", parts[1], _DURABILITY),
        history=policy("history", history, _HISTORY),
        depth=int(depth) if depth and int(depth) > 0 else DEFAULT_DEPTH,
    )


def dds_type_name(msgtype: str) -> str:
    """The DDS type name rmw_zenoh puts in keys: ``sensor_msgs/msg/Imu`` ->
    ``sensor_msgs::msg::dds_::Imu_``."""
    package, kind, name = _split_type(msgtype)
    return f"{package}::{kind}::dds_::{name}_"


def ros_type_name(dds_name: str) -> str:
    """The inverse of :func:`dds_type_name`: ``sensor_msgs::msg::dds_::Imu_`` ->
    ``sensor_msgs/msg/Imu``; ``FieldError`` naming ``type`` for anything else."""
    parts = dds_name.split("::")
    if len(parts) != 4 or parts[2] != "dds_" or not parts[3].endswith("_") or not all(parts):
        raise FieldError("type", f"not a DDS type name: {dds_name!r}")
    return f"{parts[0]}/{parts[1]}/{parts[3][:-1]}"


def _split_type(msgtype: str) -> tuple[str, str, str]:
    parts = msgtype.split("/")
    if len(parts) != 3 or not all(parts):
        raise FieldError("type", f"expected pkg/msg/Type, got {msgtype!r}")
    return parts[0], parts[1], parts[2]


def type_hash(msgtype: str) -> str:
    """The REP-2016 type hash of ``msgtype`` (``RIHS01_<64 hex>``), as rosidl computes it, from
    the suite's typestore (:func:`ros4crs.interfaces.typestore`); ``KeyError`` for a type it
    does not know."""
    from ros4crs.interfaces import typestore

    return typestore().hash_rihs01(msgtype)


def topic_key(domain: int, topic: str, msgtype: str, hash_: str | None = None) -> str:
    """The Zenoh key of ``topic``'s samples: ``<domain>/<topic>/<DDS type>/<type hash>``, the
    topic without its leading and trailing ``/``. ``hash_`` defaults to :func:`type_hash`."""
    name = topic[1:] if topic.startswith("/") else topic
    name = name[:-1] if name.endswith("/") else name
    return f"{domain}/{name}/{dds_type_name(msgtype)}/{hash_ or type_hash(msgtype)}"


def liveliness_prefix(domain: int) -> str:
    """The key expression of every token of ``domain``: ``@ros2_lv/<domain>/**``."""
    return f"{ADMIN_SPACE}/{domain}/**"


def mangle(name: str) -> str:
    """A name as one chunk of a key: every ``/`` becomes ``%``; an empty name is ``%``."""
    return name.replace("/", "%") if name else "%"


def demangle(chunk: str) -> str:
    """The inverse of :func:`mangle` (``%`` -> ``/``)."""
    return chunk.replace("%", "/")


def gid(token: str) -> bytes:
    """An endpoint's 16-byte GID as rmw_zenoh derives it: XXH3-128 (seed 0) of its liveliness
    key, the low 64 bits then the high 64 bits, each little endian."""
    import xxhash

    return xxhash.xxh3_128_intdigest(token.encode()).to_bytes(_GID_SIZE, "little")


def node_token(
    domain: int, zid: str, nid: int, namespace: str, name: str, enclave: str = "/"
) -> str:
    """A node's liveliness key (``NN``); ``namespace`` is ``/`` for the root namespace."""
    node = f"{mangle(enclave)}/{mangle(namespace)}/{mangle(name)}"
    return f"{ADMIN_SPACE}/{domain}/{zid}/{nid}/{nid}/NN/{node}"


def endpoint_token(
    kind: str,
    domain: int,
    zid: str,
    nid: int,
    eid: int,
    namespace: str,
    node: str,
    topic: str,
    msgtype: str,
    qos: Qos,
    enclave: str = "/",
    hash_: str | None = None,
) -> str:
    """A publisher's (``MP``) or subscription's (``MS``) liveliness key. ``topic`` is the fully
    qualified name (``/car1/sensors/imu``), ``msgtype`` ``pkg/msg/Type``; ``hash_`` defaults to
    :func:`type_hash`."""
    if kind not in KINDS[1:]:
        raise FieldError("kind", f"one of {', '.join(KINDS[1:])}, got {kind!r}")
    owner = f"{mangle(enclave)}/{mangle(namespace)}/{mangle(node)}"
    what = f"{mangle(topic)}/{dds_type_name(msgtype)}/{hash_ or type_hash(msgtype)}"
    return f"{ADMIN_SPACE}/{domain}/{zid}/{nid}/{eid}/{kind}/{owner}/{what}/{qos_string(qos)}"


@dataclass(frozen=True)
class NodeInfo:
    """A node as its token (``NN``) announces it."""

    domain: int
    zid: str
    nid: str
    enclave: str
    namespace: str
    name: str

    @property
    def full_name(self) -> str:
        """``/namespace/name``."""
        return f"{self.namespace.rstrip('/')}/{self.name}"


@dataclass(frozen=True)
class EndpointInfo:
    """A publisher, subscription, service or client as its token announces it.

    ``msgtype`` is ``pkg/msg/Type``; :meth:`key` is the key its samples travel on.
    """

    domain: int
    zid: str
    nid: str
    eid: str
    kind: str
    enclave: str
    namespace: str
    node: str
    topic: str
    msgtype: str
    type_hash: str
    qos: Qos

    def key(self) -> str:
        """The key of this endpoint's samples (:func:`topic_key` with the announced hash)."""
        return topic_key(self.domain, self.topic, self.msgtype, self.type_hash)


def parse_token(key: str) -> NodeInfo | EndpointInfo:
    """The node or endpoint a liveliness key announces; ``FieldError`` naming ``token`` for a
    key that is not one of rmw_zenoh's."""
    parts = str(key).split("/")
    if len(parts) < 9 or parts[0] != ADMIN_SPACE or not all(parts[:9]):
        raise FieldError("token", f"not an rmw_zenoh liveliness token: {key!r}")
    domain, zid, nid, eid, kind, enclave, namespace, name = parts[1:9]
    if not domain.isdigit() or kind not in KINDS:
        raise FieldError("token", f"bad domain or entity kind in {key!r}")
    owner = (demangle(enclave), demangle(namespace), demangle(name))
    if kind == "NN":
        if len(parts) != 9:
            raise FieldError("token", f"a node token has 9 chunks: {key!r}")
        return NodeInfo(int(domain), zid, nid, *owner)
    if len(parts) != 13 or not all(parts[9:12]):
        raise FieldError("token", f"an endpoint token has 13 chunks: {key!r}")
    topic, dds_name, hash_, qos = parts[9:13]
    return EndpointInfo(
        int(domain),
        zid,
        nid,
        eid,
        kind,
        *owner,
        topic=demangle(topic),
        msgtype=ros_type_name(dds_name),
        type_hash=hash_,
        qos=parse_qos(qos),
    )


@dataclass(frozen=True)
class Attachment:
    """The attachment of every sample (rmw_zenoh 0.2.4 and later).

    Attributes
    ----------
    sequence : int
        The publisher's sequence number (from 1).
    source_timestamp_ns : int
        Publication time, ns since the Unix epoch (system clock of the publishing machine).
    gid : bytes
        The publisher's 16-byte GID (:func:`gid`).
    """

    sequence: int
    source_timestamp_ns: int
    gid: bytes

    def encode(self) -> bytes:
        """33 bytes: int64 sequence (LE), int64 time (LE), ``0x10``, the GID."""
        if len(self.gid) != _GID_SIZE:
            raise FieldError("attachment.gid", f"must be 16 bytes, got {len(self.gid)}")
        return _ATTACHMENT.pack(self.sequence, self.source_timestamp_ns, _GID_SIZE, self.gid)

    @classmethod
    def decode(cls, data: bytes) -> Attachment:
        """The attachment in ``data``; ``FieldError`` naming ``attachment`` if it is not one."""
        if len(data) != ATTACHMENT_SIZE:
            raise FieldError("attachment", f"expected {ATTACHMENT_SIZE} bytes, got {len(data)}")
        sequence, stamp, length, gid_ = _ATTACHMENT.unpack(data)
        if length != _GID_SIZE:
            raise FieldError("attachment", f"GID length byte must be 16, got {length}")
        return cls(sequence, stamp, gid_)
