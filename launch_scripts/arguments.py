"""What the ``crs`` commands share: :class:`Command`, the declaration of a command (its parser,
arguments and handler, added by :mod:`launch_scripts.cli`), the option blocks several commands
take, and argument types (one-line errors naming the value)."""

from __future__ import annotations

import argparse
import math
import shlex
import sys
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from crs_core.errors import FieldError

OVERWRITE_HELP = (
    "replace the --out an earlier crs run wrote (a folder holding other files is always refused)"
)


@dataclass(frozen=True)
class Command:
    """A ``crs`` command, or a sub-command of one, declared as data.

    ``name``, ``help`` (its line in the parent's ``--help``), ``description``, ``epilog`` and
    ``formatter_class`` make its parser; ``arguments(parser)`` adds its options; ``handler(args)``
    runs it (:func:`launch_scripts.cli.main` calls it: an exit code, or anything else for 0).
    A command with ``subcommands`` picks one of them (required) as ``args.<dest>``, listed as
    ``metavar`` (default: their names); each sub-command has its own handler. Called with a
    parser's sub-commands, it adds itself there (the registry of :mod:`launch_scripts.cli`).
    """

    name: str
    help: str
    description: str | None = None
    arguments: Callable[[argparse.ArgumentParser], None] | None = None
    handler: Callable[[argparse.Namespace], Any] | None = None
    subcommands: Sequence[Command] = ()
    dest: str | None = None
    metavar: str | None = None
    epilog: str | None = None
    formatter_class: type[argparse.HelpFormatter] = argparse.HelpFormatter

    def __post_init__(self) -> None:
        if self.subcommands and self.dest is None:
            raise ValueError(f"{self.name}: a command with sub-commands needs a dest")

    def __call__(self, parsers: argparse._SubParsersAction) -> argparse.ArgumentParser:
        """Add this command to ``parsers`` (a parser's sub-commands); return its parser."""
        parser = parsers.add_parser(
            self.name,
            help=self.help,
            description=self.description,
            epilog=self.epilog,
            formatter_class=self.formatter_class,
        )
        if self.arguments is not None:
            self.arguments(parser)
        if self.subcommands:
            chosen = parser.add_subparsers(dest=self.dest, required=True, metavar=self.metavar)
            for subcommand in self.subcommands:
                subcommand(chosen)
        if self.handler is not None:
            parser.set_defaults(handler=self.handler)
        return parser


def command_line() -> str:
    """This run's command, ``crs ARGS`` (shell-quoted), as the reports and JSON files record it."""
    return "crs " + " ".join(shlex.quote(a) for a in sys.argv[1:])


def argument_type(parse: Callable[[str], Any]) -> Callable[[str], Any]:
    """An argparse type from a parser raising ``ValueError`` (its message, one line)."""

    def parse_argument(text: str) -> Any:
        try:
            return parse(text)
        except ValueError as error:
            raise argparse.ArgumentTypeError(str(error)) from None

    parse_argument.__name__ = parse.__name__
    return parse_argument


def bounded_number(
    name: str,
    unit: str,
    low: float,
    high: float = math.inf,
    kind: type = float,
    *,
    include_low: bool = False,
) -> Callable[[str], Any]:
    """An argparse type: a finite ``kind`` in ``(low, high]`` (``[low, high]`` with
    ``include_low``), the error naming ``name``: ``'0': stations must be >= 1 and <= 8``."""

    def parse(text: str) -> Any:
        try:
            value = kind(text)
        except ValueError:
            what = "an integer" if kind is int else "a number"
            raise argparse.ArgumentTypeError(f"{text!r} is not {what}") from None
        above = value >= low if include_low else value > low
        if not (math.isfinite(value) and above and value <= high):
            bounds = f"{name} must be {'>=' if include_low else '>'} {low:g}"
            if math.isfinite(high):
                bounds += f" and <= {high:g}"
            raise argparse.ArgumentTypeError(f"{text!r}: {bounds} {unit}".rstrip())
        return value

    parse.__name__ = name
    return parse


def add_track(parser: argparse.ArgumentParser, whose: str = "") -> None:
    """``--track``: a track YAML file (unset: the demo track); ``whose`` follows "track YAML"
    in the help."""
    parser.add_argument(
        "--track", type=Path, help=f"track YAML{whose} (CRS format; default: DEMO_TRACK)"
    )


def add_domain(parser: argparse.ArgumentParser, whose: str, default: str) -> None:
    """``--domain``: a ROS_DOMAIN_ID, 0..232 (unset: ``None``, the caller picks ``default``, which
    the help names); ``whose`` follows "ROS_DOMAIN_ID" in the help."""
    parser.add_argument(
        "--domain",
        type=bounded_number("domain", "", -1, 232, int),
        help=f"ROS_DOMAIN_ID{whose}, 0..232 (default: {default})",
    )


#: Longest simulation, race or benchmark run the CLI accepts, s.
MAX_DURATION_S = 3600.0


def add_out(parser: argparse.ArgumentParser, help_text: str, **kwargs: Any) -> None:
    """``--out`` (a ``Path``) and ``--overwrite`` (replace what an earlier run wrote there)."""
    parser.add_argument("--out", type=Path, help=help_text, **kwargs)
    parser.add_argument("--overwrite", action="store_true", help=OVERWRITE_HELP)


def add_duration(parser: argparse.ArgumentParser, default: float, what: str) -> None:
    """``--duration``: ``what`` in s, ``(0, MAX_DURATION_S]``."""
    parser.add_argument(
        "--duration",
        type=bounded_number("duration", "s", 0.0, MAX_DURATION_S),
        default=default,
        help=f"{what}, s (default {default:g}, at most {MAX_DURATION_S:g})",
    )


def add_evaluations(parser: argparse.ArgumentParser, what: str) -> None:
    """``--evaluations`` of a drive design: how many drives its search simulates (default 400)."""
    parser.add_argument(
        "--evaluations",
        type=bounded_number("evaluations", "", 1, 100000, kind=int, include_low=True),
        default=400,
        help=f"drives {what} simulates (default 400, ~0.2 s each)",
    )


def add_estimator(parser: argparse.ArgumentParser) -> None:
    """``--estimator ekf|mhe`` (default mhe)."""
    parser.add_argument(
        "--estimator", choices=["ekf", "mhe"], default="mhe", help="(default mhe, at 60 Hz)"
    )


def add_seed(
    parser: argparse.ArgumentParser, help_text: str = "seed of all noise", default: int = 0
) -> None:
    """``--seed`` (an integer, default ``default``)."""
    parser.add_argument(
        "--seed",
        type=bounded_number("seed", "", 0, 2**31 - 1, int, include_low=True),
        default=default,
        help=f"{help_text}, 0..2^31-1 (default {default})",
    )


def add_cars(parser: argparse.ArgumentParser) -> None:
    """``--cars`` of a launched stack: 1..8 (default 1)."""
    parser.add_argument(
        "--cars", type=bounded_number("cars", "", 0, 8, int), default=1, help="1..8 (default 1)"
    )


def add_simulated_stations(parser: argparse.ArgumentParser, help_text: str) -> None:
    """``--stations``: the Lighthouse base stations of a simulation, 1..8 (default 1)."""
    stations = bounded_number("stations", "", 0, 8, int)
    parser.add_argument("--stations", type=stations, default=1, help=help_text)


def _parse_effect(text: str) -> Any:
    """:func:`crs_core.model.effects.parse_effect`, imported when an option is parsed (the
    model's package imports casadi: a command that parses no effect does not load it)."""
    from crs_core.model.effects import parse_effect

    return parse_effect(text)


def add_effect(
    parser: argparse.ArgumentParser, help_text: str, dest: str = "effect", flag: str = "--effect"
) -> None:
    """``--effect NAME[.PARAM][=VALUE]`` (repeatable): a model effect, every command building a
    model takes it (``flag`` and ``dest``: another option of the same kind, e.g. the simulated
    car's ``--car-effect``)."""
    parser.add_argument(
        flag,
        dest=dest,
        type=argument_type(_parse_effect),
        action="append",
        metavar="NAME[.PARAM][=VALUE]",
        help=help_text,
    )


def _parse_model(text: str) -> str:
    """A model spec that loads (:func:`~crs_core.model.plants.load_plant`), kept as given."""
    from crs_core.model.plants import load_plant

    try:
        load_plant(text)
    except FieldError as error:
        raise ValueError(error.reason) from None
    return text.strip()


def add_model(
    parser: argparse.ArgumentParser,
    help_text: str = "the model: dynamic (default), kinematic, or FILE.py:CLASS / MODULE:CLASS, "
    "a model of your own (docs/own-model.md); by default the one --params names",
    flag: str = "--model",
    dest: str = "model",
) -> None:
    """``--model SPEC``: which model a command runs (``flag`` and ``dest``: another option of
    the same kind, e.g. the simulated car's ``--car-model``)."""
    parser.add_argument(
        flag, dest=dest, type=argument_type(_parse_model), metavar="MODEL", help=help_text
    )


def add_process_scale(parser: argparse.ArgumentParser, help_text: str) -> None:
    """``--process-scale``: a factor > 0 on the process noise std of an identification's FIE
    (default 1.0)."""
    parser.add_argument(
        "--process-scale",
        type=bounded_number("process-scale", "", 0.0),
        default=1.0,
        help=help_text,
    )


def endpoints(text: str) -> list[str]:
    """An argparse type for ``action="extend"``: ``ENDPOINT[,ENDPOINT...]`` -> the Zenoh
    endpoints (a repeated option collects them all; checked where the settings are made)."""
    return [endpoint.strip() for endpoint in text.split(",") if endpoint.strip()]


#: The option that lets a Zenoh listener beyond loopback admit any machine, unauthenticated
#: (``crs launch``, ``crs zenoh-router``; :func:`ros4crs.zenoh.admission.check_listening`).
ZENOH_OPEN = "--zenoh-open"


def add_zenoh_open(parser: argparse.ArgumentParser, listen: str, config: str) -> None:
    """:data:`ZENOH_OPEN` (``args.zenoh_open``), for a command listening on its option
    ``listen`` with the Zenoh configuration of its option ``config``."""
    parser.add_argument(
        ZENOH_OPEN,
        action="store_true",
        help=f"let {listen} beyond loopback admit any machine, unauthenticated (one warning "
        f"line); without it such a listener needs a {config} that authenticates who joins "
        "(user/password or mutual TLS; examples: docs/zenoh/)",
    )
