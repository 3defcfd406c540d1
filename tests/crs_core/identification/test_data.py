"""Tests of crs_core.identification.data: channel weights and the commands held per interval."""

from __future__ import annotations

import numpy as np
import pytest

from crs_core.dataset import Y_CHANNELS, Dataset
from crs_core.identification import FieData, FieSettings
from crs_core.measurements import InputSample


def test_nan_channels_drop_out(drives):
    """A sensor missing everywhere gets weight 0; the rest keep 1/sigma."""
    dataset = drives[0]
    y = dataset.y.copy()
    y[:, 8:12] = np.nan
    data = FieData.from_dataset(
        Dataset(t=dataset.t, u=dataset.u, y=y, x=dataset.x), FieSettings().noise
    )
    assert np.all(data.weight[:, 8:12] == 0) and np.all(data.y[:, 8:12] == 0)
    assert "wheel_encoders" not in data.channels_present
    assert np.all(data.weight[:, 12] == pytest.approx(1 / FieSettings().noise.gyro_std))


def test_sampled_commands_hold_their_interval_middle_held_commands_split_it():
    """Without a command stream ``u`` samples the command signal: an interval holds its value at
    the middle, (u_k + u_k+1) / 2, so a ramp is followed without the half-interval lag of
    holding u_k. With the stream, each command is held from its stamp."""
    from crs_core.identification.data import input_segments

    t = np.array([0.0, 0.02, 0.04, 0.06])
    u = np.stack([t * 10.0, np.full(4, 0.3)], axis=1)  # a steering ramp, 10 rad/s
    y = np.full((4, len(Y_CHANNELS)), np.nan)
    seg_u, seg_dt, count = input_segments(Dataset(t=t, u=u, y=y))
    np.testing.assert_array_equal(count, [1, 1, 1])
    np.testing.assert_allclose(seg_u[:, 0, 0], [0.1, 0.3, 0.5])
    np.testing.assert_allclose(seg_dt[:, 0], 0.02)
    held = [InputSample(0.0, [0.0, 0.3]), InputSample(0.03, [0.5, 0.3])]
    seg_u, seg_dt, count = input_segments(Dataset(t=t, u=u, y=y, inputs=held))
    np.testing.assert_array_equal(count, [1, 2, 1])
    np.testing.assert_allclose(seg_u[1, :2, 0], [0.0, 0.5])
    np.testing.assert_allclose(seg_dt[1, :2], [0.01, 0.01])
    np.testing.assert_allclose(seg_u[2, 0, 0], 0.5)
