"""The first-plane sweep lag of a recording without a stream: stated through the metadata,
estimated by the FIE's profile cost (the real-recording layout loses the lag the simulator's
stream knows)."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from crs_core.dataset import Dataset
from crs_core.discrepancy.sweep_lag import (
    estimate_plane1_lag,
    plane1_lag_source,
    with_plane1_lag,
)
from crs_core.identification.data import PLANE1_LAG_KEY, plane1_lag
from crs_core.identification.problem import DYNAMICS_FIT, FieSettings
from crs_core.identification.solve import identify
from crs_core.model import CarModel
from sim.scenarios import SIM_PROCESS_SCALE, simulate_dataset


@pytest.fixture(scope="module")
def simulated() -> Dataset:
    return simulate_dataset(8.0, 7)


@pytest.fixture(scope="module")
def recording(simulated, tmp_path_factory) -> Dataset:
    """The same run in the real recordings' layout (no stream, no dataset.yaml)."""
    folder = tmp_path_factory.mktemp("recording")
    return Dataset.load(simulated.save(folder / "run", metadata=False))


def test_a_stated_lag_reaches_the_fie_only_without_a_stream(simulated, recording):
    known = plane1_lag(simulated)
    assert 0.005 < np.median(known) < 0.015  # about half a sweep period
    assert np.array_equal(plane1_lag(with_plane1_lag(simulated, 0.002)), known)
    assert not plane1_lag(recording).any()
    stated = with_plane1_lag(recording, 0.01)
    lag = plane1_lag(stated)
    assert lag[0] == 0.0 and np.all(lag[1:] == 0.01)
    assert PLANE1_LAG_KEY not in recording.meta  # a copy of the metadata
    with pytest.raises(ValueError, match=PLANE1_LAG_KEY):
        plane1_lag(replace(recording, meta={PLANE1_LAG_KEY: -0.01}))
    with pytest.raises(ValueError, match=PLANE1_LAG_KEY):
        plane1_lag(replace(recording, meta={PLANE1_LAG_KEY: "soon"}))


def test_where_the_lag_comes_from(simulated, recording):
    assert plane1_lag_source(simulated) == "stream"
    assert plane1_lag_source(recording) == "unknown"
    assert plane1_lag_source(with_plane1_lag(recording, 0.01)) == "dataset"
    y = recording.y.copy()
    y[:, 0:4] = np.nan
    assert plane1_lag_source(replace(recording, y=y)) == "none"


def test_the_profile_finds_the_lag_the_layout_lost(simulated, recording):
    """Taken as 0, the lag leaves a misfit on every plane-1 angle; the profile of the current
    model's FIE cost finds the simulator's lag (about 10 ms) and its fit is better."""
    settings = FieSettings(fit=DYNAMICS_FIT, process_scale=SIM_PROCESS_SCALE)
    current = identify(recording, CarModel(), settings)
    lag, std, fit = estimate_plane1_lag(recording, CarModel(), current, settings)
    truth = float(np.mean(plane1_lag(simulated)[1:]))
    assert abs(lag - truth) < 0.002
    assert math.isfinite(std) and std < 0.002
    assert fit.cost < current.cost
    assert np.allclose(fit.data.plane1_lag[1:], lag)
