"""Recorder node: chosen topics to a ROS 2 bag (MCAP by default) via rosbags.

Subscribes raw (no deserialization) to every topic that matches ``topics`` (comma-separated
names or prefixes; relative names resolve in the node's namespace; empty = everything), picking
up topics as their first publisher appears (transient-local topics, such as the estimates and
the commands, with the messages published before it joined; a topic seen only through its
subscriptions waits for a publisher, whose QoS says how to subscribe). Each message is written
with its receive time on the node's clock (``/clock`` with ``use_sim_time``). The callbacks only
queue the messages; a thread of its own writes them, so a slow disk never blocks the
subscriptions. The bag is closed cleanly on shutdown.

Parameters: ``output`` (bag directory, must not exist), ``topics``, ``storage`` (mcap | sqlite3),
``flush_period`` (s between writes to disk: what a killed recorder loses at most).
"""

from __future__ import annotations

import queue
import threading
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile
from rosbags.rosbag2 import StoragePlugin, Writer
from rosbags.rosbag2.storage_mcap import McapWriter

from ros4crs.interfaces import typestore
from ros4crs.node_support import (
    LOG_QOS,
    STREAM_QOS,
    declare,
    message_class,
    one_of,
    positive,
    run,
    topic_selected,
)


def _new_folder(path: str) -> str | None:
    """A :func:`declare` check: a folder that can be created (not there yet, parent exists)."""
    if not path:
        return "must name the bag folder to create"
    if Path(path).exists():
        return "exists already (a bag goes to a new folder)"
    if not Path(path).absolute().parent.is_dir():
        return "its parent folder does not exist"
    return None


class RecorderNode(Node):
    """Writes raw CDR messages of matching topics into a bag."""

    def __init__(self, **node_options: Any) -> None:
        super().__init__("recorder", **node_options)
        output = Path(declare(self, "output", "bag", "bag directory to create", _new_folder))
        patterns = declare(self, "topics", "", "comma-separated topic names or prefixes")
        plugins = {"mcap": StoragePlugin.MCAP, "sqlite3": StoragePlugin.SQLITE3}
        storage = declare(self, "storage", "mcap", "mcap or sqlite3", one_of(*plugins))
        flush_period = declare(
            self, "flush_period", 1.0, "s between writes of the pending data to disk", positive
        )
        self.patterns = [self._resolve(p.strip()) for p in patterns.split(",") if p.strip()]
        self.writer = Writer(output, version=9, storage_plugin=plugins[storage])
        self.writer.open()
        # the callbacks only queue; a thread of its own writes (and waits for the disk)
        self._lock = threading.Lock()
        self._queue: queue.SimpleQueue = queue.SimpleQueue()
        self._thread = threading.Thread(target=self._write_queued, name="bag-writer", daemon=True)
        self._thread.start()
        self.create_timer(flush_period, self._flush)
        self.connections: dict[str, object] = {}
        self.counts: dict[str, int] = {}
        self._store = typestore()
        self.create_timer(0.2, self._discover)
        self._discover()
        self.get_logger().info(f"recording {self.patterns or ['everything']} to {output}")

    def _resolve(self, name: str) -> str:
        if name.startswith("/"):
            return name
        namespace = self.get_namespace().rstrip("/")
        return f"{namespace}/{name}"

    def _discover(self) -> None:
        for topic, types in self.get_topic_names_and_types():
            if topic in self.connections or not topic_selected(topic, self.patterns):
                continue
            offered = [i.qos_profile.durability for i in self.get_publishers_info_by_topic(topic)]
            if not offered:
                # seen through its subscriptions only (the estimator's input before the
                # controller is up): its QoS is not known yet, and a volatile subscription now
                # would miss the history a transient-local publisher keeps for late joiners
                continue
            msgtype = types[0]
            try:
                message_class(msgtype)
                with self._lock:
                    connection = self.writer.add_connection(topic, msgtype, typestore=self._store)
            except (ImportError, AttributeError, KeyError) as error:
                self.get_logger().warning(f"cannot record {topic} ({msgtype}): {error}")
                self.connections[topic] = None
                continue
            self.connections[topic] = connection
            self.counts[topic] = 0
            self.create_subscription(
                message_class(msgtype),
                topic,
                self._writer_for(topic, connection),
                _qos_for(offered),
                raw=True,
            )

    def _writer_for(self, topic: str, connection):
        def write(data: bytes) -> None:
            self._queue.put((connection, self.get_clock().now().nanoseconds, data))
            self.counts[topic] += 1

        return write

    def _write_queued(self) -> None:
        """The writer thread: everything queued, in order, until the ``None`` sentinel."""
        while True:
            batch = [self._queue.get()]
            while not self._queue.empty() and len(batch) < 1000:
                batch.append(self._queue.get())
            with self._lock:
                for item in batch:
                    if item is None:
                        return
                    self.writer.write(*item)

    def _flush(self) -> None:
        """Write the pending MCAP chunk to the file now (rosbags keeps up to 1 MiB in memory),
        so that a recorder that is killed loses at most ``flush_period`` s of messages: the
        cut-off file is read up to its last complete chunk (:mod:`ros4crs.bag_repair`)."""
        with self._lock:
            storage = self.writer.storage
            if isinstance(storage, McapWriter) and storage.chunk.msgs:
                storage.close_chunk()
                storage.bio.flush()

    def destroy_node(self) -> None:
        self._queue.put(None)  # write what is queued, then close
        self._thread.join()
        self.writer.close()
        total = sum(self.counts.values())
        self.get_logger().info(f"bag closed: {total} messages on {len(self.counts)} topics")
        super().destroy_node()


def _qos_for(offered: list[DurabilityPolicy]) -> QoSProfile:
    """Transient-local (getting what was published before it joined) when every publisher of
    the topic offers it (``offered``: their durabilities), else the stream QoS."""
    if all(d == DurabilityPolicy.TRANSIENT_LOCAL for d in offered):
        return LOG_QOS
    return STREAM_QOS


def main(argv: Sequence[str] | None = None) -> int:
    return run(RecorderNode, argv)


if __name__ == "__main__":
    raise SystemExit(main())
