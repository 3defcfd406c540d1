"""The built-in live page (issue 29): a small web page for people without Foxglove.

``start_page_server(host, port, ws_port)`` serves the page's three static files
(``index.html``, ``page.js``, ``page.css``, installed as package data) over HTTP from a daemon
thread. The page itself connects to the visualizer node's foxglove-sdk WebSocket server
(subprotocol ``foxglove.sdk.v1``) on the host it was loaded from, subscribes to
``/viz/page/track`` and ``/viz/page/cars`` and draws them; see docs/live-view.md. The WebSocket's
port is ``ws_port``, the one the visualizer serves on: the server writes it into index.html's
``<meta name="crs-ws-port">`` (in place of :data:`WS_PORT_PLACEHOLDER`), and page.js reads it
there; a ``?ws=PORT`` in the page's address overrides it.
"""

from __future__ import annotations

import errno
import logging
import threading
from collections.abc import Callable
from http import HTTPStatus
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from importlib import resources
from urllib.parse import urlsplit

from crs_core.errors import FieldError

log = logging.getLogger(__name__)

#: The served files: URL path -> (file of this package, content type).
FILES: dict[str, tuple[str, str]] = {
    "/": ("index.html", "text/html; charset=utf-8"),
    "/index.html": ("index.html", "text/html; charset=utf-8"),
    "/page.js": ("page.js", "text/javascript; charset=utf-8"),
    "/page.css": ("page.css", "text/css; charset=utf-8"),
}


#: What index.html holds where the server writes the WebSocket's port (exactly once).
WS_PORT_PLACEHOLDER = b"@WS_PORT@"


class PageServerError(OSError):
    """The page server could not start (its port is taken, its host cannot be bound, ...)."""


def _read_files(ws_port: int) -> dict[str, bytes]:
    """The files' contents by file name, index.html with ``ws_port`` written in; a clear error
    when one is not installed."""
    package = resources.files(__name__)
    contents = {}
    for name, _ in FILES.values():
        try:
            contents[name] = (package / name).read_bytes()
        except OSError as e:
            raise PageServerError(
                f"ros4crs.viz_page: the page file {name} is not installed ({e}); reinstall the "
                "project (./run.sh setup) so its package data is present"
            ) from e
    html = contents["index.html"]
    if html.count(WS_PORT_PLACEHOLDER) != 1:
        raise PageServerError(
            f"ros4crs.viz_page: index.html must hold {WS_PORT_PLACEHOLDER.decode()} once (where "
            f"the WebSocket's port is written), found it {html.count(WS_PORT_PLACEHOLDER)} times"
        )
    contents["index.html"] = html.replace(WS_PORT_PLACEHOLDER, str(ws_port).encode())
    return contents


class _Handler(BaseHTTPRequestHandler):
    """Serves the files of ``FILES`` (GET and HEAD); 404 for any other path, 405 for other
    methods. Paths are looked up exactly, so nothing outside the package can be reached."""

    server: _HTTPServer

    def _send(self, body: bool) -> None:
        entry = FILES.get(urlsplit(self.path).path)
        if entry is None:
            self.send_error(HTTPStatus.NOT_FOUND)
            return
        name, content_type = entry
        data = self.server.contents[name]
        self.send_response(HTTPStatus.OK)
        self.send_header("Content-Type", content_type)
        self.send_header("Content-Length", str(len(data)))
        self.send_header("Cache-Control", "no-store")
        self.send_header("X-Content-Type-Options", "nosniff")
        self.end_headers()
        if body:
            self.wfile.write(data)

    def do_GET(self) -> None:
        self._send(body=True)

    def do_HEAD(self) -> None:
        self._send(body=False)

    def _not_allowed(self) -> None:
        self.send_response(HTTPStatus.METHOD_NOT_ALLOWED)
        self.send_header("Allow", "GET, HEAD")
        self.send_header("Content-Length", "0")
        self.end_headers()

    def __getattr__(self, name: str) -> Callable[[], None]:
        """``do_<METHOD>`` of any other method (POST, PUT, ...): 405, not the base class's 501."""
        if name.startswith("do_"):
            return self._not_allowed
        raise AttributeError(name)

    def log_message(self, format: str, *args: object) -> None:
        log.debug("%s: " + format, self.address_string(), *args)


class _HTTPServer(ThreadingHTTPServer):
    """Holds the file contents, read once at start."""

    def __init__(self, address: tuple[str, int], contents: dict[str, bytes]) -> None:
        self.contents = contents
        super().__init__(address, _Handler)


class PageServer:
    """The running page server; ``close()`` stops it and frees its port."""

    def __init__(self, httpd: _HTTPServer, ws_port: int) -> None:
        self._httpd = httpd
        self.host: str = httpd.server_address[0]
        #: The bound port (the chosen one when started with port 0).
        self.port: int = httpd.server_address[1]
        #: The WebSocket port the page connects to unless its address says ``?ws=``.
        self.ws_port = ws_port
        self._thread = threading.Thread(
            target=httpd.serve_forever,
            kwargs={"poll_interval": 0.05},  # how long close() may wait
            name="viz-page-server",
            daemon=True,
        )
        self._closed = False
        self._thread.start()

    @property
    def url(self) -> str:
        """The page's address, e.g. ``http://127.0.0.1:8766/``."""
        return f"http://{self.host}:{self.port}/"

    def close(self) -> None:
        """Stop serving and free the port (a second call does nothing)."""
        if self._closed:
            return
        self._closed = True
        self._httpd.shutdown()
        self._httpd.server_close()
        self._thread.join()

    def __enter__(self) -> PageServer:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def start_page_server(host: str, port: int, ws_port: int) -> PageServer:
    """Serve the live page on ``host``:``port`` (0: any free port) from a daemon thread; the
    page connects to the WebSocket on ``ws_port`` of the host it was loaded from (the port the
    visualizer's WebSocket server was started with), unless its address says ``?ws=PORT``.

    Raises
    ------
    FieldError
        ``ws_port`` is not a port number (1..65535).
    PageServerError
        A page file is not installed, or the address cannot be bound (the message names
        ``page_port``; a port in use says so).
    """
    if isinstance(ws_port, bool) or not isinstance(ws_port, int) or not 1 <= ws_port <= 65535:
        raise FieldError("ws_port", f"must be a port number in 1..65535, got {ws_port!r}")
    contents = _read_files(ws_port)
    try:
        httpd = _HTTPServer((host, port), contents)
    except OSError as e:
        if e.errno == errno.EADDRINUSE:
            raise PageServerError(
                e.errno,
                f"page_port {port} is already in use on {host}: choose another page_port "
                "(0 picks a free one) or stop what is listening there",
            ) from e
        raise PageServerError(
            e.errno, f"cannot serve the page on {host}:{port} (host, page_port): {e.strerror}"
        ) from e
    return PageServer(httpd, ws_port)
