"""The live page in a real browser: headless Chromium loads it from the page server, it connects
to a foxglove-sdk WebSocket server run here (the suite's demo track, one car driving along the
centreline at 30 Hz) and draws them; the screenshots' pixels are checked.

Chromium is driven over the DevTools protocol through a pipe (``--remote-debugging-pipe``: fd 3
takes commands, fd 4 answers, each message NUL-terminated), so the test waits until the data is
drawn instead of guessing a time budget, and opens no debugging port. Skips without a ``chromium``
binary (Debian: ``apt-get install chromium``; .ci/run installs it).
"""

from __future__ import annotations

import base64
import fcntl
import io
import json
import os
import queue
import re
import shutil
import subprocess
import threading
import time
from collections.abc import Callable, Iterator
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from numpy.typing import NDArray
from PIL import Image

from crs_core.track import Track, load_demo_track
from ros4crs.viz_page import PageServer, start_page_server

foxglove = pytest.importorskip("foxglove", reason="foxglove-sdk is not installed")

pytestmark = pytest.mark.slow

CHROMIUM = shutil.which("chromium")
needs_chromium = pytest.mark.skipif(
    CHROMIUM is None, reason="no chromium binary (Debian: apt-get install chromium)"
)
TRACK_TOPIC = "/viz/page/track"
CARS_TOPIC = "/viz/page/cars"
SPEED = 1.0  # m/s of the test car along the centreline
SCHEMA = {"type": "object"}
#: Largest difference per colour channel of a pixel that counts as a colour of the page.
TOLERANCE = 8


def page_colours() -> dict[str, NDArray[np.int64]]:
    """The page's drawing colours (``--name: #rrggbb`` in page.css) as RGB."""
    css = (resources.files("ros4crs.viz_page") / "page.css").read_text()
    return {
        name: np.array([int(value[i : i + 2], 16) for i in (0, 2, 4)])
        for name, value in re.findall(r"--([\w-]+):\s*#([0-9a-fA-F]{6});", css)
    }


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


class DevTools:
    """Headless Chromium showing ``url``, driven over the DevTools protocol through a pipe."""

    def __init__(self, url: str, profile: Path) -> None:
        commands_read, self._commands = os.pipe()
        self._answers, answers_write = os.pipe()
        # Chromium reads fd 3 and writes fd 4: move our ends above them first, so bash's
        # redirections cannot overwrite one another (dash takes no fd above 9).
        child_in = fcntl.fcntl(commands_read, fcntl.F_DUPFD, 10)
        child_out = fcntl.fcntl(answers_write, fcntl.F_DUPFD, 10)
        for fd in (commands_read, answers_write):
            os.close(fd)
        args = [
            "--headless=new",
            "--no-sandbox",
            "--disable-gpu",
            "--disable-dev-shm-usage",
            "--no-first-run",
            "--window-size=900,700",
            "--remote-debugging-pipe",
            f"--user-data-dir={profile}",
            url,
        ]
        self.process = subprocess.Popen(
            ["bash", "-c", f'exec "$0" "$@" 3<&{child_in} 4>&{child_out}', CHROMIUM, *args],
            pass_fds=(child_in, child_out),
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
        )
        os.close(child_in)
        os.close(child_out)
        self._replies: queue.Queue[dict[str, Any]] = queue.Queue()
        threading.Thread(target=self._read, daemon=True).start()
        self._next_id = 0
        self.session = ""

    def _read(self) -> None:
        buffer = b""
        while chunk := os.read(self._answers, 65536):
            buffer += chunk
            *messages, buffer = buffer.split(b"\0")
            for message in messages:
                self._replies.put(json.loads(message))

    def call(self, method: str, timeout: float = 10.0, **params: Any) -> dict[str, Any]:
        """Send one command (to the page once attached) and return its result."""
        self._next_id += 1
        command: dict[str, Any] = {"id": self._next_id, "method": method, "params": params}
        if self.session:
            command["sessionId"] = self.session
        os.write(self._commands, json.dumps(command).encode() + b"\0")
        deadline = time.monotonic() + timeout
        while True:
            reply = self._replies.get(timeout=max(deadline - time.monotonic(), 0.01))
            if reply.get("id") == self._next_id:  # not an event
                assert "error" not in reply, f"{method}: {reply['error']}"
                return reply["result"]

    def attach_to_page(self) -> None:
        deadline = time.monotonic() + 10
        while not (
            pages := [
                t for t in self.call("Target.getTargets")["targetInfos"] if t["type"] == "page"
            ]
        ):
            assert time.monotonic() < deadline, "Chromium opened no page"
            time.sleep(0.1)
        self.session = self.call(
            "Target.attachToTarget", targetId=pages[0]["targetId"], flatten=True
        )["sessionId"]

    def evaluate(self, expression: str) -> Any:
        """The value of a JavaScript expression in the page."""
        return self.call("Runtime.evaluate", expression=expression, returnByValue=True)["result"][
            "value"
        ]

    def screenshot(self) -> bytes:
        return base64.b64decode(self.call("Page.captureScreenshot", format="png")["data"])

    def close(self) -> None:
        self.session = ""
        try:
            self.call("Browser.close", timeout=5)
        except (queue.Empty, OSError):
            pass  # gone already; killed below
        try:
            self.process.wait(timeout=5)
        except subprocess.TimeoutExpired:
            self.process.kill()
            self.process.wait()
        os.close(self._commands)
        os.close(self._answers)


def pixels(png: bytes) -> NDArray[np.int64]:
    return np.asarray(Image.open(io.BytesIO(png)).convert("RGB"), dtype=np.int64)


def mask(image: NDArray[np.int64], rgb: NDArray[np.int64]) -> NDArray[np.bool_]:
    return np.all(np.abs(image - rgb) <= TOLERANCE, axis=2)


def bounding_box(m: NDArray[np.bool_]) -> tuple[int, int, int, int]:
    rows, columns = np.nonzero(m)
    return int(columns.min()), int(columns.max()), int(rows.min()), int(rows.max())


@pytest.fixture
def visualizer() -> Iterator[Visualizer]:
    server = Visualizer(load_demo_track())
    yield server
    server.stop()


@pytest.fixture
def page() -> Iterator[PageServer]:
    with start_page_server("127.0.0.1", 0) as server:
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
    url = f"{page.url}?ws={visualizer.server.port}"
    colours = page_colours()
    browser = DevTools(url, tmp_path / "profile")
    try:
        browser.attach_to_page()
        # Wait until the track and the car are drawn, then take a second shot a second later.
        deadline = time.monotonic() + 10
        while True:
            first = browser.screenshot()
            image = pixels(first)
            if (
                mask(image, colours["track-centre"]).sum() > 200
                and mask(image, colours["status-ok"]).sum() > 30
            ):
                break
            assert time.monotonic() < deadline, "the page drew no track and car within 10 s"
            time.sleep(0.2)
        time.sleep(1.0)
        second = browser.screenshot()
    finally:
        browser.close()
    (tmp_path / "first.png").write_bytes(first)
    (tmp_path / "second.png").write_bytes(second)
    image, later = pixels(first), pixels(second)

    # Where the world lands on screen: the borders' pixels span the borders' box (the page
    # fits the track with one scale for x and y, y up).
    track = visualizer.track
    left, right = track.borders()
    world = np.vstack([left, right])
    x0, x1, y0, y1 = bounding_box(mask(image, colours["track-border"]))
    scale = ((x1 - x0) / np.ptp(world[:, 0]) + (y1 - y0) / np.ptp(world[:, 1])) / 2
    assert abs((x1 - x0) / np.ptp(world[:, 0]) - scale) < 0.02 * scale, "aspect ratio kept"
    columns = x0 + (track.x - world[:, 0].min()) * scale
    rows = y0 + (world[:, 1].max() - track.y) * scale

    # The centreline's colour along the projected centreline (the car may cover a little).
    centre = mask(image, colours["track-centre"])
    near = [
        centre[int(r) - 3 : int(r) + 4, int(c) - 3 : int(c) + 4].any()
        for r, c in zip(rows, columns, strict=True)
    ]
    assert np.mean(near) > 0.9, f"centreline drawn at only {np.mean(near):.0%} of its points"

    # The car's colour inside the track's box (the side table's "ok" badge is outside it).
    def car_centre(shot: NDArray[np.int64]) -> NDArray[np.float64]:
        car = mask(shot, colours["status-ok"])[y0 : y1 + 1, x0 : x1 + 1]
        assert car.sum() > 30, "no car drawn"
        rows_, columns_ = np.nonzero(car)
        return np.array([columns_.mean(), rows_.mean()])

    moved = np.linalg.norm(car_centre(later) - car_centre(image))
    # ~1 s at 1 m/s: about scale pixels (less on a bend); at least a car length.
    assert moved > 0.3 * scale, f"the car moved {moved:.0f} px in 1 s ({scale:.0f} px/m)"

    assert sorted(set(visualizer.subscribed)) == [CARS_TOPIC, TRACK_TOPIC]
    assert visualizer.client_channels == []


@needs_chromium
def test_the_page_reconnects_when_the_server_comes_back(page: PageServer, tmp_path: Path) -> None:
    first = Visualizer(load_demo_track())
    port = first.server.port
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
