"""``crs zenoh-router`` as a process: two client sessions exchange a sample through it, Ctrl-C
stops it with exit code 0, and a port in use is refused in one line. Who may join: it listens on
loopback unless told; beyond loopback it needs a ``--config`` that authenticates (a router with
docs/zenoh/listener.json5 on every interface admits members and refuses strangers) or
``--zenoh-open`` (one warning line)."""

from __future__ import annotations

import signal
import subprocess
import sys
import threading
from pathlib import Path

import pytest

from crs_core.errors import FieldError
from launch_scripts.cli import main
from launch_scripts.commands import zenoh_router
from ros4crs.zenoh import session
from ros4crs.zenoh.admission import is_local
from ros4crs.zenoh.session import ZenohSettings, open_session

ENDPOINT = "tcp/127.0.0.1:17621"
EXAMPLES = Path(__file__).resolve().parents[3] / "docs" / "zenoh"


def _start_router(endpoint: str, *options: str, cwd: Path | None = None) -> subprocess.Popen:
    router = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "launch_scripts.cli",
            "zenoh-router",
            "--listen",
            endpoint,
            *options,
        ],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        cwd=cwd,
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


# --- who may join -----------------------------------------------------------------------------


class _OpenCalledError(Exception):
    """Raised by the stand-in of ``open_session``: the router got as far as opening."""


def _opened_settings(argv: list[str], monkeypatch: pytest.MonkeyPatch) -> ZenohSettings:
    """The settings ``crs zenoh-router ARGV`` opens its session with (nothing listens)."""
    opened: list[ZenohSettings] = []

    def fake_open(settings: ZenohSettings):
        opened.append(settings)
        raise _OpenCalledError

    monkeypatch.setattr(session, "open_session", fake_open)
    with pytest.raises(_OpenCalledError):
        main(["zenoh-router", *argv])
    return opened[0]


def test_it_listens_on_loopback_by_default_silently(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture
):
    assert zenoh_router.DEFAULT_LISTEN == "tcp/127.0.0.1:7447"
    assert is_local(zenoh_router.DEFAULT_LISTEN)
    assert _opened_settings([], monkeypatch).listen == (zenoh_router.DEFAULT_LISTEN,)
    assert capsys.readouterr().err == ""


def test_listening_openly_is_refused_in_one_line_naming_config_and_the_examples(
    capsys: pytest.CaptureFixture,
):
    assert main(["zenoh-router", "--listen", "tcp/0.0.0.0:17623"]) == 2
    err = capsys.readouterr().err
    assert err.startswith(
        "crs zenoh-router: error: --listen: tcp/0.0.0.0:17623 admits any machine that reaches "
        "it, and any of them may publish a car's input: give --config FILE that authenticates "
        "who joins (examples: docs/zenoh/listener.json5 (user/password), "
        "docs/zenoh/mtls-listener.json5 (mutual TLS);"
    ), err
    assert "or pass --zenoh-open to listen openly" in err
    assert err.count("\n") == 1


def test_a_config_that_authenticates_nobody_is_refused_in_one_line(capsys: pytest.CaptureFixture):
    argv = ["--listen", "tcp/[::]:17623", "--config", str(EXAMPLES / "member.json5")]
    assert main(["zenoh-router", *argv]) == 2
    err = capsys.readouterr().err
    assert err.startswith("crs zenoh-router: error: --config: ")
    assert "member.json5 authenticates nobody" in err
    assert err.count("\n") == 1


def test_zenoh_open_listens_openly_after_one_warning(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture
):
    settings = _opened_settings(["--listen", "tcp/0.0.0.0:17623", "--zenoh-open"], monkeypatch)
    assert settings.listen == ("tcp/0.0.0.0:17623",)
    assert capsys.readouterr().err == (
        "crs zenoh-router: warning: --listen tcp/0.0.0.0:17623 admits any machine that reaches "
        "it, unauthenticated (--zenoh-open): any of them may publish a car's input\n"
    )


def test_a_router_on_every_interface_with_user_passwords_admits_members_only():
    """End to end: ``crs zenoh-router --listen tcp/0.0.0.0:PORT --config listener.json5``
    (started in docs/zenoh/, where its relative dictionary_file is) starts without a warning;
    two members (``member.json5``) exchange a sample through it, a stranger is refused."""
    router = _start_router(
        "tcp/0.0.0.0:17624", "--config", str(EXAMPLES / "listener.json5"), cwd=EXAMPLES
    )
    try:
        address = ("tcp/127.0.0.1:17624",)
        member = ZenohSettings("client", connect=address, config_file=EXAMPLES / "member.json5")
        with pytest.raises(FieldError, match="Unable to connect"):
            open_session(ZenohSettings("client", connect=address))  # no credentials
        received = threading.Event()
        with open_session(member) as listener, open_session(member) as talker:
            listener.declare_subscriber("155/car1/input/**", lambda sample: received.set())
            for _ in range(50):  # until the subscription has reached the talker's router
                talker.put("155/car1/input/test", b"hello")
                if received.wait(0.1):
                    break
        assert received.is_set()
        router.send_signal(signal.SIGINT)
        assert router.wait(10) == 0
        assert router.stderr.read() == ""  # no warning: authenticated
    finally:
        if router.poll() is None:
            router.kill()
            router.wait()
