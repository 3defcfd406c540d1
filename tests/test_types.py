"""Issue 26: the type hints of crs_core are checked by a type checker.

Runs the venv's mypy (pinned in requirements.lock) over crs_core with the configuration in
pyproject.toml (``[tool.mypy]``: the files, the Python version, the one library without types),
in a subprocess from the repository root, as ``.venv/bin/mypy`` does by hand. Its incremental
cache, ``.mypy_cache/`` (git-ignored), makes every run after the first take well under a
second; the first, with no cache, takes 10 to 20 s.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def test_crs_core_passes_mypy():
    pytest.importorskip(
        "mypy.api",
        reason="mypy is not installed in this environment (requirements.lock pins it: "
        "./run.sh setup installs it)",
    )
    result = subprocess.run(
        [sys.executable, "-m", "mypy", "--config-file", str(ROOT / "pyproject.toml")],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=600,
        check=False,
    )
    assert result.returncode == 0, (
        f"mypy over crs_core failed (exit {result.returncode}):\n{result.stdout}{result.stderr}"
    )
