"""Shared helpers of the command-line tests."""

from __future__ import annotations

import contextlib
import io
from collections.abc import Callable

import pytest

from launch_scripts.cli import main


def run_crs(argv: list[str]) -> tuple[int, str, str]:
    """``crs ARGV`` in this process, as the console script runs it: (exit code, stdout, stderr)."""
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = main(argv)
    return code, out.getvalue(), err.getvalue()


@pytest.fixture(scope="session")
def crs() -> Callable[[list[str]], tuple[int, str, str]]:
    """The ``crs`` command line in this process: ``crs(argv) -> (code, stdout, stderr)``."""
    return run_crs


def refused(argv: list[str]) -> str:
    """What ``crs ARGV`` prints when it refuses its input: exit code 2 and one line on stderr,
    ``crs COMMAND: error: ...`` without a traceback (asserted); that line."""
    code, _, err = run_crs(argv)
    assert code == 2, err
    assert err.startswith(f"crs {argv[0]}: error: "), err
    assert err.count("\n") == 1 and err.endswith("\n") and "Traceback" not in err, err
    return err


@pytest.fixture(scope="session")
def crs_refuses() -> Callable[[list[str]], str]:
    """``crs_refuses(argv)``: the error line of a refused ``crs`` command (:func:`refused`)."""
    return refused
