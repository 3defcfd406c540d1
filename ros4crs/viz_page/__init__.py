"""PLACEHOLDER for the built-in page (written by another engineer; replaced at merge): an HTTP
server on ``host:port`` answering GET with a one-line index."""

from __future__ import annotations

import threading
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer


class _Index(BaseHTTPRequestHandler):
    def do_GET(self) -> None:
        body = b"Chronos/CRS live view: placeholder page\n"
        self.send_response(200)
        self.send_header("Content-Type", "text/plain; charset=utf-8")
        self.send_header("Content-Length", str(len(body)))
        self.end_headers()
        self.wfile.write(body)

    def log_message(self, format: str, *args: object) -> None:
        pass


class PageServer:
    """The running server (a thread of its own); :meth:`close` stops it."""

    def __init__(self, host: str, port: int) -> None:
        self._server = ThreadingHTTPServer((host, port), _Index)
        self._thread = threading.Thread(target=self._server.serve_forever, daemon=True)
        self._thread.start()

    def close(self) -> None:
        self._server.shutdown()
        self._server.server_close()


def start_page_server(host: str, port: int) -> PageServer:
    """Serve the page on ``host:port`` (``OSError`` when the port is taken)."""
    return PageServer(host, port)
