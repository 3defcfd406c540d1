"""Zenoh link node: this machine's ROS 2 topics to and from other machines, in rmw_zenoh's format.

One per machine (``python -m ros4crs.zenoh_link_node --ros-args -p connect:=tcp/10.0.0.1:7447``),
node ``zenoh_link`` in the global namespace. It joins a Zenoh network (:mod:`ros4crs.zenoh.session`)
and speaks rmw_zenoh's wire format (:mod:`ros4crs.zenoh.wire`), so another machine running this
node, or a stock ROS 2 machine running ``rmw_zenoh_cpp``, sees this machine's topics and this
machine sees theirs; discovery is dynamic on both sides, like rmw_zenoh's.

* Interest: every 0.25 s the local ROS graph is polled for topics (matching ``topics``) with a
  subscription other than this node's; each gets an ``MS`` token, as rmw_zenoh declares one per
  subscription, so far machines see what this one listens to (and withdrawn when the last local
  subscription goes).
* Export: in the same poll, topics with a publisher other than this node; a transient-local one
  is exported always (a far subscriber joining late gets its history), a volatile one only while
  another session has an ``MS`` token for it (a far subscriber): a topic nobody far away listens
  to is not subscribed here, so its publisher sees no subscriber (a controller then builds no
  plan for a viewer that is not there) and nothing crosses the network. An exported topic gets a
  raw subscription (CDR bytes, never deserialized), with the publishers' reliability and
  durability, and its samples are put on Zenoh at the topic's key with rmw_zenoh's attachment
  (sequence number, source time, GID). The node declares its ``NN`` token and an ``MP`` token
  per exported topic.
  Transient-local topics go through a Zenoh advanced publisher with a cache (the last
  ``LOG_DEPTH`` samples; ROS does not report a remote publisher's depth) so that a far
  subscriber joining late gets the history; volatile ones through a plain publisher of
  ``STREAM_QOS.depth``. Congestion control: drop (block only for
  keep-all, as rmw_zenoh). A topic whose publishers are all gone, or (volatile) whose far
  subscribers are, is withdrawn.
* Import: the node follows the liveliness tokens of ``domain`` (with history); for each
  publisher token (``MP``) of another Zenoh session whose topic matches ``topics`` it publishes
  the samples on that topic locally, raw, with the announced QoS (an advanced subscriber with
  history for transient-local ones). When the far publishers' tokens go, the Zenoh subscriber
  goes and the local publisher stays; a far node that restarts is found again by its new tokens.
* No loops: this node's own publishers are never exported, its Zenoh subscribers take no
  samples of its own session (``Locality.REMOTE``), and on a topic that is both imported and
  exported the export drops the payloads it has just published itself (rclpy gives no
  publisher GID to a subscription callback to tell them apart).
* Validation: an imported sample without an attachment, with a malformed one, on a key whose
  type hash differs from the local type's, or whose CDR does not deserialize (rosbags) is
  dropped and counted by reason (``no_attachment``, ``bad_attachment``, ``type_hash``, ``cdr``),
  with a warning naming topic and reason (at most one a second per topic).

Parameters: ``mode`` (router | peer | client), ``listen`` and ``connect`` (comma-separated Zenoh
endpoints, ``tcp/10.0.0.1:7447``), ``config_file`` (a Zenoh JSON5 configuration; '' none),
``domain`` (the domain id in keys and tokens; default ``ROS_DOMAIN_ID`` or 0: it may differ from
the local ROS domain), ``topics`` (comma-separated topic names or prefixes to carry; '' all;
``/rosout`` and ``/parameter_events`` never).

Topics: publishes ``zenoh_link/diagnostics`` (``std_msgs/String``, JSON, 1 Hz: per direction
and topic the samples and bytes forwarded and the drops by reason, and the far Zenoh sessions
with their node names); logs one summary line when it stops.
"""

from __future__ import annotations

import collections
import json
import os
import queue
import threading
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

from crs_core.errors import FieldError
from ros4crs.interfaces import typestore
from ros4crs.node_support import (
    LOG_DEPTH,
    STREAM_QOS,
    declare,
    file_or_empty,
    in_range,
    message_class,
    one_of,
    run,
    throttled_warning,
    topic_selected,
)
from ros4crs.zenoh import wire
from ros4crs.zenoh.session import MODES, ZenohSettings, open_session

#: Seconds between polls of the local ROS graph and of the queued liveliness changes.
DISCOVERY_PERIOD = 0.25
#: Reasons an imported sample is dropped.
DROP_REASONS = ("no_attachment", "bad_attachment", "type_hash", "cdr")
#: Heartbeat period of a reliable transient-local publisher's miss detection, s (rmw_zenoh's).
HEARTBEAT_PERIOD = 0.5


def _default_domain() -> int:
    value = os.environ.get("ROS_DOMAIN_ID", "")
    return int(value) if value.isdigit() else 0


def _split(text: str) -> tuple[str, ...]:
    return tuple(part.strip() for part in text.split(",") if part.strip())


class Counts:
    """What went through one topic in one direction (samples, bytes, drops by reason)."""

    def __init__(self) -> None:
        self.samples = 0
        self.bytes = 0
        self.dropped: collections.Counter[str] = collections.Counter()

    def as_dict(self) -> dict[str, Any]:
        return {"samples": self.samples, "bytes": self.bytes, "dropped": dict(self.dropped)}


class EchoFilter:
    """The payloads this node published locally on one topic, recently (the last ``size``):
    the export of the same topic drops them, once each, instead of sending them back. Added to
    from Zenoh's threads, taken from the executor's."""

    def __init__(self, size: int) -> None:
        self._order: collections.deque[bytes] = collections.deque()
        self._count: collections.Counter[bytes] = collections.Counter()
        self._size = size
        self._lock = threading.Lock()

    def add(self, data: bytes) -> None:
        with self._lock:
            self._order.append(data)
            self._count[data] += 1
            if len(self._order) > self._size:
                self._forget(self._order.popleft())

    def take(self, data: bytes) -> bool:
        """Whether ``data`` is one of them (and forget it)."""
        with self._lock:
            if not self._count.get(data):
                return False
            self._forget(data)
            self._order.remove(data)
            return True

    def _forget(self, data: bytes) -> None:
        self._count[data] -= 1
        if self._count[data] <= 0:
            del self._count[data]


def _endpoint_qos(endpoints: list, all_transient: bool) -> wire.Qos:
    """The QoS to announce for local endpoints (rclpy ``TopicEndpointInfo``): best effort if
    one is, transient-local if all are (publishers: ``all_transient``) or one is
    (subscriptions), with the depth the link uses for it."""
    best_effort = any(e.qos_profile.reliability == ReliabilityPolicy.BEST_EFFORT for e in endpoints)
    durable = [e.qos_profile.durability == DurabilityPolicy.TRANSIENT_LOCAL for e in endpoints]
    transient = all(durable) if all_transient else any(durable)
    return wire.Qos(
        reliability="best_effort" if best_effort else "reliable",
        durability="transient_local" if transient else "volatile",
        depth=LOG_DEPTH if transient else STREAM_QOS.depth,
    )


def _profile(qos: wire.Qos) -> QoSProfile:
    """The rclpy QoS of an announced QoS."""
    return QoSProfile(
        depth=qos.depth,
        history=HistoryPolicy.KEEP_ALL if qos.history == "keep_all" else HistoryPolicy.KEEP_LAST,
        reliability=ReliabilityPolicy.BEST_EFFORT
        if qos.reliability == "best_effort"
        else ReliabilityPolicy.RELIABLE,
        durability=DurabilityPolicy.TRANSIENT_LOCAL
        if qos.durability == "transient_local"
        else DurabilityPolicy.VOLATILE,
    )


class ZenohLinkNode(Node):
    """Carries ROS 2 topics between this machine and others over Zenoh (rmw_zenoh's format)."""

    def __init__(self, **node_options: Any) -> None:
        super().__init__("zenoh_link", **node_options)
        mode = declare(self, "mode", "peer", "router, peer or client", one_of(*MODES))
        listen = declare(self, "listen", "", "comma-separated Zenoh endpoints to listen on")
        connect = declare(self, "connect", "", "comma-separated Zenoh endpoints to connect to")
        config_file = declare(
            self, "config_file", "", "Zenoh JSON5 configuration; empty: none", file_or_empty
        )
        self.domain = declare(
            self,
            "domain",
            _default_domain(),
            "domain id in the Zenoh keys and tokens (default ROS_DOMAIN_ID or 0)",
            in_range(0, 232),
        )
        self.patterns = _split(
            declare(self, "topics", "", "comma-separated topic names or prefixes; empty: all")
        )
        settings = ZenohSettings(
            mode, _split(listen), _split(connect), Path(config_file) if config_file else None
        )
        self.session = open_session(settings)
        self.zid = str(self.session.zid())
        self._store = typestore()
        self._warn = throttled_warning(self)
        self._entity_ids = iter(range(1, 1 << 62))
        self._warned_types: set[str] = set()
        self.exports: dict[str, _Export] = {}
        self.imports: dict[str, _Import] = {}  # by Zenoh key
        self.import_counts: dict[str, Counts] = {}  # by topic: kept across far restarts
        self._local_publishers: dict[str, Any] = {}  # by topic: kept while the node runs
        self._echo: dict[str, EchoFilter] = {}  # by topic
        self.far_nodes: dict[str, set[str]] = collections.defaultdict(set)  # zid -> node names
        self._far_tokens: set[str] = set()
        #: Far subscriptions (``MS`` tokens of other sessions), by topic.
        self.far_subscriptions: dict[str, set[str]] = collections.defaultdict(set)
        #: This machine's subscriptions announced as ``MS`` tokens, by topic.
        self.interests: dict[str, Any] = {}
        self._node_token = self.session.liveliness().declare_token(
            wire.node_token(self.domain, self.zid, 0, self.get_namespace(), self.get_name())
        )
        self._changes: queue.SimpleQueue = queue.SimpleQueue()
        self._liveliness = self.session.liveliness().declare_subscriber(
            wire.liveliness_prefix(self.domain), self._changes.put, history=True
        )
        from std_msgs.msg import String

        self._diagnostics = self.create_publisher(String, "zenoh_link/diagnostics", 10)
        self.create_timer(1.0, self._publish_diagnostics)
        self.create_timer(DISCOVERY_PERIOD, self._discover)
        self.get_logger().info(
            f"Zenoh session {self.zid} ({mode}; listen {list(settings.listen)}, connect "
            f"{list(settings.connect)}), domain {self.domain}, topics "
            f"{list(self.patterns) or 'all'}"
        )

    # ------------------------------------------------------------------ discovery
    def _known_type(self, msgtype: str) -> bool:
        """Whether rclpy and the typestore both know ``msgtype`` (warn once if not)."""
        if msgtype in self._warned_types:
            return False
        try:
            message_class(msgtype)
            wire.type_hash(msgtype)
        except (ImportError, AttributeError, KeyError, ValueError) as error:
            self._warned_types.add(msgtype)
            self.get_logger().warning(f"cannot carry {msgtype}: unknown type ({error})")
            return False
        return True

    def _discover(self) -> None:
        self._take_liveliness_changes()
        self._update_graph()

    def _update_graph(self) -> None:
        """Announce the local subscriptions, export what far subscribers want (module doc)."""
        published, listened, local_publishers = set(), set(), set()
        for topic, types in self.get_topic_names_and_types():
            if not topic_selected(topic, self.patterns):
                continue
            publishers = self._others(self.get_publishers_info_by_topic(topic))
            subscriptions = self._others(self.get_subscriptions_info_by_topic(topic))
            # the type is checked once, when a topic is first announced or exported
            if subscriptions and (topic in self.interests or self._known_type(types[0])):
                listened.add(topic)
                if topic not in self.interests:
                    self.interests[topic] = self._interest(topic, types[0], subscriptions)
            if not publishers:
                continue
            local_publishers.add(topic)
            qos = _endpoint_qos(publishers, all_transient=True)
            if qos.durability == "volatile" and not self.far_subscriptions.get(topic):
                continue  # nobody far away listens
            if topic not in self.exports:
                if not self._known_type(types[0]):
                    continue
                self.exports[topic] = self._export(topic, types[0], qos)
            published.add(topic)
        for topic in set(self.interests) - listened:
            self.interests.pop(topic).undeclare()
        for topic in set(self.exports) - published:
            self.exports.pop(topic).close(self)
            why = "far subscriber" if topic in local_publishers else "local publisher"
            self.get_logger().info(f"export of {topic} withdrawn (no {why})")

    def _others(self, endpoints: list) -> list:
        """The endpoints (rclpy ``TopicEndpointInfo``) of other nodes than this one."""
        me = (self.get_name(), self.get_namespace())
        return [e for e in endpoints if (e.node_name, e.node_namespace) != me]

    def _interest(self, topic: str, msgtype: str, subscriptions: list) -> Any:
        """The ``MS`` token announcing this machine's subscriptions of ``topic``."""
        token = wire.endpoint_token(
            "MS", self.domain, self.zid, 0, next(self._entity_ids), self.get_namespace(),
            self.get_name(), topic, msgtype, _endpoint_qos(subscriptions, all_transient=False),
        )  # fmt: skip
        return self.session.liveliness().declare_token(token)

    def _export(self, topic: str, msgtype: str, qos: wire.Qos) -> _Export:
        export = _Export(self, topic, msgtype, qos, next(self._entity_ids))
        self.get_logger().info(f"exporting {topic} ({msgtype}) on {export.key}")
        return export

    def _take_liveliness_changes(self) -> None:
        import zenoh

        while True:
            try:
                sample = self._changes.get_nowait()
            except queue.Empty:
                return
            key = str(sample.key_expr)
            try:
                entity = wire.parse_token(key)
            except FieldError as error:
                self._warn(f"ignored a liveliness token: {error}")
                continue
            if entity.zid == self.zid:
                continue
            alive = sample.kind == zenoh.SampleKind.PUT
            if isinstance(entity, wire.NodeInfo):
                names = self.far_nodes[entity.zid]
                (names.add if alive else names.discard)(entity.full_name)
            elif entity.kind == "MP" and topic_selected(entity.topic, self.patterns):
                self._far_publisher(key, entity, alive)
            elif entity.kind == "MS" and topic_selected(entity.topic, self.patterns):
                tokens = self.far_subscriptions[entity.topic]
                (tokens.add if alive else tokens.discard)(key)

    def _far_publisher(self, token: str, entity: wire.EndpointInfo, alive: bool) -> None:
        key = entity.key()
        current = self.imports.get(key)
        if alive and token not in self._far_tokens:
            self._far_tokens.add(token)
            if current is None and self._known_type(entity.msgtype):
                self.imports[key] = _Import(self, entity)
                self.get_logger().info(f"importing {entity.topic} from {entity.zid} on {key}")
            elif current is not None:
                current.tokens.add(token)
        elif not alive and token in self._far_tokens:
            self._far_tokens.discard(token)
            if current is not None:
                current.tokens.discard(token)
                if not current.tokens:
                    del self.imports[key]
                    current.close()
                    self.get_logger().info(f"far publishers of {entity.topic} gone ({key})")

    def local_publisher(self, topic: str, msgtype: str, qos: wire.Qos) -> Any:
        """The raw publisher of an imported topic (created once; reused when far publishers
        come back) and the :class:`EchoFilter` of the topic."""
        if topic not in self._local_publishers:
            self._local_publishers[topic] = self.create_publisher(
                message_class(msgtype), topic, _profile(qos)
            )
            self._echo[topic] = EchoFilter(2 * max(qos.depth, STREAM_QOS.depth))
        return self._local_publishers[topic], self._echo[topic]

    def echo_filter(self, topic: str) -> EchoFilter | None:
        return self._echo.get(topic)

    # ------------------------------------------------------------------ diagnostics
    def report(self) -> dict[str, Any]:
        """The diagnostics: counts per direction and topic, the far sessions' node names."""
        return {
            "zid": self.zid,
            "domain": self.domain,
            "export": {t: e.counts.as_dict() for t, e in self.exports.items()},
            "import": {t: c.as_dict() for t, c in self.import_counts.items()},
            "far_sessions": {z: sorted(n) for z, n in self.far_nodes.items() if n},
        }

    def _publish_diagnostics(self) -> None:
        from std_msgs.msg import String

        self._diagnostics.publish(String(data=json.dumps(self.report(), sort_keys=True)))

    def destroy_node(self) -> None:
        report = self.report()
        self.session.close()  # no Zenoh callback publishes from here on
        exported = sum(c["samples"] for c in report["export"].values())
        imported = sum(c["samples"] for c in report["import"].values())
        dropped = sum(sum(c["dropped"].values()) for c in report["import"].values())
        self.get_logger().info(
            f"stopped: exported {exported} samples on {len(report['export'])} topics, imported "
            f"{imported} on {len(report['import'])} topics, dropped {dropped}; far sessions "
            f"{report['far_sessions']}"
        )
        super().destroy_node()


class _Export:
    """One local topic put on Zenoh: its raw subscription, Zenoh publisher and ``MP`` token."""

    def __init__(self, node: ZenohLinkNode, topic: str, msgtype: str, qos: wire.Qos, eid: int):
        import zenoh
        from zenoh import ext

        self.topic, self.counts = topic, Counts()
        hash_ = wire.type_hash(msgtype)
        self.key = wire.topic_key(node.domain, topic, msgtype, hash_)
        token = wire.endpoint_token(
            "MP", node.domain, node.zid, 0, eid, node.get_namespace(), node.get_name(),
            topic, msgtype, qos, hash_=hash_,
        )  # fmt: skip
        self._gid = wire.gid(token)
        self._sequence = 0
        reliable = qos.reliability == "reliable"
        options: dict[str, Any] = {
            "congestion_control": zenoh.CongestionControl.BLOCK
            if reliable and qos.history == "keep_all"
            else zenoh.CongestionControl.DROP,
            "reliability": zenoh.Reliability.RELIABLE
            if reliable
            else zenoh.Reliability.BEST_EFFORT,
            "allowed_destination": zenoh.Locality.REMOTE,
        }
        if qos.durability == "transient_local":
            self._publisher = ext.declare_advanced_publisher(
                node.session,
                self.key,
                cache=ext.CacheConfig(qos.depth),
                sample_miss_detection=ext.MissDetectionConfig(
                    heartbeat=None, sporadic_heartbeat=HEARTBEAT_PERIOD
                )
                if reliable
                else None,
                publisher_detection=True,
                **options,
            )
        else:
            self._publisher = node.session.declare_publisher(self.key, **options)
        self._echo = node.echo_filter
        self._subscription = node.create_subscription(
            message_class(msgtype), topic, self._forward, _profile(qos), raw=True
        )
        self._token = node.session.liveliness().declare_token(token)

    def _forward(self, data: bytes) -> None:
        echo = self._echo(self.topic)
        if echo is not None and echo.take(data):
            return  # published here by the import of the same topic
        self._sequence += 1
        attachment = wire.Attachment(self._sequence, time.time_ns(), self._gid).encode()
        self._publisher.put(data, attachment=attachment)
        self.counts.samples += 1
        self.counts.bytes += len(data)

    def close(self, node: ZenohLinkNode) -> None:
        node.destroy_subscription(self._subscription)
        self._token.undeclare()
        self._publisher.undeclare()


class _Import:
    """The samples of far publishers on one Zenoh key, validated and published locally."""

    def __init__(self, node: ZenohLinkNode, entity: wire.EndpointInfo) -> None:
        import zenoh
        from zenoh import ext

        self.topic, self.msgtype = entity.topic, entity.msgtype
        self.counts = node.import_counts.setdefault(entity.topic, Counts())
        self.tokens: set[str] = set()
        self._hash_ok = entity.type_hash == wire.type_hash(entity.msgtype)
        self._deserialize = node._store.deserialize_cdr
        self._warn: Callable[[str], None] = throttled_warning(node)
        self._publisher, self._echo = node.local_publisher(entity.topic, entity.msgtype, entity.qos)
        key = entity.key()
        if entity.qos.durability == "transient_local":
            self._subscriber = ext.declare_advanced_subscriber(
                node.session,
                key,
                self._on_sample,
                allowed_origin=zenoh.Locality.REMOTE,
                history=ext.HistoryConfig(
                    detect_late_publishers=True, max_samples=entity.qos.depth
                ),
                recovery=ext.RecoveryConfig(periodic_queries=None, heartbeat=True)
                if entity.qos.reliability == "reliable"
                else None,
                subscriber_detection=True,
            )
        else:
            self._subscriber = node.session.declare_subscriber(
                key, self._on_sample, allowed_origin=zenoh.Locality.REMOTE
            )

    def _drop(self, reason: str, detail: str = "") -> None:
        self.counts.dropped[reason] += 1
        self._warn(f"dropped a sample on {self.topic}: {reason}{detail}")

    def _on_sample(self, sample: Any) -> None:
        """A Zenoh thread: validate, then publish the CDR bytes locally."""
        attachment = sample.attachment
        if attachment is None:
            return self._drop("no_attachment")
        try:
            wire.Attachment.decode(attachment.to_bytes())
        except FieldError as error:
            return self._drop("bad_attachment", f" ({error})")
        if not self._hash_ok:
            return self._drop("type_hash", f" ({sample.key_expr} is not the local type)")
        data = sample.payload.to_bytes()
        try:
            self._deserialize(data, self.msgtype)
        except Exception as error:  # rosbags raises what the bytes make it raise
            return self._drop("cdr", f" ({type(error).__name__})")
        self._echo.add(data)
        self._publisher.publish(data)
        self.counts.samples += 1
        self.counts.bytes += len(data)
        return None

    def close(self) -> None:
        self._subscriber.undeclare()


def zenoh_link() -> ZenohLinkNode:
    """The node (named as :func:`~ros4crs.node_support.run` names it in a start-up error)."""
    return ZenohLinkNode()


def main(argv: Sequence[str] | None = None) -> int:
    return run(zenoh_link, argv)


if __name__ == "__main__":
    raise SystemExit(main())
