"""The Foxglove viewer against a foxglove-sdk server run here: it subscribes to every channel,
also one advertised after it connected, hands over each message with its channel, and ends
when the server goes."""

from __future__ import annotations

import asyncio
import json
import threading
import time
from typing import Any

import pytest

from benchmarks.foxglove_viewer import watch

foxglove = pytest.importorskip("foxglove", reason="foxglove-sdk is not installed")

SCHEMA = {"type": "object"}


def test_the_viewer_gets_every_channel_and_ends_with_the_server() -> None:
    context = foxglove.Context()
    first = foxglove.Channel("/first", schema=SCHEMA, context=context)
    server = foxglove.start_server(name="test", host="127.0.0.1", port=0, context=context)
    channels: dict[str, dict[str, Any]] = {}
    got: dict[str, list[Any]] = {}
    infos: list[dict[str, Any]] = []

    def take(channel: dict[str, Any], payload: bytes) -> None:
        got.setdefault(channel["topic"], []).append(json.loads(payload))

    def advertised(channel: dict[str, Any]) -> None:
        channels[channel["topic"]] = channel

    stop = threading.Event()
    later: list[Any] = []

    def publish() -> None:
        k = 0
        while not stop.is_set():
            k += 1
            first.log({"k": k})
            if k == 10:  # a channel advertised while the viewer watches
                later.append(foxglove.Channel("/later", schema=SCHEMA, context=context))
            if later:
                later[0].log({"k": k})
            time.sleep(0.02)

    publisher = threading.Thread(target=publish, daemon=True)
    publisher.start()
    url = f"ws://127.0.0.1:{server.port}"
    try:
        asyncio.run(
            watch(
                url,
                time.monotonic() + 10.0,
                take,
                until=lambda: len(got.get("/later", [])) >= 5,
                on_info=infos.append,
                on_channel=advertised,
            )
        )
        assert infos and infos[0]["op"] == "serverInfo"
        assert set(channels) == {"/first", "/later"}
        assert channels["/first"]["encoding"] == "json"
        ks = [m["k"] for m in got["/first"]]
        assert len(ks) >= 5 and ks == sorted(ks)
        # the server going ends the watch before its deadline
        threading.Timer(0.5, server.stop).start()
        started = time.monotonic()
        asyncio.run(watch(url, time.monotonic() + 10.0, take))
        assert time.monotonic() - started < 5.0
    finally:
        stop.set()
        publisher.join()
        server.stop()
