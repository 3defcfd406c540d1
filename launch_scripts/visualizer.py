"""The visualizer node of a launched stack (``crs launch sim|car --viz``) or of ``crs viz``
(:mod:`ros4crs.visualizer_node`: the Foxglove WebSocket and the built-in page)."""

from __future__ import annotations

import argparse
import ipaddress
from dataclasses import dataclass
from typing import Any

from crs_core.errors import FieldError
from launch_scripts.launcher import NodeSpec

__all__ = [
    "DEFAULT_PAGE_PORT",
    "DEFAULT_PORT",
    "VIZ_NODE",
    "VizSettings",
    "add_serving_options",
    "visualizer_node",
]

#: The node's name (global namespace) and module.
VIZ_NODE = ("visualizer", "ros4crs.visualizer_node")
#: The Foxglove WebSocket's port unless told (the Foxglove app's default).
DEFAULT_PORT = 8765
#: The built-in page's HTTP port unless told.
DEFAULT_PAGE_PORT = 8766


@dataclass(frozen=True)
class VizSettings:
    """Where the visualizer serves (``FieldError`` naming the field when it cannot).

    Attributes
    ----------
    host : str
        The address both servers bind to: ``127.0.0.1`` (this machine only) unless told;
        ``0.0.0.0`` serves every interface (the lab network), never by default.
    port : int
        The Foxglove WebSocket's TCP port.
    page_port : int
        The built-in page's TCP port (not ``port``).
    """

    host: str = "127.0.0.1"
    port: int = DEFAULT_PORT
    page_port: int = DEFAULT_PAGE_PORT

    def __post_init__(self) -> None:
        try:
            ipaddress.ip_address(self.host)
        except ValueError:
            raise FieldError("host", f"must be an IP address, got {self.host!r}") from None
        for name in ("port", "page_port"):
            value = getattr(self, name)
            if not 1 <= value <= 65535:
                raise FieldError(name, f"must be in 1..65535, got {value}")
        if self.page_port == self.port:
            raise FieldError("page_port", f"must differ from port, got {self.page_port}")

    def parameters(self) -> dict[str, Any]:
        """The node's ``host``, ``port`` and ``page_port``."""
        return {"host": self.host, "port": self.port, "page_port": self.page_port}


def visualizer_node(settings: VizSettings, cars: int, files: dict[str, str]) -> NodeSpec:
    """The visualizer of a stack of ``cars`` cars (``/car1``...), serving as ``settings`` say,
    with the stack's ``track_file`` (of ``files``, if given)."""
    track = {"track_file": files["track_file"]} if "track_file" in files else {}
    name, module = VIZ_NODE
    cars_text = ",".join(f"car{i}" for i in range(1, cars + 1))
    return NodeSpec(name, module, "", {**settings.parameters(), "cars": cars_text, **track})


def add_serving_options(parser: argparse.ArgumentParser, prefix: str, what: str = "") -> None:
    """``--PREFIXport``, ``--PREFIXpage-port`` and ``--PREFIXhost`` (``crs viz``: no prefix;
    ``crs launch --viz``: ``viz-``), each the :class:`VizSettings` field of its name, none
    given by default (the settings' defaults apply); ``what`` starts each help text."""
    from launch_scripts.arguments import bounded_number

    for name, default, text in (
        ("port", DEFAULT_PORT, "the Foxglove WebSocket's port"),
        ("page-port", DEFAULT_PAGE_PORT, "the built-in page's port"),
    ):
        parser.add_argument(
            f"--{prefix}{name}",
            type=bounded_number(f"{prefix}{name}", "", 1, 65535, int, include_low=True),
            metavar="N",
            help=f"{what}{text} (default {default})",
        )
    parser.add_argument(
        f"--{prefix}host",
        metavar="HOST",
        help=f"{what}the address both serve on (default 127.0.0.1, this machine only; "
        "0.0.0.0: every interface, for the lab network)",
    )
