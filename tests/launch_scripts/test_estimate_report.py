"""Tests of launch_scripts.estimate_report: the error-over-time panels of ``estimate.png``."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from crs_core.analysis.angles import wrap_angle
from crs_core.dataset import Y_CHANNELS, Dataset
from crs_core.estimation.offline import OfflineEstimates
from launch_scripts.estimate_report import _reference, error_bands, write_figure

REAL = Path(__file__).resolve().parents[2].parent / "shared" / "data" / "chronos_real"
N, LOST = 200, 10
PNG = b"\x89PNG\r\n\x1a\n"


def _reference_states() -> np.ndarray:
    """(N, 6) a car on a circle, the yaw unwrapped over more than one turn."""
    phase = np.linspace(0.0, 7.0, N)
    states = np.zeros((N, 6))
    states[:, 0], states[:, 1], states[:, 2] = np.cos(phase), np.sin(phase), phase + np.pi / 2
    states[:, 3] = 1.0
    return states


def _estimates(reference: np.ndarray) -> OfflineEstimates:
    """Estimates off the reference by known amounts: x +1 mm (σ 1 mm: inside ±2σ), y ±3 mm
    (σ 1 mm: outside), yaw +2 mrad and wrapped to [-pi, pi) (σ 2 mrad: inside); the first
    samples lost."""
    t = 100.0 + 0.02 * np.arange(N)
    x = reference.T.copy()
    x[0] += 1e-3
    x[1] += 3e-3 * np.where(np.arange(N) % 2, 1.0, -1.0)
    x[2] = wrap_angle(x[2] + 2e-3)
    x[:, :LOST] = 0.0  # the held guess before the first fix
    variance = np.tile(np.array([1e-3, 1e-3, 2e-3, 0.1, 0.1, 0.1])[:, None] ** 2, (1, N))
    variance[:, :LOST] = 1.0
    status = np.array(["lost"] * LOST + ["ok"] * (N - LOST - 20) + ["degraded"] * 20)
    reasons = np.where(status == "ok", "", "test")
    return OfflineEstimates(t, x, variance, status, reasons, {}, estimator=None)


def _dataset(reference: np.ndarray | None, source: str = "simulated") -> Dataset:
    t = 100.0 + 0.02 * np.arange(N)
    y = np.full((N, len(Y_CHANNELS)), np.nan)
    return Dataset(t=t, u=None, y=y, x=reference, meta={"source": source})


def test_error_bands_on_known_errors():
    """mm / mrad errors with the yaw wrapped, NaN where lost, RMSE and ±2σ fraction per axis."""
    reference = _reference_states()
    bands = error_bands(_estimates(reference), _dataset(reference))
    errors, sigmas, stats = bands["errors"], bands["sigmas"], bands["stats"]
    assert np.all(np.isnan(errors[:LOST]))
    assert errors[LOST:, 0] == pytest.approx(np.full(N - LOST, 1.0))
    assert np.abs(errors[LOST:, 1]) == pytest.approx(np.full(N - LOST, 3.0))
    assert errors[LOST:, 2] == pytest.approx(np.full(N - LOST, 2.0))  # not 2 mrad - 2 pi k
    assert sigmas[LOST:] == pytest.approx(np.tile([1.0, 1.0, 2.0], (N - LOST, 1)))
    assert stats["x"] == {
        "rmse": pytest.approx(1.0),
        "inside_2sigma": 1.0,
        "samples": N - LOST,
        "samples_with_sigma": N - LOST,
    }
    assert stats["y"]["rmse"] == pytest.approx(3.0) and stats["y"]["inside_2sigma"] == 0.0
    assert stats["yaw"]["rmse"] == pytest.approx(2.0) and stats["yaw"]["inside_2sigma"] == 1.0
    assert error_bands(_estimates(reference), _dataset(None)) is None


def test_write_figure_with_and_without_a_reference(tmp_path: Path):
    """The figure is written with a reference and, band only, without one."""
    reference = _reference_states()
    for name, dataset in (("ref.png", _dataset(reference)), ("none.png", _dataset(None))):
        path = write_figure(_estimates(reference), dataset, tmp_path / name, "test")
        data = path.read_bytes()
        assert data[:8] == PNG and len(data) > 20_000


def test_reference_is_labelled_honestly():
    """Simulation truth is called so; a recording's x.npy is its own Lighthouse-based on-line
    estimate, never ground truth."""
    assert _reference(_dataset(_reference_states())) == "simulation truth"
    recorded = _dataset(_reference_states(), source="my-lab")
    assert "not ground truth" in _reference(recorded)
    run = REAL / "fie_mpc_lighthouse_1"
    if not run.is_dir():
        pytest.skip(f"{run} not found")
    label = _reference(Dataset.load(run))
    assert "Lighthouse-based" in label and "not ground truth" in label
