"""The car emulator as a real process on loopback, for the tests that run ``crs car-emulator``."""

from __future__ import annotations

import socket
import subprocess
import sys
from collections.abc import Iterator
from contextlib import closing, contextmanager
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
LISTENING = "crs car-emulator: listening on 127.0.0.1:"


@contextmanager
def emulator_process(
    duration: str, *options: str, timeout: float
) -> Iterator[tuple[subprocess.Popen[str], socket.socket, tuple[str, int]]]:
    """``python -m chronos_bridge.emulator_process`` on 127.0.0.1 port 0 for ``duration`` s with
    the further ``options``, sending to a fresh host socket whose reads time out after
    ``timeout`` s; stdout and stderr are pipes. Yields ``(process, host socket, the car's
    address)`` once the process has said where it listens. On leaving, a process still running
    is killed and the socket closed."""
    host = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    with closing(host):
        host.bind(("127.0.0.1", 0))
        host.settimeout(timeout)
        command = [sys.executable, "-m", "chronos_bridge.emulator_process", "--host", "127.0.0.1"]
        command += ["--host-port", str(host.getsockname()[1]), "--port", "0"]
        command += ["--duration", duration, *options]
        process = subprocess.Popen(
            command, cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
        )
        try:
            line = process.stdout.readline()  # type: ignore[union-attr]
            assert line.startswith(LISTENING), line
            yield process, host, ("127.0.0.1", int(line.split(",")[0].rsplit(":", 1)[1]))
        finally:
            if process.poll() is None:
                process.kill()
                process.wait()
