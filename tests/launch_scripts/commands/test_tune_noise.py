"""Tests of ``crs tune-noise``: the fitted noise written into a parameter YAML that ``crs
estimate`` then uses, and one-line errors."""

from __future__ import annotations

import contextlib
import io
import json
import re
from pathlib import Path

import pytest
import yaml

from crs_core.estimation.noise import EstimatorNoise, noise_in_file
from launch_scripts.cli import main


@pytest.fixture(scope="module")
def recording(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("tune") / "drive"
    assert main(["sim", "--duration", "12", "--seed", "6", "--out", str(out), "--no-report"]) == 0
    return out


@pytest.fixture(scope="module")
def params(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("tune") / "car.yaml"
    path.write_text("parameters:\n  m: 0.205\n")
    return path


def test_the_fitted_noise_goes_into_a_copy_of_the_params_that_estimate_uses(
    recording: Path, params: Path, tmp_path: Path
):
    """The simulated car follows its model: its pose noise comes out under the default; the
    output keeps the car's parameters, and ``crs estimate --params`` runs with that noise."""
    out = tmp_path / "tuned"
    printed = io.StringIO()
    with contextlib.redirect_stdout(printed):
        code = main(["tune-noise", str(recording), "--params", str(params), "--out", str(out)])
    assert code == 0
    assert {"params.yaml", "noise_fit.json", "noise_fit.png"} <= {p.name for p in out.iterdir()}
    document = yaml.safe_load((out / "params.yaml").read_text())
    assert document["parameters"] == {"m": 0.205}
    noise = noise_in_file(out / "params.yaml")
    assert noise.process_std[0] < EstimatorNoise().process_std[0]
    report = json.loads((out / "noise_fit.json").read_text())
    assert report["process_std"] == list(noise.process_std)
    assert report["log_likelihood"] >= report["start_log_likelihood"]
    assert "process_std" in printed.getvalue()
    estimated = tmp_path / "estimates"
    arguments = ["estimate", str(recording), "--estimator", "ekf", "--out", str(estimated)]
    assert main([*arguments, "--params", str(out / "params.yaml")]) == 0
    diagnostics = json.loads((estimated / "diagnostics.json").read_text())
    assert diagnostics["process_std"] == list(noise.process_std)


@pytest.mark.parametrize(
    ("extra", "message"),
    [
        (["--fit", "attitude"], r"--fit: one or more of pose, velocity"),
        (["--sensors", "lh+radar"], r"--sensors: "),
    ],
)
def test_bad_options_are_refused_in_one_line(recording: Path, tmp_path: Path, extra, message):
    printed = io.StringIO()
    with contextlib.redirect_stderr(printed):
        code = main(["tune-noise", str(recording), "--out", str(tmp_path / "o"), *extra])
    assert code != 0
    assert len(printed.getvalue().strip().splitlines()) == 1
    assert re.search(message, printed.getvalue())
    assert not (tmp_path / "o").exists()  # refused before anything is written


def test_a_bad_noise_section_in_params_is_named(recording: Path, tmp_path: Path):
    bad = tmp_path / "bad.yaml"
    bad.write_text("parameters: {}\nnoise:\n  process_std: [1, 2]\n")
    printed = io.StringIO()
    with contextlib.redirect_stderr(printed):
        code = main(["tune-noise", str(recording), "--params", str(bad), "--out", str(tmp_path)])
    assert code != 0
    assert "--params" in printed.getvalue() and "noise.process_std" in printed.getvalue()
