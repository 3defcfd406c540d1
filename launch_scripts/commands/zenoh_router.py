"""``crs zenoh-router``: a Zenoh router in this process (no ``zenohd`` binary), for a lab whose
machines meet at one place (``docs/several-machines.md``)."""

from __future__ import annotations

import argparse
import signal
import threading
from pathlib import Path

from crs_core.errors import FieldError
from launch_scripts.arguments import Command, endpoints

#: Where the router listens unless told: every interface, Zenoh's port (as ``rmw_zenohd``).
DEFAULT_LISTEN = "tcp/[::]:7447"
#: The signals that stop the router (exit code 0).
_STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM)


def zenoh_router(args: argparse.Namespace) -> int:
    """Open a router session listening on ``--listen`` (with ``--config``), print one line with
    its endpoints and Zenoh id, and run until SIGINT or SIGTERM (exit code 0)."""
    from ros4crs.zenoh.session import ZenohSettings, open_session

    flags = {"listen": "--listen", "config_file": "--config"}
    try:
        settings = ZenohSettings(
            "router", listen=tuple(args.listen or (DEFAULT_LISTEN,)), config_file=args.config
        )
        session = open_session(settings)
    except FieldError as error:
        if "already in use" in error.reason:
            raise FieldError(
                "--listen",
                f"{', '.join(settings.listen)}: the address is in use (another router, or a crs "
                "launch --zenoh-listen, on this machine?)",
            ) from None
        raise error.renamed(flags.get(error.field, error.field)) from None
    stop = threading.Event()
    previous = {sig: signal.signal(sig, lambda *_: stop.set()) for sig in _STOP_SIGNALS}
    try:
        print(
            f"crs zenoh-router: listening on {', '.join(settings.listen)}, zid "
            f"{session.info.zid()} (Ctrl-C stops)",
            flush=True,
        )
        while not stop.wait(0.5):
            pass
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)
        session.close()
    print("crs zenoh-router: stopped", flush=True)
    return 0


def add_arguments(sub: argparse.ArgumentParser) -> None:
    """``crs zenoh-router``'s arguments."""
    sub.add_argument(
        "--listen",
        action="extend",
        type=endpoints,
        metavar="ENDPOINT",
        help=f"where the router listens (repeatable or comma-separated; default {DEFAULT_LISTEN}"
        ", every interface)",
    )
    sub.add_argument(
        "--config",
        type=Path,
        metavar="FILE",
        help="a Zenoh JSON5 configuration read first: TLS, who may join (transport/auth/usrpwd), "
        "access control; --listen, the router mode and the scouting are set over it (examples: "
        "docs/zenoh/)",
    )


COMMAND = Command(
    "zenoh-router",
    help="a Zenoh router joining the machines of a split stack",
    description="A Zenoh router in this process (no zenohd binary): the machines of a stack "
    "split with crs launch --nodes connect to it (--zenoh-connect tcp/THIS_HOST:7447, "
    "--zenoh-mode client or peer), and it routes between them. Prints its endpoints and Zenoh "
    "id, runs until Ctrl-C or SIGTERM. Who may join: --config with the examples of docs/zenoh/ "
    "(docs/several-machines.md).",
    arguments=add_arguments,
    handler=zenoh_router,
)
