"""Tests of the ``crs`` command line: each bad argument and each run-time error is one line with
exit code 2."""

from __future__ import annotations

from pathlib import Path

import pytest

from launch_scripts.cli import main

BAD_INPUTS = [
    (["sim", "--duration", "inf"], "crs sim: error: argument --duration: 'inf': duration must be"),
    (["sim", "--duration", "1e9"], "duration must be > 0 and <= 3600 s"),
    (["sim", "--duration", "-3"], "duration must be > 0 and <= 3600 s"),
    (["sim", "--duration", "nan"], "argument --duration: 'nan'"),
    (["sim", "--blackout", "bogus:1:1"], "argument --blackout: 'bogus:1:1': sensor 'bogus'"),
    (["sim", "--blackout", "lighthouse:nan:1"], "START 'nan' is not a finite number"),
    (["sim", "--blackout", "lighthouse:1"], "expected SENSOR:START:DURATION"),
    (["sim", "--speed", "-1"], "argument --speed: '-1': speed must be > 0 and <= 5 m/s"),
    (["sim", "--stations", "0"], "argument --stations: '0': stations must be > 0"),
    (["launch", "sim", "--duration", "0"], "crs launch: error: argument --duration: '0'"),
    (["launch", "sim", "--cars", "0"], "argument --cars: '0': cars must be > 0"),
    (
        ["launch", "sim", "--output", "velocity", "--controller", "path"],
        "crs launch: error: --output: velocity needs --controller mpcc (the path controller",
    ),
    (["launch", "sim", "--output", "speed"], "crs launch: error: argument --output: invalid"),
    (["ros", "echo"], "crs ros: error: TOPIC: echo needs a topic"),
    (["ros", "hz", "/car1/input", "--window", "-1"], "argument --window: '-1': window must"),
]


@pytest.mark.parametrize(("argv", "message"), BAD_INPUTS)
def test_bad_arguments_give_one_line_and_start_nothing(
    argv: list[str], message: str, tmp_path: Path, crs_refuses
):
    """Each bad argument: exit code 2, one line naming the argument, no output written."""
    out = tmp_path / "out"
    if argv[0] in ("sim", "launch"):
        argv = [*argv, "--out", str(out)]
    assert message in crs_refuses(argv)
    assert not out.exists()


def test_run_time_errors_exit_with_code_2(tmp_path: Path, capsys: pytest.CaptureFixture):
    """A missing parameter file or a zero duration returns 2 with a `crs sim: error:` line."""
    code = main(["sim", "--out", str(tmp_path / "a"), "--params", str(tmp_path / "none.yaml")])
    assert code == 2
    assert "crs sim: error:" in capsys.readouterr().err
    code = main(["sim", "--out", str(tmp_path / "b"), "--duration", "0"])
    assert code == 2
    assert "duration must be > 0" in capsys.readouterr().err


def _parsers(parser):
    """``parser`` and every sub-command's parser below it, depth first."""
    import argparse

    yield parser
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for child in action.choices.values():
                yield from _parsers(child)


def test_every_command_has_a_help_text() -> None:
    """``--help`` of every command and sub-command formats (a ``%`` in a help text that argparse
    would read as a format breaks it)."""
    from launch_scripts.cli import make_parser

    parsers = list(_parsers(make_parser()))
    assert len(parsers) > 20
    for parser in parsers:
        assert parser.format_help().startswith("usage: "), parser.prog


def test_the_registry_names_each_command_as_it_adds_itself() -> None:
    import argparse

    from launch_scripts.cli import REGISTRY, command_adder

    for name in REGISTRY:
        commands = argparse.ArgumentParser().add_subparsers()
        command_adder(name)(commands)
        assert list(commands.choices) == [name]


def test_a_run_imports_only_its_own_commands_module() -> None:
    """``crs ros --help`` in a fresh interpreter: no other command's module is imported (nor
    casadi, which the model's commands need)."""
    import subprocess
    import sys

    code = (
        "import sys\nfrom launch_scripts.cli import main\n"
        "assert main(['ros', '--help']) == 0\n"
        "print(sorted(m for m in sys.modules if m.startswith('launch_scripts.commands.') "
        "or m == 'casadi'))"
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip().splitlines()[-1] == "['launch_scripts.commands.ros']"
