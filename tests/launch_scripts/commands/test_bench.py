"""Tests of ``crs bench``: what it passes to a benchmark and what it saves (the benchmark itself
is replaced; nothing is measured here)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest

from benchmarks import link as link_benchmark
from launch_scripts.cli import main


def test_bench_link_passes_its_matrix(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture
):
    seen: dict[str, Any] = {}

    def fake_bench(work: Path, **kwargs: Any) -> dict[str, Any]:
        seen.update(kwargs, work=work)
        return {"duration_s": 15.0, "estimator": "mhe", "controller": "mpcc", "seed": 3, "runs": []}

    monkeypatch.setattr(link_benchmark, "link_benchmark", fake_bench)
    out = tmp_path / "link.json"
    argv = ["bench", "link", "--presets", "clean,bad", "--loads", "0", "--cars", "1"]
    assert main([*argv, "--duration", "15", "--seed", "3", "--out", str(out)]) == 0
    assert seen["presets"] == ("clean", "bad") and seen["loads"] == (0,)
    assert seen["car_counts"] == (1,) and seen["duration"] == 15.0 and seen["seed"] == 3
    assert seen["work"] == tmp_path / "link_runs"
    saved = json.loads(out.read_text())
    assert saved["command"].startswith("crs ") and "machine" in saved
    assert main(["bench", "link", "--out", str(tmp_path / "all.json")]) == 0
    assert seen["presets"] == ("clean", "typical", "bad", "outages")
    assert seen["loads"] == (0, 1, 2) and seen["car_counts"] == (1, 2)
