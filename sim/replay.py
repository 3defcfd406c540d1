"""A simulated run fed to an estimator as it would arrive live, and its errors.

:func:`replay` delivers a run's measurements (and commanded inputs) at their stamps and asks the
estimator for the state on a regular grid, timing each update; :func:`errors` and :func:`rmse`
compare the estimates with the run's truth. The estimation benchmarks and the estimator tests
share these (a test takes its scenario from here, not from benchmark code).
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from crs_core.analysis.metrics import STATE_NAMES, state_errors, state_rmse
from crs_core.analysis.statistics import summary
from crs_core.estimation.base import Estimator
from crs_core.measurements import in_stamp_order
from sim.simulator import SimulationResult

#: Initial estimate error of the standard runs: x, y (m), yaw (rad), vx, vy, omega.
INITIAL_ERROR = np.array([0.1, -0.1, 0.2, 0.0, 0.0, 0.0])
#: RMSE is taken after this settling time, s.
SETTLING_S = 2.0


@dataclass
class Run:
    """Estimates of one estimator over one simulated run."""

    stamps: np.ndarray
    estimates: np.ndarray
    update_times_s: np.ndarray
    statuses: list[str]


def stream_events(result: SimulationResult, inputs: bool = True) -> list[tuple[float, object]]:
    """The run's data as ``(arrival time, item)`` in stamp order, arriving at their stamps.

    Commanded inputs come before measurements of the same stamp; ``inputs=False`` leaves them
    out (a recording without commands).
    """
    events = in_stamp_order(result.measurements, result.inputs if inputs else ())
    return [(item.stamp, item) for item in events]


def replay_schedule(
    estimator: Estimator,
    deliveries: Sequence[tuple[float, object]],
    queries: Sequence[tuple[float, float]],
    x0: np.ndarray | None,
    on_update: Callable[[float], None] | None = None,
) -> Run:
    """Feed ``deliveries`` in their order and ask for estimates as ``queries`` say.

    ``deliveries`` are ``(arrival time, item)`` (an :class:`InputSample` or a
    :class:`Measurement`) with non-decreasing arrival times; ``queries`` are ``(query time,
    stamp asked)``, by query time. Before each query every item that has arrived by its query
    time is delivered, then ``estimate(stamp asked)`` is called. ``x0=None`` is a blind start
    (``reset(0.0)``). The per-update time includes the delivery work.
    """
    if x0 is None:
        estimator.reset(0.0)
    else:
        estimator.reset(0.0, x0)
    stamps, estimates, times, statuses = [], [], [], []
    k = 0
    for now, asked in queries:
        start = time.perf_counter()
        while k < len(deliveries) and deliveries[k][0] <= now:
            estimator.add(deliveries[k][1])
            k += 1
        estimate = estimator.estimate(asked)
        times.append(time.perf_counter() - start)
        stamps.append(asked)
        estimates.append(estimate.x)
        statuses.append(estimate.status)
        if on_update:
            on_update(asked)
    return Run(np.array(stamps), np.array(estimates), np.array(times), statuses)


def query_grid(result: SimulationResult, rate_hz: float) -> np.ndarray:
    """The regular query stamps ``1/rate_hz, 2/rate_hz, ...`` before the end of the run."""
    return np.arange(1.0 / rate_hz, result.duration, 1.0 / rate_hz)


def replay(
    estimator: Estimator,
    result: SimulationResult,
    rate_hz: float,
    x0: np.ndarray | None,
    on_update: Callable[[float], None] | None = None,
    *,
    inputs: bool = True,
) -> Run:
    """Feed a run to an estimator as it would arrive live and query it at ``rate_hz``.

    Data stamped up to each query time is delivered before the query, so the per-update time
    includes the work on the measurements that arrived since the previous query.

    Parameters
    ----------
    x0 : array or None
        Start state at t = 0; ``None`` starts blind (``reset(0.0)``): the estimator initialises
        itself from Lighthouse pose fixes and is ``lost`` until then.
    inputs : bool
        ``False`` withholds the commanded inputs (as in a recording without commands).
    """
    grid = query_grid(result, rate_hz)
    return replay_schedule(
        estimator, stream_events(result, inputs), [(t, t) for t in grid], x0, on_update
    )


def errors(run: Run, result: SimulationResult) -> np.ndarray:
    """Estimate minus truth at the query stamps (yaw wrapped), shape (n, 6)."""
    return state_errors(run.estimates, result.truth_at(run.stamps))


def rmse(run: Run, result: SimulationResult, after: float = SETTLING_S) -> dict[str, float]:
    """Root-mean-square error per state after the settling time, SI units."""
    values = state_rmse(run.estimates, result.truth_at(run.stamps), run.stamps >= after)
    return {name: values[name] if values else math.nan for name in STATE_NAMES}


def time_summary(seconds: Sequence[float]) -> dict[str, float]:
    return summary(np.asarray(seconds) * 1e3, ("median", "p95", "p99", "max"), digits=4)


def start_state(result: SimulationResult) -> np.ndarray:
    """The standard wrong initial estimate: truth at t = 0 plus :data:`INITIAL_ERROR`."""
    return result.truth_x[0] + INITIAL_ERROR
