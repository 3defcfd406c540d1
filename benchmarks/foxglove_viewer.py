"""A Foxglove WebSocket viewer: connects as the Foxglove app does (subprotocol
``foxglove.sdk.v1``), subscribes to every channel the server advertises, and hands each message
to a callback. The visualizer's benchmark watches with it (so the node does the work a viewer
makes it do) and its integration test decodes what arrives.

Protocol (foxglove-sdk 0.30.3): JSON text frames (``serverInfo``, ``advertise``, ``status``), and
binary message frames ``0x01 | u32 LE subscription id | u64 LE log time ns | payload``; a
subscription's id here is its channel's id.
"""

from __future__ import annotations

import asyncio
import json
import struct
import time
from collections.abc import Callable
from typing import Any

__all__ = ["SUBPROTOCOL", "watch"]

SUBPROTOCOL = "foxglove.sdk.v1"
#: Byte 0 of a message-data frame, and where its payload starts.
MESSAGE_DATA, PAYLOAD_AT = 0x01, 13


async def _connect(url: str, deadline: float) -> Any:
    """A connection to ``url``, retried until ``deadline`` (monotonic s) while the server is
    not up yet."""
    import websockets

    while True:
        try:
            return await websockets.connect(url, subprotocols=[SUBPROTOCOL], max_size=None)
        except OSError:
            if time.monotonic() > deadline:
                raise
            await asyncio.sleep(0.3)


async def watch(
    url: str,
    deadline: float,
    on_message: Callable[[dict[str, Any], bytes], None],
    until: Callable[[], bool] = lambda: False,
    on_info: Callable[[dict[str, Any]], None] = lambda info: None,
    on_channel: Callable[[dict[str, Any]], None] = lambda channel: None,
) -> None:
    """Watch the server at ``url`` (``ws://HOST:PORT``) until ``until()`` or ``deadline``
    (monotonic s): every channel advertised is subscribed to, and each message is given to
    ``on_message(channel, payload)`` (the channel as advertised: ``topic``, ``encoding``,
    ``schemaName``, ...); the ``serverInfo`` message to ``on_info``, each channel as it is
    advertised to ``on_channel``."""
    import websockets

    ws = await _connect(url, deadline)
    channels: dict[int, dict[str, Any]] = {}
    try:
        while not until() and time.monotonic() < deadline:
            try:
                frame = await asyncio.wait_for(ws.recv(), max(deadline - time.monotonic(), 0.1))
            except (TimeoutError, websockets.ConnectionClosed):  # the server went: done
                break
            if isinstance(frame, bytes):
                if frame[0] == MESSAGE_DATA:
                    (subscription,) = struct.unpack_from("<I", frame, 1)
                    on_message(channels[subscription], frame[PAYLOAD_AT:])
                continue
            message = json.loads(frame)
            if message["op"] == "serverInfo":
                on_info(message)
            elif message["op"] == "advertise":
                new = [c for c in message["channels"] if c["id"] not in channels]
                for channel in new:
                    channels[channel["id"]] = channel
                    on_channel(channel)
                await _subscribe(ws, [c["id"] for c in new])
            elif message["op"] == "status" and "Unknown channel ID" in message["message"]:
                # foxglove-sdk 0.30.3 may refuse a subscription sent the instant a channel is
                # advertised (before its server has registered it): subscribe again
                await asyncio.sleep(0.1)
                await _subscribe(ws, [int(message["message"].rsplit(":", 1)[1])])
    finally:
        await ws.close()


async def _subscribe(ws: Any, channel_ids: list[int]) -> None:
    if channel_ids:
        subscriptions = [{"id": c, "channelId": c} for c in channel_ids]
        await ws.send(json.dumps({"op": "subscribe", "subscriptions": subscriptions}))
