"""The live page's HTTP server (ros4crs.viz_page): the three static files and nothing else, and
the WebSocket port it was started with written into the page (what the page connects to is
checked by running page.js in Node.js with a stand-in for the browser; those tests skip without
a ``node`` binary)."""

from __future__ import annotations

import errno
import http.client
import json
import re
import shutil
import socket
import subprocess
import tomllib
from collections.abc import Iterator
from importlib import resources
from pathlib import Path

import pytest

from crs_core.errors import FieldError
from ros4crs.viz_page import (
    FILES,
    WS_PORT_PLACEHOLDER,
    PageServer,
    PageServerError,
    start_page_server,
)

ROOT = Path(__file__).resolve().parents[2]
PAGE_FILES = ("index.html", "page.js", "page.css")
#: The WebSocket port the test server is started with: not the default 8765.
WS_PORT = 18800
NODE = shutil.which("node")
needs_node = pytest.mark.skipif(
    NODE is None, reason="no node binary (Debian: apt-get install nodejs)"
)


@pytest.fixture
def server() -> Iterator[PageServer]:
    page = start_page_server("127.0.0.1", 0, WS_PORT)
    yield page
    page.close()


def request(
    server: PageServer, method: str, path: str
) -> tuple[int, http.client.HTTPMessage, bytes]:
    """Send one request (``path`` as is, not normalised); the status, headers and body."""
    connection = http.client.HTTPConnection(server.host, server.port, timeout=5)
    try:
        connection.request(method, path)
        response = connection.getresponse()
        return response.status, response.headers, response.read()
    finally:
        connection.close()


def package_file(name: str) -> bytes:
    return (resources.files("ros4crs.viz_page") / name).read_bytes()


def served_file(name: str, ws_port: int = WS_PORT) -> bytes:
    """What the server sends for the file ``name``: index.html with ``ws_port`` written in."""
    data = package_file(name)
    return (
        data.replace(WS_PORT_PLACEHOLDER, str(ws_port).encode()) if name == "index.html" else data
    )


@pytest.mark.parametrize(
    ("path", "name", "content_type"),
    [
        ("/", "index.html", "text/html"),
        ("/?ws=8765", "index.html", "text/html"),
        ("/index.html", "index.html", "text/html"),
        ("/page.js", "page.js", "text/javascript"),
        ("/page.css", "page.css", "text/css"),
    ],
)
def test_serves_the_page_files_with_their_content_types(
    server: PageServer, path: str, name: str, content_type: str
) -> None:
    status, headers, body = request(server, "GET", path)
    assert status == 200
    assert headers.get_content_type() == content_type
    assert headers.get_content_charset() == "utf-8"
    assert body == served_file(name)
    assert int(headers["Content-Length"]) == len(body)


def test_head_sends_the_headers_without_the_body(server: PageServer) -> None:
    status, headers, body = request(server, "HEAD", "/page.js")
    assert status == 200
    assert int(headers["Content-Length"]) == len(package_file("page.js"))
    assert body == b""


@pytest.mark.parametrize(
    "path",
    [
        "/nothing.html",
        "/__init__.py",
        "/viz_page/",
        "/ros4crs/viz_page/index.html",
        "/../pyproject.toml",
        "/%2e%2e/pyproject.toml",
        "/..%2f..%2fpyproject.toml",
        "//etc/passwd",
    ],
)
def test_any_other_path_is_not_found(server: PageServer, path: str) -> None:
    status, _, body = request(server, "GET", path)
    assert status == 404
    assert b"[project]" not in body and b"root:" not in body


@pytest.mark.parametrize("method", ["POST", "PUT", "DELETE", "PATCH", "OPTIONS", "BREW"])
def test_only_get_and_head_are_allowed(server: PageServer, method: str) -> None:
    status, headers, _ = request(server, method, "/")
    assert status == 405
    assert headers["Allow"] == "GET, HEAD"


def test_a_port_in_use_is_a_clear_error_naming_page_port() -> None:
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        with pytest.raises(PageServerError, match=f"page_port {port} is already in use") as err:
            start_page_server("127.0.0.1", port, WS_PORT)
    assert err.value.errno == errno.EADDRINUSE


def test_an_address_that_cannot_be_bound_names_host_and_page_port() -> None:
    with pytest.raises(PageServerError, match=r"192\.0\.2\.1:0 \(host, page_port\)"):
        start_page_server("192.0.2.1", 0, WS_PORT)  # TEST-NET-1: not an address of this machine


def test_close_stops_serving_and_frees_the_port() -> None:
    page = start_page_server("127.0.0.1", 0, WS_PORT)
    assert page.port > 0
    assert page.url == f"http://127.0.0.1:{page.port}/"
    assert request(page, "GET", "/")[0] == 200
    page.close()
    page.close()  # a second close does nothing
    with pytest.raises(ConnectionRefusedError):
        request(page, "GET", "/")
    # A node started again gets the same page_port.
    with start_page_server("127.0.0.1", page.port, WS_PORT) as again:
        assert request(again, "GET", "/")[0] == 200


def test_the_page_files_are_package_data() -> None:
    """They are installed with the package (pyproject.toml), not only found in the source tree."""
    package_data = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"][
        "package-data"
    ]
    assert sorted(package_data["ros4crs.viz_page"]) == sorted(PAGE_FILES)
    assert sorted({name for name, _ in FILES.values()}) == sorted(PAGE_FILES)


@pytest.mark.parametrize("name", PAGE_FILES)
def test_the_page_fetches_nothing_from_outside(name: str) -> None:
    text = package_file(name).decode()
    assert not re.search(r"https?:|//[a-z0-9.-]+\.[a-z]{2,}/|@import|\bfetch\(", text), name


def test_the_page_sends_only_subscribe_and_unsubscribe() -> None:
    ops = re.findall(r'send\(socket, \{op: "(\w+)"', package_file("page.js").decode())
    assert sorted(set(ops)) == ["subscribe", "unsubscribe"]
    assert "socket.send(" in package_file("page.js").decode()
    assert package_file("page.js").decode().count(".send(") == 1  # only through send()


# --- the WebSocket port the page connects to -------------------------------------------------

#: page.js run in Node.js with a stand-in for the browser (the DOM calls it makes at load, and a
#: WebSocket that records its address); prints what it connected to and its header line.
BROWSER_STAND_IN = r"""
const vm = require("vm");
const {script, html, search} = JSON.parse(require("fs").readFileSync(0, "utf8"));
const element = () => new Proxy({classList: {toggle() {}}}, {
  get: (target, key) => (key in target ? target[key] : () => element()),
});
const meta = html.match(/<meta name="crs-ws-port" content="([^"]*)">/);
const sockets = [];
const header = {classList: {toggle() {}}, textContent: ""};
const sandbox = {
  location: {search, hostname: "127.0.0.1"},
  document: {
    documentElement: {},
    getElementById: (id) => (id === "connection" ? header : element()),
    querySelector: (selector) => (selector === 'meta[name="crs-ws-port"]'
      ? (meta === null ? null : {content: meta[1]}) : element()),
  },
  getComputedStyle: () => ({getPropertyValue: () => ""}),
  window: {addEventListener() {}},
  requestAnimationFrame() {},
  setTimeout() {},
  TextDecoder,
  URLSearchParams,
  WebSocket: class {
    constructor(url, protocols) {
      sockets.push({url, protocols});
    }
  },
};
vm.runInNewContext(script, sandbox);
console.log(JSON.stringify({sockets, header: header.textContent}));
"""


def run_page(html: bytes, search: str = "") -> tuple[list[str], str]:
    """Load page.js in Node.js as if from ``html`` at an address ending in ``search``: the
    WebSocket addresses it opened and its header line."""
    assert NODE is not None
    source = {"script": package_file("page.js").decode(), "html": html.decode(), "search": search}
    done = subprocess.run(
        [NODE, "-e", BROWSER_STAND_IN],
        input=json.dumps(source),
        capture_output=True,
        text=True,
        timeout=30,
        check=True,
    )
    result = json.loads(done.stdout)
    assert all(s["protocols"] == ["foxglove.sdk.v1"] for s in result["sockets"])
    return [s["url"] for s in result["sockets"]], result["header"]


def test_index_html_carries_the_websocket_port_the_server_was_started_with(
    server: PageServer,
) -> None:
    assert server.ws_port == WS_PORT
    for path in ("/", "/index.html", "/?ws=9000"):
        _, _, body = request(server, "GET", path)
        assert f'<meta name="crs-ws-port" content="{WS_PORT}">'.encode() in body, path
        assert WS_PORT_PLACEHOLDER not in body
    assert package_file("index.html").count(WS_PORT_PLACEHOLDER) == 1


@needs_node
def test_the_page_connects_to_the_websocket_port_its_server_was_started_with(
    server: PageServer,
) -> None:
    _, _, html = request(server, "GET", "/")
    assert run_page(html) == (
        [f"ws://127.0.0.1:{WS_PORT}"],
        f"connecting to ws://127.0.0.1:{WS_PORT}…",
    )


@needs_node
def test_ws_in_the_address_overrides_the_servers_port(server: PageServer) -> None:
    _, _, html = request(server, "GET", "/?ws=9000")
    assert run_page(html, "?ws=9000")[0] == ["ws://127.0.0.1:9000"]


@needs_node
@pytest.mark.parametrize("search", ["?ws=abc", "?ws=0", "?ws=70000", "?ws=", "?ws=8765.5"])
def test_a_bad_ws_in_the_address_is_said_and_nothing_is_opened(
    server: PageServer, search: str
) -> None:
    _, _, html = request(server, "GET", "/" + search)
    assert run_page(html, search) == ([], "?ws= must be a port number (1-65535), e.g. ?ws=8765")


@needs_node
def test_a_page_not_served_by_the_visualizer_asks_for_ws() -> None:
    """index.html opened as a file: no port written in, so no guess at one."""
    sockets, header = run_page(package_file("index.html"))
    assert sockets == []
    assert "?ws=PORT" in header


@pytest.mark.parametrize("ws_port", [0, 65536, -1, True, "8765", 8765.0])
def test_ws_port_must_be_a_port_number(ws_port: object) -> None:
    with pytest.raises(FieldError, match=r"^ws_port: must be a port number in 1\.\.65535"):
        start_page_server("127.0.0.1", 0, ws_port)  # type: ignore[arg-type]
