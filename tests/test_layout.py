"""The tests mirror the tree (issue 26): the tests of module ``package/a/b.py`` live in
``tests/package/a/test_b.py`` (of ``package/x.py`` in ``tests/package/test_x.py``), and every
test file there is named after the module it tests.

Every package is listed in ``MIRRORED``; generated modules (``*_pb2.py``) are not mirrored.
``tests/integration`` is the one folder that mirrors nothing (``NOT_MIRRORED``). Every folder under
``tests/`` is a package, so test files with the same name in two folders do not clash. Helper
modules (``stack_probe.py``, ``bridge_builders.py``, ``conftest.py``, ...) are not test files: only
``test_*.py`` is checked.
"""

from __future__ import annotations

from collections.abc import Collection
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]

#: The packages whose tests mirror their tree.
MIRRORED = ("crs_core", "ros4crs", "chronos_bridge", "sim", "launch_scripts", "benchmarks")

#: Folders under tests/ that mirror no package, each with the reason.
NOT_MIRRORED: dict[str, str] = {
    # Its tests start real node processes talking DDS (several modules of several packages at
    # once), so they are named after what they drive, not after one module.
    "integration": "multi-process tests of the running stack",
    # A model written outside crs_core, loaded by path as a researcher's would be (docs/
    # own-model.md's example); a fixture of the model tests, not a test of its own.
    "own_model": "a model from outside crs_core, loaded by path by the tests",
}

#: Generated modules, not mirrored (their tests are named after what they check).
GENERATED = "*_pb2.py"

#: Modules (path from the repository root) with no test file of their own, each with the reason.
#: A test of their own makes no sense for these; their behaviour is asserted where it is used.
EXEMPT: dict[str, str] = {
    # Draws the calibration figures into files (matplotlib) and returns their paths; that they
    # are written is checked end to end by the calibration command-line tests
    # (tests/launch_scripts/commands/test_calibration.py).
    "crs_core/calibration/plots.py": "figures only, checked through the calibration command",
    # ROS nodes: started as processes by tests/integration (test_bridge, test_stack, test_replay);
    # what they share is tested in tests/ros4crs (node_support, settings_parameters, conversions).
    "ros4crs/replayer_node.py": "a ROS node, driven by tests/integration/test_replay.py",
    # Need a running graph; tests/integration/test_tools.py drives them.
    "ros4crs/tools.py": "needs a running ROS graph, driven by tests/integration/test_tools.py",
    "launch_scripts/commands/ros.py": "needs a running ROS graph, driven by test_tools.py",
    # A build tool needing grpcio-tools; its output (the *_pb2.py) is checked by
    # tests/chronos_bridge/proto/test_bridge_wire_format.py.
    "chronos_bridge/proto/regenerate.py": "build tool (grpcio-tools), its output is tested",
    # A full simulation; it provides the recordings of the calibration tests.
    "sim/mocap_recording.py": "a full simulation, used by the calibration tests",
    # Needs a dataset on disk; covered by test_output_folder.py and the crs_core model tests.
    "launch_scripts/commands/consistency.py": "needs a dataset on disk, covered elsewhere",
    # Runs of minutes without a cheap public function; their docs tables are checked by
    # tests/benchmarks/test_docs.py.
    "benchmarks/contingency.py": "minutes-long runs, docs table checked by test_docs.py",
    # The model interface's modules are tested together in tests/crs_core/model/test_plant.py
    # (the interface, the loader, the kinematic bicycle against the dynamic one).
    "crs_core/model/car_state.py": "two constants, used by every model test",
    "crs_core/model/kinematic.py": "tested in tests/crs_core/model/test_plant.py",
    "crs_core/model/plants.py": "tested in tests/crs_core/model/test_plant.py",
    "launch_scripts/stack_models.py": "tested through tests/launch_scripts/commands/test_launch.py",
    "benchmarks/control_peers.py": "minutes-long runs, docs table checked by test_docs.py",
}

#: Modules whose tests exist but still sit in another module's test file, each with where they
#: are and where they go. Empty this as the tests move.
PENDING: dict[str, str] = {}

#: Test files (path from the repository root) in a mirrored folder that are not named after a
#: module of the package, each with the reason.
STRAY: dict[str, str] = {
    # The MPCC, hold-safety filter and supervisor, and the FIE, on models other than the
    # dynamic bicycle (issue 41): several modules each.
    "tests/crs_core/control/test_other_models.py": "control on the kinematic and own models",
    "tests/crs_core/identification/test_other_models.py": "identification of other models",
    # Checks the parameter table of every node in docs/ros-interface.md against the parameters
    # the nodes declare (read from the source of all of ros4crs), not one module.
    "tests/ros4crs/test_parameter_docs.py": "docs/ros-interface.md against every node",
    # Checks the .proto files and the generated chronos_pb2 / vector3_pb2 (not mirrored) against
    # the wire-format spec, the output of regenerate.py.
    "tests/chronos_bridge/proto/test_bridge_wire_format.py": "the generated protobuf modules",
    # Checks who may join a Zenoh link: Zenoh's own authentication and access control, set up by
    # the example configurations of docs/zenoh/ through ros4crs.zenoh.session's config_file.
    "tests/ros4crs/zenoh/test_access.py": "the docs/zenoh/ configurations, Zenoh's own checks",
    # The tests of the package ros4crs/viz_page/ (its __init__.py: the page server) and of the
    # page's static files beside it.
    "tests/ros4crs/test_viz_page.py": "the ros4crs.viz_page package: page server and files",
    # Online parameters (crs_core.model.online, tested beside it) estimated by the EKF and the
    # MHE on simulated cars: the estimators and the model together, not one module.
    "tests/crs_core/estimation/test_online.py": "online parameters through the EKF and the MHE",
}


def modules(package: str, root: Path = ROOT) -> list[str]:
    """Every module of ``package`` (not ``__init__.py``, not generated), as a path from ``root``."""
    return sorted(
        p.relative_to(root).as_posix()
        for p in (root / package).rglob("*.py")
        if p.name != "__init__.py" and not p.match(GENERATED)
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


def test_every_tests_folder_is_a_package() -> None:
    """An ``__init__.py`` in every folder: test files are imported by their package path, so two
    with the same name in different folders do not clash."""
    folders = [ROOT / "tests", *(ROOT / "tests").rglob("*/")]
    missing = [
        f.relative_to(ROOT).as_posix()
        for f in folders
        if f.is_dir() and f.name != "__pycache__" and not (f / "__init__.py").is_file()
    ]
    assert not missing, "folders without __init__.py:\n" + "\n".join(missing)


def test_every_tests_folder_mirrors_a_package_or_says_why_not() -> None:
    folders = {f.name for f in (ROOT / "tests").iterdir() if f.is_dir() and f.name != "__pycache__"}
    assert folders == set(MIRRORED) | NOT_MIRRORED.keys()
    assert not set(MIRRORED) & NOT_MIRRORED.keys()


def test_generated_modules_are_not_mirrored(tmp_path: Path) -> None:
    for name in ("pkg/__init__.py", "pkg/proto/__init__.py", "pkg/proto/wire_pb2.py"):
        (tmp_path / name).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / name).touch()
    assert modules("pkg", tmp_path) == []


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
