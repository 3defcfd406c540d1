"""Tests of sim.report: the figures of ``crs demo`` / ``crs sim --report`` and their numbers."""

from __future__ import annotations

import json
from pathlib import Path

import matplotlib.pyplot as plt
import numpy as np
import pytest

from crs_core.control.path_following import PathFollower, PathFollowerSettings
from crs_core.model import CarModel
from crs_core.track import load_demo_track
from sim import SensorSuite, SimulationResult, Simulator
from sim.report import path_figure, sensors_figure, speed_colour_limits, write_report

PNG = b"\x89PNG\r\n\x1a\n"


@pytest.fixture(scope="module")
def run() -> SimulationResult:
    """4 s of the path follower on DEMO_TRACK with the default (noisy) sensors."""
    track = load_demo_track()
    model = CarModel()
    wheelbase = model.parameters.value("lf") + model.parameters.value("lr")
    controller = PathFollower(track, wheelbase, PathFollowerSettings(v_ref=1.0))
    x0 = track.start_state()
    return Simulator(model, SensorSuite(), seed=3).run(controller, 4.0, x0)


def test_speed_colour_limits_follow_the_driven_speeds():
    """Start-up from rest is left out: the limits span the speeds driven, not 0..max."""
    rng = np.random.default_rng(1)
    vx = np.r_[np.linspace(0.0, 0.9, 30), rng.uniform(0.9, 1.1, 1000)]
    low, high = speed_colour_limits(vx)
    assert 0.88 < low < 0.92 and 1.08 < high <= 1.1
    assert speed_colour_limits(np.full(50, 1.0)) == pytest.approx((0.975, 1.025))
    assert speed_colour_limits(np.zeros(10)) == pytest.approx((-0.025, 0.025))


def test_path_figure_colours_span_the_driven_speeds(run: SimulationResult):
    """The colour scale of the path is the driven speed range, well above 0 m/s."""
    fig = path_figure(run, load_demo_track())
    clim = [c.get_clim() for c in fig.axes[0].collections if c.get_array() is not None]
    plt.close(fig)
    assert clim == [pytest.approx(speed_colour_limits(run.truth_x[:, 3]))]
    assert clim[0][0] > 0.5


def test_sensors_figure_shows_every_photodiode_and_units(run: SimulationResult):
    """Both planes show the four photodiodes; every y axis has a unit and there are separate
    steering (rad) and torque panels."""
    fig = sensors_figure(run)
    labels = [ax.get_ylabel() for ax in fig.axes]
    per_plane = [
        sorted(line.get_label() for line in ax.lines)
        for ax in fig.axes
        if "plane" in ax.get_ylabel()
    ]
    plt.close(fig)
    assert per_plane == [[f"diode {d}" for d in range(4)]] * 2
    assert all("[" in label and "]" in label for label in labels), labels
    assert any("steering" in label and "[rad]" in label for label in labels)
    assert any("torque" in label for label in labels)


def test_report_writes_the_estimation_figure_and_numbers(run: SimulationResult, tmp_path: Path):
    """With an estimator: estimation.png and RMSE / ±2σ fractions in summary.json and .txt."""
    folder = write_report(run, load_demo_track(), tmp_path / "r", {"note": 1}, estimator="ekf")
    for name in ("path.png", "sensors.png", "estimation.png"):
        data = (folder / name).read_bytes()
        assert data[:8] == PNG and len(data) > 10_000
    summary = json.loads((folder / "summary.json").read_text())
    estimation = summary["estimation"]
    assert estimation["estimator"] == "ekf" and estimation["start"] == "blind"
    assert estimation["samples_not_lost"] > 0.9 * estimation["samples"] > 100
    for name, key in (("x", "rmse_mm"), ("y", "rmse_mm"), ("yaw", "rmse_mrad")):
        assert 0.0 < estimation[name][key] < 50.0
        assert 0.0 <= estimation[name]["inside_2sigma"] <= 1.0
    assert summary["note"] == 1
    text = (folder / "summary.txt").read_text()
    assert "estimation: EKF on lh+imu+we" in text and "% inside ±2σ" in text


def test_report_without_estimator_or_lighthouse(run: SimulationResult, tmp_path: Path):
    """``estimator=None`` skips the estimation; without Lighthouse data it is skipped with the
    reason in the summary."""
    folder = write_report(run, load_demo_track(), tmp_path / "none", estimator=None)
    assert sorted(p.name for p in folder.glob("*.png")) == ["path.png", "sensors.png"]
    assert "estimation" not in json.loads((folder / "summary.json").read_text())

    blind = SimulationResult(
        **{
            **run.__dict__,
            "measurements": [m for m in run.measurements if "lighthouse" not in m.sensor],
        }
    )
    folder = write_report(blind, load_demo_track(), tmp_path / "blind", estimator="ekf")
    summary = json.loads((folder / "summary.json").read_text())
    assert "no samples" in summary["estimation"]["skipped"]
    assert sorted(p.name for p in folder.glob("*.png")) == ["path.png", "sensors.png"]
