"""Tests of crs_core.estimation.realtime without ROS: start, query grid, adaptive lag, late and
reordered data, clock jumps and deadline misses."""

from __future__ import annotations

import math

import numpy as np
import pytest

from crs_core.estimation import ExtendedKalmanFilter
from crs_core.estimation.base import Diagnostics, Estimate
from crs_core.estimation.realtime import (
    CLOCK_JUMP_S,
    GRID_TOLERANCE,
    LAG_MARGIN_S,
    LAG_WINDOW_S,
    RealtimeEstimator,
    RealtimeSettings,
    WindowMax,
)
from crs_core.measurements import InputSample, Measurement
from crs_core.model import CarModel
from sim.scenarios import standard_drive

X0 = np.array([1.0, 2.0, 0.5, 0.0, 0.0, 0.0])


class FakeEstimator:
    """Records what it is given; late is anything stamped before the last query (an EKF)."""

    def __init__(self, sensors=frozenset({"lh", "imu"})) -> None:
        self.sensors = sensors
        self.diagnostics = Diagnostics()
        self.added: list = []
        self.resets: list[tuple[float, np.ndarray | None]] = []
        self.queries: list[float] = []
        self._processed = -math.inf

    def add(self, item) -> bool:
        if item.stamp < self._processed:
            self.diagnostics.late += 1
            return False
        self.added.append(item)
        return True

    def reset(self, t0, x0=None) -> None:
        self.resets.append((t0, x0))
        self._processed = t0
        self.added.clear()

    def estimate(self, t) -> Estimate:
        self.queries.append(t)
        self._processed = t
        return Estimate(t, X0, np.eye(6))


def imu(stamp: float) -> Measurement:
    return Measurement(stamp, "imu", [0.0, 0.0, 0.0])


def test_window_max_keeps_the_largest_value_of_the_last_seconds():
    window = WindowMax(5.0)
    assert window.value(100.0) == -math.inf
    window.add(100.2, 0.03)
    window.add(100.7, 0.01)
    window.add(102.5, 0.02)
    assert window.value(102.9) == 0.03
    assert window.value(104.9) == 0.03  # second 100 is one of the last five
    assert window.value(105.0) == 0.02  # ... and now it is not
    for second in range(107, 130):  # long runs keep a bounded number of buckets
        window.add(second + 0.5, 0.001)
    assert window.value(129.9) == 0.001 and len(window._buckets) <= 6


def test_starts_on_the_first_measurement_at_the_ticks_scheduled_time():
    """No estimate before a measurement (an input alone does not start it); the start is at
    ``now - lag - lateness`` on the buffered data stamped from then on, with the command in
    effect then re-stamped at the start; older measurements are dropped, not counted late."""
    fake = FakeEstimator()
    realtime = RealtimeEstimator(fake, RealtimeSettings(rate_hz=50.0, lag=0.02), X0)
    realtime.deliver(InputSample(9.90, [0.1, 0.2]), source="input")
    assert realtime.update(9.95).queried is False and not fake.resets
    old, kept = imu(9.95), imu(9.98)
    realtime.deliver(old, source="imu")
    realtime.deliver(kept, source="imu")
    result = realtime.update(10.0, tick_lateness=0.004)
    assert result.started and result.queried and result.t == pytest.approx(9.976)
    np.testing.assert_array_equal(result.initial, X0)
    assert fake.resets == [(result.t, X0)]
    assert [type(i).__name__ for i in fake.added] == ["InputSample", "Measurement"]
    assert fake.added[0].stamp == result.t and fake.added[1] is kept
    assert fake.diagnostics.late == 0 and realtime.newest == {"input": 9.90, "imu": 9.98}
    assert realtime.oldest == {"input": 9.90, "imu": 9.95}  # the first each, as it arrived
    blind = RealtimeEstimator(FakeEstimator(), RealtimeSettings(rate_hz=50.0))
    blind.deliver(imu(9.99))
    assert blind.update(10.0).started and blind.update(10.0).initial is None


def test_queries_sit_on_the_grid_of_the_start():
    """Ticks with up to 40 % of a period of jitter: every query is at ``origin + n period``,
    never later than ``now - lag`` by more than GRID_TOLERANCE periods, never a period
    earlier, and never the same time twice."""
    rng = np.random.default_rng(4)
    period, lag = 1 / 60, 0.02
    fake = FakeEstimator()
    realtime = RealtimeEstimator(fake, RealtimeSettings(rate_hz=60.0, lag=lag), X0)
    realtime.deliver(imu(4.99))
    origin = realtime.update(5.0, tick_lateness=0.003).t
    for k in range(1, 300):
        now = 5.0 + k * period + rng.uniform(-0.1, 0.3) * period
        result = realtime.update(now)
        if result.queried:
            steps = (result.t - origin) / period
            assert steps == pytest.approx(round(steps), abs=1e-6)
            assert now - lag - period < result.t <= now - lag + GRID_TOLERANCE * period + 1e-9
    assert np.all(np.diff(fake.queries) > 0.5 * period)
    assert len(fake.queries) >= 250


def test_a_clock_jump_back_restarts_blind_on_the_data_that_follow():
    fake = FakeEstimator()
    realtime = RealtimeEstimator(fake, RealtimeSettings(rate_hz=50.0), X0)
    realtime.deliver(imu(99.99), source="imu")
    realtime.update(100.0)
    realtime.update(100.02)
    assert realtime.update(100.04).queried and realtime.restarts == 0
    # a looped replay: the clock back by 10 s; the data that follow drain in at the tick
    result = realtime.update(90.04, drain=lambda: realtime.deliver(imu(90.01), source="imu"))
    assert realtime.restarts == 1 and [w.kind for w in result.warnings] == ["restart"]
    assert "jumped back by 10.00 s" in result.warnings[0].message
    assert result.started and result.initial is None  # blind: it has the Lighthouse
    assert fake.resets[-1][0] == pytest.approx(result.t) and result.t < 90.04
    assert realtime.newest == realtime.oldest == {"imu": 90.01}  # cleared at the restart
    # a jump back by less than CLOCK_JUMP_S is not a restart (only nothing new to ask)
    small = realtime.update(result.t + 0.02 - 0.5 * CLOCK_JUMP_S)
    assert realtime.restarts == 1 and not small.queried
    # without Lighthouse or pose a restart starts from the initial state again
    plain = RealtimeEstimator(FakeEstimator(frozenset({"imu"})), RealtimeSettings(), X0)
    plain.deliver(imu(9.99))
    plain.update(10.0)
    plain.update(10.1)
    assert plain.update(5.0, drain=lambda: plain.deliver(imu(4.99))).initial is not None


def test_deadline_misses_are_counted_when_an_update_takes_longer_than_the_period():
    durations = iter([0.0, 0.010, 0.0, 0.030, 0.0, 0.016, 0.0, 0.017])
    clock = [0.0]

    def timer() -> float:
        clock[0] += next(durations)
        return clock[0]

    fake = FakeEstimator()
    realtime = RealtimeEstimator(fake, RealtimeSettings(rate_hz=60.0), X0, timer=timer)
    realtime.deliver(imu(0.99))
    realtime.update(1.0)
    results = [realtime.update(1.0 + k / 60) for k in range(1, 5)]
    assert [r.elapsed for r in results] == pytest.approx([0.010, 0.030, 0.016, 0.017])
    assert realtime.deadline_misses == 2 and realtime.updates == 4
    assert [w.kind for r in results for w in r.warnings] == ["deadline", "deadline"]
    assert realtime.take_max_update_time() == pytest.approx(0.030)
    assert realtime.take_max_update_time() == 0.0


def test_the_lag_rises_to_cover_60_ms_late_data_and_decays_after_the_window():
    """Data arriving 60 ms after their stamps raise the lag to 65 ms (within max_lag): after
    the first two (which arrive before any delay was seen) none is late; 5 s after the last late
    one the lag is back at ``lag``."""
    settings = RealtimeSettings(rate_hz=50.0, lag=0.02, max_lag=0.1)
    fake = FakeEstimator()
    realtime = RealtimeEstimator(fake, settings, X0)
    assert realtime.tracks_delays
    period = 0.02
    lags, kinds, late, now = [], [], [], 10.0
    realtime.deliver(imu(now - 0.06), now)
    for k in range(1, 600):  # 12 s: 2 s of data 60 ms late, then 5 ms late
        now = 10.0 + k * period
        delay = 0.06 if now < 12.0 else 0.005
        result = realtime.update(now, drain=lambda t=now, d=delay: realtime.deliver(imu(t - d), t))
        lags.append(realtime.current_lag)
        late.append(fake.diagnostics.late)
        kinds += [w.kind for w in result.warnings]
    lags = np.array(lags)
    times = 10.0 + period * np.arange(1, 600)
    assert lags.max() == pytest.approx(0.06 + LAG_MARGIN_S)
    assert np.all(lags[(times > 10.1) & (times < 12.0)] == pytest.approx(0.065))
    assert late[-1] == 2 and late[4] == 2 and kinds.count("lag") == 1
    # the window holds whole seconds: the last late second (11) leaves it 5 to 6 s later
    assert np.all(lags[(times > 10.1) & (times < 11.0 + LAG_WINDOW_S)] == pytest.approx(0.065))
    assert np.all(lags[times >= 12.0 + LAG_WINDOW_S] == pytest.approx(0.02))
    # the same data with the lag fixed (no max_lag): most of them arrive late
    fixed = FakeEstimator()
    realtime = RealtimeEstimator(fixed, RealtimeSettings(rate_hz=50.0, lag=0.02), X0)
    realtime.deliver(imu(9.94))
    for k in range(1, 100):
        now = 10.0 + k * period
        realtime.update(now, drain=lambda t=now: realtime.deliver(imu(t - 0.06)))
    assert fixed.diagnostics.late > 90


def _replay(result, delays: np.ndarray, lag: float) -> tuple[ExtendedKalmanFilter, list]:
    """The drive's stream through an EKF at 60 Hz, each item arriving ``delays`` after its
    stamp (independently: reordered), delivered at the first tick at or after its arrival."""
    items = sorted([*result.inputs, *result.measurements], key=lambda i: i.stamp)
    arrivals = np.array([i.stamp for i in items]) + delays
    order = np.argsort(arrivals, kind="stable")
    ekf = ExtendedKalmanFilter(CarModel(), "lh+imu+we")
    realtime = RealtimeEstimator(ekf, RealtimeSettings(rate_hz=60.0, lag=lag), result.truth_x[0])
    estimates, k = [], 0
    for now in np.arange(0.1, result.truth_t[-1], 1 / 60):

        def drain(now: float = now) -> None:
            nonlocal k
            while k < len(order) and arrivals[order[k]] <= now:
                realtime.deliver(items[order[k]], arrivals[order[k]])
                k += 1

        update = realtime.update(now, drain=drain)
        if update.estimate is not None:
            estimates.append((update.t, update.estimate.x))
    return ekf, estimates


def test_reordered_data_within_the_lag_are_all_used_by_the_ekf():
    """Each datagram delayed 5 + |N(0, 12)| ms (at most 45 ms), independently, so the stream
    arrives reordered: with a 50 ms lag none is late and every estimate equals the one from the
    stream delivered in order; with the default 20 ms lag some are late (4 %)."""
    drive = standard_drive(seed=3, duration=4.0)
    rng = np.random.default_rng(25)
    n = len(drive.inputs) + len(drive.measurements)
    delays = 0.005 + np.minimum(np.abs(rng.normal(0.0, 0.012, n)), 0.04)
    ekf, reordered = _replay(drive, delays, lag=0.05)
    in_order_ekf, in_order = _replay(drive, np.zeros(n), lag=0.05)
    assert ekf.diagnostics.late == 0
    assert ekf.diagnostics.processed == in_order_ekf.diagnostics.processed
    assert len(reordered) == len(in_order) > 200
    for (t, x), (t_ref, x_ref) in zip(reordered, in_order, strict=True):
        assert t == t_ref
        np.testing.assert_allclose(x, x_ref, rtol=0, atol=1e-9)
    short_lag, _ = _replay(drive, delays, lag=0.02)
    assert short_lag.diagnostics.late > 0.02 * n
