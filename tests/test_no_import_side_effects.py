"""Library code leaves matplotlib's global state alone.

Importing any module of the project must neither switch matplotlib's backend (as
``matplotlib.use("Agg")`` did) nor load ``matplotlib.pyplot``: a notebook user who imports the
core keeps their backend and their pyplot figures. The figures are drawn with matplotlib's
object-oriented API (``matplotlib.figure.Figure``) instead.
"""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
#: The packages walked. ros4crs is left out on purpose: its modules are ROS 2 nodes (rclpy and
#: the generated message packages), draw nothing, and are allowed to be skipped.
PACKAGES = ("crs_core", "sim", "launch_scripts", "chronos_bridge")

# Runs in a fresh interpreter with MPLBACKEND=svg; prints one JSON line.
_SCRIPT = r"""
import importlib, json, pkgutil, sys

import matplotlib

# Missing pieces of a ROS 2 installation: a module whose import fails for one of these is
# skipped (it needs the ROS 2 runtime), any other import failure fails the test.
ROS_NAMES = (
    "rclpy", "rosbag2", "rosidl", "rpyutils", "rmw", "rcl_interfaces", "builtin_interfaces",
    "std_msgs", "geometry_msgs", "nav_msgs", "sensor_msgs", "tf2_msgs", "chronos_msgs",
)
backend = matplotlib.get_backend()
names = []
for package in PACKAGES:
    names.append(package)
    module = importlib.import_module(package)
    walk = pkgutil.walk_packages(module.__path__, package + ".", onerror=lambda name: None)
    names += [info.name for info in walk if not info.name.endswith(".__main__")]
imported, skipped, failed = [], {}, {}
first_pyplot = first_backend = None
for name in names:
    try:
        importlib.import_module(name)
    except ImportError as error:
        text = f"{type(error).__name__}: {error}"
        target = skipped if any(r in f"{error.name} {error}" for r in ROS_NAMES) else failed
        target[name] = text
        continue
    except Exception as error:
        failed[name] = f"{type(error).__name__}: {error}"
        continue
    imported.append(name)
    if first_pyplot is None and "matplotlib.pyplot" in sys.modules:
        first_pyplot = name
    if first_backend is None and matplotlib.rcParams["backend"] != backend:
        first_backend = name
pyplot_loaded = "matplotlib.pyplot" in sys.modules
print(json.dumps({
    "before": backend,
    "backend": matplotlib.get_backend(),
    "pyplot": pyplot_loaded,
    "first_pyplot": first_pyplot,
    "first_backend": first_backend,
    "imported": imported,
    "skipped": skipped,
    "failed": failed,
}))
"""


def test_importing_every_module_keeps_the_backend_and_loads_no_pyplot():
    env = {**os.environ, "MPLBACKEND": "svg"}
    script = f"PACKAGES = {PACKAGES!r}\n{_SCRIPT}"
    done = subprocess.run(
        [sys.executable, "-c", script],
        cwd=ROOT,
        env=env,
        capture_output=True,
        text=True,
        timeout=120,
        check=False,
    )
    assert done.returncode == 0, done.stderr
    report = json.loads(done.stdout.strip().splitlines()[-1])
    assert report["failed"] == {}, report["failed"]
    assert len(report["imported"]) > 50, report
    assert report["before"] == "svg"
    assert report["backend"] == "svg", f"backend switched by {report['first_backend']}"
    assert not report["pyplot"], f"matplotlib.pyplot loaded by {report['first_pyplot']}"


def test_library_sources_use_neither_pyplot_nor_matplotlib_use():
    """Also inside functions (drawn lazily): no ``pyplot`` import and no ``matplotlib.use``."""
    pattern = re.compile(r"matplotlib\.pyplot|from matplotlib import pyplot|matplotlib\.use\(")
    offenders = [
        f"{path.relative_to(ROOT)}:{number}"
        for package in (*PACKAGES, "ros4crs")
        for path in sorted((ROOT / package).rglob("*.py"))
        for number, line in enumerate(path.read_text(encoding="utf-8").splitlines(), 1)
        if pattern.search(line)
    ]
    assert offenders == []
