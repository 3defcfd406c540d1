"""Tests of crs_core.estimation.base, the estimator interface, on both estimators (EKF and MHE):
convergence, any delivery order or timing, late data, boundaries, settings, history, memory."""

import math

import numpy as np
import pytest

from crs_core.errors import FieldError
from crs_core.estimation import (
    EkfSettings,
    EstimatorNoise,
    ExtendedKalmanFilter,
    MheSettings,
    make_estimator,
)
from crs_core.estimation.health import HealthSettings
from crs_core.estimation.initialization import InitializationSettings
from crs_core.estimation.mhe import MovingHorizonEstimator
from crs_core.estimation.realtime import RealtimeSettings
from crs_core.measurements import InputSample, Measurement, lighthouse_sensor
from crs_core.model import CarModel
from crs_core.track import load_demo_track
from sim.replay import SETTLING_S, errors, replay, rmse, start_state
from sim.scenarios import JoystickDriver, standard_drive
from sim.sensors import Blackout, SensorSpec, SensorSuite
from sim.simulator import Simulator
from tests.crs_core.estimation.conftest import KINDS, _events, _late_ticks, _position_error, _run

# --- 1. bounded under any timing ---------------------------------------------------------


@pytest.mark.parametrize("late_s", [0.3, 1.0])
@pytest.mark.parametrize("kind", KINDS)
def test_late_updates_stay_bounded(drive, kind, late_s):
    """Updates late by up to 1 s (the MHE run-away of loaded stacks): finite and on track.

    Before the fixed grid the MHE integrated a 0.5 s stage with the 5 substeps meant for
    1/60 s and ran away to a kilometre."""
    queries = _late_ticks(np.random.default_rng(7), drive.duration - 0.5, late_s)
    xs, _ = _run(make_estimator(kind, "lh+imu+we"), drive, queries)
    assert np.all(np.isfinite(xs))
    error = _position_error(drive, queries, xs)
    settled = np.asarray(queries) > 2.0
    assert error[settled].max() < 0.02, error[settled].max()


@pytest.mark.parametrize("kind", KINDS)
def test_stall_and_resume(drive, kind):
    """No query and no data for 2.5 s, then everything at once: the estimator skips to the
    newest data (MHE) or predicts across (EKF) and is back on track within a second."""
    queries = [*np.arange(1 / 60, 3.0, 1 / 60), *np.arange(5.5, 7.5, 1 / 60)]
    estimator = make_estimator(kind, "lh+imu+we")
    xs, statuses = _run(estimator, drive, queries)
    assert np.all(np.isfinite(xs))
    error = _position_error(drive, queries, xs)
    after = np.asarray(queries) > 6.5
    assert error[after].max() < 0.01
    if kind == "mhe":
        assert estimator.diagnostics.skipped_s > 1.0
        assert "degraded" in statuses  # the skip is reported


@pytest.mark.parametrize("kind", KINDS)
def test_out_of_order_bursts_and_duplicate_stamps(drive, kind):
    """Data delivered in shuffled 200 ms bursts, part of it after the queries passed it, and
    every measurement twice: finite, never far off, late data counted."""
    rng = np.random.default_rng(3)
    estimator = make_estimator(kind, "lh+imu+we")
    estimator.reset(0.0, start_state(drive))
    events = _events(drive)
    xs, queries, k = [], [], 0
    for burst_end in np.arange(0.2, drive.duration, 0.2):
        batch = []
        while k < len(events) and events[k].stamp <= burst_end:
            batch.append(events[k])
            k += 1
        batch = [batch[i] for i in rng.permutation(len(batch))]
        batch += [m for m in batch if isinstance(m, Measurement)]  # duplicates
        held_back = batch[: len(batch) // 10]  # arrives after the queries below
        for item in batch[len(batch) // 10 :]:
            estimator.add(item)
        for t in np.arange(burst_end - 0.2 + 1 / 60, burst_end + 1e-9, 1 / 60):
            xs.append(estimator.estimate(t).x)
            queries.append(t)
        for item in held_back:
            estimator.add(item)
    xs = np.array(xs)
    assert np.all(np.isfinite(xs))
    error = _position_error(drive, queries, xs)
    assert error[np.asarray(queries) > 2.0].max() < 0.02
    assert estimator.diagnostics.late > 0


# --- 6. API for users ---------------------------------------------------------------------


@pytest.mark.parametrize("kind", KINDS)
def test_time_offset_corrects_a_sensor_latency(kind):
    """Lighthouse stamps 25 ms late (stamped on arrival): the per-sensor time offset puts them
    back where they belong and the position error drops. Queried 30 ms behind the data (as the
    node's ``lag``), so the EKF has not passed the corrected stamps yet."""
    suite = SensorSuite(lighthouse=SensorSpec(50.0, (1e-3,) * 4, latency_s=0.025))
    track, model = load_demo_track(), CarModel()
    wheelbase = model.parameters.value("lf") + model.parameters.value("lr")
    x0 = track.start_state()
    result = Simulator(model, suite, seed=1).run(JoystickDriver(track, wheelbase, 1), 6.0, x0)
    queries = np.arange(1, 360) / 60.0
    rms = {}
    for offset in (0.0, 0.025):
        settings = (EkfSettings if kind == "ekf" else MheSettings)(time_offsets={"lh": offset})
        estimator = make_estimator(kind, "lh+imu+we", settings=settings)
        xs, _ = _run(estimator, result, queries, lag=0.03)
        error = _position_error(result, queries, xs)[queries > 2]
        rms[offset] = float(np.sqrt(np.mean(error**2)))
    assert rms[0.025] < 0.6 * rms[0.0], rms


@pytest.mark.parametrize(
    ("make", "field", "reason"),
    [
        (lambda: EstimatorNoise(process_std=(0.02,) * 7), "noise.process_std", "needs 6 values"),
        (lambda: EstimatorNoise(pose_std=(0.1, 0.1)), "noise.pose_std", "needs 3 values"),
        (lambda: EstimatorNoise(gyro_std=0.0), "noise.gyro_std", "every standard deviation"),
        (lambda: EkfSettings(initial_std=(1.0,) * 5), "initial_std", "needs 6 finite values"),
        (lambda: EkfSettings(gate_probability=1.0), "gate_probability", "must be in (0, 1)"),
        (lambda: EkfSettings(time_offsets={"lidar": 0.01}), "time_offsets", "'lidar' is neither"),
        (
            lambda: EkfSettings(time_offsets={"imu": math.nan}),
            "time_offsets['imu']",
            "must be a finite number of seconds",
        ),
        (lambda: MheSettings(horizon=0), "horizon", "must be >= 1"),
        (lambda: MheSettings(discount=0.0), "discount", "must be within (0, 1], got 0.0"),
        (lambda: MheSettings(state_upper=(1.0, 1.0)), "state_upper", "needs 3 values"),
        (lambda: MheSettings(process_bound=(0.1,) * 8), "process_bound", "needs 6 values"),
        (
            lambda: HealthSettings(lost_after_s=0.0),
            "health.lost_after_s",
            "must be a finite number > 0, got 0.0",
        ),
        (
            lambda: HealthSettings(rejected_fraction=1.5),
            "health.rejected_fraction",
            "must be within [0, 1], got 1.5",
        ),
        (
            lambda: InitializationSettings(span_s=math.nan),
            "initialization.span_s",
            "must be a finite number > 0, got nan",
        ),
        (lambda: InitializationSettings(min_fixes=1), "initialization.min_fixes", "must be >= 2"),
        (lambda: RealtimeSettings(rate_hz=0.0), "rate_hz", "must be a finite number > 0"),
        (lambda: RealtimeSettings(max_lag=-0.1), "max_lag", "must be a finite number >= 0"),
    ],
)
def test_a_bad_setting_is_a_field_error_naming_it(make, field: str, reason: str):
    with pytest.raises(FieldError) as error:
        make()
    assert error.value.field == field
    assert error.value.reason.startswith(reason), error.value


def test_time_offsets_parse_from_text():
    from crs_core.estimation.base import parse_time_offsets

    assert parse_time_offsets("lh:0.004, lighthouse/0/1:0.01") == {
        "lh": 0.004,
        "lighthouse/0/1": 0.01,
    }
    assert parse_time_offsets("") == {}
    with pytest.raises(FieldError, match=r"time_offsets: 'imu=0\.1' is not") as error:
        parse_time_offsets("imu=0.1")
    assert error.value.field == "time_offsets"


def test_no_lighthouse_and_no_x0_is_refused():
    estimator = make_estimator("ekf", "imu+we", inputs="commanded")
    with pytest.raises(ValueError, match="x0: an estimator without Lighthouse"):
        estimator.reset(0.0)


def test_replay_blind_without_inputs_starts_lost_then_finds_the_car():
    drive = standard_drive(0, duration=2.0)
    run = replay(make_estimator("ekf", "lh", inputs="estimated"), drive, 60.0, None, inputs=False)
    assert run.statuses[0] == "lost"
    assert run.statuses[-1] != "lost"
    assert np.all(np.isfinite(run.estimates))


@pytest.mark.parametrize("kind", KINDS)
def test_queries_in_the_past_are_answered_from_history_or_refused(drive, kind):
    """A stamp before the newest data is answered from the kept states (EKF: 2 s of them, MHE:
    its window), and further back refused with an error naming ``t`` (never the newest state
    under an old stamp)."""
    queries = np.arange(1, 360) / 60.0
    estimator = make_estimator(kind, "lh+imu+we")
    _run(estimator, drive, queries)
    for back in (0.1, 0.5):
        t = queries[-1] - back
        estimate = estimator.estimate(t)
        assert _position_error(drive, [t], estimate.x[None, :])[0] < 0.005
    with pytest.raises(FieldError, match=r"t: .* is before the oldest state") as error:
        estimator.estimate(queries[-1] - 5.0)
    assert error.value.field == "t"


@pytest.mark.parametrize("kind", KINDS)
def test_a_runaway_without_lighthouse_restarts_instead_of_failing(drive, kind):
    """IMU and encoders only, fed a wheel speed that claims 30 m/s: the EKF's state leaves the
    envelope, the estimate says lost and restarts from the last good one (no exception); the
    MHE's soft speed bounds keep it inside."""
    estimator = make_estimator(kind, "imu+we", inputs="commanded")
    estimator.reset(0.0, start_state(drive))
    for k in range(1, 40):
        t = k / 60
        estimator.add_measurement(Measurement(t, "wheel_encoders", np.full(4, 30 / 0.0175)))
        estimate = estimator.estimate(t)
        assert np.all(np.isfinite(estimate.x))
    if kind == "ekf":
        assert estimator.diagnostics.reinitializations >= 1
    else:
        assert abs(estimate.x[3]) <= 10.0


@pytest.mark.parametrize(
    ("kind", "end", "traced_from", "sample_every", "bound", "collect"),
    [("ekf", 70.0, 10.0, 0.25, 16_000, False), ("mhe", 120.0, 40.0, 10.0, 32_000, True)],
)
def test_memory_stays_flat_over_a_long_stream(kind, end, traced_from, sample_every, bound, collect):
    """A long stream (a car circling; sensors at their real rates, 600 events/s, queries at
    20 Hz) in bounded memory: the memory the estimator holds, traced from ``traced_from`` s on,
    never rises in the second half of the traced span more than ``bound`` above its peak of
    the first half. A leak of ``r`` B/s adds ``r`` times half the traced span to that peak.

    EKF: traced 10-70 s, sampled every 0.25 s, bound 16 kB. Its held memory is a sawtooth
    (it keeps 2-4 s of states: 1.05-1.41 MB, period 2 s), full 4 s after tracing starts; the
    peaks vary by under 7 kB within 10 s and drift down by about 0.6 kB/s. Measured: -9 kB
    (25 kB under the bound); with a leak of 1.2 kB/s injected (58 B per query) +26 kB, fails;
    an EKF that never cuts its history +12 MB. The 6-minute stream this replaces (traced
    120-360 s, bound 64 kB, about 100 s; tracing makes the loop about 4x slower) sat at about
    -76 kB, so it let a 1.2 kB/s leak pass (-76 + 139 = 63 kB): this one detects from about 0.8 kB/s
    ((16 + 9) kB / 30 s), the old one from about 1.2 kB/s ((64 + 76) kB / 120 s).

    MHE: its held memory fills for about 30 s, so it is traced 40-120 s, sampled every 10 s,
    each sample after a full collection (``collect``: ``gc.collect()`` also empties the
    interpreter's free lists). Without it the traced memory rose 1-2 kB/s from 65 s on, past
    the 64 kB this test once allowed in one CI run: the free list of 2-tuples filling
    (435 -> 1392 of its 2000 in 40-190 s, 56 B each), which is the interpreter's, not the
    estimator's. Collected, it rises 6 kB over the first half's peak (23.9 -> 29.7 kB, slowing
    to 0.1 kB/s by 190 s); bound 32 kB (0.8 kB/s). The EKF is sampled too often for a
    collection each time (60 ms each, 14 s in all) and never needed one.

    The stream is simulated before the loop (the command is constant, so it is the same
    stream) and each measurement handed over as a fresh copy made in the loop (its stamp a new
    float, its values a new array): whatever the estimator keeps of it is allocated while
    tracing, as from a live session, but the simulator no longer runs under tracemalloc (it
    took about 40 % of the traced loop's time; its own memory is flat, test_simulator checks
    it). Measured the same either way (before the MHE's collection): EKF -9.9 kB (live session
    -9.8), MHE +42 kB (live 38-45 kB). Handing over the pre-made objects themselves would hide
    a kept stamp.
    """
    import gc
    import tracemalloc

    session = Simulator(CarModel(), SensorSuite(), seed=5).session(
        np.array([0.0, 0.0, 0.0, 0.8, 0.0, 0.0]), keep_history=False
    )
    estimator = make_estimator(kind, "lh+imu+we")
    estimator.reset(0.0, session.base_state.copy())
    command = np.array([0.15, 0.12])
    session.command(command)
    estimator.add(InputSample(0.0, command))
    stamps = np.arange(0.05, end, 0.05)
    stream = [session.advance(t) for t in stamps]
    held = []
    start, every = round(traced_from / 0.05), round(sample_every / 0.05)
    for k, (t, items) in enumerate(zip(stamps, stream, strict=True), 1):
        for item in items:
            estimator.add(Measurement(item.stamp + 0.0, item.sensor, item.values))  # a copy
        estimate = estimator.estimate(t - 0.02)
        assert np.all(np.isfinite(estimate.x))
        if k == start:
            tracemalloc.start()
        if tracemalloc.is_tracing() and k % every == 0:
            if collect:
                gc.collect()
            held.append(tracemalloc.get_traced_memory()[0])
    tracemalloc.stop()
    middle, last = held[: len(held) // 2], held[len(held) // 2 :]
    assert len(middle) >= 3 and len(last) >= 3
    assert max(last) <= max(middle) + bound, (max(last) - max(middle), middle, last)


# --- on the standard drive of the documented bounds: convergence, order, boundaries ---------------


#: The sensor combinations of the paper's Table I.
SENSOR_SETS = ("lh", "lh+imu", "lh+we", "lh+imu+we")


#: Documented bounds after 2 s of settling on the standard drive (8 s, seed 11), in SI units.
#: Measured (worst over estimators and sensor sets): position 1.9 mm, yaw 30 mrad,
#: vx 60 mm/s, vy 50 mm/s, yaw rate 0.2 rad/s (LH only leaves yaw rate weakly observed).
BOUNDS = {"x": 0.006, "y": 0.006, "yaw": 0.06, "vx": 0.12, "vy": 0.1, "omega": 0.4}


def _make(kind: str, sensors: str):
    if kind == "ekf":
        return ExtendedKalmanFilter(CarModel(), sensors)
    return MovingHorizonEstimator(CarModel(), sensors, MheSettings(rate_hz=60.0))


@pytest.mark.parametrize("drive", [11], indirect=True)  # seed 11: the drive of BOUNDS
@pytest.mark.parametrize("sensors", SENSOR_SETS)
@pytest.mark.parametrize("kind", ["ekf", "mhe"])
def test_converges_from_wrong_initial_state(drive, kind, sensors):
    """From 14 cm and 0.2 rad off, the estimate settles within the documented bounds."""
    run = replay(_make(kind, sensors), drive, 60.0, start_state(drive))
    result = rmse(run, drive)
    for state, bound in BOUNDS.items():
        assert result[state] < bound, (kind, sensors, state, result)
    settled = [s for s, t in zip(run.statuses, run.stamps, strict=True) if t >= SETTLING_S]
    assert settled == ["ok"] * len(settled)


@pytest.mark.parametrize("drive", [11], indirect=True)  # seed 11: the drive of BOUNDS
@pytest.mark.parametrize("kind", ["ekf", "mhe"])
def test_same_stamps_in_another_interleaving_give_the_same_estimate(drive, kind):
    """Delivering the same measurements in a shuffled order (same stamps) changes nothing."""
    rng = np.random.default_rng(0)
    estimates = []
    for shuffle in (False, True):
        estimator = _make(kind, "lh+imu+we")
        estimator.reset(0.0, start_state(drive))
        measurements = list(drive.measurements)
        inputs = list(drive.inputs)
        for t in np.arange(0.1, 4.0, 0.1):  # deliver in 100 ms batches
            batch = [m for m in measurements if t - 0.1 < m.stamp <= t]
            batch += [s for s in inputs if t - 0.1 < s.stamp <= t]
            if shuffle:
                batch = [batch[i] for i in rng.permutation(len(batch))]
            for item in batch:
                if isinstance(item, Measurement):
                    estimator.add_measurement(item)
                else:
                    estimator.add_input(item)
            for query in np.arange(t - 0.1 + 1 / 60, t + 1e-9, 1 / 60):
                estimates.append(estimator.estimate(query).x)
    half = len(estimates) // 2
    np.testing.assert_array_equal(np.array(estimates[:half]), np.array(estimates[half:]))


@pytest.mark.parametrize("burst_s", [0.1, 0.5])
@pytest.mark.parametrize("kind", ["ekf", "mhe"])
def test_blackout_and_outlier_burst_do_not_diverge(kind, burst_s):
    """A 1.127 s Lighthouse blackout, then 0.1 or 0.5 s of wild sweeps (10 or 50, more than the
    rejection cap of 25: the cap lets only consistent innovations through): no divergence."""
    dark = standard_drive(seed=5, duration=8.0, blackouts=[Blackout("lighthouse", 3.0, 1.127)])
    rng = np.random.default_rng(1)
    corrupted = []
    for m in dark.measurements:
        if m.sensor.startswith("lighthouse") and 5.0 <= m.stamp < 5.1:
            jump = rng.uniform(0.2, 0.6) * rng.choice([-1, 1])
            m = Measurement(m.stamp, m.sensor, m.values + jump)
        corrupted.append(m)
    dark.measurements = corrupted
    estimator = _make(kind, "lh+imu+we")
    run = replay(estimator, dark, 60.0, start_state(dark))
    position = np.hypot(*errors(run, dark)[:, :2].T)
    during = (run.stamps > 3.0) & (run.stamps < 4.127)
    assert position[during].max() < 0.1  # dead reckoning on IMU + encoders for 1.1 s
    burst = (run.stamps >= 5.0) & (run.stamps < 5.5 + burst_s)
    assert position[burst].max() < 0.03
    assert sum(estimator.diagnostics.rejected.values()) > 0
    tail = run.stamps > 6.5
    assert position[tail].max() < 0.006


def test_nan_and_inf_are_rejected_at_the_boundary():
    """Non-finite readings never reach an estimator: the message names the field and sensor."""
    for bad in (np.nan, np.inf):
        with pytest.raises(ValueError, match=r"values: lighthouse/0/1 at t=0\.5 has NaN or inf"):
            Measurement(0.5, lighthouse_sensor(0, 1), [0.1, bad, 0.1, 0.1])
    estimator = ExtendedKalmanFilter(CarModel(), "lh")
    with pytest.raises(TypeError, match="measurement"):
        estimator.add_measurement((0.5, "lighthouse/0/1", [np.nan] * 4))


@pytest.mark.parametrize("kind", ["ekf", "mhe"])
def test_unused_sensors_are_ignored_and_unknown_ones_refused(kind):
    """Sensors outside the chosen set are ignored and counted; a station the model lacks is
    refused at the boundary with an error naming it."""
    estimator = _make(kind, "lh")
    assert not estimator.add_measurement(Measurement(0.1, "imu", [0.0, 0.0, 0.0]))
    assert estimator.diagnostics.ignored["imu"] == 1
    with pytest.raises(ValueError, match=r"'lighthouse/3/1' is not a sensor of the estimator"):
        estimator.add_measurement(Measurement(0.1, lighthouse_sensor(3, 1), [0.1] * 4))


@pytest.mark.parametrize("drive", [11], indirect=True)  # seed 11: the drive of BOUNDS
def test_late_measurements_are_counted_not_used(drive):
    """A measurement older than what was processed is rejected as late."""
    estimator = ExtendedKalmanFilter(CarModel(), "lh+imu+we")
    estimator.reset(0.0, start_state(drive))
    estimator.add_measurement(Measurement(1.0, "wheel_encoders", [50.0] * 4))
    estimator.estimate(1.0)
    assert not estimator.add_measurement(Measurement(0.5, "wheel_encoders", [50.0] * 4))
    assert estimator.diagnostics.late == 1


@pytest.mark.parametrize("kind", ["ekf", "mhe"])
def test_recovers_when_commands_ran_ahead_of_the_data(kind):
    """Commands for 1.5 s before any sensor data (a launch where the simulator starts late): the
    prediction runs away, yet once data arrive both estimators return to the truth, finite
    (every sweep rejected for 0.5 s, or a state outside the physical envelope, makes the
    estimate lost and re-initialises it from the Lighthouse)."""
    drive = standard_drive(seed=2, duration=8.0)
    delay = 1.5
    estimator = _make(kind, "lh+imu+we")
    estimator.reset(0.0, drive.truth_x[0])
    for t in np.arange(0.0, delay, 0.02):
        estimator.add_input(InputSample(float(t), np.array([0.2, 0.6])))
    for sample in drive.inputs:
        estimator.add_input(InputSample(sample.stamp + delay, sample.u))
    for m in drive.measurements:
        estimator.add_measurement(Measurement(m.stamp + delay, m.sensor, m.values))
    stamps = np.arange(1 / 60, drive.duration + delay, 1 / 60)
    estimates = np.array([estimator.estimate(t).x for t in stamps])
    assert np.all(np.isfinite(estimates))
    tail = stamps > delay + 4.0
    truth = drive.truth_at(stamps[tail] - delay)
    position = np.hypot(*(estimates[tail, :2] - truth[:, :2]).T)
    assert position.max() < 0.01
