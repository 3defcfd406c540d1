"""The benchmarks find the shared data where the project's layout puts it."""

from __future__ import annotations

from pathlib import Path

from benchmarks.machine import REAL_DATA

PROJECT = Path(__file__).resolve().parents[2]


def test_real_recordings_are_looked_for_beside_the_project_folder():
    """``../shared/data/chronos_real`` from the project root (a wrong ``parents[...]`` once made
    ``crs bench sysid`` look inside the project and fail; another, one folder above it, after
    the benchmarks moved to ``benchmarks/``)."""
    assert (PROJECT / "pyproject.toml").is_file()
    assert REAL_DATA == PROJECT.parent / "shared" / "data" / "chronos_real"
