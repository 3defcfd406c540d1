"""Headless Chromium for the live page's tests: driven over the DevTools protocol through a pipe
(``--remote-debugging-pipe``: fd 3 takes commands, fd 4 answers, each message NUL-terminated), so
a test waits until the data is drawn instead of guessing a time budget, and no debugging port is
opened; and the checks of a screenshot's pixels against the page's colours (page.css). Tests
using it skip without a ``chromium`` binary (Debian: ``apt-get install chromium``; .ci/run
installs it)."""

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
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from numpy.typing import NDArray
from PIL import Image

from crs_core.track import Track

CHROMIUM = shutil.which("chromium")
needs_chromium = pytest.mark.skipif(
    CHROMIUM is None, reason="no chromium binary (Debian: apt-get install chromium)"
)
#: Largest difference per colour channel of a pixel that counts as a colour of the page.
TOLERANCE = 8
#: Seconds Chromium has to answer its first command: a first start on a fresh machine builds
#: its font cache and profile, which beside a busy test suite has taken more than 10 s.
STARTUP_S = 90.0


def page_colours() -> dict[str, NDArray[np.int64]]:
    """The page's drawing colours (``--name: #rrggbb`` in page.css) as RGB."""
    css = (resources.files("ros4crs.viz_page") / "page.css").read_text()
    return {
        name: np.array([int(value[i : i + 2], 16) for i in (0, 2, 4)])
        for name, value in re.findall(r"--([\w-]+):\s*#([0-9a-fA-F]{6});", css)
    }


class DevTools:
    """Headless Chromium showing ``url``, driven over the DevTools protocol through a pipe."""

    def __init__(self, url: str, profile: Path) -> None:
        profile.mkdir(parents=True, exist_ok=True)
        self.log = profile / "chromium.log"
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
        with self.log.open("wb") as log:
            self.process = subprocess.Popen(
                ["bash", "-c", f'exec "$0" "$@" 3<&{child_in} 4>&{child_out}', CHROMIUM, *args],
                pass_fds=(child_in, child_out),
                stdout=subprocess.DEVNULL,
                stderr=log,
            )
        os.close(child_in)
        os.close(child_out)
        self._replies: queue.Queue[dict[str, Any]] = queue.Queue()
        threading.Thread(target=self._read, daemon=True).start()
        self._next_id = 0
        self.session = ""
        try:
            self.call("Browser.getVersion", timeout=STARTUP_S)
        except AssertionError:
            self.close()
            raise

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
            try:
                reply = self._replies.get(timeout=max(deadline - time.monotonic(), 0.01))
            except queue.Empty:
                raise AssertionError(self._silence(method, timeout)) from None
            if reply.get("id") == self._next_id:  # not an event
                assert "error" not in reply, f"{method}: {reply['error']}"
                return reply["result"]

    def _silence(self, method: str, timeout: float) -> str:
        """Why ``method`` got no answer: Chromium's exit status and the end of its log."""
        code = self.process.poll()
        state = "running" if code is None else f"exited with {code}"
        tail = self.log.read_bytes()[-1500:].decode(errors="replace")
        return f"Chromium ({state}) did not answer {method} in {timeout:.0f} s; its log:\n{tail}"

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
        # in front and focused, as a page someone watches: a page the browser takes for hidden
        # may get no animation frames, and the page draws in them
        self.call("Page.bringToFront")
        self.call("Emulation.setFocusEmulationEnabled", enabled=True)

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
        except (AssertionError, OSError):
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


#: The page's cars as it last received them (its script's ``cars``: name, status, estimate).
PAGE_CARS = "JSON.stringify(cars.map((c) => [c.name, c.status, c.estimate]))"


def two_screenshots(url: str, profile: Path) -> tuple[bytes, bytes]:
    """PNG screenshots of the page at ``url``: once it shows the track and an ``ok`` car (within
    10 s), and a second later once the page has received a new position of its cars (within
    5 s; an assertion error naming the page's connection line when none came)."""
    colours = page_colours()
    browser = DevTools(url, profile)
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
        drawn = browser.evaluate(PAGE_CARS)
        time.sleep(1.0)
        deadline = time.monotonic() + 4.0
        while browser.evaluate(PAGE_CARS) == drawn:
            assert time.monotonic() < deadline, (
                "the page received no new car position in 5 s "
                f"({browser.evaluate('header.textContent')!r}; cars {drawn})"
            )
            time.sleep(0.1)
        second = browser.screenshot()
    finally:
        browser.close()
    return first, second


def check_track_and_moving_car(first: bytes, second: bytes, track: Track) -> None:
    """The page drew ``track`` (its borders' box, one scale for x and y, and the centreline's
    colour along the projected centreline) and an ``ok`` car that moved between the two
    screenshots (a second apart) by at least 0.3 m."""
    colours = page_colours()
    image, later = pixels(first), pixels(second)
    # Where the world lands on screen: the borders' pixels span the borders' box (the page
    # fits the track with one scale for x and y, y up).
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
