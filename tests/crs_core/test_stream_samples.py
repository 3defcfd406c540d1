"""crs_core.stream_samples: the 13-channel samples of a stream, built by hand here."""

from __future__ import annotations

import numpy as np
import pytest

from crs_core.errors import FieldError
from crs_core.measurements import InputSample, Measurement, lighthouse_sensor
from crs_core.stream_samples import held_at, interpolated_at, nominal_period, sample_stream

PLANE1, PLANE2 = lighthouse_sensor(0, 1), lighthouse_sensor(0, 2)


def _sweeps(plane2_stamps: list[float], skip_plane1: tuple[int, ...] = ()) -> list[Measurement]:
    """Sweeps of a 50 Hz rotation: plane 1 10 ms before each plane 2, angles = stamp."""
    out = []
    for k, t in enumerate(plane2_stamps):
        if k not in skip_plane1:
            out.append(Measurement(t - 0.01, PLANE1, np.full(4, t - 0.01)))
        out.append(Measurement(t, PLANE2, np.full(4, t)))
    return out


def _wheels(stamps: np.ndarray) -> list[Measurement]:
    """Wheel speeds 10 * stamp (rad/s), linear: interpolation is exact."""
    return [Measurement(t, "wheel_encoders", np.full(4, 10.0 * t)) for t in stamps]


def test_samples_pair_both_planes_of_a_rotation_and_interpolate_the_rest():
    t2 = [0.02 * k + 0.015 for k in range(1, 11)]
    imu = [Measurement(t, "imu", [0.0, 0.0, 2.0 * t]) for t in np.arange(0.0, 0.25, 0.004)]
    stream = _sweeps(t2, skip_plane1=(3,)) + _wheels(np.arange(0.0, 0.25, 0.004)) + imu
    samples = sample_stream(stream[::-1])  # any order
    expected = np.delete(np.array(t2), 3)  # no plane-1 sweep for the 4th rotation
    np.testing.assert_array_equal(samples.t, expected)
    np.testing.assert_allclose(samples.y[:, :4], (expected - 0.01)[:, None].repeat(4, 1))
    np.testing.assert_allclose(samples.y[:, 4:8], expected[:, None].repeat(4, 1))
    np.testing.assert_allclose(samples.y[:, 8:12], 10.0 * expected[:, None].repeat(4, 1))
    np.testing.assert_allclose(samples.y[:, 12], 2.0 * expected)


def test_a_plane1_sweep_of_the_previous_rotation_does_not_pair():
    """A plane-1 sweep 0.75 rotations or more before the plane-2 sweep is another rotation's."""
    stream = [
        Measurement(0.0, PLANE1, np.zeros(4)),
        Measurement(0.02, PLANE2, np.ones(4)),  # 1 rotation later: the 0.01 s sweep was lost
        Measurement(0.03, PLANE1, np.zeros(4)),
        Measurement(0.04, PLANE2, np.ones(4)),
        Measurement(0.06, PLANE2, np.ones(4)),
    ]
    assert sample_stream(stream, {PLANE2: 0.02}).t.tolist() == [0.04]


def test_no_value_is_invented_across_a_gap_or_outside_the_data():
    t2 = [0.02 * k + 0.015 for k in range(1, 11)]
    wheels = np.concatenate([np.arange(0.03, 0.09, 0.004), np.arange(0.15, 0.18, 0.004)])
    samples = sample_stream(_sweeps(t2) + _wheels(wheels))
    has_wheels = np.isfinite(samples.y[:, 8])
    inside = ((samples.t >= 0.03) & (samples.t <= 0.088)) | (
        (samples.t >= 0.15) & (samples.t <= 0.178)
    )
    np.testing.assert_array_equal(has_wheels, inside)
    assert np.all(np.isnan(samples.y[:, 12]))  # no IMU, no gyro: no yaw rate


def test_the_gyro_gives_the_yaw_rate_where_there_is_no_imu():
    t2 = [0.035, 0.055]
    gyro = [Measurement(t, "gyro", [t]) for t in np.arange(0.0, 0.1, 0.004)]
    samples = sample_stream(_sweeps(t2) + gyro)
    np.testing.assert_allclose(samples.y[:, 12], t2)


def test_a_stream_without_both_planes_has_no_samples():
    samples = sample_stream(_wheels(np.arange(0.0, 0.1, 0.004)))
    assert samples.t.shape == (0,) and samples.y.shape == (0, 13)


def test_the_nominal_period_is_the_median_interval():
    assert nominal_period(np.array([0.0, 0.01, 0.02, 0.02, 0.5, 0.51])) == pytest.approx(0.01)
    assert np.isnan(nominal_period(np.array([1.0])))


def test_interpolation_with_a_given_period():
    stamps = np.array([0.0, 0.1, 0.3])
    values = np.array([[0.0], [1.0], [3.0]])
    out = interpolated_at(np.array([0.05, 0.2]), stamps, values, period=0.1)
    np.testing.assert_allclose(out[:, 0], [0.5, np.nan])  # 0.2 s gap > 1.5 periods
    out = interpolated_at(np.array([0.05, 0.2]), stamps, values, period=0.15)
    np.testing.assert_allclose(out[:, 0], [0.5, 2.0])


def test_inputs_are_held_from_their_stamps():
    inputs = [InputSample(1.0, [0.1, 0.2]), InputSample(2.0, [0.3, 0.4])]
    held = held_at(inputs, np.array([0.5, 1.0, 1.5, 2.0, 9.0]))
    np.testing.assert_array_equal(held[:, 0], [0.1, 0.1, 0.1, 0.3, 0.3])
    with pytest.raises(FieldError, match="inputs"):
        held_at([], np.array([0.0]))
