"""Tests of crs_core.analysis.consistency: replaying recorded states through the sensor models."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from crs_core.analysis.consistency import channel_errors, predicted_samples
from crs_core.dataset import Y_CHANNELS, Dataset
from crs_core.model import CarModel


def test_consistency_replay_needs_inputs(saved: Path):
    """The sensor-model replay refuses a dataset without inputs (front wheels need the steer)."""
    data = Dataset.load(saved)
    data.u = None
    with pytest.raises(ValueError, match=r"^dataset: has no inputs u\.npy"):
        predicted_samples(data, CarModel())


def test_channel_errors_are_median_and_p95_of_the_absolute_residual(simulated: Dataset):
    """Readings equal to the replay plus a known residual on the yaw rate: that channel reports
    the median and 95th percentile of its absolute residual (NaN samples skipped and not
    counted), every other channel zero."""
    predicted = predicted_samples(simulated, CarModel())
    n = len(simulated.t)
    residual = np.linspace(-0.3, 0.5, n)
    y = predicted.copy()
    y[:, 12] += residual
    y[7, 12] = np.nan
    errors = channel_errors(replace(simulated, y=y))
    kept = np.abs(np.delete(residual, 7))
    assert errors["yaw_rate"]["samples"] == n - 1
    assert errors["yaw_rate"]["median"] == pytest.approx(np.median(kept), rel=1e-9)
    assert errors["yaw_rate"]["p95"] == pytest.approx(np.percentile(kept, 95), rel=1e-9)
    for name in Y_CHANNELS[:12]:
        assert errors[name] == {"median": 0.0, "p95": 0.0, "samples": n}


def test_a_dataset_without_states_is_refused(simulated: Dataset):
    with pytest.raises(ValueError, match=r"^dataset: has no state trajectory x\.npy"):
        predicted_samples(replace(simulated, x=None), CarModel())
