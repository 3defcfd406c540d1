"""Tests of ``crs discrepancy``: a run in the real recordings' layout (no dataset.yaml, no
stream), the report contract, and one-line input errors that write nothing."""

from __future__ import annotations

import json
import re
from pathlib import Path

import pytest

from crs_core.model import CarModel
from sim.scenarios import simulate_dataset

STEERING_OFFSET = 0.03


@pytest.fixture(scope="module")
def recordings(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    """12 s to train on, 8 s held out: the offset is named and fitted as well as from 20 s and
    12 s (measured: 0.03019 +- 0.0011 rad, gap 0.22 -> 0.021 m; from 20 s and 12 s 0.03018
    +- 0.0009 rad, gap 0.24 -> 0.022 m) in about half the time."""
    truth = CarModel({"steering_offset": {"steering_offset": STEERING_OFFSET}})
    root = tmp_path_factory.mktemp("discrepancy")
    train = simulate_dataset(12.0, 31, truth, driver="joystick")
    held_out = simulate_dataset(8.0, 32, truth, driver="joystick")
    return (
        train.save(root / "train", metadata=False),
        held_out.save(root / "held_out", metadata=False),
    )


@pytest.mark.slow
def test_names_a_hidden_steering_offset_in_recordings_without_metadata(recordings, tmp_path, crs):
    train, held_out = recordings
    out = tmp_path / "result"
    code, stdout, stderr = crs(
        [
            "discrepancy",
            str(train),
            "--validate",
            str(held_out),
            "--out",
            str(out),
            "--fit",
            "Iz,Df,Dr,Cm1",
            "--candidates",
            "steering_offset,gyro_bias,steering_gain",
            "--process-scale",
            "0.1",
            "--workers",  # the suite's other worker has the second core
            "1",
        ]
    )
    assert code == 0, stderr
    assert len(re.findall(r"\[\d/3\] (steering_offset|gyro_bias|steering_gain) ", stderr)) == 3
    report = json.loads((out / "report.json").read_text())
    assert report["verdict"] == "effect" and report["effects"] == ["steering_offset"]
    fitted = report["parameters"]["steering_offset"]["steering_offset"]
    assert fitted["value"] == pytest.approx(STEERING_OFFSET, rel=0.15)
    assert fitted["unit"] == "rad" and fitted["std"] > 0
    assert report["gap_after"] < report["gap_before"]
    assert set(report["residual_rms_before"]) == set(report["residual_rms_after"])
    assert "steering_offset" in (out / "params.yaml").read_text()
    assert (out / "report.md").read_text().startswith("**Finding: steering_offset**")
    assert "effect steering_offset" in stdout


@pytest.mark.parametrize(
    ("extra", "expected"),
    [
        (["--candidates", "nope"], "--candidates: unknown effect 'nope'"),
        (["--fit", "Cm1,nope"], "--fit: unknown parameter 'nope'"),
        (["--false-alarm-rate", "0"], "false-alarm-rate"),
        (["--validate", "/nonexistent/folder"], "--validate: dataset folder"),
        (["--params", "/nonexistent.yaml"], "--params"),
    ],
)
def test_bad_input_is_one_line_error_and_writes_nothing(
    recordings, tmp_path, extra, expected, crs_refuses
):
    train, _ = recordings
    out = tmp_path / "never"
    assert expected in crs_refuses(["discrepancy", str(train), "--out", str(out), *extra])
    assert not out.exists()
