"""The benchmarks find the shared data where the project's layout puts it."""

from __future__ import annotations

from pathlib import Path

from benchmarks.machine import REAL_DATA, format_ms

PROJECT = Path(__file__).resolve().parents[2]


def test_real_recordings_are_looked_for_beside_the_project_folder():
    """``../shared/data/chronos_real`` from the project root (a wrong ``parents[...]`` once made
    ``crs bench sysid`` look inside the project and fail; another, one folder above it, after
    the benchmarks moved to ``benchmarks/``)."""
    assert (PROJECT / "pyproject.toml").is_file()
    assert REAL_DATA == PROJECT.parent / "shared" / "data" / "chronos_real"


def test_a_time_in_ms_has_three_significant_digits_and_no_exponent() -> None:
    assert [format_ms(v) for v in (0.03812, 0.781, 3.0, 41.26, 241.4, 1899.6, 12345.0)] == [
        "0.0381", "0.781", "3", "41.3", "241", "1900", "12345",
    ]  # fmt: skip
