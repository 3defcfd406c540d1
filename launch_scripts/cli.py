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
import importlib
import sys
from collections.abc import Callable, Sequence

#: The commands in the order ``crs --help`` lists them: each name, and where what adds it to the
#: ``crs`` parser's sub-commands lives (``module:attribute``: a
#: :class:`~launch_scripts.arguments.Command`, or ``car-emulator``'s own ``add_command``:
#: :mod:`chronos_bridge` declares its parser itself). A run imports only its command's module.
REGISTRY: dict[str, str] = {
    "sim": "launch_scripts.commands.simulate:SIM",
    "demo": "launch_scripts.commands.simulate:DEMO",
    "dataset": "launch_scripts.commands.dataset:COMMAND",
    "estimate": "launch_scripts.commands.estimate:COMMAND",
    "tune-noise": "launch_scripts.commands.tune_noise:COMMAND",
    "consistency": "launch_scripts.commands.consistency:COMMAND",
    "sysid": "launch_scripts.commands.sysid:SYSID",
    "validate": "launch_scripts.commands.sysid:VALIDATE",
    "discrepancy": "launch_scripts.commands.discrepancy:COMMAND",
    "plan-drive": "launch_scripts.commands.plan_drive:COMMAND",
    "calibrate-lighthouse": "launch_scripts.commands.calibration:COMMAND",
    "launch": "launch_scripts.commands.launch:COMMAND",
    "viz": "launch_scripts.commands.viz:COMMAND",
    "zenoh-router": "launch_scripts.commands.zenoh_router:COMMAND",
    "car-emulator": "chronos_bridge.emulator_process:add_command",
    "bag": "launch_scripts.commands.bag:COMMAND",
    "ros": "launch_scripts.commands.ros:COMMAND",
    "bench": "launch_scripts.commands.bench:COMMAND",
}


def command_adder(name: str) -> Callable[[argparse._SubParsersAction], object]:
    """What adds the command ``name`` (a key of :data:`REGISTRY`) to the sub-commands."""
    module, attribute = REGISTRY[name].split(":")
    return getattr(importlib.import_module(module), attribute)


class OneLineParser(argparse.ArgumentParser):
    """Argument errors as one line, ``crs <cmd>: error: <argument>: <reason>``, exit code 2."""

    def error(self, message: str):  # type: ignore[override]
        self.exit(2, f"{self.prog}: error: {message} (see {self.prog} --help)\n")


def make_parser(command: str | None = None) -> argparse.ArgumentParser:
    """The ``crs`` parser: with only ``command``'s sub-command when it names one (a run needs
    no other command's module, and their imports cost ~0.7 s), else with every command."""
    parser = OneLineParser(
        prog="crs",
        description="Chronos/CRS: simulate, estimate, identify, calibrate, race (crs COMMAND "
        "--help for one).",
    )
    commands = parser.add_subparsers(dest="command", required=True)
    for name in [command] if command in REGISTRY else REGISTRY:
        command_adder(name)(commands)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    try:
        args = make_parser(argv[0] if argv else None).parse_args(argv)
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
