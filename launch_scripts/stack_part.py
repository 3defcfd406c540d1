"""One machine's part of a stack (``crs launch sim|car --nodes``) and the Zenoh link that joins
the parts.

A stack's nodes can run on several machines: each runs ``crs launch`` with the same stack
options and its own ``--nodes``, and the suite's topics travel between the machines through one
``zenoh_link`` node per machine (:mod:`ros4crs.zenoh_link_node`: it discovers the local
publishers and carries every topic across; ``docs/several-machines.md``). :class:`StackPart`
says which of a stack's nodes run here and how this machine joins the link; its
:meth:`~StackPart.launched` is the one selection both stacks apply to their nodes
(:func:`launch_scripts.sim_stack.stack_nodes`, :func:`launch_scripts.car_stack.car_nodes`).

The simulator holds its clock until its sensor topics have their subscribers
(:meth:`StackPart.sensor_subscribers`). A far subscriber is not seen as itself: the link node
subscribes locally in its place, once however many far subscribers there are, so the simulator
waits for the local ones plus the link (with no link, the others are on this machine's DDS, from
another ``crs launch``). It also waits for a publisher of commands, which is the far controller
through the link's local publisher; the controller publishes from its start (stop commands until
it has estimates), so that publisher appears whether the link declares it on discovery or on the
first sample.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from crs_core.errors import FieldError
from launch_scripts.launcher import NodeSpec
from ros4crs.zenoh.session import ZenohSettings

__all__ = ["LINK_NODE", "STACK_NODES", "StackPart", "link_node", "parse_nodes"]

#: The nodes of each stack, by the names ``--nodes`` takes (per car, and one recorder and, with
#: ``--viz``, one visualizer).
STACK_NODES: dict[str, tuple[str, ...]] = {
    "sim": ("simulator", "estimator", "controller", "recorder", "visualizer"),
    "car": ("bridge", "estimator", "controller", "recorder", "visualizer"),
}
#: Processes that run with another node: an emulated car (``crs launch car --emulate``) with
#: its bridge.
GOES_WITH = {"emulator": "bridge"}
#: The nodes of every stack that subscribe to a car's sensor topics.
SENSOR_SUBSCRIBERS = ("estimator", "recorder")
#: The link node's name (global namespace) and module.
LINK_NODE = ("zenoh_link", "ros4crs.zenoh_link_node")

_ALL_NODES = tuple(dict.fromkeys(name for names in STACK_NODES.values() for name in names))


def parse_nodes(text: str) -> tuple[str, ...]:
    """``NAME[,NAME...]`` -> the names, each a node of some stack, none twice (``ValueError``
    naming the name)."""
    names = tuple(part.strip() for part in text.split(","))
    _check_names(names)
    return names


def _check_names(names: Sequence[str]) -> None:
    """``ValueError`` unless ``names`` are nodes of some stack, none twice."""
    for name in names:
        if name not in _ALL_NODES:
            raise ValueError(f"{name!r} is not a node (one of {', '.join(_ALL_NODES)})")
    if len(set(names)) != len(names):
        raise ValueError(f"{','.join(names)!r} names a node twice")


@dataclass(frozen=True)
class StackPart:
    """The part of a stack this machine runs.

    Attributes
    ----------
    nodes : tuple of str or None
        The stack's nodes that run here (names of :data:`STACK_NODES`, for every car; an
        emulated car goes with its ``bridge``); None: all of them.
    zenoh : ZenohSettings or None
        How this machine joins the Zenoh link (a ``zenoh_link`` node is launched); None: no
        link (one machine, or the others on this machine's DDS).
    """

    nodes: tuple[str, ...] | None = None
    zenoh: ZenohSettings | None = None

    def __post_init__(self) -> None:
        if self.nodes is not None:
            if not self.nodes:
                raise FieldError("nodes", "name at least one node")
            try:
                _check_names(self.nodes)
            except ValueError as error:
                raise FieldError("nodes", str(error)) from None

    def runs(self, name: str) -> bool:
        """True when the stack's node (or process) ``name`` runs here."""
        return self.nodes is None or GOES_WITH.get(name, name) in self.nodes

    def check(self, stack: str, field: str = "nodes") -> None:
        """``FieldError`` naming ``field`` when a node is not one of ``stack``'s
        (``"sim"`` or ``"car"``)."""
        foreign = [name for name in self.nodes or () if name not in STACK_NODES[stack]]
        if foreign:
            raise FieldError(
                field,
                f"{', '.join(foreign)}: not a node of the {stack} stack (its nodes: "
                f"{', '.join(STACK_NODES[stack])})",
            )

    def launched(self, specs: Iterable[NodeSpec], stack: str) -> list[NodeSpec]:
        """The ``specs`` of ``stack``'s nodes that run here, then the link node (if any)."""
        self.check(stack)
        here = [spec for spec in specs if self.runs(spec.name)]
        return here + ([link_node(self.zenoh)] if self.zenoh is not None else [])

    def sensor_subscribers(self) -> int:
        """How many subscribers of its sensor topics the simulator waits for: the local ones
        of :data:`SENSOR_SUBSCRIBERS`, plus the link (one subscription for all the far ones),
        or with no link the others themselves (on this machine's DDS)."""
        here = sum(self.runs(name) for name in SENSOR_SUBSCRIBERS)
        far = len(SENSOR_SUBSCRIBERS) - here
        return here + (min(far, 1) if self.zenoh is not None else far)

    def described(self) -> dict[str, Any]:
        """For a report: the nodes that run here (None: all) and the link settings."""
        zenoh = self.zenoh
        return {
            "nodes": list(self.nodes) if self.nodes is not None else None,
            "zenoh": None
            if zenoh is None
            else {
                "mode": zenoh.mode,
                "listen": list(zenoh.listen),
                "connect": list(zenoh.connect),
                "config_file": str(zenoh.config_file) if zenoh.config_file else None,
            },
        }


def link_node(settings: ZenohSettings) -> NodeSpec:
    """The ``zenoh_link`` node joining this machine to the others as ``settings`` say (its
    ``topics`` empty: every topic; no ``domain``: the node's default, the ROS domain the
    launcher gives every process)."""
    name, module = LINK_NODE
    config = settings.config_file
    return NodeSpec(
        name,
        module,
        "",
        {
            "mode": settings.mode,
            "listen": ",".join(settings.listen),
            "connect": ",".join(settings.connect),
            "config_file": str(Path(config).resolve()) if config is not None else "",
            "topics": "",
        },
    )


#: ``crs launch``'s Zenoh options, by the :class:`ZenohSettings` field they set.
ZENOH_FLAGS = {
    "mode": "--zenoh-mode",
    "listen": "--zenoh-listen",
    "connect": "--zenoh-connect",
    "config_file": "--zenoh-config",
}


def zenoh_settings(
    mode: str | None,
    listen: Sequence[str] | None,
    connect: Sequence[str] | None,
    config_file: Path | None,
) -> ZenohSettings | None:
    """``crs launch``'s Zenoh options as settings (``mode`` default ``peer``); None when none
    is given. Errors name the option."""
    if mode is None and not listen and not connect and config_file is None:
        return None
    try:
        return ZenohSettings(mode or "peer", tuple(listen or ()), tuple(connect or ()), config_file)
    except FieldError as error:
        raise error.renamed(ZENOH_FLAGS[error.field]) from None
