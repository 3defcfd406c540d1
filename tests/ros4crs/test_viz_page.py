"""The live page's HTTP server (ros4crs.viz_page): the three static files and nothing else."""

from __future__ import annotations

import errno
import http.client
import re
import socket
import tomllib
from collections.abc import Iterator
from importlib import resources
from pathlib import Path

import pytest

from ros4crs.viz_page import FILES, PageServer, PageServerError, start_page_server

ROOT = Path(__file__).resolve().parents[2]
PAGE_FILES = ("index.html", "page.js", "page.css")


@pytest.fixture
def server() -> Iterator[PageServer]:
    page = start_page_server("127.0.0.1", 0)
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
    assert body == package_file(name)
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
            start_page_server("127.0.0.1", port)
    assert err.value.errno == errno.EADDRINUSE


def test_an_address_that_cannot_be_bound_names_host_and_page_port() -> None:
    with pytest.raises(PageServerError, match=r"192\.0\.2\.1:0 \(host, page_port\)"):
        start_page_server("192.0.2.1", 0)  # TEST-NET-1: not an address of this machine


def test_close_stops_serving_and_frees_the_port() -> None:
    page = start_page_server("127.0.0.1", 0)
    assert page.port > 0
    assert page.url == f"http://127.0.0.1:{page.port}/"
    assert request(page, "GET", "/")[0] == 200
    page.close()
    page.close()  # a second close does nothing
    with pytest.raises(ConnectionRefusedError):
        request(page, "GET", "/")
    # A node started again gets the same page_port.
    with start_page_server("127.0.0.1", page.port) as again:
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
