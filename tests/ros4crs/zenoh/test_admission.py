"""Who may join a listening session (:mod:`ros4crs.zenoh.admission`): an endpoint other machines
reach needs a configuration that authenticates (the examples of docs/zenoh/), or is opened on
purpose with a warning; loopback passes silently. The commands that use the check are tested in
tests/launch_scripts/test_stack_part.py (``crs launch``) and
tests/launch_scripts/commands/test_zenoh_router.py; Zenoh's own enforcement of the examples in
tests/ros4crs/zenoh/test_access.py."""

from __future__ import annotations

from pathlib import Path

import pytest

from crs_core.errors import FieldError
from ros4crs.zenoh.admission import check_listening, is_local
from ros4crs.zenoh.session import ZenohSettings

EXAMPLES = Path(__file__).resolve().parents[3] / "docs" / "zenoh"
OPEN = "tcp/0.0.0.0:17650"
#: ``crs launch``'s options, as the command passes them.
FLAGS = {"listen": "--zenoh-listen", "config_file": "--zenoh-config"}


def check(*listen: str, config: Path | None = None, open_listening: bool = False) -> str | None:
    settings = ZenohSettings("peer", listen=listen, config_file=config)
    return check_listening(settings, open_listening, FLAGS, "--zenoh-open")


def refusal(*listen: str, config: Path | None = None) -> FieldError:
    with pytest.raises(FieldError) as error:
        check(*listen, config=config)
    assert "\n" not in str(error.value)
    return error.value


def mtls_config(tmp_path: Path, **changes: str) -> Path:
    """``mtls-listener.json5`` with its CA certificate in ``tmp_path`` (an empty file: only its
    existence is checked here) and the ``changes`` (old text -> new text)."""
    ca = tmp_path / "lab-ca.pem"
    ca.write_text("")
    text = (EXAMPLES / "mtls-listener.json5").read_text()
    text = text.replace("/etc/crs/zenoh/lab-ca.pem", str(ca))
    for old, new in changes.items():
        text = text.replace(old, new)
    config = tmp_path / "listener.json5"
    config.write_text(text)
    return config


@pytest.mark.parametrize(
    "endpoint",
    [
        "tcp/127.0.0.1:7447",
        "tcp/127.3.2.1:7447",
        "tcp/[::1]:7447",
        "tcp/[::ffff:127.0.0.1]:7447",
        "tcp/localhost:7447",
        "tls/LOCALHOST:7447",
        "udp/127.0.0.1:7447?rel=1#iface=lo",
        "unixsock-stream//tmp/crs.sock",
    ],
)
def test_loopback_and_unix_sockets_are_local(endpoint: str) -> None:
    assert is_local(endpoint)


@pytest.mark.parametrize(
    "endpoint",
    [
        "tcp/0.0.0.0:7447",
        "tcp/[::]:7447",
        "tcp/10.0.0.1:7447",
        "tcp/[fe80::1]:7447",
        "tls/router.lab:7447",
        "tcp/localhost.lab:7447",
        "quic/128.0.0.1:7447",
    ],
)
def test_every_other_address_is_not(endpoint: str) -> None:
    assert not is_local(endpoint)


def test_loopback_is_accepted_silently(capsys: pytest.CaptureFixture) -> None:
    assert check("tcp/127.0.0.1:17650", "tcp/[::1]:17651", "tcp/localhost:17652") is None
    assert check("tcp/127.0.0.1:17650", open_listening=True) is None  # nothing open to warn of
    assert capsys.readouterr() == ("", "")


def test_connecting_is_not_listening() -> None:
    settings = ZenohSettings("client", connect=("tcp/10.0.0.1:7447",))
    assert check_listening(settings) is None


def test_listening_openly_without_a_config_is_refused_naming_the_option_and_the_examples() -> None:
    error = refusal("tcp/127.0.0.1:17650", OPEN, "tcp/[::]:17651")
    assert error.field == "--zenoh-listen"
    assert str(error).startswith(
        "--zenoh-listen: tcp/0.0.0.0:17650, tcp/[::]:17651 admits any machine that reaches it, "
        "and any of them may publish a car's input: give --zenoh-config FILE that authenticates"
    )
    for words in (
        "docs/zenoh/listener.json5",
        "docs/zenoh/mtls-listener.json5",
        "--zenoh-open",
        "tcp/127.0.0.1:PORT",
    ):
        assert words in str(error)
    assert "tcp/127.0.0.1:17650" not in str(error)  # the loopback one is fine


def test_the_default_messages_name_the_settings_fields() -> None:
    with pytest.raises(FieldError, match=r"^listen: .* give config_file FILE .* open_listening"):
        check_listening(ZenohSettings("router", listen=(OPEN,)))


def test_a_user_password_dictionary_authenticates(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.chdir(EXAMPLES)  # its dictionary_file, users.txt, is relative
    assert check(OPEN, "tcp/[::]:17651", config=EXAMPLES / "listener.json5") is None


def test_a_dictionary_that_is_not_there_is_refused_naming_the_field(
    monkeypatch: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    monkeypatch.chdir(tmp_path)
    error = refusal(OPEN, config=EXAMPLES / "listener.json5")
    assert str(error).startswith(
        "--zenoh-config: transport/auth/usrpwd/dictionary_file: no such file: users.txt"
    )


def test_mutual_tls_authenticates_its_tls_endpoints(tmp_path: Path) -> None:
    config = mtls_config(tmp_path)
    assert check("tls/0.0.0.0:17650", "quic/[::]:17651", config=config) is None


def test_mutual_tls_leaves_a_tcp_endpoint_open(tmp_path: Path) -> None:
    """Zenoh's TLS settings apply to tls/ and quic/ links only: tcp/ beside them admits anyone."""
    error = refusal("tls/0.0.0.0:17650", "tcp/0.0.0.0:17651", config=mtls_config(tmp_path))
    assert error.field == "--zenoh-listen"
    assert str(error).startswith(
        "--zenoh-listen: tcp/0.0.0.0:17651 admits any machine that reaches it (the mutual TLS "
        "of --zenoh-config"
    )


@pytest.mark.parametrize(
    "changes",
    [
        {"enable_mtls: true": "enable_mtls: false"},  # TLS: encrypted, but anyone may connect
        {"root_ca_certificate: ": "// root_ca_certificate: "},  # no CA to check clients with
    ],
)
def test_tls_without_client_certificates_does_not_authenticate(
    tmp_path: Path, changes: dict[str, str]
) -> None:
    error = refusal("tls/0.0.0.0:17650", config=mtls_config(tmp_path, **changes))
    assert error.field == "--zenoh-config"
    assert "authenticates nobody" in str(error)


def test_a_ca_certificate_that_is_not_there_is_refused_naming_the_field() -> None:
    error = refusal("tls/0.0.0.0:17650", config=EXAMPLES / "mtls-listener.json5")
    assert str(error).startswith(
        "--zenoh-config: transport/link/tls/root_ca_certificate: no such file: "
        "/etc/crs/zenoh/lab-ca.pem"
    )


def test_a_config_that_authenticates_nobody_is_refused_naming_it() -> None:
    """``member.json5`` gives this machine's own user and password (for connecting) and checks
    nobody who connects."""
    config = EXAMPLES / "member.json5"
    error = refusal(OPEN, config=config)
    assert error.field == "--zenoh-config"
    assert str(error).startswith(
        f"--zenoh-config: {config} authenticates nobody (no "
        "transport/auth/usrpwd/dictionary_file, no transport/link/tls/enable_mtls with a "
        f"root_ca_certificate), so {OPEN} admits any machine that reaches it"
    )
    assert "docs/zenoh/listener.json5" in str(error) and "--zenoh-open" in str(error)


def test_a_config_zenoh_cannot_read_is_refused_naming_it(tmp_path: Path) -> None:
    config = tmp_path / "bad.json5"
    config.write_text("{transport: {auth: {usrpwd: {dictionary: 'users.txt'}}}}")
    error = refusal(OPEN, config=config)
    assert str(error).startswith(f"--zenoh-config: Zenoh cannot read {config}: ")
    assert "unknown field `dictionary`" in str(error)


def test_open_listening_warns_in_one_line(tmp_path: Path) -> None:
    expected = (
        f"--zenoh-listen {OPEN} admits any machine that reaches it, unauthenticated "
        "(--zenoh-open): any of them may publish a car's input"
    )
    assert check(OPEN, "tcp/127.0.0.1:17651", open_listening=True) == expected
    # the same with a configuration that authenticates nobody
    assert check(OPEN, config=EXAMPLES / "member.json5", open_listening=True) == expected


def test_open_listening_has_nothing_to_warn_of_when_authenticated(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    monkeypatch.chdir(EXAMPLES)
    assert check(OPEN, config=EXAMPLES / "listener.json5", open_listening=True) is None
