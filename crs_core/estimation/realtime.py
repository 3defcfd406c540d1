"""The real-time policy around an estimator: when to ask it for what, on a live stream.

:class:`RealtimeEstimator` is what a live loop (the ROS estimator node) drives: every arriving
measurement or command goes to :meth:`~RealtimeEstimator.deliver`, and a timer at ``rate_hz``
calls :meth:`~RealtimeEstimator.update`, which asks the estimator for the state at
``now - lag``. What it decides:

* **Start.** Nothing is estimated before the first measurement arrived (a controller must not
  drive on a guess with no data behind it); data are buffered until then. The estimator starts
  at the first update after it, at ``now - lag`` taken at the tick's scheduled time (``now``
  minus the tick's lateness), on the buffered data stamped from then on and the command in effect
  then (:func:`~crs_core.measurements.from_start`), from ``initial_state`` or blind.
* **Query grid.** Every later query is at the newest time of a grid of ``1 / rate_hz`` anchored
  at the start by ``now - lag`` (a query this close, :data:`GRID_TOLERANCE` of a period, before a
  grid time is asked at it): the MHE's nodes sit on that grid, and a query between two nodes costs
  an EKF pass over the data since the newer one.
* **Adaptive lag.** With ``max_lag > lag`` the lag is raised to cover the largest arrival delay
  (arrival minus stamp) of the last :data:`LAG_WINDOW_S` s plus :data:`LAG_MARGIN_S`, up to
  ``max_lag``, so that reordered and late data arrive before their time is processed; it decays
  back once the window has no such delay.
* **Late data.** Data stamped before what the estimator already processed are dropped by it and
  counted (its ``diagnostics.late``); each drop is reported.
* **Clock jumps.** A query time more than :data:`CLOCK_JUMP_S` before the previous one (a looped
  bag replay with ``/clock``) restarts the estimator, blind, on the data that follow.
* **Deadlines.** An update slower than the period counts as a deadline miss.

Nothing here logs: what happened comes back as data (:class:`UpdateResult`,
:class:`RealtimeWarning`) for the caller to publish and log. Times are in s on the stream's
clock; arrival times on the same clock as the stamps.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from crs_core.estimation.base import Estimate, Estimator, checked_initial_state
from crs_core.measurements import InputSample, Measurement, from_start
from crs_core.settings import Settings, non_negative, positive

__all__ = [
    "CLOCK_JUMP_S",
    "GRID_TOLERANCE",
    "LAG_MARGIN_S",
    "LAG_WINDOW_S",
    "RealtimeEstimator",
    "RealtimeSettings",
    "RealtimeWarning",
    "UpdateResult",
    "WindowMax",
]

#: A clock that goes back by more than this (s) restarts the estimator (a looped replay).
CLOCK_JUMP_S = 0.5
#: A query this close (in periods) before the next grid time is asked at that time.
GRID_TOLERANCE = 0.05
#: The lag covers the largest arrival delay (receipt minus stamp) of the last this many s ...
LAG_WINDOW_S = 5.0
#: ... plus this margin, s.
LAG_MARGIN_S = 0.005


class WindowMax:
    """The largest value added in the last ``window`` s (whole seconds of buckets)."""

    def __init__(self, window: float) -> None:
        self._buckets: dict[int, float] = {}
        self._window = math.ceil(window)

    def add(self, now: float, value: float) -> None:
        """Add ``value`` observed at time ``now`` (s)."""
        second = math.floor(now)
        if value > self._buckets.get(second, -math.inf):
            self._buckets[second] = value
            if len(self._buckets) > self._window + 1:
                self._buckets = {
                    k: v for k, v in self._buckets.items() if k > second - self._window
                }

    def value(self, now: float) -> float:
        """The largest value of the window ending at ``now`` (-inf: none)."""
        oldest = math.floor(now) - self._window
        return max((v for k, v in self._buckets.items() if k > oldest), default=-math.inf)


@dataclass(frozen=True)
class RealtimeSettings(Settings):
    """Timing of :class:`RealtimeEstimator`.

    Attributes
    ----------
    rate_hz : float
        Update rate, Hz: the query grid's spacing is ``1 / rate_hz`` s and an update slower than
        that is a deadline miss.
    lag : float
        Estimate this far in the past, s (lets data in flight arrive first; must exceed the
        transport latency).
    max_lag : float
        The lag may rise up to this for late data, s (below ``lag``: the lag stays). For an EKF,
        which drops late data; the MHE takes them into its window at its next update.
    """

    rate_hz: float = positive(60.0)
    lag: float = non_negative(0.02)
    max_lag: float = non_negative(0.0)


@dataclass(frozen=True)
class RealtimeWarning:
    """Something the caller should log (throttled per kind).

    Attributes
    ----------
    kind : str
        ``"late"`` (data dropped: late, out of order, or of a sensor the model lacks),
        ``"deadline"`` (an update over the period), ``"lag"`` (the lag was raised),
        ``"status"`` (the estimate is not ok, or could not be computed) or ``"restart"``.
    message : str
        One line saying what and why.
    """

    kind: str
    message: str


@dataclass(frozen=True)
class UpdateResult:
    """What one :meth:`RealtimeEstimator.update` did.

    Attributes
    ----------
    t : float
        The query time of this update, s.
    queried : bool
        The estimator was started or asked at ``t`` (to be logged as a query, with
        :attr:`RealtimeEstimator.oldest` and :attr:`RealtimeEstimator.newest`, so that a
        recording replays exactly).
    started : bool
        The estimator was started at ``t`` by this update.
    initial : numpy.ndarray or None
        Started from this state (6,) at ``t`` (None: not started, or started blind).
    estimate : Estimate or None
        The estimate at ``t`` (None: none asked, or it failed).
    elapsed : float
        Wall time of the estimator's call, s (0 without one).
    warnings : tuple of RealtimeWarning
    """

    t: float
    queried: bool = False
    started: bool = False
    initial: np.ndarray | None = None
    estimate: Estimate | None = None
    elapsed: float = 0.0
    warnings: tuple[RealtimeWarning, ...] = ()


class RealtimeEstimator:
    """An :class:`~crs_core.estimation.base.Estimator` driven by a live clock.

    Parameters
    ----------
    estimator : Estimator
        The EKF or MHE (or any estimator of the interface).
    settings : RealtimeSettings, optional
    initial_state : array_like, optional
        State ``[x, y, yaw, vx, vy, omega]`` to start from; None: start blind (from the
        Lighthouse). A restart after a clock jump is blind when the estimator has the
        Lighthouse or pose sensors.
    timer : callable, optional
        Wall clock measuring the update's duration (s; default :func:`time.perf_counter`).
    """

    def __init__(
        self,
        estimator: Estimator,
        settings: RealtimeSettings | None = None,
        initial_state: ArrayLike | None = None,
        timer: Callable[[], float] = time.perf_counter,
    ) -> None:
        self.estimator = estimator
        self.settings = settings or RealtimeSettings()
        s = self.settings
        self.initial = None if initial_state is None else checked_initial_state(initial_state)
        self.period = 1.0 / s.rate_hz
        self.lag = s.lag
        self.max_lag = max(s.lag, s.max_lag)
        #: whether arrival delays are tracked (the lag can rise): ``deliver`` then needs ``now``
        self.tracks_delays = self.max_lag > self.lag
        #: the lag in use, s: ``lag`` raised while data arrive late (up to ``max_lag``)
        self.current_lag = self.lag
        self._timer = timer
        self._delays = WindowMax(LAG_WINDOW_S)
        #: the newest stamp delivered per source (e.g. topic) since the (re)start, s
        self.newest: dict[str, float] = {}
        #: the stamp of the first item delivered per source since the (re)start, s (a bag of
        #: the stream may begin earlier: its recorder subscribed first)
        self.oldest: dict[str, float] = {}
        self.started = False
        self.restarts = 0
        self.updates = 0
        self.deadline_misses = 0
        #: CPU time of this thread spent in the estimator's updates so far, s (its own cost,
        #: whatever else the machine does)
        self.update_cpu_seconds = 0.0
        self._max_update_time = 0.0
        self._buffer: list[tuple[Measurement | InputSample, float | None]] = []
        self._buffered_measurement = False
        self._last_query = -math.inf
        self._grid_origin = 0.0

    # --- stream in ----------------------------------------------------------------------
    def deliver(
        self, item: Measurement | InputSample, now: float | None = None, source: str = ""
    ) -> RealtimeWarning | None:
        """Take an arrived measurement or command: into the estimator, or a buffer until it
        starts.

        Parameters
        ----------
        item : Measurement or InputSample
        now : float, optional
            Its arrival time, s (needed only when :attr:`tracks_delays`).
        source : str, optional
            Where it came from (e.g. a topic): :attr:`newest` keeps its newest stamp,
            :attr:`oldest` its first.

        Returns
        -------
        RealtimeWarning or None
            Why it was dropped (late, or a sensor the model does not have).
        """
        if source:
            newest = self.newest.get(source)
            if newest is None or item.stamp > newest:
                self.newest[source] = item.stamp
            self.oldest.setdefault(source, item.stamp)
        if not self.started:
            self._buffer.append((item, now))
            if not self._buffered_measurement and isinstance(item, Measurement):
                self._buffered_measurement = True
            return None
        return self._ingest(item, now)

    def _ingest(self, item: Measurement | InputSample, now: float | None) -> RealtimeWarning | None:
        if self.tracks_delays and now is not None:
            self._delays.add(now, now - item.stamp)
        diagnostics = self.estimator.diagnostics
        late_before = diagnostics.late
        try:
            self.estimator.add(item)
        except ValueError as error:  # a sensor the model does not have
            return RealtimeWarning("late", f"dropped: {error}")
        if diagnostics.late > late_before:
            return RealtimeWarning(
                "late",
                f"dropped out-of-order data stamped {item.stamp:.3f} s: older than what the "
                "estimator already processed",
            )
        return None

    # --- the timer ------------------------------------------------------------------------
    def update(
        self,
        now: float,
        tick_lateness: float = 0.0,
        drain: Callable[[], object] | None = None,
    ) -> UpdateResult:
        """The timer's tick at ``now`` (s): start the estimator, or estimate at the query time.

        Parameters
        ----------
        now : float
            The clock, s.
        tick_lateness : float
            How late this tick fired after its scheduled time, s (used at the start only: the
            grid is anchored at the scheduled time; clamped to ``[0, period]``).
        drain : callable, optional
            Called after the clock check and before the estimator is asked, to deliver
            everything that has arrived (a ROS node's pending messages).
        """
        warnings: list[RealtimeWarning] = []
        t = self._query_time(now, tick_lateness, warnings)
        if self.started and t < self._last_query - CLOCK_JUMP_S:
            self._restart(f"the clock jumped back by {self._last_query - t:.2f} s", warnings)
        if drain is not None:
            drain()
        if not self.started:
            if not self._buffered_measurement:  # no data yet: never a guess with none behind
                return UpdateResult(t, warnings=tuple(warnings))
            return self._start(t, warnings)
        if t <= self._last_query:
            return UpdateResult(t, warnings=tuple(warnings))
        self._last_query = t
        started, cpu_started = self._timer(), time.thread_time()
        try:
            estimate = self.estimator.estimate(t)
        except ValueError as error:  # e.g. a clock that jumped back: say so, keep running
            warnings.append(RealtimeWarning("status", f"no estimate at {t:.3f} s: {error}"))
            return UpdateResult(t, queried=True, warnings=tuple(warnings))
        elapsed = self._timer() - started
        self.update_cpu_seconds += time.thread_time() - cpu_started
        self.updates += 1
        self._max_update_time = max(self._max_update_time, elapsed)
        if elapsed > self.period:
            self.deadline_misses += 1
            warnings.append(
                RealtimeWarning(
                    "deadline",
                    f"update took {1e3 * elapsed:.0f} ms, over the {1e3 * self.period:.0f} ms "
                    f"period ({self.deadline_misses} misses): the next one estimates at the "
                    "newest time",
                )
            )
        if estimate.status != "ok":
            warnings.append(RealtimeWarning("status", f"estimate {estimate.summary}"))
        return UpdateResult(
            t, queried=True, estimate=estimate, elapsed=elapsed, warnings=tuple(warnings)
        )

    def take_max_update_time(self) -> float:
        """The longest update since the last call, s (0 without one)."""
        longest, self._max_update_time = self._max_update_time, 0.0
        return longest

    def _query_time(self, now: float, tick_lateness: float, warnings: list) -> float:
        """``now - lag`` on the grid of the timer's schedule: the start is taken at its tick's
        scheduled time (``now`` minus the tick's lateness), and every later query at the
        newest grid time by ``now - lag``: on a node, never later than before by more than
        :data:`GRID_TOLERANCE` of a period, earlier only by the start tick's lateness (a query
        between nodes would cost the MHE an EKF pass over the data since the newer one, whose
        length would otherwise be set by how late the start's tick happened to fire: up to a
        whole period, a quarter of the estimator's CPU)."""
        period = self.period
        lag = self.lag
        if self.tracks_delays:
            delay = self._delays.value(now)
            lag = min(max(self.lag, delay + LAG_MARGIN_S), self.max_lag)
            if lag > self.current_lag + LAG_MARGIN_S:
                warnings.append(
                    RealtimeWarning(
                        "lag",
                        f"data arrive up to {1e3 * delay:.0f} ms after their stamps: estimating "
                        f"{1e3 * lag:.0f} ms in the past (max_lag {1e3 * self.max_lag:.0f} ms)",
                    )
                )
        self.current_lag = lag
        raw = now - lag
        if not self.started:
            return raw - min(max(tick_lateness, 0.0), period)
        steps = math.floor((raw - self._grid_origin) / period + GRID_TOLERANCE)
        return self._grid_origin + steps * period

    def _start(self, t: float, warnings: list) -> UpdateResult:
        """Start at ``t`` on the buffered data, with the command in effect then."""
        # a restart is blind when the estimator can initialise itself (Lighthouse or pose)
        blind = self.initial is None or (
            self.restarts > 0 and bool(self.estimator.sensors & {"lh", "pose"})
        )
        start_state = None if blind else self.initial
        self.estimator.reset(t, start_state)
        self.started = True
        self._grid_origin = t
        self._last_query = t
        # data still in flight from before a clock jump lie in the future: not ours
        horizon = t + self.lag + CLOCK_JUMP_S
        arrived = {id(item): now for item, now in self._buffer if item.stamp <= horizon}
        buffered = [item for item, _ in self._buffer if id(item) in arrived]
        for item in from_start(buffered, t):
            warning = self._ingest(item, arrived.get(id(item)))
            if warning is not None:
                warnings.append(warning)
        self._buffer.clear()
        self._buffered_measurement = False
        initial = None if start_state is None else start_state.copy()
        return UpdateResult(
            t, queried=True, started=True, initial=initial, warnings=tuple(warnings)
        )

    def _restart(self, why: str, warnings: list) -> None:
        """Start over on the data that come next (the Lighthouse initialises it when the
        estimator has it; else ``initial_state``), e.g. when a looped bag replay with
        ``/clock`` jumps back in time: continuing would call everything that follows late."""
        self.restarts += 1
        self.started = False
        self._buffer.clear()
        self._buffered_measurement = False
        self.newest.clear()
        self.oldest.clear()
        warnings.append(
            RealtimeWarning("restart", f"{why}: restarting the estimator (restart {self.restarts})")
        )
