"""``crs zenoh-router`` as a process: two client sessions exchange a sample through it, Ctrl-C
stops it with exit code 0, and a port in use is refused in one line."""

from __future__ import annotations

import signal
import subprocess
import sys
import threading

import pytest

from launch_scripts.cli import main
from ros4crs.zenoh.session import ZenohSettings, open_session

ENDPOINT = "tcp/127.0.0.1:17621"


def _start_router(endpoint: str) -> subprocess.Popen:
    router = subprocess.Popen(
        [sys.executable, "-m", "launch_scripts.cli", "zenoh-router", "--listen", endpoint],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    line = router.stdout.readline()
    assert line.startswith(f"crs zenoh-router: listening on {endpoint}, zid "), (
        line + router.stderr.read()
    )
    return router


def test_two_clients_exchange_a_sample_through_the_router_until_ctrl_c():
    router = _start_router(ENDPOINT)
    try:
        client = ZenohSettings("client", connect=(ENDPOINT,))
        received = threading.Event()
        payloads: list[bytes] = []

        def on_sample(sample) -> None:
            payloads.append(sample.payload.to_bytes())
            received.set()

        with open_session(client) as listener, open_session(client) as talker:
            listener.declare_subscriber("155/car1/input/**", on_sample)
            for _ in range(50):  # until the subscription has reached the talker's router
                talker.put("155/car1/input/test", b"hello")
                if received.wait(0.1):
                    break
        assert payloads and payloads[0] == b"hello"
        router.send_signal(signal.SIGINT)
        assert router.wait(10) == 0
        assert "crs zenoh-router: stopped" in router.stdout.read()
    finally:
        if router.poll() is None:
            router.kill()
            router.wait()


def test_a_port_in_use_is_refused_in_one_line(capsys: pytest.CaptureFixture):
    router = _start_router("tcp/127.0.0.1:17622")
    try:
        assert main(["zenoh-router", "--listen", "tcp/127.0.0.1:17622"]) == 2
        err = capsys.readouterr().err
        assert err.startswith(
            "crs zenoh-router: error: --listen: tcp/127.0.0.1:17622: the address is in use"
        ), err
        assert err.count("\n") == 1
    finally:
        router.terminate()
        assert router.wait(10) == 0


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["--listen", "7447"], "--listen: an endpoint is PROTOCOL/ADDRESS"),
        (["--config", "/no/such.json5"], "--config: no such file"),
    ],
)
def test_bad_options_are_refused_in_one_line(
    argv: list[str], message: str, capsys: pytest.CaptureFixture
):
    assert main(["zenoh-router", *argv]) == 2
    assert message in capsys.readouterr().err
