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
