"""Tests of ``crs plan-drive``: its outputs and its one-line input errors."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import yaml

from crs_core.discrepancy.drive_file import load_drive

QUICK = ["--duration", "1", "--segment", "0.5", "--evaluations", "3"]


@pytest.fixture(scope="module")
def params(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("plan") / "params.yaml"
    path.write_text(yaml.safe_dump({"parameters": {"Dr": 0.95, "Br": 2.4}}))
    return path


def test_plan_drive_writes_the_drive_its_report_and_its_figure(params, tmp_path, crs) -> None:
    out = tmp_path / "drive"
    argv = ["plan-drive", "--params", str(params), "--open", "Dr,Br,tau_motor", "--out", str(out)]
    code, stdout, stderr = crs([*argv, *QUICK])
    assert code == 0, stderr
    drive = load_drive(out / "drive.yaml")
    assert drive.open == ("Dr", "Br", "tau_motor") and drive.duration_s == 1.0
    report = json.loads((out / "report.json").read_text())
    assert set(report["sigma"]) == {"Dr", "Br", "tau_motor"}
    for row in report["sigma"].values():
        assert 0 < row["after"] <= row["before"]
    assert "prior_std" in report["prior"]
    assert (out / "drive.png").stat().st_size > 0
    assert "tau_motor: sigma" in stdout


def test_plan_drive_uses_a_sysid_results_correlations(params, tmp_path, crs) -> None:
    folder = tmp_path / "sysid"
    folder.mkdir()
    (folder / "params.yaml").write_text(params.read_text())
    result = {
        "parameters": {"Dr": {"std": 0.02}, "Br": {"std": 0.3}},
        "correlation": {"names": ["Dr", "Br"], "matrix": [[1.0, -0.95], [-0.95, 1.0]]},
    }
    (folder / "result.json").write_text(json.dumps(result))
    out = tmp_path / "drive"
    argv = ["plan-drive", "--params", str(folder / "params.yaml"), "--open", "Dr,Br"]
    code, _, stderr = crs([*argv, "--out", str(out), *QUICK])
    assert code == 0, stderr
    report = json.loads((out / "report.json").read_text())
    assert "result.json" in report["prior"]
    assert report["sigma"]["Dr"]["before"] == pytest.approx(0.02)


def test_an_unknown_open_parameter_is_one_line_naming_open(params, tmp_path, crs_refuses):
    line = crs_refuses(
        ["plan-drive", "--params", str(params), "--open", "Dr,grip", "--out", str(tmp_path / "o")]
    )
    assert "--open" in line and "'grip'" in line
    line = crs_refuses(
        [
            "plan-drive",
            "--params",
            str(params),
            "--open",
            "input_delay",
            "--out",
            str(tmp_path / "o"),
        ]
    )
    assert line.startswith("crs plan-drive: error: --open: 'input_delay' is a transport delay")
    assert not (tmp_path / "o").exists()


def test_a_file_that_is_no_parameter_yaml_is_one_line_naming_it(tmp_path, crs_refuses) -> None:
    bad = tmp_path / "track.yaml"
    bad.write_text(yaml.safe_dump({"track": {"xCoords": [0, 1]}}))
    line = crs_refuses(["plan-drive", "--params", str(bad), "--open", "Dr", "--out", "o"])
    assert str(bad) in line and "parameters" in line
    line = crs_refuses(["plan-drive", "--params", str(tmp_path), "--open", "Dr", "--out", "o"])
    assert "folder" in line
