"""The live page in a real browser: headless Chromium loads it from the page server, it connects
to a foxglove-sdk WebSocket server run here (the suite's demo track, one car driving along the
centreline at 30 Hz) and draws them; the screenshots' pixels are checked.

Chromium is driven through :mod:`tests.integration.browser` (the DevTools protocol over a pipe);
skips without a ``chromium`` binary (Debian: ``apt-get install chromium``; .ci/run installs
it). ``tests/integration/test_visualizer.py`` loads the page against a running stack too.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from crs_core.track import Track, load_demo_track
from ros4crs.viz_page import PageServer, start_page_server
from tests.integration.browser import (
    DevTools,
    check_track_and_moving_car,
    needs_chromium,
    two_screenshots,
)

foxglove = pytest.importorskip("foxglove", reason="foxglove-sdk is not installed")

pytestmark = pytest.mark.slow

TRACK_TOPIC = "/viz/page/track"
CARS_TOPIC = "/viz/page/cars"
SPEED = 1.0  # m/s of the test car along the centreline
SCHEMA = {"type": "object"}


class Visualizer:
    """The visualizer node's part: a foxglove-sdk server (a context of its own) publishing the
    track and one car along the centreline at 30 Hz; records what the page asks of it."""

    def __init__(self, track: Track, port: int = 0) -> None:
        self.track = track
        left, right = track.borders()
        self.track_message = {
            "centre": np.column_stack([track.x, track.y]).tolist(),
            "left": left.tolist(),
            "right": right.tolist(),
        }
        self.subscribed: list[str] = []
        self.client_channels: list[Any] = []
        self.context = foxglove.Context()  # kept: the channels close with it
        self.track_channel = foxglove.Channel(TRACK_TOPIC, schema=SCHEMA, context=self.context)
        self.cars_channel = foxglove.Channel(CARS_TOPIC, schema=SCHEMA, context=self.context)
        # A channel the page must leave alone.
        self.other_channel = foxglove.Channel("/viz/other", schema=SCHEMA, context=self.context)
        self.server = foxglove.start_server(
            name="test", host="127.0.0.1", port=port, context=self.context, server_listener=self
        )
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    # The server listener's callbacks.
    def on_subscribe(self, client: Any, channel: Any) -> None:
        self.subscribed.append(channel.topic)

    def on_client_advertise(self, client: Any, channel: Any) -> None:
        self.client_channels.append(channel)

    def car(self, t: float) -> dict[str, Any]:
        s = SPEED * t
        x, y, heading, _ = self.track.interpolate(s)
        plan_x, plan_y, _, _ = self.track.interpolate(s + np.linspace(0.0, 0.6, 12))
        return {
            "name": "car1",
            "status": "ok",
            "reason": "",
            "estimate": [float(x), float(y), float(heading)],
            "truth": [float(x) + 0.02, float(y), float(heading)],
            "plan": np.column_stack([plan_x, plan_y]).tolist(),
            "size": [0.12, 0.06],
            "laps": int(s // self.track.length),
            "last_lap_s": None,
            "parameters": [{"name": "Cm1", "value": 0.95, "std": 0.012, "informed": True}],
        }

    def _run(self) -> None:
        start = time.monotonic()
        next_track = start
        while not self._stop.wait(1 / 30):
            now = time.monotonic()
            # Every 0.5 s (the node: every 2 s), so a page that just subscribed soon has it.
            if now >= next_track:
                self.track_channel.log(self.track_message)
                next_track = now + 0.5
            self.cars_channel.log({"stamp": now - start, "cars": [self.car(now - start)]})
            self.other_channel.log({"ignored": True})

    def stop(self) -> None:
        self._stop.set()
        self._thread.join()
        self.server.stop()


@pytest.fixture
def visualizer() -> Iterator[Visualizer]:
    server = Visualizer(load_demo_track())
    yield server
    server.stop()


@pytest.fixture
def page(visualizer: Visualizer) -> Iterator[PageServer]:
    """The page server of ``visualizer``'s WebSocket port (the page connects to it unasked)."""
    with start_page_server("127.0.0.1", 0, visualizer.server.port) as server:
        yield server


def wait_for(condition: Callable[[], bool], what: str, timeout: float = 10.0) -> None:
    deadline = time.monotonic() + timeout
    while not condition():
        assert time.monotonic() < deadline, f"not within {timeout:.0f} s: {what}"
        time.sleep(0.1)


@needs_chromium
def test_the_page_draws_the_track_and_the_moving_car(
    visualizer: Visualizer, page: PageServer, tmp_path: Path
) -> None:
    first, second = two_screenshots(page.url, tmp_path / "profile")  # no ?ws=: the server's port
    (tmp_path / "first.png").write_bytes(first)
    (tmp_path / "second.png").write_bytes(second)
    check_track_and_moving_car(first, second, visualizer.track)

    assert sorted(set(visualizer.subscribed)) == [CARS_TOPIC, TRACK_TOPIC]
    assert visualizer.client_channels == []


@needs_chromium
def test_the_page_reconnects_when_the_server_comes_back(tmp_path: Path) -> None:
    first = Visualizer(load_demo_track())
    port = first.server.port
    # ?ws= overrides the port the page server was started with (here one nothing listens on)
    page = start_page_server("127.0.0.1", 0, 9)
    browser = DevTools(f"{page.url}?ws={port}", tmp_path / "profile")
    try:
        browser.attach_to_page()

        def header() -> str:
            return browser.evaluate("document.getElementById('connection')?.textContent ?? ''")

        connected = f"connected to ws://127.0.0.1:{port}, 3 channels"
        wait_for(lambda: header() == connected, f"header {connected!r}")
        first.stop()
        wait_for(lambda: header().startswith("not connected"), "header 'not connected ...'")
        again = Visualizer(load_demo_track(), port)
        try:
            wait_for(lambda: header() == connected, "connected again (retries every 2 s)")
            wait_for(lambda: len(again.subscribed) == 2, "subscribed again")
            assert sorted(again.subscribed) == [CARS_TOPIC, TRACK_TOPIC]
        finally:
            again.stop()
    finally:
        browser.close()
        page.close()
