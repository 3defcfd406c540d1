"""Tests of sim.simulator: noise, drop-outs, blackouts, latency, rates, effects, streaming."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from crs_core.measurements import lighthouse_sensor
from crs_core.model import CarModel
from sim import Blackout, SensorSpec, SensorSuite, SimulationResult, Simulator
from sim.report import sensor_statistics
from sim.simulator import LIGHTHOUSE_VIEW_LIMIT
from tests.sim.sim_runs import (
    AT_REST,
    DRIVE,
    DRIVE_DURATION,
    IDEAL,
    NOISY,
    REST,
    REST_DURATION,
    STRAIGHT,
    first_crossing,
    model_outputs,
    truth_index,
)


# --- noise, bias, drop-outs -----------------------------------------------------------------------
def test_car_at_rest_with_zero_input_stays_exactly_at_rest(rest_run: SimulationResult):
    """Zero input from rest keeps every true state exactly zero for the whole run."""
    assert rest_run.truth_t[-1] == pytest.approx(REST_DURATION, abs=0.01)
    assert np.all(rest_run.truth_x == 0.0)


@pytest.mark.parametrize("family", ["imu", "wheel_encoders", "lighthouse", "pose"])
def test_noise_std_and_bias_match_configuration(
    rest_run: SimulationResult, base_model: CarModel, family: str
):
    """Per-channel residual std is within 10 % of noise_std, mean within 4 SE of the bias."""
    spec = NOISY.spec(family)
    names = (
        [lighthouse_sensor(0, 1), lighthouse_sensor(0, 2)] if family == "lighthouse" else [family]
    )
    residuals = []
    for name in names:
        _, values = rest_run.measurements_of(name)
        truth = base_model.numeric.outputs(AT_REST, np.zeros(2), base_model.parameters.vector())
        residuals.append(values - truth[name])
    r = np.concatenate(residuals)
    std = np.array(spec.noise_std)
    bias = np.array(spec.bias or np.zeros(std.size))
    assert r.shape[0] > 900
    np.testing.assert_array_less(np.abs(r.std(axis=0, ddof=1) / std - 1.0), 0.10)
    standard_error = std / np.sqrt(r.shape[0])
    np.testing.assert_array_less(np.abs(r.mean(axis=0) - bias), 4 * standard_error)
    if family == "imu":  # the configured bias is really there, not only within noise of zero
        np.testing.assert_array_less(4 * standard_error, np.abs(bias))


def test_lighthouse_dropout_rate_matches_probability(rest_run: SimulationResult):
    """Lost Lighthouse sweeps are within a binomial 4-sigma band of the 5 % setting."""
    p = NOISY.lighthouse.dropout_probability
    scheduled = 2 * round(NOISY.lighthouse.rate_hz * REST_DURATION)  # two planes, one station
    received = sum(rest_run.measurements_of(lighthouse_sensor(0, k))[0].size for k in (1, 2))
    dropped = scheduled - received
    assert abs(dropped - p * scheduled) <= 4 * np.sqrt(scheduled * p * (1 - p))
    assert dropped > 0
    # IMU and encoders have no drop-outs configured: every 250 Hz sample is there
    for name in ("imu", "wheel_encoders"):
        assert rest_run.measurements_of(name)[0].size == round(250 * REST_DURATION)


def test_dropouts_and_other_sensors_settings_do_not_reshuffle_noise(
    rest_run: SimulationResult, base_model: CarModel
):
    """Changing drop-out probability or another sensor's noise leaves each sample's noise as is."""
    changed = replace(
        NOISY,
        lighthouse=replace(NOISY.lighthouse, dropout_probability=0.0),
        imu=replace(NOISY.imu, noise_std=(1.0, 1.0, 0.1)),
    )
    other = Simulator(base_model, changed, seed=7).run(REST, REST_DURATION, AT_REST)
    for name in (lighthouse_sensor(0, 1), lighthouse_sensor(0, 2)):
        t_few, v_few = rest_run.measurements_of(name)
        t_all, v_all = other.measurements_of(name)
        # jitter may move the sweep due at t = duration just inside the run
        assert abs(t_all.size - round(NOISY.lighthouse.rate_hz * REST_DURATION)) <= 1
        assert t_all.size > t_few.size
        keep = np.isin(t_all, t_few)
        np.testing.assert_array_equal(t_all[keep], t_few)
        np.testing.assert_array_equal(v_all[keep], v_few)
    np.testing.assert_array_equal(
        other.measurements_of("wheel_encoders")[1], rest_run.measurements_of("wheel_encoders")[1]
    )


def test_sampling_jitter_is_independent_of_measurement_noise(base_model: CarModel):
    """With IMU jitter switched on, the noise draws are not copies of the jitter draws."""
    jitter, noise = 1e-4, 1.0
    sensors = SensorSuite(imu=SensorSpec(250.0, (noise,) * 3, jitter_std_s=jitter))
    result = Simulator(base_model, sensors, seed=0).run(REST, 1.0, AT_REST)
    stamps, values = result.measurements_of("imu")
    jitter_draws = (stamps - np.arange(stamps.size) / 250.0) / jitter
    noise_draws = values.ravel() / noise
    shared = np.isclose(noise_draws[:, None], jitter_draws[None, :], rtol=0, atol=1e-8)
    assert shared.sum() == 0


# --- blackout -------------------------------------------------------------------------------------
def test_blackout_removes_exactly_its_window(rest_run: SimulationResult, base_model: CarModel):
    """A Lighthouse blackout drops exactly the sweeps in [start, start+duration), nothing else."""
    start, length = 2.0, 1.127
    sensors = replace(NOISY, blackouts=(Blackout("lighthouse", start, length),))
    blacked = Simulator(base_model, sensors, seed=7).run(REST, REST_DURATION, AT_REST)
    for name in (lighthouse_sensor(0, 1), lighthouse_sensor(0, 2)):
        t_ref, v_ref = rest_run.measurements_of(name)
        t_out, v_out = blacked.measurements_of(name)
        inside = (t_ref >= start) & (t_ref < start + length)
        assert inside.sum() >= 0.8 * length * NOISY.lighthouse.rate_hz  # the window is not empty
        assert not np.any((t_out >= start) & (t_out < start + length))
        np.testing.assert_array_equal(t_out, t_ref[~inside])
        np.testing.assert_array_equal(v_out, v_ref[~inside])
    for name in ("imu", "wheel_encoders", "pose"):
        for ref, out in zip(
            rest_run.measurements_of(name), blacked.measurements_of(name), strict=True
        ):
            np.testing.assert_array_equal(out, ref)


def test_blackout_prefix_selects_one_station(base_model: CarModel):
    """A blackout of "lighthouse/0/2" silences only that plane; "imu" only the IMU."""
    sensors = replace(
        IDEAL, blackouts=(Blackout("lighthouse/0/2", 0.5, 0.5), Blackout("imu", 1.0, 0.2))
    )
    result = Simulator(base_model, sensors, seed=0).run(REST, 2.0, AT_REST)
    t_plane1, _ = result.measurements_of(lighthouse_sensor(0, 1))
    t_plane2, _ = result.measurements_of(lighthouse_sensor(0, 2))
    t_imu, _ = result.measurements_of("imu")
    assert t_plane1.size == 100
    assert t_plane2.size == 100 - 25
    assert t_imu.size == 500 - 50
    assert result.measurements_of("wheel_encoders")[0].size == 500


# --- reproducibility ------------------------------------------------------------------------------
def test_same_seed_reproduces_stream_and_truth_bit_for_bit(base_model: CarModel):
    """Two runs with one seed give identical stamps, sensors, values, inputs and truth."""
    first = Simulator(base_model, NOISY, seed=11).run(DRIVE, DRIVE_DURATION, AT_REST)
    second = Simulator(base_model, NOISY, seed=11).run(DRIVE, DRIVE_DURATION, AT_REST)
    assert len(first.measurements) == len(second.measurements) > 1000
    for a, b in zip(first.measurements, second.measurements, strict=True):
        assert (a.stamp, a.sensor) == (b.stamp, b.sensor)
        np.testing.assert_array_equal(a.values, b.values)
    np.testing.assert_array_equal(first.truth_t, second.truth_t)
    np.testing.assert_array_equal(first.truth_x, second.truth_x)
    np.testing.assert_array_equal(
        np.stack([s.u for s in first.inputs]), np.stack([s.u for s in second.inputs])
    )


def test_different_seed_gives_independent_noise(rest_run: SimulationResult, base_model: CarModel):
    """Another seed draws other noise: IMU residuals differ and are uncorrelated between seeds."""
    other = Simulator(base_model, NOISY, seed=8).run(REST, REST_DURATION, AT_REST)
    t_a, v_a = rest_run.measurements_of("imu")
    t_b, v_b = other.measurements_of("imu")
    np.testing.assert_array_equal(t_a, t_b)  # the IMU has no jitter: same grid
    assert not np.any(v_a == v_b)
    a, b = (v - v.mean(axis=0) for v in (v_a, v_b))
    correlation = (a * b).sum(axis=0) / np.sqrt((a * a).sum(axis=0) * (b * b).sum(axis=0))
    np.testing.assert_array_less(np.abs(correlation), 4 / np.sqrt(t_a.size))
    assert not np.array_equal(
        rest_run.measurements_of(lighthouse_sensor(0, 1))[0],
        other.measurements_of(lighthouse_sensor(0, 1))[0],
    )  # jitter and drop-outs differ too


# --- latency --------------------------------------------------------------------------------------
def test_latency_shifts_stamps_and_values_refer_to_earlier_state(
    ideal_drive: SimulationResult, base_model: CarModel
):
    """Wheel readings with 10 ms latency are stamped 10 ms late and equal h(x(stamp - 10 ms))."""
    latency = 0.01
    sensors = replace(IDEAL, wheel_encoders=SensorSpec(250.0, (0.0,) * 4, latency_s=latency))
    late = Simulator(base_model, sensors, seed=0).run(DRIVE, DRIVE_DURATION, AT_REST)
    t_ref, v_ref = ideal_drive.measurements_of("wheel_encoders")
    t_late, v_late = late.measurements_of("wheel_encoders")
    np.testing.assert_allclose(t_late - t_ref, latency, rtol=0, atol=1e-12)
    np.testing.assert_array_equal(v_late, v_ref)
    # against the model at the true state one latency earlier (an exact integration point)
    x_then = late.truth_x[truth_index(late, t_late - latency)]
    expected = model_outputs(base_model, x_then, np.array([0.1, 0.3]), "wheel_encoders")
    np.testing.assert_allclose(v_late, expected, rtol=1e-12, atol=1e-9)
    # ... and not the state at the stamp: the car accelerates enough to tell them apart
    at_stamp = t_late < DRIVE_DURATION
    x_now = late.truth_at(t_late[at_stamp])
    now = model_outputs(base_model, x_now, np.array([0.1, 0.3]), "wheel_encoders")
    assert np.max(np.abs(v_late[at_stamp] - now)) > 0.2
    # other sensors keep zero latency
    np.testing.assert_array_equal(
        late.measurements_of("imu")[0], ideal_drive.measurements_of("imu")[0]
    )


# --- rates ----------------------------------------------------------------------------------------
def test_rates_and_lighthouse_plane_alternation_with_two_stations():
    """IMU/encoders tick at 250 Hz; each of 2 stations alternates plane 1 and 2 at 50 Hz each."""
    model = CarModel(n_base_stations=2)
    duration = 2.0
    result = Simulator(model, IDEAL, seed=0).run(REST, duration, AT_REST)
    stats = sensor_statistics(result)
    assert set(stats) == {"imu", "wheel_encoders"} | {
        lighthouse_sensor(s, k) for s in (0, 1) for k in (1, 2)
    }
    for name in ("imu", "wheel_encoders"):
        stamps, _ = result.measurements_of(name)
        assert stats[name]["rate_hz"] == 250.0
        np.testing.assert_allclose(np.diff(stamps), 1 / 250, rtol=0, atol=1e-12)
    for station in (0, 1):
        labelled = []
        for plane in (1, 2):
            name = lighthouse_sensor(station, plane)
            assert stats[name]["rate_hz"] == 50.0
            stamps, values = result.measurements_of(name)
            assert np.all(np.isfinite(values))
            labelled += [(t, plane) for t in stamps]
        labelled.sort()
        planes = np.array([plane for _, plane in labelled])
        np.testing.assert_array_equal(planes, np.tile([1, 2], 100))
        np.testing.assert_allclose(np.diff([t for t, _ in labelled]), 0.01, rtol=0, atol=1e-12)
    # the stations do not sweep at the same instants
    t0, _ = result.measurements_of(lighthouse_sensor(0, 1))
    t1, _ = result.measurements_of(lighthouse_sensor(1, 1))
    assert np.min(np.abs(t1 - t0)) > 1e-3


def test_leaving_lighthouse_coverage_loses_sweeps_instead_of_crashing(base_model: CarModel):
    """Out of the station's view exactly the unreachable sweeps are lost; the run goes on."""
    result = Simulator(base_model, IDEAL, seed=0).run(DRIVE, 3.0, AT_REST)
    assert result.measurements_of("imu")[0].size == 750
    name = lighthouse_sensor(0, 2)
    stamps, angles = result.measurements_of(name)
    assert np.all(np.isfinite(angles))
    scheduled = 0.01 + np.arange(150) * 0.02
    model = model_outputs(
        base_model, result.truth_x[truth_index(result, scheduled)], np.array([0.1, 0.3]), name
    )
    visible = np.all(np.isfinite(model) & (np.abs(model) <= LIGHTHOUSE_VIEW_LIMIT), axis=1)
    assert 0 < visible.sum() < 140 and np.any(np.isnan(model))  # the car does leave the view
    np.testing.assert_allclose(stamps, scheduled[visible], rtol=0, atol=1e-12)
    np.testing.assert_array_equal(angles, model[visible])


# --- effects as hidden truth ----------------------------------------------------------------------
def test_steering_offset_makes_car_turn_with_zero_steering(base_model: CarModel):
    """steering_offset=0.05 with zero steer turns the car left; without it, it drives straight."""
    offset_model = CarModel({"steering_offset": 0.05})
    turning = Simulator(offset_model, IDEAL, seed=0).run(STRAIGHT, DRIVE_DURATION, AT_REST)
    straight = Simulator(base_model, IDEAL, seed=0).run(STRAIGHT, DRIVE_DURATION, AT_REST)
    assert np.all(np.stack([s.u for s in turning.inputs])[:, 0] == 0.0)  # zero steer commanded
    yaw, omega = turning.truth_x[:, 2], turning.truth_x[:, 5]
    moving = turning.truth_t > 0.5
    assert np.all(omega[moving] > 0)
    assert np.all(np.diff(yaw) >= 0)
    assert yaw[-1] > 0.3
    assert turning.truth_x[-1, 1] > 0.05  # drifted left
    assert np.all(straight.truth_x[:, [1, 2, 4, 5]] == 0.0)
    assert straight.truth_x[-1, 0] > 1.0
    applied = offset_model.numeric.applied_input(
        turning.truth_x[-1], np.array([0.0, 0.3]), offset_model.parameters.vector()
    )
    np.testing.assert_allclose(applied, [0.05, 0.3], rtol=0, atol=1e-15)


def test_input_delay_postpones_the_start_by_the_delay(base_model: CarModel):
    """input_delay=0.1: v_x first exceeds 1 cm/s 0.1 s later than without the delay."""
    delayed_model = CarModel({"input_delay": 0.1})
    assert delayed_model.input_delay() == 0.1
    delayed = Simulator(delayed_model, IDEAL, seed=0).run(STRAIGHT, 1.0, AT_REST)
    prompt = Simulator(base_model, IDEAL, seed=0).run(STRAIGHT, 1.0, AT_REST)
    t_delayed = first_crossing(delayed.truth_t, delayed.truth_x[:, 3], 0.01)
    t_prompt = first_crossing(prompt.truth_t, prompt.truth_x[:, 3], 0.01)
    assert t_delayed - t_prompt == pytest.approx(0.1, abs=1e-3)
    assert np.all(delayed.truth_x[delayed.truth_t <= 0.1, 3] == 0.0)
    # the log holds the commands at the time they were given, not when they arrived
    assert delayed.inputs[0].stamp == 0.0
    np.testing.assert_array_equal(delayed.inputs[0].u, [0.0, 0.3])


def test_gyro_bias_shifts_imu_yaw_rate_only(base_model: CarModel):
    """gyro_bias=0.1 adds exactly 0.1 rad/s to the IMU yaw rate and leaves a_x, a_y alone."""
    biased_model = CarModel({"gyro_bias": 0.1})
    result = Simulator(biased_model, IDEAL, seed=0).run(DRIVE, DRIVE_DURATION, AT_REST)
    stamps, imu = result.measurements_of("imu")
    x = result.truth_x[truth_index(result, stamps)]
    assert np.max(np.abs(x[:, 5])) > 0.5  # the car really turns
    residual = imu[:, 2] - x[:, 5]
    np.testing.assert_allclose(residual, 0.1, rtol=0, atol=1e-9)
    expected = model_outputs(base_model, x, np.array([0.1, 0.3]), "imu")
    np.testing.assert_allclose(imu[:, :2], expected[:, :2], rtol=1e-12, atol=1e-9)


def test_wheel_radius_error_scales_encoder_readings(base_model: CarModel):
    """wheel_radius_error=dr: straight-line encoders read v_x / (r + dr), not v_x / r."""
    dr = 0.002
    model = CarModel({"wheel_radius_error": dr})
    result = Simulator(model, IDEAL, seed=0).run(STRAIGHT, DRIVE_DURATION, AT_REST)
    stamps, wheels = result.measurements_of("wheel_encoders")
    vx = result.truth_x[truth_index(result, stamps), 3]
    r = model.parameters.value("r")
    assert vx.max() > 1.0
    np.testing.assert_allclose(wheels, np.tile(vx[:, None] / (r + dr), 4), rtol=1e-12, atol=1e-12)
    nominal = model_outputs(
        base_model,
        result.truth_x[truth_index(result, stamps)],
        np.array([0.0, 0.3]),
        "wheel_encoders",
    )
    np.testing.assert_allclose(wheels[-1], nominal[-1] * r / (r + dr), rtol=1e-12)


def test_a_streaming_session_keeps_constant_memory_and_the_same_samples(base_model: CarModel):
    """``keep_history=False`` (the ROS simulator node): after 60 s of driving the session holds
    one truth sample and no inputs or measurements (its memory does not grow with time), and it
    streams exactly the samples of a session that keeps everything."""
    sensors = SensorSuite()
    x0 = np.array([0.0, 0.0, 0.0, 0.5, 0.0, 0.0])
    kept = Simulator(base_model, sensors, seed=4).session(x0)
    streaming = Simulator(base_model, sensors, seed=4).session(x0, keep_history=False)
    streamed = []
    for k in range(1, 60 * 50 + 1):  # 60 s at a 50 Hz control rate
        for session in (kept, streaming):
            session.command(np.array([0.2, 0.3]))
        kept.advance(k / 50)
        streamed += streaming.advance(k / 50)
    assert len(kept.measurements) > 30_000 and len(kept.truth_t) > 3_000
    assert (len(streaming.truth_t), len(streaming.inputs), len(streaming.measurements)) == (1, 0, 0)
    np.testing.assert_array_equal(streaming.base_state, kept.base_state)
    assert len(streamed) == len(kept.measurements)
    for a, b in zip(streamed, kept.measurements, strict=True):
        assert (a.stamp, a.sensor) == (b.stamp, b.sensor)
        np.testing.assert_array_equal(a.values, b.values)
