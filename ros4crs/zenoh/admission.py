"""Who may join a listening Zenoh session: a listener reachable from the lab network must
authenticate who connects, or be opened on purpose.

A session that listens on an address other machines reach admits every machine that connects,
and a machine admitted to the link may publish a car's ``input``. :func:`check_listening` is the
one check of that, run where the settings come in (``crs launch --zenoh-listen``, ``crs
zenoh-router --listen``), before anything listens:

* an endpoint on loopback (``127.0.0.0/8``, ``::1``, ``localhost``) or a Unix socket
  (``unixsock-stream/``, ``unixpipe/``) is reached from this machine only: accepted silently;
* any other endpoint (``tcp/0.0.0.0:7447``, ``tcp/[::]:7447``, ``tcp/10.0.0.1:7447``, a host
  name) needs a Zenoh configuration (``config_file``) that authenticates who connects there:

  - user / password: ``transport/auth/usrpwd/dictionary_file`` set (a file of ``user:password``
    lines; Zenoh closes any connection without one of them before a message passes), on any
    endpoint; or
  - mutual TLS: ``transport/link/tls/enable_mtls`` true with ``root_ca_certificate`` (or
    ``root_ca_certificate_base64``), on a ``tls/`` or ``quic/`` endpoint only (a ``tcp/``
    endpoint of the same session is open whatever the TLS settings say);

  the examples are ``docs/zenoh/listener.json5`` and ``docs/zenoh/mtls-listener.json5``;
* without one it is refused (``FieldError``, one line naming the option and the examples),
  unless the user opens it on purpose (``open_listening``: ``--zenoh-open``); then the check
  returns the one warning line to print.

The files the decision rests on (the dictionary, the CA certificate) must exist: a path that
names nothing is refused naming the configuration's field (a relative path is relative to the
folder the process starts in, as Zenoh reads it). An endpoint's own ``#`` configuration is not
read: such an endpoint counts as unauthenticated. Connecting (``connect``) admits nobody and is
not checked.
"""

from __future__ import annotations

import ipaddress
import json
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from crs_core.errors import FieldError
from ros4crs.zenoh.session import ZenohSettings

__all__ = ["EXAMPLES", "check_listening", "is_local"]

#: The example configurations that authenticate who joins (docs/several-machines.md).
EXAMPLES = "docs/zenoh/listener.json5 (user/password), docs/zenoh/mtls-listener.json5 (mutual TLS)"
#: Endpoint protocols reached from this machine only.
_LOCAL_PROTOCOLS = ("unixsock-stream", "unixpipe")
#: Endpoint protocols whose links the TLS settings (and so mutual TLS) apply to.
_TLS_PROTOCOLS = ("tls", "quic")
#: The configuration's fields the check reads.
_DICTIONARY = "transport/auth/usrpwd/dictionary_file"
_TLS = "transport/link/tls"


def is_local(endpoint: str) -> bool:
    """True when only this machine can reach ``endpoint`` (``PROTOCOL/ADDRESS``, Zenoh's
    locator syntax, ``?metadata`` and ``#config`` allowed): a loopback address
    (``127.0.0.0/8``, ``::1`` also IPv4-mapped), ``localhost``, or a Unix socket."""
    protocol, _, address = endpoint.partition("/")
    if protocol.lower() in _LOCAL_PROTOCOLS:
        return True
    address = address.split("#", 1)[0].split("?", 1)[0]
    host = address.rpartition(":")[0] if ":" in address else address
    host = host.removeprefix("[").removesuffix("]")
    if host.lower().rstrip(".") == "localhost":
        return True
    try:
        ip = ipaddress.ip_address(host)
    except ValueError:
        return False  # a host name (other than localhost): it may be any interface
    if isinstance(ip, ipaddress.IPv6Address) and ip.ipv4_mapped is not None:
        ip = ip.ipv4_mapped
    return ip.is_loopback


def _config_values(config_file: Path, flag: str) -> tuple[str | None, dict[str, Any]]:
    """The configuration's ``dictionary_file`` and its TLS settings, read by Zenoh's own parser
    (``FieldError`` naming ``flag`` when Zenoh cannot read it)."""
    import zenoh

    try:
        config = zenoh.Config.from_file(str(config_file))
        dictionary = json.loads(config.get_json(_DICTIONARY))
        tls = json.loads(config.get_json(_TLS))
    except zenoh.ZError as error:
        raise FieldError(flag, f"Zenoh cannot read {config_file}: {error}") from None
    return dictionary or None, tls if isinstance(tls, dict) else {}


def _require_file(path: str, field: str, flag: str) -> None:
    """``FieldError`` naming ``flag`` and the configuration's ``field`` when ``path`` is not
    a file."""
    if not Path(path).expanduser().is_file():
        raise FieldError(
            flag,
            f"{field}: no such file: {path} (a relative path is relative to the folder the "
            "process starts in; give an absolute one)",
        )


def _mutual_tls(tls: Mapping[str, Any], flag: str) -> bool:
    """Whether the TLS settings admit only certificates of a given CA (the CA file checked)."""
    if tls.get("enable_mtls") is not True:
        return False
    ca_file = tls.get("root_ca_certificate")
    if ca_file:
        _require_file(ca_file, f"{_TLS}/root_ca_certificate", flag)
        return True
    return bool(tls.get("root_ca_certificate_base64"))


def check_listening(
    settings: ZenohSettings,
    open_listening: bool = False,
    flags: Mapping[str, str] | None = None,
    open_flag: str = "open_listening",
) -> str | None:
    """Refuse listening where other machines connect unauthenticated, unless ``open_listening``.

    Parameters
    ----------
    settings
        The session's settings: its ``listen`` endpoints and ``config_file``.
    open_listening
        The user accepts unauthenticated listening (``--zenoh-open``).
    flags
        The options (or fields) the user gave ``listen`` and ``config_file`` as, for the
        messages (e.g. ``{"listen": "--zenoh-listen", "config_file": "--zenoh-config"}``);
        default the settings' field names.
    open_flag
        The option that sets ``open_listening``, for the messages.

    Returns
    -------
    str or None
        None when every endpoint is local or authenticated; with ``open_listening`` and an
        endpoint that is neither, the one warning line to print (no prefix, no newline).

    Raises
    ------
    FieldError
        An endpoint is neither local nor authenticated and ``open_listening`` is false (naming
        ``config_file``'s option when the given configuration authenticates nothing, else
        ``listen``'s); the configuration cannot be read, or a file it names for the
        authentication does not exist (naming ``config_file``'s option and the field).
    """
    flags = flags or {}
    listen_flag = flags.get("listen", "listen")
    config_flag = flags.get("config_file", "config_file")
    remote = [endpoint for endpoint in settings.listen if not is_local(endpoint)]
    if not remote:
        return None
    config_file = settings.config_file
    unauthenticated, field, cause = remote, listen_flag, ""
    if config_file is not None:
        dictionary, tls = _config_values(Path(config_file), config_flag)
        if dictionary is not None:
            _require_file(dictionary, _DICTIONARY, config_flag)
            return None
        if _mutual_tls(tls, config_flag):
            unauthenticated = [e for e in remote if e.partition("/")[0] not in _TLS_PROTOCOLS]
            cause = (
                f" (the mutual TLS of {config_flag} {config_file} checks certificates on tls/ "
                f"and quic/ endpoints only, and it sets no {_DICTIONARY})"
            )
        else:
            field = config_flag
            cause = (
                f"{config_file} authenticates nobody (no {_DICTIONARY}, no "
                f"{_TLS}/enable_mtls with a root_ca_certificate), so "
            )
    if not unauthenticated:
        return None
    where = ", ".join(unauthenticated)
    if open_listening:
        return (
            f"{listen_flag} {where} admits any machine that reaches it, unauthenticated "
            f"({open_flag}): any of them may publish a car's input"
        )
    admits = f"{where} admits any machine that reaches it"
    admits = f"{cause}{admits}" if field == config_flag else f"{admits}{cause}"
    raise FieldError(
        field,
        f"{admits}, and any of them may publish a car's input: give {config_flag} FILE that "
        f"authenticates who joins (examples: {EXAMPLES}; docs/several-machines.md), listen on "
        f"loopback only (tcp/127.0.0.1:PORT), or pass {open_flag} to listen openly",
    )
