"""Opening the Zenoh session (:mod:`ros4crs.zenoh.session`): the settings' checks, the
configuration they give, and a refused endpoint as a ``FieldError`` naming ``listen``."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from crs_core.errors import FieldError
from ros4crs.zenoh.session import ZenohSettings, open_session, zenoh_config


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"mode": "hub", "listen": ("tcp/127.0.0.1:17540",)}, "mode: must be one of"),
        ({"listen": ("127.0.0.1:17540",)}, "listen: an endpoint is PROTOCOL/ADDRESS"),
        ({"mode": "client"}, "connect: a client needs a router to connect to"),
        ({"mode": "peer"}, "listen: a peer needs an endpoint"),
        ({"connect": ("tcp/h:1",), "config_file": Path("/nonexistent.json5")}, "config_file"),
    ],
)
def test_bad_settings_name_the_field(kwargs: dict, message: str) -> None:
    with pytest.raises(FieldError, match=message):
        ZenohSettings(**kwargs)


def test_the_configuration_has_the_endpoints_and_no_multicast() -> None:
    settings = ZenohSettings("router", listen=("tcp/127.0.0.1:17541",))
    config = zenoh_config(settings)
    assert json.loads(config.get_json("mode")) == "router"
    assert json.loads(config.get_json("listen/endpoints")) == ["tcp/127.0.0.1:17541"]
    assert json.loads(config.get_json("scouting/multicast/enabled")) is False
    assert json.loads(config.get_json("scouting/gossip/enabled")) is True


def test_an_endpoint_in_use_is_refused_naming_listen() -> None:
    settings = ZenohSettings("peer", listen=("tcp/127.0.0.1:17542",))
    with open_session(settings) as session:
        assert str(session.zid())
        with pytest.raises(FieldError, match=r"^listen: cannot open the Zenoh session"):
            open_session(settings)


def test_a_client_without_its_router_is_refused_naming_connect() -> None:
    with pytest.raises(FieldError, match=r"^connect: cannot open the Zenoh session"):
        open_session(ZenohSettings("client", connect=("tcp/127.0.0.1:17598",)))
