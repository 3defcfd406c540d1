"""Opening a Zenoh session the way the suite's machines meet: explicit endpoints, no multicast.

A lab's machines find each other through endpoints given on the command line
(``tcp/10.0.0.1:7447``), never through multicast scouting (off on routed and Wi-Fi networks,
and on a shared lab network it would find strangers). Three roles:

* ``router``: a Zenoh router in this process (no ``zenohd`` binary): it listens, and routes
  between the sessions that connect to it (``crs zenoh-router``).
* ``peer``: listens and/or connects; peers talk directly once connected (two machines: one
  listens, the other connects).
* ``client``: connects to a router only; the mode a stock ``rmw_zenohd`` router needs, which
  does not forward between peers.

Security (TLS endpoints and certificates, user / password authentication, access-control rules)
is Zenoh's own configuration: ``config_file`` names a Zenoh JSON5 configuration that is read first;
the settings' mode, endpoints and scouting are applied over it. Whether a listener beyond
loopback authenticates who joins is checked by the commands, before the session opens
(:func:`ros4crs.zenoh.admission.check_listening`).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from crs_core.errors import FieldError
from crs_core.settings import Settings

__all__ = ["MODES", "ZenohSettings", "open_session", "zenoh_config"]

#: The session roles (Zenoh's ``mode``).
MODES = ("router", "peer", "client")


@dataclass(frozen=True)
class ZenohSettings(Settings):
    """How this machine joins the Zenoh link.

    Attributes
    ----------
    mode : {"router", "peer", "client"}
        The session's role (:data:`MODES`).
    listen : tuple of str
        Endpoints to listen on, Zenoh locators such as ``tcp/0.0.0.0:7447``.
    connect : tuple of str
        Endpoints to connect to, such as ``tcp/10.0.0.1:7447``.
    config_file : Path or None
        A Zenoh JSON5 configuration read first (TLS, ``transport/auth``, ``access_control``);
        ``mode``, the endpoints and the scouting settings are set over it.
    """

    mode: str = "peer"
    listen: tuple[str, ...] = ()
    connect: tuple[str, ...] = ()
    config_file: Path | None = None

    def _check_relations(self) -> None:
        if self.mode not in MODES:
            raise FieldError("mode", f"must be one of {', '.join(MODES)}, got {self.mode!r}")
        for name in ("listen", "connect"):
            for endpoint in getattr(self, name):
                protocol, slash, address = str(endpoint).partition("/")
                if not (protocol and slash and address):
                    raise FieldError(
                        name,
                        f"an endpoint is PROTOCOL/ADDRESS (tcp/10.0.0.1:7447), got {endpoint!r}",
                    )
        if self.mode == "client" and not self.connect:
            raise FieldError("connect", "a client needs a router to connect to")
        if self.mode != "client" and not (self.listen or self.connect):
            raise FieldError(
                "listen", f"a {self.mode} needs an endpoint to listen on or connect to"
            )
        if self.config_file is not None and not Path(self.config_file).is_file():
            raise FieldError("config_file", f"no such file: {self.config_file}")


def zenoh_config(settings: ZenohSettings):
    """The ``zenoh.Config`` of ``settings``: the configuration file's (if any), with the mode,
    the endpoints, multicast scouting off and gossip on (peers learn of each other through
    the ones they connect to)."""
    import json

    import zenoh

    if settings.config_file is not None:
        config = zenoh.Config.from_file(str(settings.config_file))
    else:
        config = zenoh.Config()
    config.insert_json5("mode", json.dumps(settings.mode))
    config.insert_json5("listen/endpoints", json.dumps(list(settings.listen)))
    config.insert_json5("connect/endpoints", json.dumps(list(settings.connect)))
    config.insert_json5("scouting/multicast/enabled", "false")
    config.insert_json5("scouting/gossip/enabled", "true")
    return config


def open_session(settings: ZenohSettings):
    """A Zenoh session for ``settings`` (``zenoh.Session``; close it, or use it as a context
    manager). Raises ``FieldError`` naming ``listen`` when an endpoint cannot be bound, and
    ``connect`` when a client cannot reach its router."""
    import zenoh

    try:
        return zenoh.open(zenoh_config(settings))
    except zenoh.ZError as error:
        field = "connect" if "connect" in str(error).lower() and settings.connect else "listen"
        raise FieldError(field, f"cannot open the Zenoh session: {error}") from None
