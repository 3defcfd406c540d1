"""Shared fixtures of the command-line tests (the helpers: :mod:`tests.launch_scripts.crs_cli`)."""

from __future__ import annotations

from collections.abc import Callable

import pytest

from tests.launch_scripts.crs_cli import refused, run_crs


@pytest.fixture(scope="session")
def crs() -> Callable[[list[str]], tuple[int, str, str]]:
    """The ``crs`` command line in this process: ``crs(argv) -> (code, stdout, stderr)``."""
    return run_crs


@pytest.fixture(scope="session")
def crs_refuses() -> Callable[[list[str]], str]:
    """``crs_refuses(argv)``: the error line of a refused ``crs`` command (:func:`refused`)."""
    return refused
