"""Who may join (issue 28): a listener configured with ``docs/zenoh/listener.json5`` (a user /
password dictionary) carries the samples of sessions with credentials of ``member.json5``, and
nothing of a session without them or with a wrong password: a machine that is not ours can
neither command a car (put on its ``input``) nor read the suite's keys. The ``viewer`` of its
access-control rules reads every key, and its commands to a car are dropped. With mutual TLS
(``mtls-listener.json5``, ``mtls-member.json5``) only a certificate of the lab's CA joins."""

from __future__ import annotations

import shutil
import subprocess
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from ros4crs.zenoh.session import ZenohSettings, open_session

EXAMPLES = Path(__file__).resolve().parents[3] / "docs" / "zenoh"
ENDPOINT = "tcp/127.0.0.1:17631"
#: A car's commands in ROS domain 155 (rmw_zenoh's key: domain / topic / type / hash).
INPUT_KEYS = "155/car1/input/**"
INPUT = "155/car1/input/chronos_msgs::msg::dds_::CarInput_/RIHS01_00"


@pytest.fixture
def router(monkeypatch: pytest.MonkeyPatch) -> Iterator[None]:
    """A router requiring a user and password of ``docs/zenoh/users.txt`` (the dictionary path
    is relative to the folder the router starts in)."""
    monkeypatch.chdir(EXAMPLES)
    settings = ZenohSettings("router", listen=(ENDPOINT,), config_file=EXAMPLES / "listener.json5")
    with open_session(settings):
        yield


def member(mode: str = "client", config_file: Path | None = EXAMPLES / "member.json5"):
    return open_session(ZenohSettings(mode, connect=(ENDPOINT,), config_file=config_file))


def _credentials(tmp_path: Path, user: str, password: str) -> Path:
    """A copy of ``member.json5`` with another user and password."""
    config = tmp_path / f"{user}-{password}.json5"
    text = (EXAMPLES / "member.json5").read_text()
    config.write_text(
        text.replace('"pit-laptop"', f'"{user}"').replace('"change-me-2"', f'"{password}"')
    )
    return config


class Received:
    """The payloads a subscriber got, and an event set by the first."""

    def __init__(self) -> None:
        self.payloads: list[bytes] = []
        self.first = threading.Event()

    def __call__(self, sample) -> None:
        self.payloads.append(sample.payload.to_bytes())
        self.first.set()


def test_members_exchange_samples_and_strangers_neither_command_nor_listen(
    router: None, tmp_path: Path
):
    wrong = _credentials(tmp_path, "pit-laptop", "guessed")
    # a client refuses to open without its router: no credentials, or a wrong password
    for config in (None, wrong):
        with pytest.raises(ValueError, match="Unable to connect"):
            member("client", config)
    received, overheard = Received(), {"bare": Received(), "guessing": Received()}
    with (
        member() as listener,
        member() as talker,
        member("peer", None) as bare,
        member("peer", wrong) as guessing,
    ):
        # a peer opens alone (it listens on nothing here) but is never let in
        assert not list(bare.info.routers_zid()) and not list(guessing.info.routers_zid())
        listener.declare_subscriber(INPUT_KEYS, received)
        bare.declare_subscriber(INPUT_KEYS, overheard["bare"])
        guessing.declare_subscriber(INPUT_KEYS, overheard["guessing"])
        for _ in range(50):  # until the member's subscription has reached the router
            talker.put(INPUT, b"member")
            if received.first.wait(0.1):
                break
        assert received.payloads, "a member's sample did not reach the other member"
        deadline = time.monotonic() + 1.0
        while time.monotonic() < deadline:
            bare.put(INPUT, b"stranger")
            guessing.put(INPUT, b"guessed")
            talker.put(INPUT, b"member")
            time.sleep(0.05)
    assert set(received.payloads) == {b"member"}
    # each stranger hears its own puts only (Zenoh delivers within a session)
    assert set(overheard["bare"].payloads) == {b"stranger"}
    assert set(overheard["guessing"].payloads) == {b"guessed"}


def test_a_viewer_reads_the_cars_but_cannot_command_them(router: None, tmp_path: Path):
    received, seen = Received(), Received()
    viewer_config = _credentials(tmp_path, "viewer", "change-me-3")
    state = INPUT.replace("/input/", "/estimate/state/")
    with member() as car, member() as talker, member("client", viewer_config) as viewer:
        car.declare_subscriber("155/car1/**", received)
        viewer.declare_subscriber("155/car1/**", seen)
        for _ in range(50):  # until both subscriptions have reached the router
            talker.put(state, b"member")
            if received.first.wait(0.1) and seen.first.wait(0.1):
                break
        assert b"member" in received.payloads and b"member" in seen.payloads
        for _ in range(10):
            viewer.put(INPUT, b"viewer command")
            viewer.put(state, b"viewer state")  # not a command: carried
            time.sleep(0.05)
        time.sleep(0.3)
    assert b"viewer state" in received.payloads
    assert b"viewer command" not in received.payloads


def _certificates(folder: Path) -> None:
    """The lab's CA, the listener's and a member's certificates signed by it (for localhost and
    127.0.0.1), and a stranger's signed by another CA, as docs/several-machines.md makes them."""
    extensions = folder / "leaf.ext"
    extensions.write_text(
        "subjectAltName=DNS:localhost,IP:127.0.0.1\nbasicConstraints=CA:FALSE\n"
        "extendedKeyUsage=serverAuth,clientAuth\n"
    )

    def openssl(*arguments: str) -> None:
        subprocess.run(["openssl", *arguments], cwd=folder, check=True, capture_output=True)

    new_key = ["-newkey", "ec", "-pkeyopt", "ec_paramgen_curve:P-256", "-nodes"]
    for ca in ("lab-ca", "other-ca"):
        openssl("req", "-x509", *new_key, "-keyout", f"{ca}-key.pem", "-out", f"{ca}.pem",
                "-days", "2", "-subj", f"/CN={ca}")  # fmt: skip
    for name, ca in (("listener", "lab-ca"), ("member", "lab-ca"), ("stranger", "other-ca")):
        openssl("req", *new_key, "-keyout", f"{name}-key.pem", "-out", f"{name}.csr",
                "-subj", f"/CN={name}")  # fmt: skip
        openssl(
            "x509", "-req", "-in", f"{name}.csr", "-CA", f"{ca}.pem", "-CAkey", f"{ca}-key.pem",
            "-CAcreateserial", "-out", f"{name}.pem", "-days", "2", "-extfile", "leaf.ext",
        )  # fmt: skip


@pytest.mark.skipif(shutil.which("openssl") is None, reason="no openssl to make certificates")
def test_mutual_tls_admits_the_labs_certificates_only(tmp_path: Path):
    _certificates(tmp_path)

    def config(example: str, name: str = "member") -> Path:
        """The example configuration with the certificates of ``tmp_path`` (``name``'s)."""
        path = tmp_path / f"{name}-{example}"
        text = (EXAMPLES / example).read_text().replace("/etc/crs/zenoh/", f"{tmp_path}/")
        path.write_text(text.replace("member", name))
        return path

    endpoint = "tls/localhost:17632"
    listener = ZenohSettings(
        "router", listen=(endpoint,), config_file=config("mtls-listener.json5")
    )

    def joined(config_file: Path | None):
        return open_session(ZenohSettings("client", connect=(endpoint,), config_file=config_file))

    received = Received()
    with open_session(listener) as router:
        router.declare_subscriber(INPUT_KEYS, received)
        with joined(config("mtls-member.json5")) as member_session:
            for _ in range(50):
                member_session.put(INPUT, b"member")
                if received.first.wait(0.1):
                    break
        assert received.payloads
        for stranger in (config("mtls-member.json5", "stranger"), None):
            with pytest.raises(ValueError, match="Unable to connect"):
                joined(stranger)
