"""Tests of the ``crs discrepancy`` report: files, strict JSON, a loadable params.yaml, the
verdict in the first line of report.md (a real ``effect`` run, hand-made ``none``,
``unexplained`` and ``input_delay`` results)."""

from __future__ import annotations

import copy
import dataclasses
import json
from pathlib import Path

import pytest

from crs_core.dataset import Dataset
from crs_core.discrepancy.report import write_discrepancy_report
from crs_core.discrepancy.workflow import DiscrepancyResult, DiscrepancySettings, find_discrepancy
from crs_core.identification.models import identification_model
from crs_core.identification.problem import FieSettings
from crs_core.model import CarModel
from crs_core.model.car_model import effects_in_file
from sim.scenarios import simulate_dataset

#: Every test uses the module's workflow run (on 12 s of training and 8 s of held-out data:
#: the bias is named, 0.0813 +- 0.0032 rad/s, gap 0.058 -> 0.036 m).
pytestmark = pytest.mark.slow

#: The hidden truth of the training and held-out runs: a gyro bias, rad/s.
GYRO_BIAS = 0.08
FILES = ("report.json", "report.md", "params.yaml", "hypotheses.png", "gap.png", "residuals.png")
REQUIRED = (
    "verdict",
    "effects",
    "parameters",
    "gap_before",
    "gap_after",
    "residual_rms_before",
    "residual_rms_after",
    "where",
)


@pytest.fixture(scope="module")
def train() -> Dataset:
    return simulate_dataset(12, 1, model=CarModel({"gyro_bias": {"gyro_bias": GYRO_BIAS}}))


@pytest.fixture(scope="module")
def result(train) -> DiscrepancyResult:
    validation = simulate_dataset(8, 2, model=CarModel({"gyro_bias": {"gyro_bias": GYRO_BIAS}}))
    settings = DiscrepancySettings(
        identification=FieSettings(fit=("Cm1", "Df", "Dr", "Iz"), process_scale=0.1),
        candidates=("gyro_bias", "steering_offset"),
        workers=2,  # one candidate per core: the same fits, in half the time
    )
    return find_discrepancy(train, CarModel(), validation, settings)


@pytest.fixture(scope="module")
def written(result, tmp_path_factory) -> tuple[Path, dict]:
    folder = tmp_path_factory.mktemp("discrepancy")
    return folder, write_discrepancy_report(result, folder, "train_run", "held_out_run")


def _strict_json(path: Path) -> dict:
    def refuse(constant: str) -> None:
        raise AssertionError(f"{path.name}: non-strict JSON constant {constant}")

    return json.loads(path.read_text(), parse_constant=refuse)


def _hand_made(result: DiscrepancyResult, **changes) -> DiscrepancyResult:
    """The real result's fits with another verdict (hypotheses copied, not shared)."""
    hypotheses = [copy.copy(h) for h in result.hypotheses]
    return dataclasses.replace(result, hypotheses=hypotheses, **changes)


def test_effect_report_writes_every_file(written):
    folder, _ = written
    for name in FILES:
        assert (folder / name).is_file(), name
        assert (folder / name).stat().st_size > 0, name


def test_effect_report_json_is_strict_with_required_keys(result, written):
    folder, summary = written
    report = _strict_json(folder / "report.json")
    assert report == summary
    for key in REQUIRED:
        assert key in report, key
    assert report["verdict"] == "effect"
    assert report["effects"] == ["gyro_bias"]
    bias = report["parameters"]["gyro_bias"]["gyro_bias"]
    assert bias["value"] == pytest.approx(GYRO_BIAS, abs=5 * bias["std"])
    assert report["gap_after"] < report["gap_before"]
    assert report["train_dataset"] == "train_run"
    assert report["held_out_dataset"] == "held_out_run"
    assert len(report["hypotheses"]) == len(result.hypotheses)


def test_effect_params_yaml_loads_with_the_effect(train, written):
    folder, _ = written
    path = folder / "params.yaml"
    effects = effects_in_file(path)
    assert effects == ["gyro_bias"]
    model = identification_model(train, effects, path)
    assert [e.name for e in model.effects] == ["gyro_bias"]
    assert model.parameters.value("gyro_bias") == pytest.approx(GYRO_BIAS, abs=0.015)


def test_effect_markdown_names_the_finding_first(written):
    folder, _ = written
    text = (folder / "report.md").read_text()
    first = text.splitlines()[0]
    assert first.startswith("**Finding: gyro_bias**")
    assert "gyro bias = 0.0" in first and "position RMSE" in first
    for figure in ("hypotheses.png", "gap.png", "residuals.png"):
        assert f"]({figure})" in text
    assert f"--params {folder}/params.yaml" in text
    assert "| steering_offset |" in text


def test_none_report_without_position_reference(result, train, tmp_path):
    none = _hand_made(
        result,
        verdict="none",
        effects=(),
        final=result.current,
        final_model=CarModel(parameters=result.current.parameters),
        diagnostics_after=result.diagnostics_before,
        gap={"before": None, "after": None, "horizon_s": 2.0},
    )
    for h in none.hypotheses:
        h.significant, h.reasons = False, ["held-out p = 0.5 (needs < 0.005)"]
    summary = write_discrepancy_report(none, tmp_path, "train_run", None)
    for name in FILES:
        assert (tmp_path / name).is_file(), name
    assert _strict_json(tmp_path / "report.json")["verdict"] == "none"
    assert summary["held_out_dataset"] is None and summary["gap_before"] is None
    assert summary["parameters"] == {}
    first = (tmp_path / "report.md").read_text().splitlines()[0]
    assert first.startswith("**No effect needed**")
    path = tmp_path / "params.yaml"
    assert effects_in_file(path) == []
    identification_model(train, [], path)  # loads


def test_unexplained_report_names_channel_and_regime_with_nan_as_null(result, tmp_path):
    where = {
        "channel": "yaw_rate",
        "regressor": "vx",
        "low": 0.8,
        "high": 1.2,
        "rms": 0.03,
        "normalized_rms": 2.1,
        "regime_r2": float("nan"),
        "mean": 0.01,
    }
    unexplained = _hand_made(
        result,
        verdict="unexplained",
        effects=(),
        final=result.current,
        diagnostics_after=result.diagnostics_before,
        where=where,
    )
    for h in unexplained.hypotheses:
        h.significant = False
    write_discrepancy_report(unexplained, tmp_path, "train_run", "held_out_run")
    report = _strict_json(tmp_path / "report.json")
    assert report["where"]["regime_r2"] is None
    first = (tmp_path / "report.md").read_text().splitlines()[0]
    assert first.startswith("**Unexplained misfit in yaw_rate when vx in [0.8, 1.2] m/s**")


def test_named_input_delay_is_written_to_params_yaml(result, train, tmp_path):
    delayed = _hand_made(result, effects=("input_delay",), delay_s=0.04)
    chosen = delayed.hypotheses[0]
    chosen.effects, chosen.delay_s, chosen.significant = ("input_delay",), 0.04, True
    chosen.parameters = {
        "input_delay": {"input_delay": {"value": 0.04, "std": 0.004, "unit": "s", "z": 10.0}}
    }
    delayed = dataclasses.replace(
        delayed, final=result.current, final_model=CarModel(parameters=result.current.parameters)
    )
    summary = write_discrepancy_report(delayed, tmp_path, "train_run", "held_out_run")
    assert summary["parameters"]["input_delay"]["input_delay"]["value"] == 0.04
    path = tmp_path / "params.yaml"
    assert effects_in_file(path) == ["input_delay"]
    model = identification_model(train, effects_in_file(path), path)
    assert model.input_delay() == pytest.approx(0.04)
    first = (tmp_path / "report.md").read_text().splitlines()[0]
    assert first.startswith("**Finding: input_delay** — input delay = 0.04 ± 0.004 s")
