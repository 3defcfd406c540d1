"""The shared argparse pieces: a command declared as data, bounded numbers and parsers whose
``ValueError`` becomes the one-line argument error."""

from __future__ import annotations

import argparse
import math

import pytest

from launch_scripts.arguments import Command, argument_type, bounded_number


def test_a_bounded_number_takes_its_interval_and_refuses_the_rest_naming_itself() -> None:
    speed = bounded_number("speed", "m/s", 0.0, 5.0)
    assert speed.__name__ == "speed"
    assert speed("5") == 5.0 and speed("1e-9") == 1e-9  # (low, high]
    refusals = {
        "0": "'0': speed must be > 0 and <= 5 m/s",
        "5.000001": "'5.000001': speed must be > 0 and <= 5 m/s",
        "nan": "'nan': speed must be > 0 and <= 5 m/s",
        "inf": "'inf': speed must be > 0 and <= 5 m/s",
        "fast": "'fast' is not a number",
    }
    for text, message in refusals.items():
        with pytest.raises(argparse.ArgumentTypeError) as error:
            speed(text)
        assert str(error.value) == message


def test_an_integer_with_an_included_low_and_no_high() -> None:
    cars = bounded_number("cars", "", 1, kind=int, include_low=True)
    assert cars("1") == 1 and isinstance(cars("1"), int) and cars("100000") == 100000
    with pytest.raises(argparse.ArgumentTypeError) as error:
        cars("0")
    assert str(error.value) == "'0': cars must be >= 1"  # no unit: nothing trails
    with pytest.raises(argparse.ArgumentTypeError) as error:
        cars("1.5")
    assert str(error.value) == "'1.5' is not an integer"


def test_argument_type_turns_a_value_error_into_an_argument_error() -> None:
    def angle(text: str) -> float:
        value = float(text)
        if not math.isfinite(value):
            raise ValueError(f"{text!r}: the angle must be finite")
        return value

    parse = argument_type(angle)
    assert parse.__name__ == "angle" and parse("0.5") == 0.5
    with pytest.raises(argparse.ArgumentTypeError) as error:
        parse("inf")
    assert str(error.value) == "'inf': the angle must be finite"
    parser = argparse.ArgumentParser(prog="crs test", exit_on_error=False)
    parser.add_argument("--angle", type=parse)
    with pytest.raises(argparse.ArgumentError, match="'inf': the angle must be finite"):
        parser.parse_args(["--angle", "inf"])


def _add_name(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("name")


def _greet(args: argparse.Namespace) -> str:
    return f"hello {args.name}"


def test_a_command_adds_its_parser_arguments_and_handler() -> None:
    parser = argparse.ArgumentParser(prog="crs")
    commands = parser.add_subparsers(dest="command", required=True)
    greet = Command(
        "greet", help="say hello", description="Say hello.", arguments=_add_name, handler=_greet
    )
    added = greet(commands)
    assert added.prog == "crs greet" and added.description == "Say hello."
    assert "say hello" in parser.format_help()
    args = parser.parse_args(["greet", "you"])
    assert args.command == "greet" and args.handler(args) == "hello you"


def test_a_command_with_subcommands_requires_one_of_them(capsys: pytest.CaptureFixture) -> None:
    parser = argparse.ArgumentParser(prog="crs")
    commands = parser.add_subparsers(dest="command", required=True)
    modes = tuple(
        Command(name, help=f"{name} mode", arguments=_add_name, handler=_greet)
        for name in ("loud", "quiet")
    )
    Command("greet", help="say hello", subcommands=modes, dest="mode", metavar="MODE")(commands)
    args = parser.parse_args(["greet", "quiet", "you"])
    assert (args.command, args.mode, args.handler(args)) == ("greet", "quiet", "hello you")
    with pytest.raises(SystemExit):
        parser.parse_args(["greet"])
    assert "the following arguments are required: MODE" in capsys.readouterr().err
    with pytest.raises(ValueError, match="greet: a command with sub-commands needs a dest"):
        Command("greet", help="say hello", subcommands=modes)
