"""Who may join (issue 28): a listener configured with ``docs/zenoh/listener.json5`` (a user /
password dictionary) carries the samples of sessions with credentials of ``member.json5``, and
nothing of a session without them or with a wrong password: a machine that is not ours can
neither command a car (put on its ``input``) nor read the suite's keys. The ``viewer`` of its
access-control rules reads every key, and its commands to a car are dropped."""

from __future__ import annotations

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
