"""``crs bench discrepancy --resume``: a stopped run is continued, not repeated.

The workflow itself is replaced by a stand-in that records which cases ran (the real one takes
minutes per case); what is tested is the bookkeeping around it.
"""

from __future__ import annotations

import json
from concurrent.futures import Executor

import pytest

import sim.bench.discrepancy as bench


class _StoppedError(Exception):
    """The session limit stopping a run (a stand-in for the process being killed)."""


class _InProcess(Executor):
    """Runs ``map`` here, in order (the stand-in need not be picklable)."""

    def __init__(self, max_workers: int | None = None) -> None:
        pass

    def map(self, fn, *iterables, **kwargs):
        return map(fn, *iterables)


@pytest.fixture
def ran(monkeypatch) -> list[tuple]:
    """The keys of the cases the benchmark ran, in order."""
    keys: list[tuple] = []
    stopped: list[bool] = []

    def stand_in(case):
        keys.append(bench._case_key(case))
        if len(keys) == 3 and not stopped:  # the first run "is stopped" at its third case
            stopped.append(True)
            raise _StoppedError
        return {
            **case,
            "verdict": "none",
            "named": [],
            "time_s": 0.0,
            "correct": not case["effect"],
            "gap_before_m": 0.1,
            "gap_after_m": 0.1,
            "parameters": {},
            "hypotheses": {},
        }

    monkeypatch.setattr(bench, "run_case", stand_in)
    monkeypatch.setattr(bench, "ProcessPoolExecutor", _InProcess)
    return keys


def test_a_stopped_run_is_continued_with_the_missing_cases_only(ran, tmp_path):
    out = tmp_path / "bench.json"
    with pytest.raises(_StoppedError):
        bench.discrepancy_benchmark(out, seeds=1, clean_seeds=2, speed_run=False)
    kept = json.loads(out.read_text())["cases"]
    assert len(kept) == 2
    ran.clear()
    result = bench.discrepancy_benchmark(out, seeds=1, clean_seeds=2, speed_run=False, resume=True)
    everything = [bench._case_key(c) for c in bench.cases(1, 2, 20.0)]
    assert [bench._case_key(c) for c in kept] == everything[:2]
    assert ran == everything[2:]  # the kept cases were not run again
    assert [bench._case_key(c) for c in result["cases"]] == everything
    assert json.loads(out.read_text())["summary"]["false_alarms"]["runs"] == 2


def test_resume_refuses_a_file_measured_with_other_settings(ran, tmp_path):
    out = tmp_path / "bench.json"
    out.write_text(json.dumps({"settings": {"duration_s": 5.0}, "cases": []}))
    with pytest.raises(ValueError, match=r"--resume: .* other settings"):
        bench.discrepancy_benchmark(out, seeds=1, clean_seeds=1, speed_run=False, resume=True)
    assert ran == []
