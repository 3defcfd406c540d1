"""The ``crs`` command line: a registry of the commands in :mod:`launch_scripts.commands`.

Each command module declares its command as data, a :class:`~launch_scripts.arguments.Command`
(name, help, description, a function adding its arguments, the handler that runs it); the
registry adds them in order. A handler returns an exit code or anything else (0). ROS is imported
only by the commands that need it. A ``ValueError``, ``KeyError`` or missing / existing file
raised by a handler is reported in one line, ``crs <command>: error: <field>: <reason>``, with
exit code 2.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable, Sequence

from chronos_bridge.emulator_process import add_command as add_car_emulator
from launch_scripts.commands import (
    bag,
    bench,
    calibration,
    consistency,
    dataset,
    discrepancy,
    estimate,
    launch,
    ros,
    simulate,
    sysid,
    viz,
    zenoh_router,
)

#: The commands in the order ``crs --help`` lists them; each adds itself to the ``crs`` parser's
#: sub-commands (a :class:`~launch_scripts.arguments.Command`, or ``car-emulator``'s own
#: ``add_command``: :mod:`chronos_bridge` declares its parser itself).
REGISTRY: tuple[Callable[[argparse._SubParsersAction], object], ...] = (
    simulate.SIM,
    simulate.DEMO,
    dataset.COMMAND,
    estimate.COMMAND,
    consistency.COMMAND,
    sysid.SYSID,
    sysid.VALIDATE,
    discrepancy.COMMAND,
    calibration.COMMAND,
    launch.COMMAND,
    viz.COMMAND,
    zenoh_router.COMMAND,
    add_car_emulator,
    bag.COMMAND,
    ros.COMMAND,
    bench.COMMAND,
)


class OneLineParser(argparse.ArgumentParser):
    """Argument errors as one line, ``crs <cmd>: error: <argument>: <reason>``, exit code 2."""

    def error(self, message: str):  # type: ignore[override]
        self.exit(2, f"{self.prog}: error: {message} (see {self.prog} --help)\n")


def make_parser() -> argparse.ArgumentParser:
    parser = OneLineParser(
        prog="crs",
        description="Chronos/CRS: simulate, estimate, identify, calibrate, race (crs COMMAND "
        "--help for one).",
    )
    commands = parser.add_subparsers(dest="command", required=True)
    for add in REGISTRY:
        add(commands)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    try:
        args = make_parser().parse_args(argv)
    except SystemExit as exit_:  # --help, or an argument error already printed in one line
        return int(exit_.code or 0)
    try:
        code = args.handler(args)  # an exit code, or what the command made (0)
    except (ValueError, KeyError, FileNotFoundError, FileExistsError) as error:
        print(f"crs {args.command}: error: {error}", file=sys.stderr)
        return 2
    return code if isinstance(code, int) else 0


if __name__ == "__main__":
    sys.exit(main())
