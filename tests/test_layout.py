"""The tests mirror the tree (issue 26): the tests of module ``package/a/b.py`` live in
``tests/package/a/test_b.py`` (of ``package/x.py`` in ``tests/package/test_x.py``), and every
test file there is named after the module it tests.

Only the packages listed in ``MIRRORED`` are checked; another package is added by listing it
(with its exemptions) once its tests are mirrored.
"""

from __future__ import annotations

from collections.abc import Collection
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]

#: The packages whose tests mirror their tree.
MIRRORED = ("crs_core",)

#: Modules (path from the repository root) with no test file of their own, each with the reason.
#: A test of their own makes no sense for these; their behaviour is asserted where it is used.
EXEMPT: dict[str, str] = {
    # Draws the calibration figures into files (matplotlib) and returns their paths; that they
    # are written is checked end to end by the calibration command-line tests
    # (tests/launch_scripts/commands/test_calibration.py).
    "crs_core/calibration/plots.py": "figures only, checked through the calibration command",
}

#: Modules whose tests exist but still sit in another module's test file, each with where they
#: are and where they go. Empty this as the tests move.
PENDING: dict[str, str] = {}

#: Test files (path from the repository root) in a mirrored folder that are not named after a
#: module of the package, each with the reason.
STRAY: dict[str, str] = {}


def modules(package: str, root: Path = ROOT) -> list[str]:
    """Every module of ``package`` (not ``__init__.py``), as a path from ``root``."""
    return sorted(
        p.relative_to(root).as_posix()
        for p in (root / package).rglob("*.py")
        if p.name != "__init__.py"
    )


def mirror(module: str) -> str:
    """``crs_core/a/b.py`` -> ``tests/crs_core/a/test_b.py``."""
    path = Path(module)
    return (Path("tests") / path.parent / f"test_{path.name}").as_posix()


def mirrored_test_files(package: str, root: Path = ROOT) -> list[str]:
    return sorted(
        p.relative_to(root).as_posix() for p in (root / "tests" / package).rglob("test_*.py")
    )


def missing_mirrors(package: str, allowed: Collection[str], root: Path = ROOT) -> list[str]:
    """The modules of ``package`` without their mirrored test file (``allowed`` left out)."""
    return [
        module
        for module in modules(package, root)
        if module not in allowed and not (root / mirror(module)).is_file()
    ]


def stray_test_files(package: str, allowed: Collection[str], root: Path = ROOT) -> list[str]:
    """The test files under ``tests/package`` named after no module (``allowed`` left out)."""
    mirrored = {mirror(module) for module in modules(package, root)}
    return [f for f in mirrored_test_files(package, root) if f not in mirrored | set(allowed)]


@pytest.mark.parametrize("package", MIRRORED)
def test_every_module_has_its_mirrored_test_file(package: str) -> None:
    missing = missing_mirrors(package, EXEMPT.keys() | PENDING.keys())
    assert not missing, "\n".join(f"{module}: no {mirror(module)}" for module in missing)


@pytest.mark.parametrize("package", MIRRORED)
def test_every_test_file_mirrors_a_module(package: str) -> None:
    stray = stray_test_files(package, STRAY)
    assert not stray, "test files named after no module:\n" + "\n".join(stray)


def test_every_exemption_is_still_needed() -> None:
    """An exemption names an existing module (or test file) that still lacks its mirror."""
    known = {module for package in MIRRORED for module in modules(package)}
    stale = [
        module
        for module in EXEMPT.keys() | PENDING.keys()
        if module not in known or (ROOT / mirror(module)).is_file()
    ]
    stale += [f for f in STRAY if not (ROOT / f).is_file()]
    assert not stale, "exemptions no longer needed:\n" + "\n".join(sorted(stale))


def test_the_mirror_of_a_module() -> None:
    assert mirror("crs_core/track/geometry.py") == "tests/crs_core/track/test_geometry.py"
    assert mirror("crs_core/dataset.py") == "tests/crs_core/test_dataset.py"


def test_a_planted_module_without_tests_and_a_stray_test_file_are_found(tmp_path: Path) -> None:
    for name in (
        "pkg/__init__.py",
        "pkg/a.py",
        "pkg/sub/__init__.py",
        "pkg/sub/b.py",
        "pkg/sub/c.py",
        "tests/pkg/test_a.py",
        "tests/pkg/sub/test_b.py",
        "tests/pkg/sub/test_topic.py",
        "tests/pkg/sub/conftest.py",
    ):
        (tmp_path / name).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / name).touch()
    assert missing_mirrors("pkg", (), tmp_path) == ["pkg/sub/c.py"]
    assert missing_mirrors("pkg", {"pkg/sub/c.py"}, tmp_path) == []
    assert stray_test_files("pkg", (), tmp_path) == ["tests/pkg/sub/test_topic.py"]
