"""``crs bench discrepancy --resume``: a stopped run is continued, not repeated.

The workflow itself is replaced by a stand-in that records which cases ran (the real one takes
minutes per case); what is tested is the bookkeeping around it.
"""

from __future__ import annotations

import json
from concurrent.futures import Executor
from dataclasses import dataclass, field

import pytest

import benchmarks.discrepancy as bench


class _StoppedError(Exception):
    """The session limit stopping a run (a stand-in for the process being killed)."""


class _InProcess(Executor):
    """Runs ``map`` here, in order (the stand-in need not be picklable)."""

    def __init__(self, max_workers: int | None = None) -> None:
        pass

    def map(self, fn, *iterables, **kwargs):
        return map(fn, *iterables)


@dataclass
class _Runs:
    """The keys of the cases run, in order; with ``stop_at`` set, that call is "stopped"."""

    keys: list[tuple] = field(default_factory=list)
    stop_at: int | None = None

    def __call__(self, case: dict) -> dict:
        self.keys.append(bench._case_key(case))
        if len(self.keys) == self.stop_at:
            self.stop_at = None
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
            "where": None,
            "prediction": {"coherence": 0.5, "structured": False},
            "proposed": [],
            "shape_right": False,
        }


@pytest.fixture
def runs(monkeypatch) -> _Runs:
    stand_in = _Runs()
    monkeypatch.setattr(bench, "run_case", stand_in)
    monkeypatch.setattr(bench, "ProcessPoolExecutor", _InProcess)
    return stand_in


def test_a_stopped_run_is_continued_with_the_missing_cases_only(runs, tmp_path):
    out = tmp_path / "bench.json"
    runs.stop_at = 3
    with pytest.raises(_StoppedError):
        bench.discrepancy_benchmark(out, seeds=1, clean_seeds=2, speed_run=False)
    kept = json.loads(out.read_text())["cases"]
    runs.keys.clear()
    result = bench.discrepancy_benchmark(out, seeds=1, clean_seeds=2, speed_run=False, resume=True)
    everything = [bench._case_key(c) for c in bench.cases(1, 2, 20.0)]
    assert [bench._case_key(c) for c in kept] == everything[:2]
    assert runs.keys == everything[2:]  # the kept cases were not run again
    assert [bench._case_key(c) for c in result["cases"]] == everything
    assert json.loads(out.read_text())["summary"]["false_alarms"]["runs"] == 2


def test_resume_refuses_a_file_measured_with_other_settings(runs, tmp_path):
    out = tmp_path / "bench.json"
    out.write_text(json.dumps({"settings": {"duration_s": 5.0}, "cases": []}))
    with pytest.raises(ValueError, match=r"--resume: .* other settings"):
        bench.discrepancy_benchmark(out, seeds=1, clean_seeds=1, speed_run=False, resume=True)
    assert runs.keys == []


def test_resume_on_an_empty_file_runs_everything(runs, tmp_path):
    """``--resume`` on the empty file that checking ``--out`` creates starts afresh."""
    out = tmp_path / "bench.json"
    out.touch()
    result = bench.discrepancy_benchmark(out, seeds=1, clean_seeds=0, speed_run=False, resume=True)
    assert len(result["cases"]) == len(bench.cases(1, 0, 20.0))


#: A hidden-effect case as the benchmark records it: a gyro bias, named and fitted.
HIDDEN_CASE = {
    "effect": "gyro_bias",
    "magnitude": "large",
    "values": {"gyro_bias": 0.05},
    "seed": 100,
    "independent": True,
    "noise": "nominal",
    "verdict": "effect",
    "named": ["gyro_bias"],
    "parameters": {"gyro_bias": {"gyro_bias": {"value": 0.0493, "std": 0.0024}}},
    "hypotheses": {"gyro_bias": {"improvement": 0.21, "p_value": 3e-5}},
    "gap_before_m": 0.037,
    "gap_after_m": 0.028,
}


def test_markdown_table_has_a_line_per_hidden_effect_and_counts_the_clean_runs():
    hidden = HIDDEN_CASE
    clean = {"effect": None, "verdict": "none", "noise": "mismatched"}
    text = bench.markdown([clean, hidden])
    line = next(ln for ln in text.splitlines() if ln.startswith("| gyro_bias"))
    assert line == (
        "| gyro_bias | gyro_bias 0.05 | 100, independent | gyro_bias | 0.0493 ± 0.0024 | "
        "+21 %, p 3e-05 | 0.037 → 0.028 |"
    )
    assert "Clean runs: 1 (none 1); 1 with mismatched sensor noise (0 not `none`)." in text


def test_the_docs_account_counts_the_cases_and_gives_the_speed_run() -> None:
    """``format_markdown``: the settings line, the three bullets and the table, from a
    hand-written result with two hidden-effect cases (one named, one missed) and two clean
    runs."""
    named = {**HIDDEN_CASE, "correct": True, "within_tolerance": True}
    missed = {
        **named,
        "effect": "motor_lag",
        "values": {"tau_motor": 0.1},
        "independent": False,
        "verdict": "none",
        "named": [],
        "correct": False,
        "within_tolerance": False,
        "parameters": {},
        "hypotheses": {"motor_lag": {"improvement": 0.4, "p_value": 0.006}},
    }
    clean = [
        {
            "effect": None,
            "magnitude": None,
            "seed": 200 + k,
            "verdict": "none",
            "named": [],
            "noise": noise,
        }
        for k, noise in enumerate(("nominal", "mismatched"))
    ]
    cases = [named, clean[0], missed, clean[1]]
    result = {
        "settings": {"duration_s": 20.0, "held_out_s": 30.0, "false_alarm_rate_designed": 0.01},
        "cases": cases,
        "summary": bench.tabulate(cases),
        "speed_60s": {
            "workers": 2,
            "recording_s": 60.0,
            "held_out": "last 30 % of the training run",
            "time_s": 185.4,
            "truth": {"gyro_bias": {"gyro_bias": 0.05}},
            "verdict": "effect",
            "named": ["gyro_bias"],
            "parameters": {"gyro_bias": {"gyro_bias": {"value": 0.0494, "std": 0.0017}}},
            "gap_before_m": 0.028,
            "gap_after_m": 0.011,
        },
        "wall_time_s": 1234.4,
    }
    lines = bench.format_markdown(result).splitlines()
    assert lines[:6] == [
        "Training runs of 20 s, held-out runs of 30 s (another seed); 2 hidden-effect cases "
        "(seed 100) and 2 clean runs; the whole benchmark 1234 s.",
        "",
        "- **False alarms: 0 findings in 2 clean runs** (1 of them with mismatched sensor noise, "
        "0 findings there); designed: ≤ 1 % per round.",
        "- **Hidden effects: 1 of 2 named correctly** (1 of 1 independent), the parameter within "
        "15 % of the truth in 1 of those 1; **wrong names: 0**.",
        "- **Time:** one run on a 60 s recording (`crs discrepancy REC` with its defaults: held "
        "out the last 30 % of the training run, every hypothesis, `--workers 2`) took **185 s** "
        "(gyro_bias 0.0494 ± 0.0017 named for a hidden gyro_bias 0.05, gap 0.028 → 0.011 m).",
        "",
    ]
    assert lines[6:] == bench.markdown(cases).splitlines()
    assert (
        "| motor_lag | tau_motor 0.1 | 100, simulator | *none* | — | +40 %, p 0.006 | "
        "0.037 → 0.028 |"
    ) in lines
