"""The README's Python example runs as written and prints what the README says it prints."""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def test_the_python_example_prints_what_the_readme_says(tmp_path: Path) -> None:
    readme = (ROOT / "README.md").read_text()
    example = re.search(r"^```python\n(.*?)^```\n(.*?)\n\n", readme, re.S | re.M)
    assert example, "README.md has no Python example"
    code, after = example.group(1), " ".join(example.group(2).split())
    claim = re.search(r"it prints `([^`]+)`", after)
    assert claim, f"the README does not say what the example prints: {after!r}"
    environment = {**os.environ, "PYTHONPATH": str(ROOT)}
    done = subprocess.run(
        [sys.executable, "-c", code],
        cwd=tmp_path,  # the example writes out/my_run relative to where it runs
        env=environment,
        capture_output=True,
        text=True,
        check=False,
        timeout=300,
    )
    assert done.returncode == 0, done.stderr[-2000:]
    assert done.stdout.strip() == claim.group(1)
    assert (tmp_path / "out" / "my_run").is_dir()
