"""``crs zenoh-router``: a Zenoh router in this process (no ``zenohd`` binary), for a lab whose
machines meet at one place (``docs/several-machines.md``)."""

from __future__ import annotations

import argparse
import signal
import sys
import threading
from pathlib import Path

from crs_core.errors import FieldError
from launch_scripts.arguments import ZENOH_OPEN, Command, add_zenoh_open, endpoints

#: Where the router listens unless told: this machine only, Zenoh's port. Listening for the
#: lab network (``--listen tcp/0.0.0.0:7447``) needs a ``--config`` that authenticates who
#: joins, or ``--zenoh-open`` (:func:`ros4crs.zenoh.admission.check_listening`).
DEFAULT_LISTEN = "tcp/127.0.0.1:7447"
#: The options by the :class:`~ros4crs.zenoh.session.ZenohSettings` field they set.
FLAGS = {"listen": "--listen", "config_file": "--config"}
#: The signals that stop the router (exit code 0).
_STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM)


def zenoh_router(args: argparse.Namespace) -> int:
    """Open a router session listening on ``--listen`` (with ``--config``), print one line with
    its endpoints and Zenoh id, and run until SIGINT or SIGTERM (exit code 0). Listening beyond
    loopback needs a ``--config`` that authenticates who joins, or ``--zenoh-open`` (then one
    warning line on stderr first)."""
    from ros4crs.zenoh.admission import check_listening
    from ros4crs.zenoh.session import ZenohSettings, open_session

    try:
        settings = ZenohSettings(
            "router", listen=tuple(args.listen or (DEFAULT_LISTEN,)), config_file=args.config
        )
        warning = check_listening(settings, args.zenoh_open, FLAGS, ZENOH_OPEN)
        if warning is not None:
            print(f"crs zenoh-router: warning: {warning}", file=sys.stderr, flush=True)
        session = open_session(settings)
    except FieldError as error:
        if "already in use" in error.reason:
            raise FieldError(
                "--listen",
                f"{', '.join(settings.listen)}: the address is in use (another router, or a crs "
                "launch --zenoh-listen, on this machine?)",
            ) from None
        raise error.renamed(FLAGS.get(error.field, error.field)) from None
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
        ", this machine only; e.g. tcp/0.0.0.0:7447 for the lab network, with an "
        "authenticating --config or --zenoh-open)",
    )
    sub.add_argument(
        "--config",
        type=Path,
        metavar="FILE",
        help="a Zenoh JSON5 configuration read first: TLS, who may join (transport/auth/usrpwd), "
        "access control; --listen, the router mode and the scouting are set over it (examples: "
        "docs/zenoh/)",
    )
    add_zenoh_open(sub, "--listen", "--config")


COMMAND = Command(
    "zenoh-router",
    help="a Zenoh router joining the machines of a split stack",
    description="A Zenoh router in this process (no zenohd binary): the machines of a stack "
    "split with crs launch --nodes connect to it (--zenoh-connect tcp/THIS_HOST:7447, "
    "--zenoh-mode client or peer), and it routes between them. Prints its endpoints and Zenoh "
    "id, runs until Ctrl-C or SIGTERM. It listens on this machine only unless --listen says "
    "otherwise; listening beyond loopback needs a --config that authenticates who joins (the "
    "examples of docs/zenoh/, docs/several-machines.md) or --zenoh-open.",
    arguments=add_arguments,
    handler=zenoh_router,
)
